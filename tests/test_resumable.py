"""Forward solves in saved segments (`hyperoc.dynamics.resumable.run_resumable`): an interrupted run
resumed from its folder ends bitwise equal to one that ran through, on the chord-Newton sparse path (a
kept factorization would otherwise differ) and on the compiled 1D path; a folder of another solve is
refused."""

import numpy as np
import pytest

import hyperoc as ho
from hyperoc.dynamics import resumable
from hyperoc.errors import InputError, SolverError
from hyperoc.fem.geometry import annulus
from hyperoc.solvers.linsolve import SparseSolver


@pytest.fixture(scope="module")
def problem():
    mesh = annulus(0.5, 1.0, structured=True, n_radial=3, n_theta=16)
    control = ho.BodyForce(ho.Region("sector", r_range=(0.5, 0.7), theta_range=(-np.pi, np.pi)))
    model = ho.StateModel(mesh, ho.SaintVenantKirchhoff(0.05, 0.05), damping=2e-3, control=control)
    grid = ho.uniform_grid(T=1.0, dt=0.05)
    xi = 0.2 * np.sin(np.pi * grid.t / 2)[:, None] ** 2 * np.ones((1, model.control.size))
    return model, grid, xi


def stepper(model):
    return ho.TimeStepper(model, ho.Scheme(), SparseSolver(model, "lu"))


class Interrupted(Exception):
    pass


def test_an_interrupted_run_resumes_bitwise_equal_to_an_uninterrupted_one(problem, tmp_path, monkeypatch):
    model, grid, xi = problem
    through = resumable.run_resumable(stepper(model), grid, xi, folder=tmp_path / "through", every=6)
    solve, calls = resumable._solve_segment, []

    def dies_at_the_third_segment(*args):
        calls.append(1)
        if len(calls) == 3:
            raise Interrupted
        return solve(*args)

    monkeypatch.setattr(resumable, "_solve_segment", dies_at_the_third_segment)
    with pytest.raises(Interrupted):
        resumable.run_resumable(stepper(model), grid, xi, folder=tmp_path / "cut", every=6)
    assert sorted(p.name for p in (tmp_path / "cut").glob("segment_*")) == ["segment_00000.npz", "segment_00001.npz"]
    monkeypatch.setattr(resumable, "_solve_segment", solve)
    resumed = resumable.run_resumable(stepper(model), grid, xi, folder=tmp_path / "cut", every=6)
    for name in ("y0", "y1", "p_steps", "pressure", "newton_iterations"):
        np.testing.assert_array_equal(getattr(resumed, name), getattr(through, name))
    # and it is the solve `run` makes, to the chord stopping test's tolerance (refreshed factorizations
    # at the segments' starts change the iterates, not the solution)
    plain = stepper(model).run(grid, xi, diagnose=False)
    assert np.max(np.abs(resumed.y0 - plain.y0)) <= 1e-10 * np.max(np.abs(plain.y0))


def test_the_compiled_1d_path_resumes_bitwise_too(tmp_path):
    model = ho.StateModel(ho.interval(40), ho.SaintVenantKirchhoff(0.05, 0.05), damping=2e-4,
                          control=ho.BodyForce(ho.Region("box", lower=(0.5,), upper=(0.9,))))
    grid = ho.uniform_grid(T=2.0, dt=0.05)
    xi = 0.05 * np.sin(np.pi * grid.t)[:, None] * np.ones((1, model.control.size))
    st = ho.TimeStepper(model)
    assert st.solver.traced
    through = resumable.run_resumable(st, grid, xi, folder=tmp_path / "a", every=13)
    resumable.run_resumable(st, ho.TimeGrid(grid.t), xi, folder=tmp_path / "b", every=13)
    (tmp_path / "b" / "segment_00002.npz").unlink()  # as if stopped after two segments
    resumed = resumable.run_resumable(st, grid, xi, folder=tmp_path / "b", every=13)
    np.testing.assert_array_equal(resumed.pressure, through.pressure)
    np.testing.assert_array_equal(resumed.y0, through.y0)


def test_a_folder_of_another_solve_is_refused(problem, tmp_path):
    model, grid, xi = problem
    resumable.run_resumable(stepper(model), grid, xi, folder=tmp_path, every=10)
    with pytest.raises(InputError, match="another solve.*data_sha256"):
        resumable.run_resumable(stepper(model), grid, 2 * xi, folder=tmp_path, every=10)
    with pytest.raises(InputError, match="every"):
        resumable.run_resumable(stepper(model), grid, xi, folder=tmp_path, every=5)


def test_a_failing_step_is_named_and_the_segments_before_it_stay(problem, tmp_path):
    model, grid, _ = problem
    crush = -50.0 * np.ones((grid.t.size, model.control.size))
    with pytest.raises(SolverError) as failure:
        resumable.run_resumable(stepper(model), grid, crush, folder=tmp_path, every=2)
    step = failure.value.step
    assert len(list(tmp_path.glob("segment_*.npz"))) == step // 2 + 1

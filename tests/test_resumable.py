"""Forward solves in saved segments (`hyperoc.dynamics.resumable.run_resumable`): an interrupted run
resumed from its folder ends bitwise equal to one that ran through, on the chord-Newton sparse path (a
kept factorization would otherwise differ) and on the compiled 1D path; a folder of another solve is
refused."""

from pathlib import Path

import numpy as np
import pytest

import hyperoc as ho
from hyperoc.dynamics import resumable
from hyperoc.errors import InputError, SolverError
from hyperoc.fem.geometry import annulus
from hyperoc.solvers.linsolve import SparseSolver

ROOT = Path(__file__).resolve().parents[1]


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
    through = resumable.run_resumable(stepper(model), grid, xi, segments=resumable.Segments(tmp_path / "through", 6))
    solve, calls = resumable._solve_segment, []

    def dies_at_the_third_segment(*args):
        calls.append(1)
        if len(calls) == 3:
            raise Interrupted
        return solve(*args)

    monkeypatch.setattr(resumable, "_solve_segment", dies_at_the_third_segment)
    with pytest.raises(Interrupted):
        resumable.run_resumable(stepper(model), grid, xi, segments=resumable.Segments(tmp_path / "cut", 6))
    assert sorted(p.name for p in (tmp_path / "cut").glob("segment_*")) == ["segment_00000.npz", "segment_00001.npz"]
    monkeypatch.setattr(resumable, "_solve_segment", solve)
    resumed = resumable.run_resumable(stepper(model), grid, xi, segments=resumable.Segments(tmp_path / "cut", 6))
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
    through = resumable.run_resumable(st, grid, xi, segments=resumable.Segments(tmp_path / "a", 13))
    resumable.run_resumable(st, ho.TimeGrid(grid.t), xi, segments=resumable.Segments(tmp_path / "b", 13))
    (tmp_path / "b" / "segment_00002.npz").unlink()  # as if stopped after two segments
    resumed = resumable.run_resumable(st, grid, xi, segments=resumable.Segments(tmp_path / "b", 13))
    np.testing.assert_array_equal(resumed.pressure, through.pressure)
    np.testing.assert_array_equal(resumed.y0, through.y0)


def test_a_folder_of_another_solve_is_refused(problem, tmp_path):
    model, grid, xi = problem
    resumable.run_resumable(stepper(model), grid, xi, segments=resumable.Segments(tmp_path, 10))
    with pytest.raises(InputError, match="another solve.*data_sha256"):
        resumable.run_resumable(stepper(model), grid, 2 * xi, segments=resumable.Segments(tmp_path, 10))
    with pytest.raises(InputError, match="every"):
        resumable.run_resumable(stepper(model), grid, xi, segments=resumable.Segments(tmp_path, 5))


def test_a_failing_step_is_named_and_the_segments_before_it_stay(problem, tmp_path):
    model, grid, _ = problem
    crush = -50.0 * np.ones((grid.t.size, model.control.size))
    with pytest.raises(SolverError) as failure:
        resumable.run_resumable(stepper(model), grid, crush, segments=resumable.Segments(tmp_path, 2))
    step = failure.value.step
    assert len(list(tmp_path.glob("segment_*.npz"))) == step // 2 + 1


SIMULATE_1D = ["examples/simulate-1d.toml", "--set", "dynamics.T=2.0", "--set", "output.checkpoint_every=20",
               "--no-progress"]


def test_simulate_resume_continues_a_checkpointed_run_to_the_same_results(tmp_path, monkeypatch):
    """``hyperoc simulate --resume OUT`` on a folder holding the first segments of a run (as a killed run leaves
    it) solves the rest and writes results bitwise equal to those of the run that went through."""
    import shutil

    from hyperoc.app.cli import main
    from hyperoc.io import read_npz

    monkeypatch.chdir(ROOT)
    through, stopped = tmp_path / "through", tmp_path / "stopped"
    assert main(["simulate", *SIMULATE_1D, "--out", str(through)]) == 0
    segments = sorted((through / "segments").glob("segment_*.npz"))
    assert len(segments) == 5
    (stopped / "segments").mkdir(parents=True)
    shutil.copy(through / "config.toml", stopped / "config.toml")
    for path in [through / "segments" / "problem.json", *segments[:2]]:
        shutil.copy(path, stopped / "segments" / path.name)
    assert main(["simulate", "--resume", str(stopped), "--no-progress"]) == 0
    a, b = read_npz(through / "results.npz"), read_npz(stopped / "results.npz")
    for key in ("t", "p", "displacement", "velocity", "volume"):
        assert np.array_equal(a[key], b[key]), key


def test_simulate_refuses_to_mix_or_resume_what_is_not_a_checkpointed_run(tmp_path, monkeypatch, capsys):
    """A folder holding checkpoints needs --resume; --resume needs checkpoints and takes no --set: exit 2, one line."""
    from hyperoc.app.cli import main

    monkeypatch.chdir(ROOT)
    out = tmp_path / "run"
    (out / "segments").mkdir(parents=True)
    assert main(["simulate", *SIMULATE_1D, "--out", str(out)]) == 2
    assert "holds a checkpointed run" in capsys.readouterr().err
    plain = tmp_path / "plain"
    assert main(["simulate", "examples/simulate-1d.toml", "--set", "dynamics.T=0.1", "--out", str(plain),
                 "--no-progress"]) == 0
    assert main(["simulate", "--resume", str(plain)]) == 2
    assert "no [output] checkpoint_every" in capsys.readouterr().err
    assert main(["simulate", "--resume", str(plain), "--set", "dynamics.T=0.2"]) == 2
    assert "--set would change it" in capsys.readouterr().err
    assert main(["simulate", "--resume", str(tmp_path / "none")]) == 2

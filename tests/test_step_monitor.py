"""The time stepper's per-step monitor (`TimeStepper.run(monitor=)`, `hyperoc.dynamics.stepper.StepRecord`).

A monitor sees each step as it ends, with the values the solution keeps afterwards (Newton
iterations, min det F, the step multiplier, the volume drift), and a failing step before the solve
raises. With a traced linear solver the monitor makes the steps run from Python (`_jit_step`)
instead of one compiled `lax.scan`; both evaluate the same step function, so they agree to the
Newton tolerance: each step stops when ``|du|_inf <= rtol |u|_inf + atol`` and the error left after
a quadratically converging last update is far below that increment, so N steps of a damped,
stable scheme differ by at most ``N (rtol max|u| + atol)``.
"""

import math

import numpy as np
import pytest

from hyperoc.dynamics.stepper import MARCH_BLOCK, Scheme, StepStatus, TimeStepper
from hyperoc.dynamics.timegrid import uniform_grid
from hyperoc.errors import SolverError
from hyperoc.fem import geometry
from hyperoc.fem.mesh import interval
from hyperoc.mechanics.controls import ActiveStress, BodyForce, Region
from hyperoc.mechanics.materials import SaintVenantKirchhoff
from hyperoc.mechanics.model import StateModel
from test_regimes import constant_control

EPS = np.finfo(float).eps


@pytest.fixture(scope="module")
def bar_1d():
    """SVK bar, body force on [0.5, 1], tridiagonal (traced) solver."""
    model = StateModel(interval(50), SaintVenantKirchhoff(0.05, 0.05), damping=2e-3,
                       control=BodyForce(Region("box", lower=(0.5,), upper=(1.0,))))
    stepper = TimeStepper(model, Scheme())
    assert stepper.solver.traced
    return stepper


def check_records_match(records, sol, grid, volume_tol):
    assert [r.step for r in records] == list(range(grid.num_steps))
    assert [r.t for r in records] == list(grid.t[1:])
    assert all(r.status == "ok" for r in records)
    np.testing.assert_array_equal([r.newton_iterations for r in records], sol.newton_iterations)
    np.testing.assert_array_equal([r.min_det_F for r in records], sol.min_det_F)
    np.testing.assert_array_equal([r.pressure for r in records], sol.p_steps)
    drift = np.abs(sol.volume[1:] - sol.volume[0]) / abs(sol.volume[0])
    np.testing.assert_allclose([r.volume_drift for r in records], drift, rtol=0, atol=volume_tol)


def test_marches_of_any_length_share_one_compiled_loop_and_change_nothing(bar_1d):
    """Every traced march runs in blocks of MARCH_BLOCK steps, the last padded with inactive steps: solves of
    two lengths that are not multiples of it, with and without a progress bar, compile one loop; a solve split
    at a level that is not a block boundary (as a shorter horizon and its continuation) gives the same
    levels bit for bit."""
    N = 2 * MARCH_BLOCK + 5
    grid = uniform_grid(N * 0.02, 0.02)
    xi = constant_control(bar_1d, grid, 0.05)
    whole = bar_1d.run(grid, xi)
    shorter = bar_1d.run(uniform_grid((N - 7) * 0.02, 0.02), xi[:N - 6])
    with_bar = bar_1d.run(grid, xi, progress=True)
    for name in ("y0", "y1", "p_steps", "newton_iterations", "min_det_F"):
        np.testing.assert_array_equal(getattr(with_bar, name), getattr(whole, name))
        np.testing.assert_array_equal(getattr(shorter, name), getattr(whole, name)[:len(getattr(shorter, name))])
    assert bar_1d._block_scan._cache_size() == 1
    k = MARCH_BLOCK + 3  # continue from level k with its multiplier as Newton's first guess
    rest = bar_1d.march(whole.y0[k], whole.y1[k], whole.p_steps[k - 1], xi[k:], np.zeros((N + 1 - k, bar_1d.model.n)),
                        grid.t[k:], bar_1d.deformed_volume(whole.y0[0]))
    np.testing.assert_array_equal(rest[0], whole.y0[k + 1:])
    np.testing.assert_array_equal(rest[2], whole.p_steps[k:])
    assert bar_1d._block_scan._cache_size() == 1


def test_monitor_sees_every_step_and_leaves_the_scanned_solve_unchanged(bar_1d):
    grid = uniform_grid(2.0, 0.02)
    xi = constant_control(bar_1d, grid, 0.05)
    scanned = bar_1d.run(grid, xi)
    records = []
    looped = bar_1d.run(grid, xi, monitor=records.append)
    # Two sums of the 50 cell volumes in different orders differ by at most 50 eps relative.
    check_records_match(records, looped, grid, volume_tol=bar_1d.model.mesh.num_cells * EPS)
    sch = bar_1d.scheme
    bound = grid.num_steps * (sch.rtol * np.max(np.abs(scanned.y0)) + sch.atol)
    print(f"\nloop vs scan: |dy0| {np.max(np.abs(looped.y0 - scanned.y0)):.1e} (bound {bound:.1e})")
    assert np.max(np.abs(looped.y0 - scanned.y0)) <= bound
    assert np.max(np.abs(looped.y0)) > 1e-2  # the bar moves
    last = records[-1]
    assert last.describe() == (f"its {last.newton_iterations}, min det F {last.min_det_F:.3g}, "
                               f"dV {last.volume_drift:.1e}, p {last.pressure:.4g}")


def test_monitor_sees_the_failing_step_before_the_error(bar_1d):
    """A compressive load -0.5 inverts an element (measured: step 35, t = 0.72, det F < 0); the
    monitor's last record is that step, with the cause the error names."""
    grid = uniform_grid(2.0, 0.02)
    records = []
    with pytest.raises(SolverError) as info:
        bar_1d.run(grid, constant_control(bar_1d, grid, -0.5), monitor=records.append)
    err = info.value
    assert [r.step for r in records] == list(range(err.step + 1))
    last = records[-1]
    assert last.status == err.cause and last.t == pytest.approx(err.time, abs=1e-12)
    assert "FAILED: " + err.cause in last.describe()
    assert all(r.status == "ok" and r.min_det_F > 0 for r in records[:-1])
    if err.cause == "detF":
        assert last.min_det_F <= 0


def test_compiled_march_stops_after_the_failing_block_as_the_stepwise_one_does(bar_1d):
    """The same load failing at step 35 over 3 blocks of steps: the compiled march runs no block after the
    failing one, and its outputs are padded like the stepwise march's: the same failing step and cause,
    every later step marked as after a failure, the states equal up to the failure."""
    grid = uniform_grid(0.02 * (2 * MARCH_BLOCK + 40), 0.02)
    xi = constant_control(bar_1d, grid, -0.5)
    zero, fs = np.zeros(bar_1d.model.n), np.zeros((grid.num_steps + 1, bar_1d.model.n))
    V0 = bar_1d.deformed_volume(zero)
    blocks = []
    compiled = bar_1d.march(zero, zero, 0.0, xi, fs, grid.t, V0, on_block=blocks.append)
    stepwise = bar_1d.march_stepwise(zero, zero, 0.0, xi, fs, grid, V0, False)
    status = [np.asarray(out[4]) for out in (compiled, stepwise)]
    first = [int(np.flatnonzero(s != StepStatus.OK)[0]) for s in status]
    assert first[0] == first[1] < MARCH_BLOCK and status[0][first[0]] == status[1][first[1]] != StepStatus.OK
    assert blocks == [MARCH_BLOCK]  # the first block only
    for s in status:
        assert np.all(s[first[0] + 1:] == StepStatus.AFTER_FAILURE) and len(s) == grid.num_steps
    bound = first[0] * (bar_1d.scheme.rtol * np.max(np.abs(stepwise[0][:first[0]])) + bar_1d.scheme.atol)
    assert np.max(np.abs(compiled[0][:first[0]] - stepwise[0][:first[0]])) <= bound


@pytest.mark.slow
def test_monitor_with_host_solver_and_progress_bar_2d():
    """Annulus, P1, active stress on a quarter, sparse LU driven from Python with the progress bar:
    the records match the solution; the constraint holds at every step (as in test_volume.py:
    Newton to round-off, so 1e-10 relative is a wide margin), while det F varies by more."""
    mesh = geometry.annulus(0.5, 1.0, structured=True, n_radial=4, n_theta=32)
    control = ActiveStress(Region("sector", r_range=(0.5, 1.0), theta_range=(0.0, math.pi / 2)))
    model = StateModel(mesh, SaintVenantKirchhoff(1.0, 1.0), damping=0.05, control=control)
    stepper = TimeStepper(model, Scheme(), solver="lu")
    grid = uniform_grid(0.5, 0.05)
    xi = np.outer(0.5 * np.sin(np.pi * grid.t / 0.5), np.ones(model.control.size))
    records = []
    sol = stepper.run(grid, xi, monitor=records.append, progress=True)
    check_records_match(records, sol, grid, volume_tol=mesh.num_cells * EPS)
    assert max(r.volume_drift for r in records) <= 1e-10
    assert min(r.min_det_F for r in records) < 1 - 1e-3

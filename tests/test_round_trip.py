"""What ``optimize`` writes goes back in: its ``results.npz`` replays as ``[control] file`` with the same
pressure, and a run stopped at its iteration budget, resumed with a larger one, makes the iterates of
a run given the larger budget from the start; for 1D, 2D and 3D bodies, vector (body force) and
scalar (active stress) controls."""

import json

import numpy as np
import pytest

from helpers import small_1d_toml
from hyperoc.app.cli import main
from hyperoc.io import read_npz

COMMON = """
[material]
law = "svk"
mu = 1.0
lambda = 1.0
[dynamics]
T = 1.0
dt = 0.1
damping = 0.01
[objective]
alpha = 1e-2
[optimize]
method = "bb"
tau0 = 0.5
"""

PROBLEMS = {
    "1d-body-force": small_1d_toml(n=10, dt=0.1, lower=0.5, value=None, max_iter=2),
    "2d-body-force": """
[mesh]
kind = "rectangle"
nx = 3
[control]
kind = "body_force"
region = { kind = "box", lower = [0.5, 0.0], upper = [1.0, 1.0] }
""" + COMMON,
    "2d-active-stress": """
[mesh]
kind = "annulus"
structured = true
n_radial = 2
n_theta = 12
[control]
kind = "active_stress"
region = { kind = "sector", r_range = [0.5, 1.0], theta_range = [-0.8, 0.8] }
""" + COMMON,
    "3d-body-force": """
[mesh]
kind = "box"
nx = 2
[control]
kind = "body_force"
region = { kind = "box", lower = [0.5, 0.0, 0.0], upper = [1.0, 1.0, 1.0] }
""" + COMMON,
    "3d-active-stress": """
[mesh]
kind = "box"
nx = 2
[control]
kind = "active_stress"
region = { kind = "box", lower = [0.5, 0.0, 0.0], upper = [1.0, 1.0, 1.0] }
""" + COMMON,
}
K = 2  # iterations of the stopped run; the resumed and the uninterrupted runs make 2 K
# The 1D bar's tridiagonal full Newton solves each evaluation alike in any process: the resumed run is
# bitwise the uninterrupted one. The 2D and 3D sparse solvers use chord Newton, whose kept factorization
# depends on the evaluations the process solved before: the iterates then agree to Newton's tolerance
# (relative residual 1e-11 per step), amplified by the condition of the small tangents (< 1e3).
NEWTON_RTOL = 1e-11
ITERATE_RTOL = {"1d-body-force": 0.0}


def _optimize(cfg, out, max_iter: int):
    code = main(["optimize", str(cfg), "--out", str(out), "--no-progress", "--set", f"optimize.max_iter={max_iter}"])
    assert code == 0


@pytest.mark.parametrize("kind", [k if k.startswith("1d") else pytest.param(k, marks=pytest.mark.slow)
                                  for k in PROBLEMS])
def test_optimized_control_replays_and_a_stopped_run_extends(tmp_path, kind):
    cfg = tmp_path / "c.toml"
    cfg.write_text(PROBLEMS[kind])
    stopped, whole, replay = tmp_path / "stopped", tmp_path / "whole", tmp_path / "replay"
    _optimize(cfg, stopped, K)
    optimized = read_npz(stopped / "results.npz")
    assert np.any(optimized["xi"] != 0)

    assert main(["simulate", str(cfg), "--out", str(replay), "--no-progress",
                 "--set", f'control.file="{stopped / "results.npz"}"']) == 0
    replayed = read_npz(replay / "results.npz")
    np.testing.assert_array_equal(replayed["t"], optimized["t"])
    np.testing.assert_allclose(replayed["p"], optimized["p"], rtol=0, atol=1e-12 * np.max(np.abs(optimized["p"])))

    assert main(["optimize", "--resume", str(stopped), "--no-progress", "--set", f"optimize.max_iter={2 * K}"]) == 0
    _optimize(cfg, whole, 2 * K)
    a, b = (json.loads((d / "summary.json").read_text()) for d in (stopped, whole))
    assert a["iterations"] == b["iterations"] == 2 * K or (a["converged"] and b["converged"])
    rtol = ITERATE_RTOL.get(kind, 1e3 * NEWTON_RTOL)
    for key in ("objective_history", "tau_history", "grad_norm_history"):
        np.testing.assert_allclose(a[key], b[key], rtol=rtol, atol=0, err_msg=key)
    np.testing.assert_allclose(read_npz(stopped / "results.npz")["xi"], read_npz(whole / "results.npz")["xi"],
                               rtol=rtol, atol=rtol * np.max(np.abs(read_npz(whole / "results.npz")["xi"])))

"""The end of ``hyperoc optimize``: the stop reason, and the best iterate reported, saved and
returned when the method ends below its best value."""

import json

import numpy as np

import hyperoc.app.workflows
from helpers import small_1d_toml
from hyperoc.app.cli import main
from hyperoc.control.optimize import OptimizationResult, Termination

SMALL_1D = small_1d_toml(n=10, dt=0.1, lower=0.5, value=None, max_iter=3)

VALUES = [0.5, 1.0, 3.0, 2.0]  # J at iterations 0..3: the best is iteration 2, the last is below it


def _non_monotone(problem, m0, *, callback, max_iter, **options):
    """Three iterates along a fixed direction whose recorded J rises, then falls (as Algorithm 1's
    unguarded BB steps can); ``problem``: the `BoxProblem` the workflow passes."""
    direction = problem.J.zero(0.0)
    direction.xi[:] = 1e-3
    points = [m0 + direction * k for k in range(max_iter + 1)]
    for k in range(1, max_iter + 1):
        callback(k, points[k], VALUES[k], 1.0)
    history = {"objective": VALUES, "grad_norm": [1.0] * 4, "tau": [m0.tau] * 4, "step": [1.0] * 4}
    return OptimizationResult(points[-1], VALUES[-1], max_iter, Termination.MAX_ITERATIONS, history=history)


def test_best_iterate_reported_saved_and_returned(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(hyperoc.app.workflows, "barzilai_borwein", _non_monotone)
    cfg, out = tmp_path / "c.toml", tmp_path / "out"
    cfg.write_text(SMALL_1D)
    assert main(["optimize", str(cfg), "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert "stopped: maximum number of iterations (3) reached" in printed
    assert f"best iterate: J = 3 at iteration 2 (tau = 1), above the final J = 2: {out / 'best.npz'}" in printed
    best = json.loads((out / "summary.json").read_text())["optimization"]["best"]
    assert best == {"objective": 3.0, "iteration": 2, "tau": 1.0, "file": "best.npz"}
    with np.load(out / "best.npz") as saved:  # an open file left to the GC warns in whatever test runs then
        np.testing.assert_array_equal(saved["xi"], np.full_like(saved["xi"], 2e-3))
        assert saved["objective"] == 3.0 and saved["iteration"] == 2

    from hyperoc.app.config import load_config

    _, res = hyperoc.app.workflows.optimize_single(load_config(cfg), 1.0)
    assert res.best["iteration"] == 2 and res.best["objective"] == 3.0 and res.objective == 2.0


def test_no_best_when_the_last_iterate_is_the_best(tmp_path):
    """The paper's 1D problem from rest: two BB iterations raise J every time."""
    from hyperoc.app.config import load_config

    cfg = tmp_path / "c.toml"
    cfg.write_text(SMALL_1D.replace("max_iter = 3", "max_iter = 2"))
    _, res = hyperoc.app.workflows.optimize_single(load_config(cfg), 1.0)
    assert res.best is None and res.objective == max(res.history["objective"])

"""Multi-start over tau0 on a local Dask cluster: every start reported, best one kept, resume skips done starts."""

import tomllib

import pytest

from hyperoc.app.config import parse_config
from hyperoc.app.workflows import optimize
from hyperoc.io import read_json

TEXT = """
[mesh]
kind = "interval"
n = 10
[material]
law = "neo-hookean"
mu = 0.05
lambda = 0.05
[dynamics]
T = 2.0
dt = 0.1
damping = 2e-3
[control]
kind = "body_force"
region = { kind = "box", lower = [0.25], upper = [0.5] }
[objective]
alpha = 0.1
[optimize]
tau_starts = [0.6, 1.2]
max_iter = 3
"""


@pytest.mark.slow
def test_multistart_runs_every_start_and_resumes(tmp_path):
    cfg = parse_config(tomllib.loads(TEXT), tmp_path)
    summary = optimize(cfg, tmp_path / "out", workers=2)
    starts = summary["starts"]
    assert [s["tau0"] for s in starts] == [0.6, 1.2]
    assert all(s["status"] == "ok" for s in starts)
    best = max(starts, key=lambda s: s["objective"])
    assert summary["best_start"] == best["folder"] and summary["objective"] == best["objective"]
    for s in starts:
        assert (tmp_path / "out" / s["folder"] / "summary.json").exists()
    again = optimize(cfg, tmp_path / "out", workers=2)
    assert all(s.get("resumed") for s in again["starts"])
    assert read_json(tmp_path / "out" / "summary.json")["objective"] == summary["objective"]


def test_a_failing_start_is_reported_not_fatal(tmp_path):
    """What a Dask worker runs for one start: an error becomes a 'failed' record with its message."""
    from hyperoc.app.workflows import _run_start

    cfg = parse_config(tomllib.loads(TEXT), tmp_path)
    record = _run_start(cfg.sections, str(tmp_path), 5.0, str(tmp_path / "start_bad"))  # tau0 outside (0, T)
    assert record["status"] == "failed" and "tau" in record["error"]

"""A damaged entry of the optimizer's evaluation cache is reported, dropped and recomputed: on
``--resume`` (with the count of what is cached and done) and inside a run."""

import json
import re

import numpy as np
import pytest

from helpers import small_1d_toml
from hyperoc.app.cli import main
from hyperoc.control.optimize import EvaluationCache
from hyperoc.control.reduced import ControlPoint
from hyperoc.io import read_npz

SMALL_1D = small_1d_toml(n=10, dt=0.1, lower=0.5, value=None, max_iter=3)


def _damage(entries: list) -> None:
    """Truncate the first entry (not a zip archive), strip the gradient from the second."""
    entries[0].write_bytes(entries[0].read_bytes()[:40])
    np.savez(entries[1], J=np.float64(1.0))


@pytest.mark.slow  # a 3-iteration optimization, then its replay
def test_resume_drops_damaged_entries_and_ends_where_the_run_ended(tmp_path, capsys):
    cfg, out = tmp_path / "c.toml", tmp_path / "out"
    cfg.write_text(SMALL_1D)
    assert main(["optimize", str(cfg), "--out", str(out), "--no-progress"]) == 0
    first = json.loads((out / "summary.json").read_text())
    xi = read_npz(out / "results.npz")["xi"]
    entries = sorted((out / "cache").glob("*.npz"))
    assert len(entries) >= 3 and first["iterations"] == 3
    _damage(entries)
    capsys.readouterr()

    assert main(["optimize", "--resume", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err.splitlines()
    dropped = [line for line in err if line.startswith("hyperoc: warning: damaged evaluation cache entry")]
    assert sorted(re.search(r"entry (\S+)", line).group(1) for line in dropped) == [str(p) for p in entries[:2]]
    assert f"resuming: {len(entries) - 2} evaluations cached, 3 iterations done" in err
    again = json.loads((out / "summary.json").read_text())
    assert again["objective"] == first["objective"] and again["tau"] == first["tau"]
    np.testing.assert_array_equal(np.load(out / "results.npz")["xi"], xi)
    assert len(list((out / "cache").glob("*.npz"))) == len(entries)  # the two recomputed


class _Linear:
    """A stand-in reduced functional: J(m) = sum(xi) + tau, gradient (1, 1), counting its calls."""

    def __init__(self):
        self.calls = 0

    def value_and_gradient(self, m):
        self.calls += 1
        return float(np.sum(m.xi) + m.tau), ControlPoint(np.ones_like(m.xi), 1.0)


@pytest.mark.parametrize("damage", ["truncated", "wrong shape", "nan"])
def test_damaged_entry_is_recomputed_inside_a_run(tmp_path, damage):
    m = ControlPoint(np.arange(6.0).reshape(3, 2), 0.5)
    EvaluationCache(_Linear(), tmp_path)(m)
    (path,) = tmp_path.glob("*.npz")
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:-10])
    else:
        gxi = np.ones((2, 3)) if damage == "wrong shape" else np.full((3, 2), np.nan)
        np.savez(path, J=np.float64(15.5), gxi=gxi, gtau=np.float64(1.0))
    J = _Linear()
    with pytest.warns(RuntimeWarning, match="damaged evaluation cache entry"):
        value, g = EvaluationCache(J, tmp_path)(m)
    assert J.calls == 1 and value == 15.5 and np.array_equal(g.xi, np.ones((3, 2)))
    assert EvaluationCache.scan(tmp_path) == (1, [])  # rewritten whole

"""An optimization killed with SIGKILL and resumed ends bitwise where an uninterrupted run ends."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hyperoc.io import read_npz

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = ["--set", "mesh.n=20", "--set", "dynamics.dt=0.1", "--set", "optimize.max_iter=8", "--no-progress"]


def _optimize(*args):
    return [sys.executable, "-m", "hyperoc.app.cli", "optimize", *args]


@pytest.mark.slow
def test_sigkill_then_resume_is_bitwise_identical(tmp_path):
    reference, killed = tmp_path / "reference", tmp_path / "killed"
    subprocess.run(_optimize("examples/paper-1d.toml", "--out", str(reference), *SETTINGS), cwd=ROOT, check=True,
                   capture_output=True)
    proc = subprocess.Popen(_optimize("examples/paper-1d.toml", "--out", str(killed), *SETTINGS), cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    cache = killed / "cache"
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline:  # kill once a few evaluations are on disk
        if cache.is_dir() and len(list(cache.glob("*.npz"))) >= 4:
            os.kill(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.05)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the run ended before it could be killed"
    assert not (killed / "results.npz").exists()
    resumed = subprocess.run(_optimize("--resume", str(killed), "--no-progress"), cwd=ROOT, check=True,
                             capture_output=True, text=True)
    assert "resuming:" in resumed.stderr
    a, b = read_npz(reference / "results.npz"), read_npz(killed / "results.npz")
    for key in ("xi", "p", "displacement"):
        assert np.array_equal(a[key], b[key])

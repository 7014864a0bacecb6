"""The persistent compilation cache that the command line turns on (`hyperoc._jax.enable_compilation_cache`)."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _simulate(tmp_path, name, example="simulate-1d.toml", **env):
    cmd = [sys.executable, "-m", "hyperoc.app.cli", "simulate", f"examples/{example}", "--out",
           str(tmp_path / name), "--no-progress", "--set", "dynamics.T=0.2"]
    inherited = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, env={**inherited, **env})


def test_a_run_fills_the_cache_and_the_next_one_reads_it(tmp_path):
    """The compiled time loop is stored under HYPEROC_CACHE_DIR, and a second run reads it instead of
    writing it again (programs compiled in under 0.1 s are stored or not depending on the machine's load,
    so only the time loop is compared)."""
    cache = tmp_path / "cache"
    loops = lambda: {p.name: p.stat().st_mtime_ns for p in cache.glob("jit_run-*")}  # noqa: E731
    _simulate(tmp_path, "first", HYPEROC_CACHE_DIR=str(cache), HYPEROC_COMPILATION_CACHE="1")
    first = loops()
    assert first
    _simulate(tmp_path, "second", HYPEROC_CACHE_DIR=str(cache), HYPEROC_COMPILATION_CACHE="1")
    assert loops() == first


def test_the_sparse_path_keeps_its_step_programs_too(tmp_path):
    """In 2D and 3D Newton runs on the host around the sparse solver, and the step's residual and Jacobian
    are programs without host callbacks (which JAX never stores): the first run stores them, the second
    reads them."""
    cache = tmp_path / "cache"
    kernels = lambda: {p.name: p.stat().st_mtime_ns for name in ("jit_residual_at", "jit_jacobian_parts")  # noqa: E731
                       for p in cache.glob(f"{name}-*")}
    env = {"HYPEROC_CACHE_DIR": str(cache), "HYPEROC_COMPILATION_CACHE": "1"}
    _simulate(tmp_path, "first", "annulus-2d.toml", **env)
    first = kernels()
    assert len(first) == 2
    _simulate(tmp_path, "second", "annulus-2d.toml", **env)
    assert kernels() == first


def test_the_cache_can_be_turned_off(tmp_path):
    cache = tmp_path / "cache"
    _simulate(tmp_path, "run", HYPEROC_CACHE_DIR=str(cache), HYPEROC_COMPILATION_CACHE="0")
    assert not cache.exists()

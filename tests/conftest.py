"""Imported by pytest before the test modules: hyperoc comes before JAX, as in the CLI and the
scripts, so the suite runs with the JAX settings the package makes on import (`hyperoc._jax`).

Two tiers: ``python -m pytest`` runs the fast tier; tests marked ``slow`` are skipped unless
``--runslow`` is given (``--runslow -m slow`` runs the slow tier alone).

The command line's persistent compilation cache is off in the tests (they run the CLI in-process and
in subprocesses, and must not depend on, or fill, the user's cache); tests of the cache turn it on.
The test processes themselves (the xdist workers) share a persistent compilation cache of their own: a
model, stepper or functional built anew in another test compiles programs of the same shapes again, and
JAX then reads the compiled programs back instead of compiling them (the same programs, so the same
results: the cache's key holds the program, the JAX and XLA versions and flags). The folder is kept in
pytest's cache, ``.pytest_cache/d/hyperoc-jax`` of the checkout (cut to `TEST_CACHE_BYTES` after each run,
the oldest programs first), so a later run of the suite compiles only what changed (and the 2D and 3D time
steps, which hold host callbacks: JAX does not store those programs); ``--cache-clear``
empties it. With pytest's cache off (``-p no:cacheprovider``) it is a temporary folder of the run.
"""

import os
import shutil
import tempfile
from pathlib import Path

import pytest

import hyperoc  # noqa: F401
from hyperoc._cache import MIN_COMPILE_SECONDS
from hyperoc._jax import jax  # after hyperoc, which sets JAX up

os.environ.setdefault("HYPEROC_COMPILATION_CACHE", "0")
_RUN_CACHE = "HYPEROC_TEST_RUN_JAX_CACHE"  # the run's folder, set by the controlling process for its workers
_TEMPORARY = "HYPEROC_TEST_RUN_JAX_CACHE_IS_TEMPORARY"
#: The fast tier's compiled programs take about 15 MB (``python bench/bench_test_tier.py``); the cap leaves
#: room for the slow tier's and for many versions of both.
TEST_CACHE_BYTES = 512 * 2**20


def pytest_configure(config):
    if not hasattr(config, "workerinput"):  # the controlling process (or the only one), before any worker starts
        cache = getattr(config, "cache", None)
        if cache is not None:
            os.environ[_RUN_CACHE] = str(cache.mkdir("hyperoc-jax"))
        else:
            os.environ[_RUN_CACHE] = tempfile.mkdtemp(prefix="hyperoc-tests-jax-")
            os.environ[_TEMPORARY] = "1"
    # JAX's configuration, not `hyperoc._jax.enable_compilation_cache`: its environment variables would reach
    # the processes the tests start, which keep the cache the tests give them
    jax.config.update("jax_compilation_cache_dir", os.environ[_RUN_CACHE])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)


def pytest_unconfigure(config):
    if not hasattr(config, "workerinput"):
        folder = os.environ.pop(_RUN_CACHE)
        if os.environ.pop(_TEMPORARY, None):
            shutil.rmtree(folder, ignore_errors=True)
        else:
            _cut_to(Path(folder), TEST_CACHE_BYTES)


def _cut_to(folder: Path, size: int) -> None:
    """Remove the oldest files of ``folder`` until the rest take at most ``size`` bytes (no worker is left
    to read or write them)."""
    files = sorted((f.stat().st_mtime, f.stat().st_size, f) for f in folder.iterdir() if f.is_file())
    total = sum(n for _, n, _ in files)
    for _, n, f in files:
        if total <= size:
            break
        f.unlink(missing_ok=True)
        total -= n


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", default=False, help="also run the tests marked slow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip_slow = pytest.mark.skip(reason="slow: needs --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip_slow)

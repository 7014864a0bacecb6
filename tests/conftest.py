"""Imported by pytest before the test modules: hyperoc comes before JAX, as in the CLI and the
scripts, so the suite runs with the JAX settings the package makes on import (`hyperoc._jax`).

Two tiers: ``python -m pytest`` runs the fast tier; tests marked ``slow`` are skipped unless
``--runslow`` is given (``--runslow -m slow`` runs the slow tier alone).

The command line's persistent compilation cache is off in the tests (they run the CLI in-process and
in subprocesses, and must not depend on, or fill, the user's cache); tests of the cache turn it on.
The test processes themselves (the xdist workers) share a persistent compilation cache of their own, a
temporary folder made for the run and removed after it: a model, stepper or functional built anew in
another test compiles programs of the same shapes again, and JAX then reads the compiled programs
back instead of compiling them (the same programs, so the same results).
"""

import os
import shutil
import tempfile

import pytest

import hyperoc  # noqa: F401
from hyperoc._cache import MIN_COMPILE_SECONDS
from hyperoc._jax import jax  # after hyperoc, which sets JAX up

os.environ.setdefault("HYPEROC_COMPILATION_CACHE", "0")
_RUN_CACHE = "HYPEROC_TEST_RUN_JAX_CACHE"  # the run's folder, set by the controlling process for its workers


def pytest_configure(config):
    if not hasattr(config, "workerinput"):  # the controlling process (or the only one), before any worker starts
        os.environ[_RUN_CACHE] = tempfile.mkdtemp(prefix="hyperoc-tests-jax-")
    # JAX's configuration, not `hyperoc._jax.enable_compilation_cache`: its environment variables would reach
    # the processes the tests start, which keep the cache the tests give them
    jax.config.update("jax_compilation_cache_dir", os.environ[_RUN_CACHE])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)


def pytest_unconfigure(config):
    if not hasattr(config, "workerinput"):
        shutil.rmtree(os.environ.pop(_RUN_CACHE), ignore_errors=True)


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", default=False, help="also run the tests marked slow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip_slow = pytest.mark.skip(reason="slow: needs --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip_slow)

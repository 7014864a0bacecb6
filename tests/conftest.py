"""Imported by pytest before the test modules: hyperoc comes before JAX, as in the CLI and the
scripts, so the suite runs with the JAX settings the package makes on import (`hyperoc._jax`).

Two tiers: ``python -m pytest`` runs the fast tier; tests marked ``slow`` are skipped unless
``--runslow`` is given (``--runslow -m slow`` runs the slow tier alone).

The command line's persistent compilation cache is off in the tests (they run the CLI in-process and
in subprocesses, and must not depend on, or fill, the user's cache); tests of the cache turn it on."""

import os

import pytest

import hyperoc  # noqa: F401

os.environ.setdefault("HYPEROC_COMPILATION_CACHE", "0")


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", default=False, help="also run the tests marked slow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip_slow = pytest.mark.skip(reason="slow: needs --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip_slow)

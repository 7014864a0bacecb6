"""Imported by pytest before the test modules: hyperoc comes before JAX, as in the CLI and the
scripts, so the suite runs with the JAX settings the package makes on import (`hyperoc._jax`)."""

import hyperoc  # noqa: F401

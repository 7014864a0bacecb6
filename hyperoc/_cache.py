"""The persistent compilation cache's directory, given to JAX through its environment variables.

Importing this module imports no JAX: a process that only starts workers (`hyperoc.app.paper`) sets the
cache up for them with `cache_environment`, and JAX reads the variables when a process imports it.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_environment", "MIN_COMPILE_SECONDS"]

#: Programs that compile faster than this are not stored (reading them back would cost about as much).
MIN_COMPILE_SECONDS = 0.1


def cache_environment(directory=None) -> Path | None:
    """Create the cache directory and point JAX's ``JAX_COMPILATION_CACHE_DIR`` at it (with
    ``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS``), for this process's JAX if it is imported later and for
    every process it starts. Returns the directory, or None when the cache is off or cannot be written.

    ``directory`` defaults to ``$HYPEROC_CACHE_DIR``, else ``$XDG_CACHE_HOME/hyperoc/jax`` (``~/.cache``
    when unset). ``HYPEROC_COMPILATION_CACHE=0`` turns the cache off.
    """
    if os.environ.get("HYPEROC_COMPILATION_CACHE", "1") == "0":
        return None
    if directory is None:
        directory = os.environ.get("HYPEROC_CACHE_DIR") or (
            Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "hyperoc" / "jax")
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:  # an unwritable cache is not a reason to fail a run: compile as without it
        return None
    os.environ["JAX_COMPILATION_CACHE_DIR"] = str(directory)
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = str(MIN_COMPILE_SECONDS)
    return directory

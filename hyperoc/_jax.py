"""JAX set-up shared by every module that traces kernels: float64 everywhere.

hyperoc needs double precision (Newton to near machine precision, Taylor tests of gradients), so
importing a module that builds JAX kernels turns on ``jax_enable_x64``; in a process pinned to one
CPU it also starts the CPU backend with a thread pool of at least two threads
(`hyperoc.solvers.threads.start_backend`: with one, host solves can deadlock).

When it is imported before JAX (``import hyperoc`` first, the CLI, the bench scripts, the tests),
it also sets ``JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS=1`` unless the environment already chooses: the
kernels close over the mesh's quadrature arrays (shape gradients, weights, gather indices: 0.1 GB
each at 80k dofs), and in JAX's default mode XLA receives them as literals of the program and
constant-folds products of them at compile time ("Constant folding an instruction is taking > 1s");
in this mode they are passed as arguments. JAX reads the variable when it is imported, so after
``import jax`` it is left alone. Results are bitwise the same; compilation is faster and needs less
memory, for a slightly slower kernel evaluation (``python bench/bench_constants.py``; the docs'
performance page).

These are the package's only global side effects at import, and they are documented in the docs.
The persistent compilation cache (`enable_compilation_cache`) is turned on by the command line,
not at import.
"""

import os
import sys

import numpy as np

if "jax" not in sys.modules:
    os.environ.setdefault("JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS", "1")

import jax  # noqa: E402  (after the environment variable, which JAX reads on import)

from .solvers.threads import start_backend  # noqa: E402

jax.config.update("jax_enable_x64", True)
start_backend()


def on_device(a, dtype=np.float64):
    """``a`` (a NumPy array, a JAX array or a number) as a JAX array of ``dtype`` (None: its own). Unlike
    ``jnp.asarray``, which compiles a conversion for each new shape (tens of milliseconds, in every
    process), a transfer."""
    return jax.device_put(np.asarray(a, dtype=dtype))


def enable_compilation_cache(directory=None):
    """Turn on JAX's persistent compilation cache: compiled XLA programs are written to ``directory``
    and reused by later processes with the same program, shapes and JAX version, so a second run of a
    job skips most of its compilation. Programs that compile in under 0.1 s are not stored.
    The directory and the switch are those of `hyperoc._cache.cache_environment`. Returns the directory
    used, or None."""
    from ._cache import MIN_COMPILE_SECONDS, cache_environment

    directory = cache_environment(directory)
    if directory is not None:
        jax.config.update("jax_compilation_cache_dir", str(directory))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    return directory


# JAX's monitoring events of one compilation: tracing to a jaxpr, lowering to MLIR, XLA's compile.
_COMPILE_EVENTS = frozenset({"/jax/core/compile/jaxpr_trace_duration",
                             "/jax/core/compile/jaxpr_to_mlir_module_duration",
                             "/jax/core/compile/backend_compile_duration"})
_compiling = {"seconds": 0.0, "count": 0}


def _on_duration(event: str, duration: float, **_) -> None:
    if event in _COMPILE_EVENTS:
        _compiling["seconds"] += duration
        _compiling["count"] += event == "/jax/core/compile/backend_compile_duration"


jax.monitoring.register_event_duration_secs_listener(_on_duration)


def compilation_clock() -> tuple[float, int]:
    """``(seconds, compilations)`` this process has spent tracing, lowering and compiling JAX programs
    since hyperoc set JAX up (a program loaded from the persistent cache counts its tracing and
    lowering only): differences of two readings time the compilation inside a run."""
    return _compiling["seconds"], _compiling["count"]

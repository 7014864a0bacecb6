"""CPU affinity of this process's threads, the size of XLA's CPU thread pool, and OpenBLAS's threads
during the host solves.

XLA sizes its CPU thread pool by the CPUs the process may run on when the backend starts. Started
with one (``taskset -c 0 ...``), the pool has a single thread, and a `jax.pure_callback` can deadlock:
the callback's operands are copied to the CPU device by a task queued on that pool, whose only thread
is the one waiting inside the callback. hyperoc's traced code calls the host through such callbacks
where a host factorization is applied inside a compiled program: the mass matrix's inverse (the
consistent initial pressure, `hyperoc.mechanics.operators.apply_inverse`) and a host solver's bordered
solves when a traced Newton iteration uses one (`hyperoc.solvers.linsolve.SparseSolver.solve`); the time
steps and static solves with a host solver run their Newton iteration on the host and need no callback.

`start_backend` therefore starts the backend on every CPU of the machine and then binds the calling
thread and the threads XLA started back to the CPUs the caller had (threads that existed before keep
their own): the pool keeps several threads, the process keeps its pinning. Where the CPU set cannot
be widened (a one-CPU cpuset) it warns instead. A process started on several CPUs is left alone: its
backend starts when first used.

`openblas_threads` limits the threads of the OpenBLAS libraries loaded in the process (numpy's and
scipy's) for the duration of a host solve. After each call that it splits across threads, OpenBLAS
keeps its worker threads spinning for a while, waiting for the next call; between two host solves
of a time step (SuperLU's triangular solves, the border's dot products) XLA evaluates the residual
on the same cores, and on a two-core machine the spinning threads take a large share of them
(``python bench/bench_sparse_path.py --variants chord/lu,chord/lu_blas``). The solves of a time step
are too small for threads to pay off.
"""

import contextlib
import os
import threading
import warnings
from functools import cache

__all__ = ["bind_threads", "start_backend", "openblas_threads", "ONE_THREAD_POOL"]

#: Environment variable: ``"1"`` keeps a process started on one CPU at XLA's one-thread pool, for
#: processes that run no host solves (`hyperoc.app.paper`'s 1D workers, which run faster with one thread).
ONE_THREAD_POOL = "HYPEROC_ONE_THREAD_POOL"


def bind_threads(cpus: set, skip: set = frozenset()) -> None:
    """Set the CPU set of every thread of this process but those in ``skip`` (thread ids; affinity is
    per thread on Linux)."""
    for tid in set(map(int, os.listdir("/proc/self/task"))) - set(skip):
        try:
            os.sched_setaffinity(tid, cpus)
        except OSError:  # a thread that ended meanwhile
            pass


def start_backend() -> None:
    """Start JAX's CPU backend with a thread pool of at least two threads (module docstring)."""
    import jax
    from jax._src import xla_bridge

    if not hasattr(os, "sched_setaffinity") or xla_bridge.backends_are_initialized():
        return
    allowed = os.sched_getaffinity(0)
    if len(allowed) > 1 or os.environ.get(ONE_THREAD_POOL) == "1":
        return
    others = set(map(int, os.listdir("/proc/self/task"))) - {threading.get_native_id()}  # the caller's own threads
    try:
        os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
        widened = len(os.sched_getaffinity(0)) > 1
    except OSError:  # CPUs outside the process's cpuset
        widened = False
    try:
        jax.devices()
    finally:
        bind_threads(allowed, skip=others)  # this thread and XLA's new ones
    if not widened:
        warnings.warn("hyperoc: a single CPU: XLA's CPU thread pool has one thread, and large 3D host solves "
                      "may deadlock inside jax.pure_callback (see hyperoc.solvers.threads)", RuntimeWarning,
                      stacklevel=2)


@cache
def _openblas():
    """The OpenBLAS libraries loaded in this process (threadpoolctl's controller, read once: the first
    solve comes after scipy's sparse solvers, and with them both OpenBLAS builds, are loaded)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController().select(internal_api="openblas")


def openblas_threads(threads: int | None):
    """A context in which OpenBLAS runs ``threads`` threads (module docstring); None: as it is set."""
    if threads is None:
        return contextlib.nullcontext()
    return _openblas().limit(limits=threads)

"""CPU affinity of this process's threads, and the size of XLA's CPU thread pool.

XLA sizes its CPU thread pool by the CPUs the process may run on when the backend starts. Started
with one (``taskset -c 0 ...``), the pool has a single thread, and `jax.pure_callback` (the host
sparse solve of `hyperoc.solvers.linsolve`) can deadlock: the callback's operands are copied to the CPU
device by a task queued on that pool, whose only thread is the one waiting inside the callback.
With jax 0.10, a quasi-static solve of the Land et al. ventricle hangs with no CPU use under
``taskset -c 0``, and runs normally when the backend is started as below (`tests/test_threads.py`).

`start_backend` therefore starts the backend on every CPU of the machine and then binds the calling
thread and the threads XLA started back to the CPUs the caller had (threads that existed before keep
their own): the pool keeps several threads, the process keeps its pinning. Where the CPU set cannot
be widened (a one-CPU cpuset) it warns instead. A process started on several CPUs is left alone: its
backend starts when first used.
"""

import os
import threading
import warnings

__all__ = ["bind_threads", "start_backend", "ONE_THREAD_POOL"]

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

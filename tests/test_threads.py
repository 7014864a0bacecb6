"""A process pinned to one CPU (``taskset -c 0``) keeps XLA's CPU pool at two or more threads.

XLA sizes its CPU thread pool (threads named ``tf_XLAEigen``) by the CPUs the process may use when the
backend starts; with one, a host solve inside `jax.pure_callback` can deadlock (hyperoc.solvers.threads).
Each test runs a fresh interpreter bound to one CPU before it starts.
"""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from hyperoc.solvers.threads import ONE_THREAD_POOL

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                                reason="needs Linux CPU affinity and two CPUs")


#: Prints XLA's pool size (threads named tf_XLAEigen), the number of distinct thread CPU sets, and the size of one.
POOL_SIZE = """
    import os
    import hyperoc
    import jax
    jax.devices()
    names = [open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task")]
    cpus = {frozenset(os.sched_getaffinity(int(t))) for t in os.listdir("/proc/self/task")}
    print(names.count("tf_XLAEigen"), len(cpus), len(next(iter(cpus))))
"""


def run_pinned(code: str, timeout: float, env: dict | None = None) -> str:
    """stdout of ``code`` run by a fresh interpreter that binds itself to one CPU before any import."""
    pin = f"import os; os.sched_setaffinity(0, {{{min(os.sched_getaffinity(0))}}})\n"
    out = subprocess.run([sys.executable, "-c", pin + textwrap.dedent(code)], capture_output=True, text=True,
                         timeout=timeout, check=True, env={**os.environ, **(env or {})})
    return out.stdout


@pytest.mark.slow
def test_import_starts_a_multithreaded_pool_and_keeps_the_pinning():
    out = run_pinned(POOL_SIZE, timeout=120)
    pool, distinct_sets, cpus = map(int, out.split())
    assert pool >= 2
    assert distinct_sets == 1 and cpus == 1  # every thread still on the one CPU the process was given


@pytest.mark.slow
def test_one_thread_pool_on_request():
    """``HYPEROC_ONE_THREAD_POOL=1`` (set by `hyperoc.app.paper` for its 1D workers) keeps the one-thread pool."""
    out = run_pinned(POOL_SIZE, timeout=120, env={ONE_THREAD_POOL: "1"})
    assert int(out.split()[0]) == 1


@pytest.mark.slow
def test_pinned_host_solves_of_the_ventricle_complete():
    """The Land ventricle's static solve (host Newton) and, through a callback inside a compiled program,
    the mass matrix's inverse of the 3D example (its consistent initial pressure), in a pinned process."""
    example = Path(__file__).parents[1] / "examples" / "ventricle-3d.toml"
    out = run_pinned(f"""
        import numpy as np
        from hyperoc.app.config import load_config
        from hyperoc.cardiac.land import Formulation, LoadStepping, VentricleMesh, ventricle_apex
        r = ventricle_apex(VentricleMesh(9.0), Formulation(1000.0), LoadStepping(steps=5))
        cfg = load_config({str(example)!r})
        stepper = cfg.stepper(cfg.model())
        n, n_ctrl = stepper.model.n, stepper.model.control.size
        p0 = stepper.initial_pressure(np.zeros(n), np.zeros(n), np.zeros(n_ctrl), np.zeros(n))
        print(r.dofs, r.values["z_endo"], p0)
    """, timeout=600)
    dofs, z_endo, p0 = out.split()
    assert int(dofs) > 1000 and float(z_endo) < -17.0  # the apex moves down from z = -17 under the load
    assert np.isfinite(float(p0))  # the callback returned


def test_threads_started_before_the_import_keep_their_affinity():
    out = run_pinned("""
        import os, threading
        ready, done = threading.Event(), threading.Event()
        box = {}
        def worker():
            box["tid"] = threading.get_native_id()
            os.sched_setaffinity(0, set(range(os.cpu_count())))  # this thread: every CPU
            ready.set()
            done.wait()
        t = threading.Thread(target=worker)
        t.start()
        ready.wait()
        import hyperoc
        print(len(os.sched_getaffinity(box["tid"])), len(os.sched_getaffinity(0)))
        done.set()
        t.join()
    """, timeout=120)
    worker_cpus, main_cpus = map(int, out.split())
    assert worker_cpus == os.cpu_count() and main_cpus == 1

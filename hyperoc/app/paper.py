"""``hyperoc reproduce paper-1d``: the paper's 1D experiment, posed so that it has an answer.

All runs start from ``(xi, tau) = (0, T/2)`` on the setup of the paper's table of parameters
(``hyperoc/data/paper-1d.toml``):

1. the top level (the headline): the paper's problem with the control cost
   ``alpha/2 ||xi||^2 + beta/2 ||d xi/dt||^2``, ``alpha = beta = 10`` (`WELL_POSED`), solved by
   Newton-CG to a relative gradient of ``gtol`` (1e-6) in the H^1-in-time metric: a local maximizer.
   With the paper's weight ``alpha = 2e-3`` (with or without beta) the problem has no maximizer
   (docs/wellposedness.md); with weights at which the cost competes with the pressure it has one;
2. ``as_stated/``: the paper's Algorithm 1 (Armijo, then Barzilai-Borwein) on the problem as stated
   (a control is admissible when its state exists on all of [0, T]: ``horizon = "full"``),
   and ``ray.json``: J along ``s * xi`` for the control it ends with (is there an interior maximum, or
   does J grow until the body inverts?);
3. ``bounded/``: the problem as stated with a pointwise bound ``|xi| <= XI_MAX`` (the paper's Remark
   ``rk-box`` in pointwise form), by the spectral projected gradient method (Algorithm 1's BB steps,
   projected, with a nonmonotone Armijo test over the last ``SPG_WINDOW`` values).

Runs 2-3 are skipped with ``quick``. With two CPUs the three runs go to two worker processes, each
bound to a CPU of its own, the headline and run 2 first, run 3 to the first one free; this process
only starts them (it imports neither JAX nor SciPy) and writes the summary. The top-level
``summary.json`` holds the headline run, the paper's reported values and the diagnostic runs 2-3 with
their status.
"""

from __future__ import annotations

import os
import time
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import InputError, SolverError
from ..io import read_json, write_json
from ..solvers.threads import ONE_THREAD_POOL, bind_threads
from .config import Config, parse_config, set_entries

__all__ = ["paper_config", "wellposed_config", "reproduce_paper_1d", "PAPER_REPORT", "WELL_POSED"]

PAPER_REPORT = {
    "tau": 7.9,
    "tau0": 7.5,
    "control_off_from_t": 7.48,
    "pressure_maxima_near_t": [6.3, 7.9],
    "alpha": 2e-3,
    "beta": 0.0,
    "source": "Court, section 'Results' (Figures figControl, fig-pressure)",
}

# The headline's changes to the paper's setup: a control cost that competes with the pressure, H^1 in
# time (sqrt(beta / alpha) = 1 time unit), and the second-order method that reaches the KKT tolerance
# past the round-off of J (docs/wellposedness.md).
# Its J and gradient are computed on the steps up to tau (`ReducedFunctional.horizon`): a smooth control
# of that size keeps the state far from inversion (min det F 0.84 over [0, T] at the optimum).
WELL_POSED = {"objective.alpha": 10.0, "objective.beta": 10.0, "optimize.method": "newton",
              "optimize.horizon": "objective"}
XI_MAX = 0.05  # bound of the bounded variant (same order as the control the paper's figures suggest)
# The bounded variant's nonmonotone window (Birgin-Martinez-Raydan's SPG default): Algorithm 1's
# unguarded BB steps let J fall to a tenth of its best value there.
SPG_WINDOW = 10
RUN_NAMES = {"wellposed": "well-posed (alpha = beta = 10), Newton-CG", "as_stated": "as stated, Algorithm 1",
             "bounded": f"as stated with |xi| <= {XI_MAX}, SPG"}


def paper_config(changes: dict | None = None) -> Config:
    """The shipped configuration of Table tab-param (``hyperoc/data/paper-1d.toml``) with ``changes``
    (``{"SECTION.KEY": value}``, as `set_entries` and ``--set``, e.g. ``{"mesh.n": 50}``), validated as a
    whole (a changed method gets its own options' defaults)."""
    import tomllib

    data = tomllib.loads(resources.files("hyperoc").joinpath("data/paper-1d.toml").read_text())
    return parse_config(set_entries(data, changes or {}))


def wellposed_config(changes: dict | None = None) -> Config:
    """The headline's configuration: the paper's with `WELL_POSED` (``alpha = beta = 10``, Newton-CG)."""
    return paper_config({**WELL_POSED, **(changes or {})})


def bounded_config(changes: dict | None = None) -> Config:
    """The bounded variant of the paper's configuration: ``|xi| <= XI_MAX`` by SPG (window ``SPG_WINDOW``)."""
    # The bound keeps the state far from inversion (min det F 0.70 over [0, T] at the end, no failed trial
    # point), so J and the gradient are computed on the steps up to tau, as the headline's.
    bounds = {"optimize.xi_bounds": [-XI_MAX, XI_MAX], "optimize.nonmonotone": SPG_WINDOW,
              "optimize.horizon": "objective"}
    return paper_config({**bounds, **(changes or {})})


def _run(cfg: Config, key: str, out: Path, *, progress: bool) -> tuple[dict, object, object]:
    """One optimization from ``(0, tau0)`` written to ``out`` (figures titled with the run's name). Returns
    the run's row, J and the result."""
    from .._jax import compilation_clock
    from .workflows import CACHE_DIR, optimize_single, write_optimization_outputs

    started, (compiling, compilations) = time.perf_counter(), compilation_clock()
    J, res = optimize_single(cfg, float(cfg["optimize"]["tau0"]), cache_dir=out / CACHE_DIR, progress=progress)
    optimized, (compiled, compilations_after) = time.perf_counter(), compilation_clock()
    marks = [(t, "paper's pressure maxima") for t in PAPER_REPORT["pressure_maxima_near_t"]]
    summary = write_optimization_outputs(out, cfg, J, res, extra={"label": RUN_NAMES[key]},
                                         title=f"paper-1d, {RUN_NAMES[key]}", pressure_marks=marks)
    sol = J.state(res.point)  # the outputs' solve on [0, T], kept for the last point
    timings = {"compilation_s": compiled - compiling, "compilations": compilations_after - compilations,
               "optimization_s": optimized - started - (compiled - compiling),
               "outputs_s": time.perf_counter() - optimized}
    g = summary["grad_norm_history"]
    maxima_t, maxima_p = _local_maxima(sol.t, sol.pressure)
    return {
        "label": RUN_NAMES[key],
        "folder": "." if key == "wellposed" else key,
        "dt": float(cfg["dynamics"]["dt"]),
        "h": 1.0 / cfg["mesh"]["n"],
        "alpha": float(cfg["objective"]["alpha"]),
        "beta": float(cfg["objective"].get("beta", 0.0)),
        "method": cfg["optimize"]["method"],
        "xi_bounds": cfg["optimize"].get("xi_bounds"),
        "nonmonotone": int(cfg["optimize"].get("nonmonotone", 0)),
        "tau": summary["tau"],
        "objective": summary["objective"],
        "iterations": summary["iterations"],
        "converged": summary["converged"],
        "message": res.message,
        "relative_gradient": g[-1] / g[0] if g and g[0] > 0 else None,
        "min_det_F": float(sol.min_det_F.min()),
        "max_abs_xi": float(np.max(np.abs(res.point.xi))),
        "pressure_at_tau": float(sol.pressure[J.transform.tau_index]),
        "control_off_from_t": _control_off_time(sol.t, res.point.xi),
        "pressure_local_maxima_t": maxima_t,
        "pressure_local_maxima_p": maxima_p,
        "warnings": sol.warnings,
        "wall_time_s": time.perf_counter() - started,
        "timings": timings,
    }, J, res


def _control_off_time(t: np.ndarray, xi: np.ndarray, rel: float = 1e-3) -> float | None:
    """First time after which |xi| stays below ``rel * max|xi|``."""
    amp = np.max(np.abs(xi), axis=1)
    if amp.max() == 0:
        return None
    on = np.flatnonzero(amp > rel * amp.max())
    return float(t[min(on[-1] + 1, t.size - 1)])


def _local_maxima(t: np.ndarray, p: np.ndarray, keep: int = 4) -> tuple[list, list]:
    """Times and values of the largest local maxima of p (at most ``keep``), in increasing time."""
    idx = np.flatnonzero((p[1:-1] > p[:-2]) & (p[1:-1] >= p[2:])) + 1
    idx = np.sort(idx[np.argsort(p[idx])[::-1][:keep]])
    return [float(t[k]) for k in idx], [float(p[k]) for k in idx]


def ray_study(J, point, scales=(0.25, 0.5, 0.75, 1.0, 1.1, 1.25, 1.5, 2.0)) -> list:
    """J(s xi*, tau*) for several s (``point`` a `hyperoc.control.reduced.ControlPoint`): where does J stop
    growing, and why (solver failure, det F)."""
    from ..control.reduced import ControlPoint

    rows = []
    for s in scales:
        try:
            value = J(ControlPoint(s * point.xi, point.tau))
            sol = J.state(ControlPoint(s * point.xi, point.tau))
            rows.append({"scale": s, "J": value, "min_det_F": float(sol.min_det_F.min())})
        except SolverError as exc:
            rows.append({"scale": s, "J": None, "failure": str(exc)})
    return rows


def _headline_job(overrides: dict, out: Path, progress: bool) -> dict:
    """The well-posed problem solved by Newton-CG, written to the top level of ``out``."""
    row, _, _ = _run(wellposed_config(overrides), "wellposed", out, progress=progress)
    return {"headline": row}


def _as_stated_job(overrides: dict, out: Path, progress: bool) -> dict:
    """The problem as stated: Algorithm 1, then the ray study at its end point."""
    as_stated, J, res = _run(paper_config(overrides), "as_stated", out / "as_stated", progress=progress)
    ray = ray_study(J, res.point)
    write_json(out / "ray.json", ray)
    return {"as_stated": as_stated, "ray": ray}


def _bounded_job(overrides: dict, out: Path, progress: bool) -> dict:
    """The bounded variant |xi| <= XI_MAX of the problem as stated (SPG)."""
    bounded, _, _ = _run(bounded_config(overrides), "bounded", out / "bounded", progress=progress)
    return {"bounded": bounded}


def _jobs(out: Path, quick: bool, overrides: dict) -> dict:
    """The studies as independent jobs ``key -> (function, kwargs)``, longest first (a free worker takes the
    next): the headline and, unless ``quick``, the problem as stated and its bounded variant."""
    jobs = {"headline": (_headline_job, dict(overrides=overrides, out=out))}
    if not quick:
        jobs["as_stated"] = (_as_stated_job, dict(overrides=overrides, out=out))
        jobs["bounded"] = (_bounded_job, dict(overrides=overrides, out=out))
    return jobs


def _pin_to_cpu(index: int, allowed: list) -> set | None:
    """Bind every thread of this process to the CPU ``allowed[index % len(allowed)]`` (Linux; elsewhere a
    no-op) and return the previous CPU set. The 1D problems are too small for XLA's intra-op threads, which only
    spin: one Algorithm 1 run takes the same wall time on one CPU as on two, with 0.64x the CPU
    (`bench/bench_pinning.py`), so two unpinned jobs slow each other down."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    before = os.sched_getaffinity(0)
    bind_threads({allowed[index % len(allowed)]})
    return before


def _restore_cpus(cpus: set | None) -> None:
    if cpus is not None:
        bind_threads(cpus)


def _run_jobs(jobs: dict, workers: int, progress: bool) -> dict:
    """Results of every job, by key. With ``workers > 1`` every job runs in one of ``min(workers, jobs)``
    fresh (spawned: JAX is not fork-safe) processes, each bound to a CPU of its own (`_pin_worker`);
    progress bars are shown for the first job only.

    Why no job runs in this process: a process that loads NumPy's and SciPy's OpenBLAS with two CPUs
    keeps a BLAS thread, which spins beside the job once the process is bound to one CPU (the
    headline's Newton-CG took 2.4x as long). The workers start bound to one CPU, this process's, so
    their BLAS has no thread of its own, and bind themselves to theirs before the job imports JAX."""
    if workers == 1 or len(jobs) == 1:
        return {key: fn(progress=progress, **kwargs) for key, (fn, kwargs) in jobs.items()}
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    ctx = multiprocessing.get_context("spawn")
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    cpus = _pin_to_cpu(0, allowed)  # inherited by the workers as they start
    # The 1D problems need no host solves, and a second XLA pool thread on a worker's CPU only spins:
    # 1.2x slower (measured), so the workers keep the one-thread pool (`hyperoc.solvers.threads.start_backend`).
    os.environ[ONE_THREAD_POOL] = "1"
    try:
        with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=ctx, initializer=_pin_worker,
                                 initargs=(ctx.Value("i", 0), allowed)) as pool:
            futures = {key: pool.submit(fn, progress=progress and i == 0, **kwargs)
                       for i, (key, (fn, kwargs)) in enumerate(jobs.items())}
            return {key: fut.result() for key, fut in futures.items()}
    finally:
        os.environ.pop(ONE_THREAD_POOL, None)
        _restore_cpus(cpus)


def _pin_worker(counter, allowed: list) -> None:
    """Pool initializer: worker k (0-based, in start order) takes ``allowed[k]``."""
    with counter.get_lock():
        index = counter.value
        counter.value += 1
    _pin_to_cpu(index, allowed)


def reproduce_paper_1d(out: Path, *, quick: bool = False, progress: bool = True, workers: int | None = None,
                       overrides: dict | None = None) -> dict:
    """Run the studies listed in the module docstring; returns the top-level summary.

    ``workers`` processes run the independent studies in parallel (default: ``min(2, cpu count)``;
    1 runs everything in this process). ``overrides`` changes the shipped configuration of every run,
    as ``{"SECTION.KEY": value}`` (`set_entries`; e.g. a coarser grid for a smoke test); the paper's setup
    is the default.
    """
    overrides = dict(overrides or {})
    workers = min(2, os.cpu_count() or 1) if workers is None else int(workers)
    if workers < 1:
        raise InputError(f"workers must be >= 1, got {workers}")
    wellposed_config(overrides), bounded_config(overrides)  # bad overrides: InputError before anything is written
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    results = _run_jobs(_jobs(out, quick, overrides), workers, progress)
    headline = results["headline"]["headline"]
    diagnostics = {k: v for job in results.values() for k, v in job.items()}
    run_summary = read_json(out / "summary.json")  # the headline run's own summary (histories, files)
    summary = {**run_summary, **{k: headline[k] for k in ("label", "alpha", "beta", "method", "relative_gradient",
                                                           "pressure_at_tau", "control_off_from_t",
                                                           "pressure_local_maxima_t", "pressure_local_maxima_p",
                                                           "min_det_F", "max_abs_xi", "timings")},
               "paper": PAPER_REPORT, "diagnostics": {k: diagnostics[k] for k in ("as_stated", "bounded")
                                                     if k in diagnostics},
               "ray": diagnostics.get("ray", []), "config": wellposed_config(overrides).sections,
               "workers": workers, "wall_time_s": time.perf_counter() - started}
    write_json(out / "summary.json", summary)
    _print_report(out, summary)
    return summary


def _print_report(out: Path, summary: dict) -> None:
    """The headline first (one line), then the paper's values and the diagnostics."""
    print(f"{summary['label']}: tau* = {summary['tau']:.4f}, J* = {summary['objective']:.6g}, "
          f"converged = {summary['converged']} (relative gradient {summary['relative_gradient']:.2g} after "
          f"{summary['iterations']} iterations), pressure maxima at t = "
          f"{[round(x, 2) for x in summary['pressure_local_maxima_t']]}, control off from t = "
          f"{_rounded(summary['control_off_from_t'])}")
    p = summary["paper"]
    print(f"paper (alpha = {p['alpha']:g}, beta = 0): tau ~ {p['tau']}, control off from t ~ "
          f"{p['control_off_from_t']}, pressure maxima near t = {p['pressure_maxima_near_t']}")
    for r in summary["diagnostics"].values():
        print(f"  diagnostic, {r['label']} ({r['folder']}/): tau = {r['tau']:.4f}, J = {r['objective']:.5g}, "
              f"iterations = {r['iterations']}, converged = {r['converged']} ({r['message']}), "
              f"min det F = {r['min_det_F']:.3g}")
    print(f"-> {out / 'summary.json'} ({summary['wall_time_s']:.0f} s)")


def _rounded(x):
    return None if x is None else round(x, 2)

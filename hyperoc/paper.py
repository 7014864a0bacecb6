"""``hyperoc reproduce paper-1d``: the paper's 1D experiment, and what it takes to interpret it.

Runs, all from ``(xi, tau) = (0, T/2)`` on the setup of Table ``tab-param``:

1. ``algorithm1/`` (also copied to the top level): the paper's Algorithm 1 as stated (Armijo, then
   Barzilai-Borwein, unconstrained control);
2. ``ray.json``: J along ``s * xi*`` for the control Algorithm 1 ends with (is there an interior
   maximum, or does J grow until the body inverts?);
3. ``bounded/``: the well-posed variant with a pointwise bound ``|xi| <= xi_max`` (the paper's
   Remark ``rk-box`` in pointwise form), by the spectral projected gradient method (Algorithm 1's
   BB steps, projected, with a nonmonotone Armijo test over the last ``SPG_WINDOW`` values);
4. ``resolution.json`` (skipped with ``quick``): the bounded variant again with dt halved and with
   h halved.

Runs 1-3 share one compiled problem; the resolution study (4) runs in a second worker process
when two CPUs are available. The runs of (4) write summary.json and results.npz only.

The top-level ``summary.json`` gathers every run next to the paper's reported values.
"""

from __future__ import annotations

import os
import shutil
import time
from importlib import resources
from pathlib import Path

import numpy as np

from .config import Config, parse_config
from .errors import InputError, SolverError
from .io import write_json, write_npz
from .reduced import ControlPoint
from .threads import ONE_THREAD_POOL, bind_threads
from .workflows import optimize_single, write_optimization_outputs

__all__ = ["paper_config", "reproduce_paper_1d", "PAPER_REPORT"]

PAPER_REPORT = {
    "tau": 7.9,
    "tau0": 7.5,
    "control_off_from_t": 7.48,
    "pressure_maxima_near_t": [6.3, 7.9],
    "source": "Court, section 'Results' (Figures figControl, fig-pressure)",
}

XI_MAX = 0.05  # bound of the well-posed variant (same order as the control the paper's figures suggest)
# The bounded variant's nonmonotone window (Birgin-Martinez-Raydan's SPG default): Algorithm 1's
# unguarded BB steps let J fall to a tenth of its best value there.
SPG_WINDOW = 10


def paper_config() -> Config:
    """The shipped configuration of Table tab-param (``hyperoc/data/paper-1d.toml``)."""
    import tomllib

    text = resources.files("hyperoc").joinpath("data/paper-1d.toml").read_text()
    return parse_config(tomllib.loads(text))


def bounded_config() -> Config:
    """The paper configuration of the bounded variant: ``|xi| <= XI_MAX``, SPG (`_bounded`)."""
    return _bounded(paper_config())


def _bounded(cfg: Config) -> Config:
    """``cfg`` with the bounds ``|xi| <= XI_MAX`` and the nonmonotone window ``SPG_WINDOW``."""
    return _with(cfg, optimize__xi_bounds=[-XI_MAX, XI_MAX], optimize__nonmonotone=SPG_WINDOW)


def _with(cfg: Config, **changes) -> Config:
    sections = {k: dict(v) for k, v in cfg.sections.items()}
    for dotted, value in changes.items():
        section, key = dotted.split("__")
        sections[section][key] = value
    return Config(sections, cfg.base)


def _run(cfg: Config, tau0: float, out: Path, *, progress: bool, label: str, J=None,
         figures: bool = True) -> dict:
    """One optimization and its outputs; ``J`` reuses a compiled reduced functional of the same
    problem size; ``figures=False`` writes only summary.json and results.npz (resolution runs)."""
    started = time.perf_counter()
    if J is not None:
        J.counts.update(state=0, adjoint=0)  # evaluations are reported per run
    J, res = optimize_single(cfg, tau0, checkpoint=out / "checkpoint", progress=progress, J=J)
    sol = J.state(res.point)
    if figures:
        summary = write_optimization_outputs(out, cfg, J, res, extra={"label": label})
    else:
        summary = {**res.summary(), "label": label}
        write_npz(out / "results.npz", t=sol.t, p=sol.pressure, xi=J.model.control.nodal(res.point.xi),
                  xi_nodes=J.model.control.coordinates(J.model.space))
        write_json(out / "summary.json", summary)
    return {
        "label": label,
        "folder": out.name,
        "dt": float(cfg["dynamics"]["dt"]),
        "h": 1.0 / cfg["mesh"]["n"],
        "xi_bounds": cfg["optimize"].get("xi_bounds"),
        "nonmonotone": int(cfg["optimize"]["nonmonotone"]),
        "tau": summary["tau"],
        "objective": summary["objective"],
        "iterations": summary["iterations"],
        "converged": summary["converged"],
        "message": res.message,
        "grad_norm_first_last": [summary["grad_norm_history"][0], summary["grad_norm_history"][-1]],
        "min_det_F": float(sol.min_det_F.min()),
        "max_abs_xi": float(np.max(np.abs(res.point.xi))),
        "control_off_from_t": _control_off_time(sol.t, res.point.xi),
        "pressure_local_maxima_t": _local_maxima(sol.t, sol.pressure),
        "warnings": sol.warnings,
        "wall_time_s": time.perf_counter() - started,
    }, J, res


def _control_off_time(t: np.ndarray, xi: np.ndarray, rel: float = 1e-3) -> float | None:
    """First time after which |xi| stays below ``rel * max|xi|``."""
    amp = np.max(np.abs(xi), axis=1)
    if amp.max() == 0:
        return None
    on = np.flatnonzero(amp > rel * amp.max())
    return float(t[min(on[-1] + 1, t.size - 1)])


def _local_maxima(t: np.ndarray, p: np.ndarray, keep: int = 4) -> list:
    """Times of the largest local maxima of p (at most ``keep``), in increasing time."""
    idx = np.flatnonzero((p[1:-1] > p[:-2]) & (p[1:-1] >= p[2:])) + 1
    idx = idx[np.argsort(p[idx])[::-1][:keep]]
    return [float(t[k]) for k in sorted(idx)]


def ray_study(J, point: ControlPoint, scales=(0.25, 0.5, 0.75, 1.0, 1.1, 1.25, 1.5, 2.0)) -> list:
    """J(s xi*, tau*) for several s: where does J stop growing, and why (solver failure, det F)."""
    rows = []
    for s in scales:
        try:
            value = J(ControlPoint(s * point.xi, point.tau))
            sol = J.state(ControlPoint(s * point.xi, point.tau))
            rows.append({"scale": s, "J": value, "min_det_F": float(sol.min_det_F.min())})
        except SolverError as exc:
            rows.append({"scale": s, "J": None, "failure": str(exc)})
    return rows


def _paper_job(overrides: dict, out: Path, progress: bool) -> dict:
    """Algorithm 1 as stated, the ray study at its end point, then the bounded variant |xi| <= XI_MAX
    (SPG) with the same compiled reduced functional."""
    cfg = _with(paper_config(), **overrides)
    tau0 = float(cfg["optimize"]["tau0"])
    row, J, res = _run(cfg, tau0, out / "algorithm1", progress=progress, label="Algorithm 1 (paper)")
    ray = ray_study(J, res.point)
    write_json(out / "ray.json", ray)
    bounded, _, _ = _run(_bounded(cfg), tau0, out / "bounded", progress=progress, J=J,
                         label=f"bounded |xi| <= {XI_MAX}")
    return {"algorithm1": row, "ray": ray, "bounded": bounded}


def _resolution_job(runs: list, progress: bool) -> list:
    """Rows of the bounded variant on refined grids, ``runs = [(label, overrides, out), ...]``
    (summary.json and results.npz per run; no figures)."""
    rows = []
    for label, overrides, out in runs:
        cfg = _with(paper_config(), **overrides)
        row, _, _ = _run(_bounded(cfg), float(cfg["optimize"]["tau0"]), out, progress=progress,
                         label=label, figures=False)
        rows.append(row)
    return rows


def _jobs(cfg: Config, out: Path, quick: bool, overrides: dict) -> dict:
    """The studies as two independent jobs ``key -> (function, kwargs)`` of similar length: the
    paper's grid (Algorithm 1, ray, bounded: one compilation) and the resolution study."""
    jobs = {"paper": (_paper_job, dict(overrides=overrides, out=out))}
    if not quick:
        runs = [("bounded, dt/2", {**overrides, "dynamics__dt": cfg["dynamics"]["dt"] / 2}, out / "bounded_dt2"),
                ("bounded, h/2", {**overrides, "mesh__n": 2 * cfg["mesh"]["n"]}, out / "bounded_h2")]
        jobs["resolution"] = (_resolution_job, dict(runs=runs))
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
    """Results of every job, by key. With ``workers > 1`` the first job runs in this process and the others
    in ``workers - 1`` fresh (spawned: JAX is not fork-safe) processes meanwhile, each process bound to
    its own CPU (`_pin_to_cpu`); progress bars are shown for this process's runs only."""
    first, *others = jobs
    if workers == 1 or not others:
        return {key: fn(progress=progress, **kwargs) for key, (fn, kwargs) in jobs.items()}
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    n_pool = min(workers - 1, len(others))
    ctx = multiprocessing.get_context("spawn")
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    cpus = _pin_to_cpu(0, allowed)
    # The workers inherit this CPU set of one and pin themselves to another; they run the 1D problem
    # (no host solves), where a second XLA pool thread on their CPU only spins: 1.2x slower (measured),
    # so they keep the one-thread pool (`hyperoc.threads.start_backend`).
    os.environ[ONE_THREAD_POOL] = "1"
    try:
        with ProcessPoolExecutor(n_pool, mp_context=ctx, initializer=_pin_worker,
                                 initargs=(ctx.Value("i", 0), allowed)) as pool:
            futures = {key: pool.submit(jobs[key][0], progress=False, **jobs[key][1]) for key in others}
            fn, kwargs = jobs[first]
            results = {first: fn(progress=progress, **kwargs)}
            results.update({key: fut.result() for key, fut in futures.items()})
    finally:
        os.environ.pop(ONE_THREAD_POOL, None)
        _restore_cpus(cpus)
    return results


def _pin_worker(counter, allowed: list) -> None:
    """Pool initializer: worker k (in start order) takes ``allowed[k]`` (the main process has ``allowed[0]``)."""
    with counter.get_lock():
        counter.value += 1
        index = counter.value
    _pin_to_cpu(index, allowed)


def reproduce_paper_1d(out: Path, *, quick: bool = False, progress: bool = True, workers: int | None = None,
                       overrides: dict | None = None) -> dict:
    """Run the studies listed in the module docstring; returns the top-level summary.

    ``workers`` processes run the independent studies in parallel (default: ``min(2, cpu count)``;
    1 runs everything in this process). ``overrides`` changes the shipped configuration, as
    ``{"section__key": value}`` (e.g. a coarser grid for a smoke test); the paper's setup is the default.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    overrides = dict(overrides or {})
    cfg = _with(paper_config(), **overrides)
    workers = min(2, os.cpu_count() or 1) if workers is None else int(workers)
    if workers < 1:
        raise InputError(f"workers must be >= 1, got {workers}")
    started = time.perf_counter()
    results = _run_jobs(_jobs(cfg, out, quick, overrides), workers, progress)
    _copy_top_level(out / "algorithm1", out)
    runs = {"algorithm1": results["paper"]["algorithm1"], "bounded": results["paper"]["bounded"]}
    resolution = results.get("resolution", [])
    if resolution:
        write_json(out / "resolution.json", resolution)
    summary = {"paper": PAPER_REPORT, "runs": runs, "ray": results["paper"]["ray"], "resolution": resolution,
               "config": cfg.sections, "workers": workers, "wall_time_s": time.perf_counter() - started,
               "tau": runs["algorithm1"]["tau"], "objective": runs["algorithm1"]["objective"]}
    write_json(out / "summary.json", summary)
    _print_report(out, summary)
    return summary


def _copy_top_level(src: Path, dst: Path) -> None:
    for name in ("pressure.png", "control.png", "displacement.png", "velocity.png", "control_snapshots.png",
                 "history.png", "results.npz"):
        if (src / name).exists():
            shutil.copyfile(src / name, dst / name)


def _print_report(out: Path, summary: dict) -> None:
    p = summary["paper"]
    print(f"paper: tau ~ {p['tau']} (from tau0 = {p['tau0']}), control off from t ~ {p['control_off_from_t']}, "
          f"pressure maxima near t = {p['pressure_maxima_near_t']}")
    for key, r in summary["runs"].items():
        print(f"{r['label']}: tau = {r['tau']:.4f}, J = {r['objective']:.5g}, iterations = {r['iterations']}, "
              f"converged = {r['converged']}, min det F = {r['min_det_F']:.3g}, "
              f"control off from t = {r['control_off_from_t']}, "
              f"pressure maxima at t = {[round(x, 2) for x in r['pressure_local_maxima_t']]}")
    for r in summary["resolution"]:
        print(f"{r['label']}: tau = {r['tau']:.4f}, J = {r['objective']:.5g}, converged = {r['converged']}")
    print(f"-> {out / 'summary.json'} ({summary['wall_time_s']:.0f} s)")

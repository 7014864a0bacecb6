"""``hyperoc reproduce paper-1d``: the paper's 1D experiment, and what it takes to interpret it.

Runs, all from ``(xi, tau) = (0, T/2)`` on the setup of Table ``tab-param``:

1. ``algorithm1/`` (also copied to the top level): the paper's Algorithm 1 as stated (Armijo, then
   Barzilai-Borwein, unconstrained control);
2. ``ray.json``: J along ``s * xi*`` for the control Algorithm 1 ends with (is there an interior
   maximum, or does J grow until the body inverts?);
3. ``bounded/``: the well-posed variant with a pointwise bound ``|xi| <= xi_max`` (projected
   Algorithm 1; the paper's Remark ``rk-box`` in pointwise form);
4. ``resolution.json`` (skipped with ``quick``): the bounded variant again with dt halved and with
   h halved.

The four optimizations are independent and run in parallel worker processes (two by default).

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
from .io import write_json
from .reduced import ControlPoint
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


def paper_config() -> Config:
    """The shipped configuration of Table tab-param (``hyperoc/data/paper-1d.toml``)."""
    import tomllib

    text = resources.files("hyperoc").joinpath("data/paper-1d.toml").read_text()
    return parse_config(tomllib.loads(text))


def _with(cfg: Config, **changes) -> Config:
    sections = {k: dict(v) for k, v in cfg.sections.items()}
    for dotted, value in changes.items():
        section, key = dotted.split("__")
        sections[section][key] = value
    return Config(sections, cfg.base)


def _run(cfg: Config, tau0: float, out: Path, *, progress: bool, xi_bounds=None, label: str) -> dict:
    started = time.perf_counter()
    if xi_bounds is not None:
        cfg = _with(cfg, optimize__xi_bounds=list(xi_bounds))
    J, res = optimize_single(cfg, tau0, checkpoint=out / "checkpoint", progress=progress)
    summary = write_optimization_outputs(out, cfg, J, res, extra={"label": label})
    sol = J.state(res.point)
    return {
        "label": label,
        "folder": out.name,
        "dt": float(cfg["dynamics"]["dt"]),
        "h": 1.0 / cfg["mesh"]["n"],
        "xi_bounds": None if xi_bounds is None else list(xi_bounds),
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


def _algorithm1_job(overrides: dict, out: Path, progress: bool) -> dict:
    """Algorithm 1 as stated, then the ray study at its end point (run in a worker process)."""
    cfg = _with(paper_config(), **overrides)
    row, J, res = _run(cfg, float(cfg["optimize"]["tau0"]), out, progress=progress, label="Algorithm 1 (paper)")
    ray = ray_study(J, res.point)
    write_json(out.parent / "ray.json", ray)
    return {"run": row, "ray": ray}


def _bounded_job(overrides: dict, out: Path, progress: bool, label: str) -> dict:
    """The bounded variant |xi| <= XI_MAX, projected Algorithm 1 (run in a worker process)."""
    cfg = _with(paper_config(), **overrides)
    row, _, _ = _run(cfg, float(cfg["optimize"]["tau0"]), out, progress=progress, xi_bounds=(-XI_MAX, XI_MAX),
                     label=label)
    return {"run": row}


def _jobs(cfg: Config, out: Path, quick: bool, overrides: dict) -> dict:
    """The studies as independent jobs ``key -> (function, args)``, longest first (h/2, dt/2, ...)
    so that two workers finish together."""
    jobs = {}
    if not quick:
        jobs["h/2"] = (_bounded_job, dict(overrides={**overrides, "mesh__n": 2 * cfg["mesh"]["n"]},
                                          out=out / "bounded_h2", label="bounded, h/2"))
        jobs["dt/2"] = (_bounded_job, dict(overrides={**overrides, "dynamics__dt": cfg["dynamics"]["dt"] / 2},
                                           out=out / "bounded_dt2", label="bounded, dt/2"))
    jobs["algorithm1"] = (_algorithm1_job, dict(overrides=overrides, out=out / "algorithm1"))
    jobs["bounded"] = (_bounded_job, dict(overrides=overrides, out=out / "bounded", label=f"bounded |xi| <= {XI_MAX}"))
    return jobs


def _run_jobs(jobs: dict, workers: int, progress: bool) -> dict:
    """Results of every job: in this process when ``workers == 1`` (with per-run progress bars),
    otherwise in a pool of fresh (spawned: JAX is not fork-safe) processes with one bar over jobs."""
    if workers == 1:
        return {key: fn(progress=progress, **kwargs) for key, (fn, kwargs) in jobs.items()}
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from .workflows import _progress_bar

    bar = _progress_bar(progress, len(jobs), "paper-1d studies")
    results = {}
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(fn, progress=False, **kwargs): key for key, (fn, kwargs) in jobs.items()}
        for fut in as_completed(futures):
            results[futures[fut]] = fut.result()
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    return results


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
    runs = {"algorithm1": results["algorithm1"]["run"], "bounded": results["bounded"]["run"]}
    resolution = [results[k]["run"] for k in ("dt/2", "h/2") if k in results]
    if resolution:
        write_json(out / "resolution.json", resolution)
    summary = {"paper": PAPER_REPORT, "runs": runs, "ray": results["algorithm1"]["ray"], "resolution": resolution,
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
              f"converged = {r['converged']}, min det F = {r['min_det_F']:.3g}, control off from t = {r['control_off_from_t']}, "
              f"pressure maxima at t = {[round(x, 2) for x in r['pressure_local_maxima_t']]}")
    for r in summary["resolution"]:
        print(f"{r['label']}: tau = {r['tau']:.4f}, J = {r['objective']:.5g}, converged = {r['converged']}")
    print(f"-> {out / 'summary.json'} ({summary['wall_time_s']:.0f} s)")

"""End-to-end runs from a `Config`: simulate, optimize (single or multi-start), check gradients.

These are what the CLI calls; they are plain functions so that scripts and notebooks can call them
too. Every run writes its files atomically into an output folder.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from ..control.adjoint import Adjoint
from ..control.continuous_adjoint import ContinuousReducedFunctional
from ..control.optimize import (
    BBOptions,
    BoxProblem,
    EvaluationCache,
    NewtonCGOptions,
    OptimizationResult,
    barzilai_borwein,
    lbfgsb,
    newton_cg,
)
from ..control.reduced import ControlPoint, ReducedFunctional
from ..control.revolve import checkpoint_schedule
from ..control.verification import random_directions, taylor_test
from ..dynamics.stepper import detect_regimes
from ..errors import InputError, SolverError
from ..io import read_json, write_json, write_npz
from .config import Config
from .plotting import Units
from .report import DEFAULT_TITLE, write_state_outputs

__all__ = ["check_run", "simulate", "build_reduced", "optimize_single", "optimize", "check_gradient", "resume_state",
           "run_title", "figure_units"]

ITERATIONS_FILE = "iterations.json"  # in a run's evaluation cache folder: the last iteration completed
CACHE_DIR = "cache"  # a run's evaluation cache, OUT/cache (what --resume replays)
BEST_FILE = "best.npz"  # an iterate with a higher J than the final one (`OptimizationResult.best`)


def check_run(cfg: Config, command: str, mesh=None):
    """Everything a ``simulate`` or ``optimize`` run checks before it starts, so that bad input
    fails (`InputError`) before any output is written: the model (mesh, material, boundary tags,
    control region), the time grid, and for ``simulate`` the prescribed control, for ``optimize``
    every start's tau and the objective; the types and ranges of every entry were checked by the
    schema (`hyperoc.app.schema`); ``mesh``: the config's mesh if already built
    (`hyperoc.app.preflight.check_inputs`). Returns the model, which the run can reuse (``model=``)."""
    from ..solvers.linsolve import SparseSolver

    model = cfg.model(mesh)
    grid = cfg.grid()
    cfg.scheme()
    solver = cfg["dynamics"]["solver"]
    if solver not in ("auto", "tridiagonal", "dense", *SparseSolver.methods):
        raise InputError(f"config: [dynamics] solver {solver!r} unknown (auto, tridiagonal, dense, "
                         f"{', '.join(SparseSolver.methods)})")
    if solver.startswith("pardiso"):
        from ..solvers.pardiso import require

        require(solver)
    cfg.step_terms(model)  # a missing boundary tag, fibres an activation needs: before anything is written
    cfg.constraint(model, grid.t)  # a cavity wall the mesh lacks or that encloses nothing, a law not finite on the grid
    if command == "simulate":
        cfg.prescribed_control(model, grid.t)
    elif command == "optimize":
        cfg.tau_starts()
        cfg.objective()
    else:
        raise ValueError(f"check_run: unknown command {command!r}")
    return model


def run_title(cfg: Config) -> str:
    """The run's name in its figures' titles: the config file's name (`Config.name`), else
    `hyperoc.app.report.DEFAULT_TITLE`."""
    return cfg.name or DEFAULT_TITLE


def figure_units(cfg: Config) -> Units:
    """The figures' axis units, from ``[output] units`` (dimensionless where not given)."""
    return Units(**(cfg["output"].get("units") or {}))


def simulate(cfg: Config, out, *, progress: bool = False, monitor=None, on_segment=None, model=None,
             title: str | None = None) -> dict:
    """Forward solve with the prescribed control of ``[control]`` (`solve_prescribed`); writes the standard
    outputs (`write_simulation`) and returns the summary. ``title``: the run's name in the figures (default
    `run_title`)."""
    model = model or cfg.model()
    sol = solve_prescribed(cfg, out, cfg.stepper(model), progress=progress, monitor=monitor, on_segment=on_segment)
    return write_simulation(cfg, out, sol, model, title)


def solve_prescribed(cfg: Config, out, stepper, *, progress: bool = False, monitor=None, on_segment=None):
    """The `hyperoc.dynamics.stepper.StateSolution` of ``stepper`` (the config's, serial or distributed) with
    the prescribed control of ``[control]`` on the config's grid. ``monitor``: called with each step's
    `hyperoc.dynamics.stepper.StepRecord` (`TimeStepper.run`); with ``[output] checkpoint_every`` the solve is
    saved in segments in ``out/segments`` instead and resumes from them
    (`hyperoc.dynamics.resumable.run_resumable`, ``on_segment`` called after each)."""
    from ..dynamics.resumable import SEGMENTS_DIR, Segments, run_resumable

    grid, o = cfg.grid(), cfg["output"]
    xi = cfg.prescribed_control(stepper.model, grid.t)
    if o.get("checkpoint_every"):
        segments = Segments(Path(out) / SEGMENTS_DIR, o["checkpoint_every"], cfg.sections)
        return run_resumable(stepper, grid, xi, segments=segments, progress=progress, on_segment=on_segment)
    return stepper.run(grid, xi, progress=progress, monitor=monitor)


def write_simulation(cfg: Config, out, sol, model, title: str | None = None) -> dict:
    """`hyperoc simulate`'s outputs of the solution ``sol`` of the config's ``model`` in ``out``; returns the
    summary."""
    o = cfg["output"]
    return write_state_outputs(Path(out), sol, snapshot_times=o.get("snapshot_times"),
                               series_every=o.get("series_every"), frames=cfg.fibres(model.mesh),
                               title=title or run_title(cfg), units=figure_units(cfg), cavity=cfg.cavity_wall())


def build_reduced(cfg: Config, tau0: float, model=None) -> ReducedFunctional:
    model = model or cfg.model()
    o = cfg["optimize"]
    if cfg["dynamics"]["constraint"] == "none":
        raise InputError("config: [objective] reads the pressure, the multiplier of [dynamics] constraint = "
                         "'tissue_volume' or 'cavity_volume'; with constraint = 'none' there is none")
    functional = ContinuousReducedFunctional if o["gradient"] == "continuous" else ReducedFunctional
    return functional(model, cfg.transform(tau0), cfg.objective(), adjoint=Adjoint(cfg.stepper(model)),
                      schedule=checkpoint_schedule(o.get("checkpoint_every"), o.get("checkpoint_snapshots")),
                      horizon=o["horizon"])


def optimize_single(cfg: Config, tau0: float, *, cache_dir=None, progress: bool = False,
                    J: ReducedFunctional | None = None, iterations_done: int = 0,
                    start: ControlPoint | None = None,
                    gradient_scale: float | None = None) -> tuple[ReducedFunctional, OptimizationResult]:
    """One optimization from ``(xi, tau) = (0, tau0)``, or from ``start`` (a warm start at its own tau),
    with the method of ``[optimize]`` (whose method-specific options the schema keeps only for that method).
    ``gradient_scale``: the stopping test ``||G|| <= gtol * gradient_scale`` instead of ``gtol ||G0||``, so
    that a warm start meets a cold start's test (Barzilai-Borwein and Newton-CG).

    ``J``: the config's reduced functional (default: `build_reduced`); passing one reuses its
    compiled state and adjoint solves. ``cache_dir``: the folder of the evaluation cache, where
    the last completed iteration is also recorded (`resume_state`); ``iterations_done``: where a
    resumed run's progress bar starts (the iterations up to it replay cached evaluations).
    """
    J = J or build_reduced(cfg, tau0)
    o = cfg["optimize"]
    bar = _progress_bar(progress, o["max_iter"], f"optimize (tau0={tau0:g})", iterations_done)
    best = {"objective": -np.inf}
    if cache_dir is not None:
        Path(cache_dir).mkdir(parents=True, exist_ok=True)

    def callback(k, m, value, measure):  # measure: the stopping test's (projected, with bounds) ||G||
        if value > best["objective"]:
            best.update(point=m, objective=value, iteration=k)
        if cache_dir is not None and k > iterations_done:
            write_json(Path(cache_dir) / ITERATIONS_FILE, {"iterations": k})
        if bar is not None and k > iterations_done:
            bar.update(1)
            bar.set_postfix(J=f"{value:.5g}", tau=f"{m.tau:.4f}", G=f"{measure:.2e}")

    kwargs = dict(gtol=float(o["gtol"]), max_iter=int(o["max_iter"]), cache_dir=cache_dir, callback=callback)
    m0 = J.zero(tau0) if start is None else start
    box = BoxProblem.around(J, m0.tau, xi_bounds=cfg.xi_bounds(), tau_margin=o.get("tau_margin"))
    if gradient_scale is not None:
        if o["method"] not in ("bb", "newton"):
            raise ValueError(f"optimize_single: {o['method']} has no absolute stopping test (gradient_scale)")
        kwargs.update(gtol=0.0, gtol_abs=float(o["gtol"]) * gradient_scale)
    if o["method"] == "bb":
        res = barzilai_borwein(box, m0, options=BBOptions(o["steps"], o["bb_step"], o["nonmonotone"]), **kwargs)
    elif o["method"] == "newton":
        res = newton_cg(box, m0, options=NewtonCGOptions(o["max_cg"], o["tau_scale"]), **kwargs)
    else:
        res = lbfgsb(box, m0, tau_scale=o["tau_scale"], **kwargs)
    if bar is not None:
        bar.close()
    if res.history["objective"] and res.history["objective"][0] > best["objective"]:
        best.update(point=m0, objective=res.history["objective"][0], iteration=0)
    return J, dataclasses.replace(res, best=best if best["objective"] > res.objective else None)


def resume_state(cfg: Config, out) -> dict:
    """What a resumed run of ``cfg`` in ``out`` starts from: ``{"evaluations": N, "iterations": K,
    "dropped": [(path, reason), ...]}``, N the cached evaluations of every start (damaged entries
    dropped, `EvaluationCache.scan`), K the iterations completed (summed over the starts)."""
    out = Path(out)
    starts = cfg.tau_starts()
    folders = [out] if len(starts) == 1 else [_start_dir(out, k, t) for k, t in enumerate(starts)]
    total, iterations, dropped = 0, 0, []
    for folder in folders:
        count, bad = EvaluationCache.scan(folder / CACHE_DIR)
        total, dropped = total + count, dropped + bad
        iterations += _iterations_done(folder / CACHE_DIR)
    return {"evaluations": total, "iterations": iterations, "dropped": dropped}


def _iterations_done(cache_dir: Path) -> int:
    """The iteration recorded in ``cache_dir/iterations.json`` (0 if none or unreadable: the
    progress count only, the cached evaluations are replayed either way)."""
    try:
        k = read_json(cache_dir / ITERATIONS_FILE)["iterations"]
    except (OSError, ValueError, KeyError, TypeError):
        return 0
    return k if isinstance(k, int) and k >= 0 else 0


def _progress_bar(enabled: bool, total: int, desc: str, initial: int = 0):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, leave=False, initial=initial)


def write_optimization_outputs(out: Path, cfg: Config, J: ReducedFunctional, res: OptimizationResult,
                               extra=None, title: str | None = None, pressure_marks=None) -> dict:
    """The outputs of an optimization (`hyperoc.app.report.write_state_outputs` at its final iterate, the
    optimizer's history, ``best.npz`` when an earlier iterate was better); ``extra``: more summary
    entries; ``title``: the run's name in the figures (default `run_title`); ``pressure_marks``:
    ``[(t, label), ...]`` marked on the pressure panel. Returns the summary."""
    sol = _whole_state(J, res.point)
    sol.warnings = detect_regimes(sol)
    parts = J.objective_terms(sol)
    summary = {**res.summary(), "objective_terms": parts, "tau0": float(res.history["tau"][0]),
               "budget": cfg.budget(), **(extra or {})}
    hist = {"objective": res.history["objective"], "grad_norm": res.history["grad_norm"], "tau": res.history["tau"]}
    if res.best is not None:  # the final iterate is written below; the better earlier one beside it
        write_npz(out / BEST_FILE, xi=res.best["point"].xi, tau=np.float64(res.best["point"].tau),
                  objective=np.float64(res.best["objective"]), iteration=np.int64(res.best["iteration"]))
        summary["best"]["file"] = BEST_FILE
    else:  # a resumed run that went past it leaves no earlier better iterate behind
        (out / BEST_FILE).unlink(missing_ok=True)
    o = cfg["output"]
    return write_state_outputs(out, sol, tau=res.point.tau, eps=J.transform.eps or None, history=hist,
                               snapshot_times=o.get("snapshot_times"), series_every=o.get("series_every"),
                               frames=cfg.fibres(J.model.mesh), title=title or run_title(cfg),
                               units=figure_units(cfg), pressure_marks=pressure_marks, cavity=cfg.cavity_wall(),
                               extra_summary={"optimization": summary, "tau": summary["tau"],
                                              "objective": summary["objective"], "iterations": summary["iterations"],
                                              "converged": summary["converged"],
                                              "grad_norm_history": summary["grad_norm_history"],
                                              "objective_history": summary["objective_history"],
                                              "tau_history": summary["tau_history"],
                                              "wall_time_s": summary["wall_time_s"]})


def _whole_state(J: ReducedFunctional, point):
    """The state of ``point`` on [0, T]; a failure after the steps J solves names the remedy."""
    try:
        return J.state(point)
    except SolverError as err:
        if err.step < J.steps_solved:
            raise
        raise SolverError(err.step, err.time, err.cause,
                          "the optimizer's end point has no state after the steps the objective reads; "
                          "[optimize] horizon = \"full\" keeps such controls out") from err


def _start_dir(out: Path, k: int, tau0: float) -> Path:
    return out / f"start_{k:02d}_tau{tau0:g}"


def _run_start(cfg_sections: dict, base: str, tau0: float, folder: str, title: str | None = None) -> dict:
    """One start of a multi-start run (executed on a Dask worker or in-process); ``title``: its
    name in the figures."""
    from .config import Config as _Config

    cfg = _Config(cfg_sections, Path(base))
    folder = Path(folder)
    try:
        J, res = optimize_single(cfg, tau0, cache_dir=folder / CACHE_DIR)
        summary = write_optimization_outputs(folder, cfg, J, res, title=title)
        return {"tau0": tau0, "status": "ok", "tau": summary["tau"], "objective": summary["objective"],
                "converged": summary["converged"], "iterations": summary["iterations"], "folder": folder.name}
    except Exception as exc:  # a failed start is reported, not fatal
        return {"tau0": tau0, "status": "failed", "error": f"{type(exc).__name__}: {exc}", "folder": folder.name}


def optimize(cfg: Config, out, *, progress: bool = False, scheduler: str | None = None, workers: int = 2,
             model=None, iterations_done: int = 0, title: str | None = None) -> dict:
    """Optimize from every tau start of ``[optimize]``; several starts run in parallel on Dask.

    Each start writes into its own folder; a start whose ``summary.json`` exists with the same
    budget (`Config.budget`) is not recomputed (resume); with another budget it runs again, its
    cached evaluations replayed. The best start's outputs are also written at the top level of ``out``. ``model``: the
    config's model if already built (`check_run`), used by a single start (each start of several
    builds its own, on its worker); ``iterations_done``: a resumed single start's completed
    iterations (`resume_state`), where its progress bar starts; ``title``: the run's name in the
    figures (default `run_title`; each start of several adds its tau0).
    """
    title = title or run_title(cfg)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    starts = cfg.tau_starts()
    start_time = time.perf_counter()
    if len(starts) == 1:
        J, res = optimize_single(cfg, starts[0], cache_dir=out / CACHE_DIR, progress=progress,
                                 J=build_reduced(cfg, starts[0], model), iterations_done=iterations_done)
        return write_optimization_outputs(out, cfg, J, res, title=title)
    results = _multistart(cfg, out, starts, scheduler, workers, title)
    ok = [r for r in results if r["status"] == "ok"]
    summary = {"starts": results, "wall_time_s": time.perf_counter() - start_time}
    if ok:
        best = max(ok, key=lambda r: r["objective"])
        best_summary = read_json(out / best["folder"] / "summary.json")
        summary = {**best_summary, "best_start": best["folder"], **summary}
    write_json(out / "summary.json", summary)
    return summary


def _multistart(cfg: Config, out: Path, starts, scheduler, workers, title: str) -> list:
    todo, results = [], {}
    for k, tau0 in enumerate(starts):
        folder = _start_dir(out, k, tau0)
        done = folder / "summary.json"
        # a start that ran with another budget (a resume that extends it) runs again, replaying its cache
        if done.exists() and read_json(done).get("optimization", {}).get("budget") == cfg.budget():
            s = read_json(done)
            results[k] = {"tau0": tau0, "status": "ok", "tau": s["tau"], "objective": s["objective"],
                          "converged": s["converged"], "iterations": s["iterations"], "folder": folder.name,
                          "resumed": True}
        else:
            todo.append((k, tau0, folder))
    if todo:
        from dask.distributed import Client, LocalCluster

        cluster = None if scheduler else LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                                      dashboard_address=None)
        with Client(scheduler or cluster) as client:
            futures = [client.submit(_run_start, cfg.sections, str(cfg.base), tau0, str(folder),
                                     f"{title} (start {k}, tau0 = {tau0:g})", pure=False)
                       for k, tau0, folder in todo]
            for (k, _, _), fut in zip(todo, futures):
                results[k] = fut.result()
        if cluster is not None:
            cluster.close()
    return [results[k] for k in sorted(results)]


def check_gradient(cfg: Config, *, seed: int = 0, J: ReducedFunctional | None = None, report=None) -> dict:
    """Taylor tests of the exact gradient at a nonzero control, for xi, tau and joint directions.

    The point is ``xi = 0.1 * xi_scale * (smooth random field)`` and the configured tau0 (or T/2),
    so that J depends on tau (at xi = 0 the state is trivial and J is flat in tau). ``J``: as in
    `optimize_single`. ``report(name, result)``: called as each direction's test ends.
    """
    tau0 = cfg.tau_starts()[0]
    J = J or build_reduced(cfg, tau0)
    dirs = random_directions(J, J.zero(tau0), seed=seed)
    m = ControlPoint(0.1 * dirs["xi"].xi, tau0)
    out = {}
    for name, dm in random_directions(J, m, seed=seed + 1).items():
        r = taylor_test(J, m, dm)
        out[name] = r.as_dict()
        if report is not None:
            report(name, out[name])
    return out

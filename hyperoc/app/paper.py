"""``hyperoc reproduce paper-1d``: the paper's 1D experiment, with the paper's own bound and with a smooth cost.

All runs are on the setup of the paper's table of parameters (``hyperoc/data/paper-1d.toml``), by
projected Newton-CG (`hyperoc.control.optimize.newton_cg`) to a relative projected gradient of ``gtol``
(1e-6) from ``(xi, tau) = (0, T/2)``, unless named otherwise. The formulations
(`FORMULATIONS`):

1. ``bounded``: the paper's problem, ``alpha = 2e-3``, ``beta = 0``, with the norm bound of its Remark
   ``rk-box`` in pointwise form, ``|xi| <= XI_MAX``, on the paper's ``omega = [0.75, 1]``;
2. ``interior``: the same with ``omega = OMEGA_INTERIOR``, compactly inside the bar as the paper's
   theory assumes (no load on the constrained node);
3. ``smooth``: the cost ``alpha/2 ||xi||^2 + beta/2 ||d xi/dt||^2`` with ``alpha = beta = 10`` and no
   bound, at its largest maximum in tau: free-tau runs from the ``REFINED_MAXIMA`` largest maxima of its
   value profile, the best end kept;
4. ``smooth_local``: the same from the paper's start, the local maximizer found there;
5. ``as_stated``: the paper's Algorithm 1 on the problem as stated (no bound; a control is admissible when
   its state exists on all of [0, T]), and ``ray.json``: J along ``s * xi`` for the control it ends with.

`HEADLINE`, decided by measurement, is the formulation closest to the paper with a verified KKT point and a
mesh-converged tau*: the smooth one. The bounded problem has KKT points (projected gradient 1e-6 from the
paper's start), but its J* grows by 28 % when dt alone is refined at h = 0.01 and those runs do not reach
the KKT tolerance in 300 iterations, and its value profile grows towards T (docs/wellposedness.md).
`HEADLINE` is written to the top level of the output folder, the others to folders of their names. The
value profile ``J*(tau) = max_xi J(xi, tau)`` of the headline's formulation (`value_profile`) is solved on
``PROFILE_TAUS`` in two halves, each point warm-started from its neighbour, into ``profile.json`` and
``profile.png``. With ``quick`` only the profile and the headline run. With two CPUs the jobs go to two
worker processes, each bound to a CPU of its own (`_run_jobs`); this process only starts them (it imports
neither JAX nor SciPy) and writes the summary: the headline's keys at the top level, ``runs`` (every
formulation's converged/KKT values), ``profile`` (with the headline's starts and ends under ``maxima``), and
the paper's reported values.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import InputError, SolverError
from ..io import read_json, write_json
from ..solvers.threads import ONE_THREAD_POOL, bind_threads
from .config import Config, parse_config, set_entries

__all__ = ["paper_config", "formulation_config", "reproduce_paper_1d", "value_profile", "transferred_control",
           "PAPER_REPORT", "FORMULATIONS", "HEADLINE", "WELL_POSED", "XI_MAX", "OMEGA_INTERIOR"]

PAPER_REPORT = {
    "tau": 7.9,
    "tau0": 7.5,
    "control_off_from_t": 7.48,
    "pressure_maxima_near_t": [6.3, 7.9],
    "alpha": 2e-3,
    "beta": 0.0,
    "source": "Court, section 'Results' (Figures figControl, fig-pressure)",
}

# The bound of Remark rk-box, pointwise: with it every element stays far from the compression limit at the
# optimum (min det F ~0.89), where a bound 0.05 drives the wall element towards it (docs/wellposedness.md).
XI_MAX = 0.02
OMEGA_INTERIOR = [0.75, 0.95]  # omega compactly inside (0, 1), as the paper's control operator assumes
# The bounded problem is not concave on its free values and ill-conditioned: projected Newton-CG reaches the
# KKT tolerance where L-BFGS-B stalls far from it (docs/wellposedness.md); J and its gradient on the steps
# up to tau (`ReducedFunctional.horizon`), which give the same values. Its metric takes tau unweighted, as the
# paper's Algorithm 1 takes the gradient (weighted by its range, Newton-CG from the same start ends at another
# KKT point, at the end of tau's box, where the value profile's rise towards T ends).
BOUNDED = {"optimize.method": "newton", "optimize.xi_bounds": [-XI_MAX, XI_MAX], "optimize.horizon": "objective",
           "optimize.max_iter": 200, "optimize.tau_scale": 1.0}
# The smooth variant: a control cost that competes with the pressure, H^1 in time (sqrt(beta / alpha) = 1 time
# unit); no bound is reached (min det F 0.77 at the largest maximum, 0.84 at the one nearest T/2).
WELL_POSED = {"objective.alpha": 10.0, "objective.beta": 10.0, "optimize.method": "newton",
              "optimize.horizon": "objective"}
FORMULATIONS = {
    "bounded": (f"paper's problem, |xi| <= {XI_MAX} (Remark rk-box), omega = [0.75, 1], Newton-CG", BOUNDED),
    "interior": (f"paper's problem, |xi| <= {XI_MAX}, omega = {OMEGA_INTERIOR} (compactly inside), Newton-CG",
                 {**BOUNDED, "control.region": {"kind": "box", "lower": OMEGA_INTERIOR[:1],
                                                "upper": OMEGA_INTERIOR[1:]}}),
    "smooth": ("paper's problem with an H1-in-time cost (alpha = beta = 10), Newton-CG from the value profile's "
               "maxima", WELL_POSED),
    "smooth_local": ("the same from the paper's start (0, 7.5): a local maximizer", WELL_POSED),
    "as_stated": ("as stated, Algorithm 1", {}),
}
HEADLINE = "smooth"
HEADLINE_REASON = ("headline: the formulation closest to the paper with a verified KKT point and a mesh-converged "
                   "tau*, at the largest maximum of its value profile; the bounded problem (bounded/) has KKT "
                   "points, but its J* grows under dt refinement and its value profile rises towards T "
                   "(docs/wellposedness.md)")
# (0, T) at a quarter of the spacing of the pressure peaks: J*(tau) has maxima about 1 apart, each ~0.5 wide.
PROFILE_TAUS = tuple(float(t) for t in np.arange(1.0, 14.25, 0.5))
REFINED_MAXIMA = 2  # the profile's maxima refined with tau free on the headline's grid, the best kept
# The profile's grid: the paper's c dt / h (0.77) at h = 0.02; the headline's own grid is 4x the cost.
PROFILE_GRID = {"mesh.n": 50, "dynamics.dt": 0.04}


def paper_config(changes: dict | None = None) -> Config:
    """The shipped configuration of Table tab-param (``hyperoc/data/paper-1d.toml``) with ``changes``
    (``{"SECTION.KEY": value}``, as `set_entries` and ``--set``, e.g. ``{"mesh.n": 50}``), validated as a
    whole (a changed method gets its own options' defaults)."""
    import tomllib

    data = tomllib.loads(resources.files("hyperoc").joinpath("data/paper-1d.toml").read_text())
    return parse_config(set_entries(data, changes or {}))


def formulation_config(key: str, changes: dict | None = None) -> Config:
    """The configuration of formulation ``key`` of `FORMULATIONS` with ``changes`` on top."""
    return paper_config({**FORMULATIONS[key][1], **(changes or {})})


def _run(cfg: Config, key: str, out: Path, *, progress: bool, starts: list | None = None) -> tuple:
    """One optimization written to ``out`` (figures titled with the run's name): from ``(0, tau0)``, or the
    best of the free-tau runs from each of ``starts`` (`_optimized`). Returns the run's row, J and the
    result."""
    from .._jax import compilation_clock
    from .workflows import CACHE_DIR, write_optimization_outputs

    started, (compiling, compilations) = time.perf_counter(), compilation_clock()
    J, res, scale, ends = _optimized(cfg, starts, out / CACHE_DIR, progress)
    optimized, (compiled, compilations_after) = time.perf_counter(), compilation_clock()
    marks = [(t, "paper's pressure maxima") for t in PAPER_REPORT["pressure_maxima_near_t"]]
    label = FORMULATIONS[key][0]
    summary = write_optimization_outputs(out, cfg, J, res, extra={"label": label}, title=f"paper-1d, {label}",
                                         pressure_marks=marks)
    sol = J.state(res.point)  # the outputs' solve on [0, T], kept for the last point
    timings = {"compilation_s": compiled - compiling, "compilations": compilations_after - compilations,
               "optimization_s": optimized - started - (compiled - compiling),
               "outputs_s": time.perf_counter() - optimized}
    g = summary["grad_norm_history"]
    maxima_t, maxima_p = _local_maxima(sol.t, sol.pressure)
    region = cfg["control"]["region"]
    return {
        "name": key,
        "label": label,
        "folder": "." if key == HEADLINE else key,
        "dt": float(cfg["dynamics"]["dt"]),
        "h": 1.0 / cfg["mesh"]["n"],
        "alpha": float(cfg["objective"]["alpha"]),
        "beta": float(cfg["objective"].get("beta", 0.0)),
        "method": cfg["optimize"]["method"],
        "xi_bounds": cfg["optimize"].get("xi_bounds"),
        "omega": [region["lower"][0], region["upper"][0]],
        "observation": cfg["objective"].get("observation", "centred"),
        "nonmonotone": int(cfg["optimize"].get("nonmonotone", 0)),
        "tau": summary["tau"],
        "objective": summary["objective"],
        "iterations": summary["iterations"],
        "converged": summary["converged"],
        "message": res.message,
        "relative_gradient": g[-1] / scale if g and scale > 0 else None,
        "starts": ends,
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


def _optimized(cfg: Config, starts: list | None, cache_dir: Path, progress: bool) -> tuple:
    """``(J, result, scale, ends)``: the optimization from ``(0, tau0)``, or from each `SampledControl` of
    ``starts`` with tau free, keeping the best end point. ``scale``: the projected gradient of the zero control
    at the start's tau, to which the stopping test is relative (`cold_stationarity`); ``ends``: each start's
    tau0, end point, J, iterations and relative projected gradient."""
    from ..control.optimize import BoxProblem
    from ..control.reduced import ControlPoint
    from .workflows import build_reduced, optimize_single

    o = cfg["optimize"]
    if not starts:
        J, res = optimize_single(cfg, float(o["tau0"]), cache_dir=cache_dir, progress=progress)
        return J, res, res.history["grad_norm"][0], []
    J, ends = build_reduced(cfg, starts[0].tau), []
    for start in starts:
        tau_range = BoxProblem.around(J, start.tau, tau_margin=o.get("tau_margin")).tau_range
        scale = cold_stationarity(J, start.tau, tau_range, cfg.xi_bounds())
        _, res = optimize_single(cfg, start.tau, J=J, progress=progress, gradient_scale=scale,
                                 start=ControlPoint(start.on(J, start.tau), start.tau))
        ends.append((res, scale, start.tau))
    res, scale, _ = max(ends, key=lambda end: end[0].objective)
    return J, res, scale, [{"tau0": tau0, "tau": r.point.tau, "objective": r.objective, "converged": r.converged,
                            "relative_gradient": r.history["grad_norm"][-1] / c, "iterations": r.iterations}
                           for r, c, tau0 in ends]


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


def _formulation_job(key: str, overrides: dict, out: Path, progress: bool, profile: list | None = None) -> dict:
    """Formulation ``key`` written to the top level of ``out`` (the headline) or to ``out/key``: the headline
    by free-tau runs from the ``REFINED_MAXIMA`` largest maxima of the value ``profile`` (its halves, as
    `_profile_job` returns them), every other run from ``(0, tau0)``; the problem as stated is followed by
    the ray study at its end point. ``interior`` runs on ``PROFILE_GRID``: on the paper's grid Newton-CG does
    not reach the KKT tolerance in 300 iterations (docs/wellposedness.md)."""
    grid = PROFILE_GRID if key == "interior" else {}
    starts = None
    if key == HEADLINE:
        rows, controls = _merged_profile(profile)
        starts = [controls[k] for k in profile_maxima([r["J"] for r in rows], REFINED_MAXIMA)]
    row, J, res = _run(formulation_config(key, {**grid, **overrides}), key, out if key == HEADLINE else out / key,
                       progress=progress, starts=starts)
    if key != "as_stated":
        return {key: row}
    ray = ray_study(J, res.point)
    write_json(out / "ray.json", ray)
    return {key: row, "ray": ray}


def _merged_profile(halves: list) -> tuple[list, list]:
    """The rows and controls of the profile's halves in increasing tau."""
    pairs = sorted(((row, c) for rows, controls in halves for row, c in zip(rows, controls)),
                   key=lambda pair: pair[0]["tau"])
    return [row for row, _ in pairs], [c for _, c in pairs]


@dataclass(frozen=True)
class SampledControl:
    """A 1D control as samples, to carry it to another grid or another tau: values ``xi`` (levels, nodes) at
    the time levels ``t`` (levels,) and the control nodes' coordinates ``x`` (nodes,), for the time
    ``tau``."""

    tau: float
    t: np.ndarray
    x: np.ndarray
    xi: np.ndarray

    @classmethod
    def of(cls, J, m) -> SampledControl:
        """The samples of ``m`` (a `hyperoc.control.reduced.ControlPoint` of J) up to its tau: a maximizer is
        zero after tau, where the objective does not read the control (values left there by a warm start
        are dropped)."""
        t = J.transform.grid(m.tau).t
        kept = t <= m.tau
        return cls(float(m.tau), t[kept], J.model.control.coordinates(J.model.space)[:, 0], np.asarray(m.xi)[kept])

    def on(self, J, tau: float) -> np.ndarray:
        """The control on the time levels of J at ``tau`` and J's control nodes, shifted in time by
        ``tau - self.tau`` (it keeps its timing before tau): linear interpolation in t and x, zero before 0
        and after T. Shape (levels of J, control nodes of J)."""
        t_to = J.transform.grid(tau).t - (tau - self.tau)
        x_to = J.model.control.coordinates(J.model.space)[:, 0]
        order = np.argsort(self.x)
        in_space = np.array([np.interp(x_to, self.x[order], row[order]) for row in self.xi])
        return np.array([np.interp(t_to, self.t, col, left=0.0, right=0.0) for col in in_space.T]).T


def transferred_control(J_from, m, J_to, tau: float) -> np.ndarray:
    """The control of ``m`` (a `hyperoc.control.reduced.ControlPoint` of ``J_from``) on the time levels of
    ``J_to`` at ``tau`` and its control nodes (`SampledControl.on`)."""
    return SampledControl.of(J_from, m).on(J_to, tau)


def cold_stationarity(J, tau: float, tau_range, xi_bounds) -> float:
    """The projected gradient norm of the zero control at ``tau`` (`stationarity`): the scale of every
    stopping test of this job, so that a warm start meets the same test as a cold one."""
    from ..control.optimize import stationarity

    zero = J.zero(tau)
    return stationarity(J, zero, J.value_and_gradient(zero)[1], tau_range, xi_bounds)


def value_profile(cfg: Config, taus, *, warm_start: SampledControl | None = None) -> tuple[list, list]:
    """``J*(tau) = max_xi J(xi, tau)`` at each of ``taus`` (in that order) for ``cfg`` with tau fixed, by
    projected Newton-CG with ``cfg``'s bounds, each solve warm-started from the previous one's control
    (shifted to the new tau, `SampledControl.on`; the first from ``warm_start`` or zero) and stopped at a
    projected gradient ``gtol`` times that of the zero control at the same tau (`cold_stationarity`).

    The points share one time transform, built at the largest tau, so that they share compiled solves: the
    steps on [0, tau] are ``tau / N1``, at most the configured dt. Returns one row per tau (J*, whether the
    stopping test was met, the relative projected gradient, iterations, dt on [0, tau], min det F up to tau,
    max |xi| and the wall time, compilations included) and the maximizers as `SampledControl`, in the same order."""
    from ..control.optimize import BoxProblem, NewtonCGOptions, newton_cg
    from ..control.reduced import ControlPoint
    from .workflows import build_reduced

    J = build_reduced(cfg, max(taus))
    o, bounds = cfg["optimize"], cfg.xi_bounds()
    previous = warm_start
    rows, controls = [], []
    for tau in taus:
        started = time.perf_counter()
        cold = cold_stationarity(J, tau, (tau, tau), bounds)
        xi0 = J.zero(tau).xi if previous is None else previous.on(J, tau)
        res = newton_cg(BoxProblem.around(J, tau, xi_bounds=bounds, fix_tau=True),
                        ControlPoint(np.clip(xi0, *bounds) if bounds != (None, None) else xi0, tau),
                        gtol=0.0, gtol_abs=float(o["gtol"]) * cold, max_iter=int(o["max_iter"]),
                        options=NewtonCGOptions(max_cg=int(o["max_cg"])))
        sol = J.state(res.point)
        k = J.transform.tau_index
        rows.append({"tau": tau, "h": 1.0 / cfg["mesh"]["n"], "J": res.objective, "converged": res.converged,
                     "relative_gradient": res.history["grad_norm"][-1] / cold, "iterations": res.iterations,
                     "dt": float(np.diff(sol.t[:k + 1]).max()), "min_det_F": float(sol.min_det_F[:k + 1].min()),
                     "max_abs_xi": float(np.abs(res.point.xi[:k + 1]).max()),
                     "wall_time_s": time.perf_counter() - started})
        previous = SampledControl.of(J, res.point)
        controls.append(previous)
    return rows, controls


def profile_maxima(values, count: int) -> list[int]:
    """Indices of the ``count`` largest local maxima of ``values`` (a sequence on an ordered grid, an end
    counting when it exceeds its neighbour), largest first."""
    v = np.asarray(values, dtype=np.float64)
    padded = np.concatenate(([-np.inf], v, [-np.inf]))
    peaks = np.flatnonzero((v > padded[:-2]) & (v >= padded[2:]))
    return [int(k) for k in peaks[np.argsort(v[peaks])[::-1][:count]]]


def _profile_job(taus: list, overrides: dict, out: Path, progress: bool) -> dict:
    """`value_profile` of the headline's formulation on ``PROFILE_GRID`` (``overrides`` on top) at ``taus``."""
    return {f"profile_{taus[0]:g}": value_profile(formulation_config(HEADLINE, {**PROFILE_GRID, **overrides}),
                                                  taus)}


def refined_maximum(taus, values) -> tuple[float, float]:
    """``(tau, J)`` at the vertex of the parabola through the largest of ``values`` and its neighbours (the
    grid point itself at an end of the grid)."""
    k = int(np.argmax(values))
    if k in (0, len(values) - 1):
        return float(taus[k]), float(values[k])
    c = np.polyfit(taus[k - 1:k + 2], values[k - 1:k + 2], 2)
    tau = -c[1] / (2 * c[0])
    return float(tau), float(np.polyval(c, tau))


def _profile_summary(halves: list, headline: dict, out: Path) -> dict:
    """The two halves of the profile as one table in increasing tau, written to ``profile.json`` and drawn
    with the paper's tau and the headline's tau* in ``profile.png``."""
    from .plotting import plot_value_profile

    rows, _ = _merged_profile(halves)
    table = {key: [r[key] for r in rows] for key in rows[0]}
    tau_max, value_max = refined_maximum(np.array(table["tau"]), np.array(table["J"]))
    profile = {**table, "tau_refined": tau_max, "J_refined": value_max, "formulation": HEADLINE,
               "maxima": headline["starts"]}
    write_json(out / "profile.json", profile)
    plot_value_profile(out / "profile.png", table["tau"], table["J"], table["converged"],
                       marks=[(PAPER_REPORT["tau"], f"paper's tau = {PAPER_REPORT['tau']}"),
                              (headline["tau"], f"tau* = {headline['tau']:.3f} (headline)")],
                       title=f"paper-1d, value profile: {FORMULATIONS[HEADLINE][0]}")
    return profile


def _jobs(out: Path, quick: bool, overrides: dict) -> dict:
    """The studies as jobs ``key -> (function, kwargs, needs)``, ``needs`` the jobs whose results the function
    takes (as ``profile``), in the order a free worker takes them once what they need is done: the two
    halves of the profile (outwards from T/2, each starting cold), the headline from the profile's maxima
    and, unless ``quick``, the other formulations, longest first."""
    middle = len(PROFILE_TAUS) // 2
    halves = {f"profile_{taus[0]:g}": (_profile_job, dict(taus=list(taus), overrides=overrides, out=out), ())
              for taus in (PROFILE_TAUS[middle:], PROFILE_TAUS[:middle][::-1])}
    jobs = {**halves, HEADLINE: (_formulation_job, dict(key=HEADLINE, overrides=overrides, out=out), tuple(halves))}
    if not quick:
        jobs.update({key: (_formulation_job, dict(key=key, overrides=overrides, out=out), ())
                     for key in FORMULATIONS if key != HEADLINE})
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
    """Results of every job of `_jobs`, by key. With ``workers > 1`` every job runs in one of
    ``min(workers, jobs)`` fresh (spawned: JAX is not fork-safe) processes, each bound to a CPU of its own
    (`_pin_worker`); a job is submitted when a worker is free and what it needs is done, so that the
    headline goes before the longer runs once the profile is there; progress bars are shown for the headline
    only.

    Why no job runs in this process: a process that loads NumPy's and SciPy's OpenBLAS with two CPUs
    keeps a BLAS thread, which spins beside the job once the process is bound to one CPU (the
    headline's Newton-CG took 2.4x as long). The workers start bound to one CPU, this process's, so
    their BLAS has no thread of its own, and bind themselves to theirs before the job imports JAX."""
    if workers == 1 or len(jobs) == 1:
        results = {}
        for key, (fn, kwargs, needs) in jobs.items():  # listed after what they need
            results[key] = fn(progress=progress and key == HEADLINE, **kwargs, **_needed(needs, results))
        return results
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    ctx = multiprocessing.get_context("spawn")
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    cpus = _pin_to_cpu(0, allowed)  # inherited by the workers as they start
    # The 1D problems need no host solves, and a second XLA pool thread on a worker's CPU only spins:
    # 1.2x slower (measured), so the workers keep the one-thread pool (`hyperoc.solvers.threads.start_backend`).
    os.environ[ONE_THREAD_POOL] = "1"
    size, pending, running, results = min(workers, len(jobs)), dict(jobs), {}, {}
    try:
        with ProcessPoolExecutor(size, mp_context=ctx, initializer=_pin_worker,
                                 initargs=(ctx.Value("i", 0), allowed)) as pool:
            while pending or running:
                ready = [key for key, (_, _, needs) in pending.items() if set(needs) <= set(results)]
                for key in ready[:size - len(running)]:
                    fn, kwargs, needs = pending.pop(key)
                    running[pool.submit(fn, progress=progress and key == HEADLINE, **kwargs,
                                        **_needed(needs, results))] = key
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                results.update({running.pop(future): future.result() for future in done})
            return results
    finally:
        os.environ.pop(ONE_THREAD_POOL, None)
        _restore_cpus(cpus)


def _needed(needs: tuple, results: dict) -> dict:
    """The keyword a job takes the results of the jobs it needs by: ``profile``, their values in order."""
    return {"profile": [v for key in needs for v in results[key].values()]} if needs else {}


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
    for key in FORMULATIONS:  # bad overrides: InputError before anything is written
        formulation_config(key, overrides)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    results = {k: v for job in _run_jobs(_jobs(out, quick, overrides), workers, progress).values()
               for k, v in job.items()}
    headline = results[HEADLINE]
    runs = [results[key] for key in FORMULATIONS if key in results]
    halves = [v for k, v in results.items() if k.startswith("profile_")]
    run_summary = read_json(out / "summary.json")  # the headline run's own summary (histories, files)
    summary = {**run_summary, **{k: headline[k] for k in ("name", "label", "alpha", "beta", "method", "xi_bounds",
                                                           "omega", "relative_gradient", "pressure_at_tau",
                                                           "control_off_from_t", "pressure_local_maxima_t",
                                                           "pressure_local_maxima_p", "min_det_F", "max_abs_xi",
                                                           "timings")},
               "runs": runs, "profile": _profile_summary(halves, headline, out),
               "paper": PAPER_REPORT, "ray": results.get("ray", []),
               "config": formulation_config(HEADLINE, overrides).sections,
               "workers": workers, "wall_time_s": time.perf_counter() - started}
    write_json(out / "summary.json", summary)
    _print_report(out, summary)
    return summary


def _print_report(out: Path, summary: dict) -> None:
    """The headline first (one line), then the paper's values, the other formulations and the profile."""
    print(f"{summary['label']}: tau* = {summary['tau']:.3f}, J* = {summary['objective']:.6g}, "
          f"converged = {summary['converged']} (relative projected gradient {summary['relative_gradient']:.2g} "
          f"after {summary['iterations']} iterations), min det F = {summary['min_det_F']:.3g}, pressure maxima "
          f"at t = {[round(x, 2) for x in summary['pressure_local_maxima_t']]}, control off from t = "
          f"{_rounded(summary['control_off_from_t'])}")
    print(HEADLINE_REASON)
    p = summary["paper"]
    print(f"paper (alpha = {p['alpha']:g}, beta = 0): tau ~ {p['tau']}, control off from t ~ "
          f"{p['control_off_from_t']}, pressure maxima near t = {p['pressure_maxima_near_t']}")
    for r in summary["runs"]:
        if r["name"] != summary["name"]:
            print(f"  {r['label']} ({r['folder']}/): tau = {r['tau']:.3f}, J = {r['objective']:.5g}, "
                  f"iterations = {r['iterations']}, converged = {r['converged']} (relative gradient "
                  f"{r['relative_gradient']:.2g}), min det F = {r['min_det_F']:.3g}")
    q = summary["profile"]
    if q:
        spread = (max(q["J"]) - min(v for v, t in zip(q["J"], q["tau"]) if abs(t - q["tau_refined"]) <= 1.5))
        print(f"  value profile J*(tau) on tau = {q['tau'][0]:g} .. {q['tau'][-1]:g} (h = {q['h'][0]:g}, "
              f"dt <= {max(q['dt']):.3g}): maximum at tau = {q['tau_refined']:.2f}, J* = "
              f"{q['J_refined']:.5g}; J* varies by {spread / max(q['J']):.1%} within 1.5 of it; "
              f"{sum(q['converged'])}/{len(q['tau'])} points converged (profile.png)")
    print(f"-> {out / 'summary.json'} ({summary['wall_time_s']:.0f} s)")


def _rounded(x):
    return None if x is None else round(x, 2)

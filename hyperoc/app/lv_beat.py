"""``hyperoc reproduce lv-beat``: the paper's hybrid problem on a beating left ventricle.

The problem is the shipped configuration ``hyperoc/data/lv-beat.toml``: one beat of the cardiac elastodynamics
benchmark's ventricle (Aróstica et al. 2025; its coarse mesh, Holzapfel-Ogden, spring-dashpot epicardium and
base, SI units), the benchmark's Bestel activation T_a(t) driving it. The cavity is closed by the valves and a
3-element Windkessel (`hyperoc.dynamics.constraint.Circulation`); the left-ventricular pressure p(t) is the
multiplier of the cavity's row. From end-diastole (both valves closed) the beat passes through isovolumic
contraction, ejection, isovolumic relaxation and filling.

The control modulates the activation on the apical region: the fibre tension there is ``T_a(t) (1 - xi(x, t))``,
xi dimensionless (``[control] profile = "activation"``), within ``[optimize] xi_bounds = [-1, 1]`` (from no
tension to twice the prescribed one: a contraction cannot push), beside the free time tau. The objective is the
clinical contractility index, the rate of pressure rise, at tau,

    J(xi, tau) = (p(tau + eps) - p(tau)) / eps - alpha/2 ||xi||^2 - beta/2 ||d xi/dt||^2,

maximized by projected Newton-CG on the exact gradient and Hessian products, tau weighted in its metric by J's
curvature in tau (``tau_scale = "curvature"``), from the zero control at ``[optimize] tau0``, to a projected
gradient of ``gtol`` relative to the zero control's, or ``[optimize] max_iter`` iterations. The optimization
solves the steps up to tau + eps (``horizon = "objective"``); the outputs are the whole beat.

`reproduce_lv_beat` writes

- ``optimized/``: the optimization's outputs (``results.npz`` with the control, ``summary.json``, the ParaView
  series ``paraview/state`` with the control on the wall, ``pressure.png``, ``control.png``, ``history.png``);
- ``uncontrolled/``: the same beat without the control, on the same time grid, with tau* marked;
- ``pressure.png``: both pressures and their rates of rise over eps, tau* marked; ``pv_loops.png``: both
  pressure-volume loops (the cavity volume as the constraint holds it);
- ``summary.json``: tau*, J*, converged, the relative projected gradient, iterations, the rate of pressure
  rise at tau* with and without the control (the gain), the uncontrolled beat's largest rate, each beat's valve
  events, ejection (stroke volume, ejection fraction) and isovolumic volume change
  (`hyperoc.cardiac.hemodynamics.beat_indices`), and wall times.
"""

from __future__ import annotations

import time
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from ..cardiac.hemodynamics import solution_beat
from ..io import write_json

__all__ = ["beat_config", "reproduce_lv_beat", "pressure_rise", "BEAT_CONFIG"]

#: The shipped configuration of the job, under ``hyperoc/data``.
BEAT_CONFIG = "lv-beat.toml"
#: Half-width (s) of pressure.png's panel of the rates of rise around tau*, where the control acts.
ZOOM = 0.01


def beat_config(entries: dict | None = None):
    """The `hyperoc.app.config.Config` of the job (`BEAT_CONFIG`), with the ``{"SECTION.KEY": value}`` of
    ``entries`` set (`hyperoc.app.config.set_entries`)."""
    from .config import parse_config, set_entries

    source = resources.files("hyperoc").joinpath("data", BEAT_CONFIG)
    data = set_entries(tomllib.loads(source.read_text(encoding="utf-8")), entries or {})
    return parse_config(data, Path("."), "lv-beat")


def pressure_rise(t: np.ndarray, p: np.ndarray, eps: float) -> np.ndarray:
    """The rate of pressure rise ``(p(t + eps) - p(t)) / eps`` (pressure / time) at the levels ``t`` (L,) with
    ``t + eps`` inside the run, p (L,) interpolated linearly between levels; shape (L',) with L' <= L."""
    inside = t + eps <= t[-1] * (1 + 1e-12)
    return (np.interp(t[inside] + eps, t, p) - p[inside]) / eps


def reproduce_lv_beat(out, *, progress: bool = False, entries: dict | None = None) -> dict:
    """Run the job into the folder ``out`` (module docstring), the config's ``entries`` changed (`beat_config`);
    returns the summary."""
    from .report import write_state_outputs
    from .workflows import build_reduced, check_run, figure_units, optimize_single, write_optimization_outputs

    start = time.perf_counter()
    out = Path(out)
    cfg = beat_config(entries)
    model = check_run(cfg, "optimize")
    tau0 = float(cfg["optimize"]["tau0"])
    J = build_reduced(cfg, tau0, model)
    J, res = optimize_single(cfg, tau0, cache_dir=out / "optimized" / "cache", progress=progress, J=J)
    optimized = write_optimization_outputs(out / "optimized", cfg, J, res, title="lv-beat, optimized")
    tau, eps = res.point.tau, J.transform.eps
    sol_opt, sol_unc = J.state(res.point), J.state(J.zero(tau))
    units = figure_units(cfg)
    write_state_outputs(out / "uncontrolled", sol_unc, tau=tau, eps=eps, frames=cfg.fibres(model.mesh),
                        title="lv-beat, uncontrolled", units=units, cavity=cfg.cavity_wall())
    rise_unc = J.objective_terms(sol_unc)["PressureRise"]
    rise_opt = optimized["optimization"]["objective_terms"]["PressureRise"]
    sols = {"uncontrolled": sol_unc, "optimized": sol_opt}
    _write_figures(out, sols, tau, eps, units)
    beats = {name: solution_beat(sol) for name, sol in sols.items()}
    rates = pressure_rise(sol_unc.t, sol_unc.pressure, eps)
    k = int(np.argmax(rates))
    g = res.history["grad_norm"]
    summary = {
        "problem": "a beat of the benchmark ventricle closed by a Windkessel; max dp/dt at tau minus the control cost",
        "tau": float(tau), "objective": float(res.objective), "converged": bool(res.converged),
        "relative_gradient": float(g[-1] / g[0]), "iterations": int(res.iterations),
        "pressure_rise_at_tau": {"uncontrolled": rise_unc, "optimized": rise_opt},
        "pressure_rise_gain": rise_opt / rise_unc - 1.0,
        "uncontrolled_max_pressure_rise": {"value": float(rates[k]), "t": float(sol_unc.t[k])},
        "gain_over_uncontrolled_max": rise_opt / float(rates[k]) - 1.0,
        "control_min": float(np.min(res.point.xi)), "control_max": float(np.max(res.point.xi)),
        "beat": beats,
        "objective_terms": optimized["optimization"]["objective_terms"],
        "dofs": int(model.n), "steps": int(J.N),
        "optimization_wall_time_s": float(res.wall_time), "wall_time_s": time.perf_counter() - start,
        "folders": ["optimized", "uncontrolled"], "files": {"pressure_plot": "pressure.png", "pv_plot": "pv_loops.png"},
    }
    write_json(out / "summary.json", summary)
    return summary


def _write_figures(out: Path, sols: dict, tau: float, eps: float, units) -> None:
    """``pressure.png`` (p and its rate of rise for each run of ``sols``, tau* marked) and ``pv_loops.png``."""
    from .plotting import plot_pressure_comparison, plot_pv_loops

    curves = {name: (sol.t, sol.pressure) for name, sol in sols.items()}
    rises = {name: (sol.t[:len(r)], r) for name, sol in sols.items()
             for r in [pressure_rise(sol.t, sol.pressure, eps)]}
    plot_pressure_comparison(out / "pressure.png", curves, rises, tau=tau, eps=eps, zoom=ZOOM,
                             title="lv-beat: LV pressure, uncontrolled and optimized", units=units)
    plot_pv_loops(out / "pv_loops.png", {name: (sol.constrained_volume, sol.pressure) for name, sol in sols.items()},
                  title="lv-beat: pressure-volume loops", units=units)

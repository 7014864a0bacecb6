"""Is the paper's 1D problem well posed? The end point of Algorithm 1 under refinement, with and without
the cost ``beta/2 ||d xi/dt||^2`` (controls H^1 in time).

Setup: the paper's Table tab-param (SVK mu = lambda = 0.05, damping kappa = 2e-4, alpha = 2e-3, T = 15,
omega = [0.75, 1], phi1 = p(tau), P1), start (xi, tau) = (0, 7.5), Algorithm 1 (``method = "bb"``) to a
relative gradient norm of 1e-6 or ``--max-iter`` iterations.

Tables (into ``bench_wellposed_sweep.json``):
1. ``beta = 0`` and each ``--betas`` value: the end point for dt in ``--dts`` at h = 0.01 and for h in
   ``--hs`` at dt = 0.02 (J, p(tau), max |xi|, min det F over [0, T] and its time, iterations, final
   relative gradient, trial points where the state solver failed, the stop reason). A problem with a
   maximizer shows J converging and the relative gradient reaching 1e-6; an ill-posed one shows J or
   max |xi| growing under refinement, or the run stopping where no step keeps the state alive.
2. The discrete reaction's response to a unit nodal load held over [6.5, 7.5], at the constrained
   node x = 1 and at its neighbour: ``p(tau) = h/2`` and ``h``, whatever the material, because that
   load reaches the multiplier without straining an element (a consistency error O(h |xi|) of the
   discrete reaction, which an optimizer with a cheap control exploits).

    python bench/bench_wellposed.py                        # full study (~30 min on one core)
    python bench/bench_wellposed.py --quick                # dt in {0.04, 0.02}, h in {0.02}, one beta
    python bench/bench_wellposed.py --variant 10,10        # alpha = beta = 10: local maximizers, two methods
    python bench/bench_wellposed.py --variant 10,10 --grid # Newton-CG and L-BFGS-B on the 3 x 3 (h, dt) grid
    python bench/bench_wellposed.py --variant 10,10 --noise # the round-off of J where L-BFGS-B stops
    python bench/bench_wellposed.py --variant 10,10 --beta-sweep 0,0.1,1,10,100  # Newton-CG, alpha = 10

With ``--variant ALPHA,BETA`` it runs instead L-BFGS-B and Algorithm 1 from tau0 = 7.5 and 6.3 on
(h, dt) = (0.02, 0.04) and (0.01, 0.02) with those weights (a control cost that competes with the
pressure, so the optimum stays in the elastic range), into ``bench_wellposed_variant.json``. With
``--grid`` as well: each of ``--methods`` (default Newton-CG, the main job's method, and L-BFGS-B) from
tau0 = 7.5 on h in {0.02, 0.01, 0.005} x dt in {0.04, 0.02, 0.01} (iteration counts against their median;
successive differences of tau* and J* along each refinement, their observed order and the Richardson
estimate), into ``bench_wellposed_grid.json``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hyperoc.app.paper import paper_config
from hyperoc.app.workflows import build_reduced
from hyperoc.control.optimize import barzilai_borwein, lbfgsb, newton_cg
from hyperoc.control.reduced import ControlPoint
from hyperoc.errors import SolverError
from results import command_line, table, write_results

TAU0 = 7.5
COLUMNS = ["beta", "h", "dt", "J", "p(tau)", "max |xi|", "min det F", "at t", "tau", "iterations",
           "final rel. gradient", "failed trials", "stop"]


def end_point(beta: float, h: float, dt: float, max_iter: int) -> list:
    """One Algorithm 1 run from (0, TAU0); the row of table 1."""
    cfg = paper_config({"objective.beta": beta, "mesh.n": int(round(1 / h)), "dynamics.dt": dt})
    J = build_reduced(cfg, TAU0)
    started = time.perf_counter()
    res = barzilai_borwein(J, J.zero(TAU0), gtol=1e-6, max_iter=max_iter)
    sol = J.state(res.point)
    g = res.history["grad_norm"]
    k = int(np.argmin(sol.min_det_F))
    row = [beta, h, dt, res.objective, float(sol.pressure[J.transform.tau_index]), float(np.abs(res.point.xi).max()),
           float(sol.min_det_F[k]), float(sol.t[k + 1]), res.point.tau, res.iterations, g[-1] / g[0],
           res.failed_trials, "converged" if res.converged else res.message]
    print("  ".join(_fmt(v) for v in row), f"({time.perf_counter() - started:.0f} s)", flush=True)
    return row


METHOD_NAMES = {"newton": "Newton-CG", "lbfgsb": "L-BFGS-B", "bb": "Algorithm 1"}
VARIANT_COLUMNS = ["method", "tau0", "h", "dt", "J", "tau", "iterations", "converged", "final rel. gradient",
                   "min det F", "max |xi|", "state solves"]


def variant_run(alpha: float, beta: float, method: str, tau0: float, h: float, dt: float, max_iter: int) -> list:
    """One run of the variant with weights (alpha, beta); the row of the variant table."""
    cfg = paper_config({"objective.alpha": alpha, "objective.beta": beta, "mesh.n": int(round(1 / h)),
                       "dynamics.dt": dt})
    J = build_reduced(cfg, tau0)
    run = {"lbfgsb": lbfgsb, "bb": barzilai_borwein, "newton": newton_cg}[method]
    res = run(J, J.zero(tau0), gtol=1e-6, max_iter=max_iter)
    sol = J.state(res.point)
    g = res.history["grad_norm"]
    row = [method, tau0, h, dt, res.objective, res.point.tau, res.iterations, res.converged, g[-1] / g[0],
           float(sol.min_det_F.min()), float(np.abs(res.point.xi).max()), res.evaluations["state_solves"]]
    print("  ".join(_fmt(v) for v in row), flush=True)
    return row


def variant_study(alpha: float, beta: float, max_iter: int) -> None:
    rows = [variant_run(alpha, beta, method, tau0, h, dt, max_iter)
            for h, dt in ((0.02, 0.04), (0.01, 0.02)) for tau0 in (7.5, 6.3) for method in ("lbfgsb", "bb")]
    write_results("bench_wellposed_variant", command_line(), [table(
        f"The paper's setup with alpha = {alpha:g}, beta = {beta:g}: end points of L-BFGS-B and Algorithm 1",
        VARIANT_COLUMNS, rows, "converged: relative gradient (H^1 metric) <= 1e-6 within the iterations allowed")])


def beta_sweep(alpha: float, betas: list, max_iter: int) -> None:
    """Newton-CG from (0, 7.5) with the weight ``alpha`` and each beta, on (h, dt) = (0.02, 0.04) and
    (0.01, 0.02): for which beta does the end point converge, and stay put under refinement?"""
    rows = [[beta, *variant_run(alpha, beta, "newton", TAU0, h, dt, max_iter)[2:]]
            for beta in betas for h, dt in ((0.02, 0.04), (0.01, 0.02))]
    write_results("bench_wellposed_beta", command_line(), [table(
        f"alpha = {alpha:g}: Newton-CG from tau0 = 7.5 for a range of beta", ["beta", *VARIANT_COLUMNS[2:]], rows,
        "converged: relative gradient <= 1e-6 within the iterations allowed")])


def noise_study(alpha: float, beta: float, h: float = 0.01, dt: float = 0.02, spread: float = 1e-9, k: int = 8) -> None:
    """Why L-BFGS-B stops short of 1e-6: the round-off of J at its end point m (h, dt), against the increase
    a gradient step can still make. Along d = G/|G| (G the gradient in the control space's metric) the
    noise is the standard deviation of ``J(m + j e d) - J(m) - j e |G|``, j = -k..k, e = ``spread``
    (the quadratic part e^2 k^2 |H| / 2 is below 1e-16); the curvature |H| is a central difference
    with step 1e-3. A step along d gains at most |G|^2 / (2 |H|), which is below the noise once
    |G| < sqrt(2 |H| noise): the floor of any line search that compares values of J."""
    cfg = paper_config({"objective.alpha": alpha, "objective.beta": beta, "mesh.n": int(round(1 / h)),
                        "dynamics.dt": dt})
    J = build_reduced(cfg, TAU0)
    res = lbfgsb(J, J.zero(TAU0), gtol=1e-6, max_iter=150)
    value, G = J.value_and_gradient(res.point)  # G: the gradient in the control space's metric
    gnorm = J.norm(G)
    d = G * (1.0 / gnorm)
    wiggle = [J(res.point + d * (j * spread)) - value - j * spread * gnorm for j in range(-k, k + 1)]
    noise = float(np.std(wiggle))
    e = 1e-3
    curvature = abs(J(res.point + d * e) + J(res.point + d * (-e)) - 2 * value) / e**2
    g0 = res.history["grad_norm"][0]
    floor = float(np.sqrt(2 * curvature * noise))
    row = [h, dt, value, noise, noise / abs(value), curvature, gnorm / g0, floor / g0, res.message]
    print("  ".join(_fmt(v) for v in row), flush=True)
    write_results("bench_wellposed_noise", command_line(), [table(
        f"Round-off of J at the end point of L-BFGS-B (alpha = {alpha:g}, beta = {beta:g})",
        ["h", "dt", "J", "noise of J", "relative noise", "curvature |H|", "final rel. gradient",
         "floor sqrt(2 |H| noise) / |G0|", "stop"], [row],
        "a line search comparing values of J cannot make progress once the relative gradient is below the floor; "
        "Newton-CG steps, whose length comes from the curvature, continue past it")])


def refinement_rows(label: str, rows: list, key: int) -> list:
    """Successive differences of column ``key`` over three rows refined by 2, the observed order and
    the Richardson estimate ``v3 + (v3 - v2) / (2^q - 1)``."""
    v = [r[key] for r in rows]
    d1, d2 = v[1] - v[0], v[2] - v[1]
    q = float(np.log2(abs(d1 / d2))) if d1 and d2 else float("nan")
    richardson = v[2] + d2 / (2**q - 1) if np.isfinite(q) and q > 0 else None
    return [label, *v, d1, d2, q, richardson]


def grid_study(alpha: float, beta: float, max_iter: int, methods: list) -> None:
    """Each of ``methods`` from tau0 = 7.5 on the (h, dt) grid; the refinement table from the first."""
    hs, dts = (0.02, 0.01, 0.005), (0.04, 0.02, 0.01)
    runs = {method: {(h, dt): variant_run(alpha, beta, method, 7.5, h, dt, max_iter) for h in hs for dt in dts}
            for method in methods}
    spread = []
    for method, by_grid in runs.items():
        median = float(np.median([r[6] for r in by_grid.values()]))
        spread += [[method, h, dt, by_grid[h, dt][6], by_grid[h, dt][6] / median - 1] for h in hs for dt in dts]
    rows = runs[methods[0]]
    diagonal = [rows[h, dt] for h, dt in zip(hs, dts)]
    fixed_h = [rows[0.01, dt] for dt in dts]
    fixed_dt = [rows[h, 0.02] for h in hs]
    conv = [refinement_rows(f"{name}: {label}", seq, key) for label, seq in
            (("dt refined at h = 0.01", fixed_h), ("h refined at dt = 0.02", fixed_dt), ("both refined", diagonal))
            for name, key in (("tau*", 5), ("J*", 4))]
    for r in conv:
        print("  ".join(_fmt(v) for v in r))
    write_results("bench_wellposed_grid", command_line(), [
        table(f"alpha = {alpha:g}, beta = {beta:g}: {', '.join(METHOD_NAMES[m] for m in methods)} from tau0 = 7.5 "
              "on the (h, dt) grid", VARIANT_COLUMNS, [r for by_grid in runs.values() for r in by_grid.values()]),
        table("Iterations against their median (per method)", ["method", "h", "dt", "iterations",
              "relative to the median"], spread),
        table(f"Convergence of the optimum under refinement ({METHOD_NAMES[methods[0]]})",
              ["sequence", "coarse", "middle", "fine", "difference 1",
              "difference 2", "observed order", "Richardson estimate"], conv,
              "the paper reports tau ~ 7.9 for alpha = 2e-3, beta = 0 (no maximizer: see the well-posedness page)"),
    ])


def nodal_load_response(h: float, dt: float = 0.04) -> list:
    """p(tau) for a unit load at the node x = 1 and at x = 1 - h, held on [6.5, 7.5]; tau = 7.5."""
    J = build_reduced(paper_config({"mesh.n": int(round(1 / h)), "dynamics.dt": dt}), TAU0)
    x = J.model.control.coordinates(J.model.space).ravel()
    on = (J.transform.grid(TAU0).t > 6.5)[:, None]
    row = [h]
    for node in np.argsort(x)[::-1][:2]:
        xi = np.zeros((J.N + 1, J.model.control.size))
        xi[:, node] = 1.0
        try:
            sol = J.state(ControlPoint(xi * on, TAU0))
            row.append(float(sol.pressure[J.transform.tau_index]))
        except SolverError as err:
            row.append(str(err))
    return row + [h / 2, h]


def _fmt(v) -> str:
    return f"{v:.6g}" if isinstance(v, float) else str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--betas", default="1e-3", help="comma-separated beta > 0 to compare with beta = 0")
    ap.add_argument("--dts", default="0.04,0.02,0.01,0.005")
    ap.add_argument("--hs", default="0.02,0.01,0.005")
    ap.add_argument("--max-iter", type=int, default=100)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--variant", help="ALPHA,BETA: the variant study instead")
    ap.add_argument("--grid", action="store_true", help="with --variant: the 3 x 3 (h, dt) grid")
    ap.add_argument("--beta-sweep", help="with --variant: comma-separated betas, Newton-CG at the variant's alpha")
    ap.add_argument("--noise", action="store_true", help="with --variant: the round-off of J at L-BFGS-B's end point")
    ap.add_argument("--methods", default="newton,lbfgsb",
                    help="with --grid: comma-separated methods (newton, lbfgsb, bb); the first gives the "
                         "refinement table")
    args = ap.parse_args()
    if args.variant:
        alpha, beta = (float(v) for v in args.variant.split(","))
        if args.noise:
            return noise_study(alpha, beta)
        if args.beta_sweep:
            return beta_sweep(alpha, [float(b) for b in args.beta_sweep.split(",")], args.max_iter)
        if args.grid:
            return grid_study(alpha, beta, args.max_iter, args.methods.split(","))
        return variant_study(alpha, beta, args.max_iter)
    dts = [0.04, 0.02] if args.quick else [float(v) for v in args.dts.split(",")]
    hs = [0.02] if args.quick else [float(v) for v in args.hs.split(",")]
    betas = [0.0] + [float(v) for v in args.betas.split(",")]
    print("  ".join(COLUMNS))
    rows = []
    for beta in betas:
        cases = [(0.01, dt) for dt in dts] + [(h, 0.02) for h in hs if h != 0.01]
        rows += [end_point(beta, h, dt, args.max_iter) for h, dt in cases]
    load_rows = [nodal_load_response(h) for h in hs + ([0.01] if 0.01 not in hs else [])]
    for r in load_rows:
        print("unit nodal load: h", _fmt(r[0]), "p(tau) at x=1:", _fmt(r[1]), "at x=1-h:", _fmt(r[2]))
    write_results("bench_wellposed_sweep", command_line(), [
        table("End point of Algorithm 1 on the paper's setup (start xi = 0, tau = 7.5)", COLUMNS, rows,
              "min det F over all levels of the end point's state, 'at t' its time; 'failed trials': trial points "
              "where the state solver failed (an element inverted)"),
        table("p(tau) for a unit nodal load on [6.5, 7.5] (dt = 0.04)",
              ["h", "p(tau), load at x = 1", "p(tau), load at x = 1 - h", "h/2", "h"], load_rows,
              "the load at the constrained node reaches the multiplier without straining an element"),
    ])


if __name__ == "__main__":
    main()

"""Iterations of Algorithm 1 (Barzilai-Borwein) and L-BFGS-B to reach ||G|| <= 1e-6 ||G0|| under h and dt refinement.

Well-posed 1D case with an interior, nondegenerate optimum in (xi, tau), `hyperoc.control.problems.vibrating_bar`:
neo-Hookean (mu = lambda = 0.05), damping kappa = 1e-2, body-force control on omega = [0.25, 0.5], initial
velocity v0(x) = 0.05 sin(pi x) (compatible with the volume constraint: v0(1) = 0),
ControlCost(alpha = 10), phi1 = p(tau), T = 4, start (xi = 0, tau = T/2).
The free vibration makes p(t) peak near t = 1.3 (period ~5.2), so the optimal tau is interior; with
zero initial data the optimal value does not decrease with tau (time-shift property) and tau drifts to
the end of the interval, and with a small alpha the pressure grows faster than the control cost
until elements invert: neither setting measures the optimizers.

    python bench/bench_mesh_independence.py                    # full 3 x 3 table (h x dt), all methods
    python bench/bench_mesh_independence.py --diagonal         # only (h, dt) refined together
    python bench/bench_mesh_independence.py --json out.json    # also write the raw results
    python bench/bench_mesh_independence.py --starts 1.9,1.95,2.05,2.1   # same grid, other starts
    python bench/bench_mesh_independence.py --grid-starts 1.9,1.95,2,2.05,2.1   # every grid, every start

Writes ``bench/results/bench_mesh_independence.json`` (`bench/results.py`).

Methods: ``bb`` (Algorithm 1, the paper's joint BB step, BB1 length), ``bb-abbmin`` (joint step,
ABBmin length: `hyperoc.control.optimize.BBStepRule`), ``bb-blockwise`` (separate BB1 steps for xi and
tau), ``lbfgsb``.

Prints, per (h, dt): iterations, converged flag, final tau and J, state/adjoint solve counts,
wall time; then the spread max/min of the iteration counts per method. With ``--grid-starts`` it
also prints, per method and grid, the median count over the starts and the spread of these
medians across grids: a BB iteration count is an irregular function of the start, so one start
per grid confounds that irregularity with a dependence on the grid.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import hyperoc as ho
from hyperoc.control.problems import vibrating_bar

T, TAU0, ALPHA = 4.0, 2.0, 10.0
HS = (0.02, 0.01, 0.005)
DTS = (0.04, 0.02, 0.01)


def run(h: float, dt: float, method: str, max_iter: int, alpha: float = ALPHA, tau0: float = TAU0) -> dict:
    J = vibrating_bar(h, dt, T=T, tau0=tau0, alpha=alpha)
    t0 = time.perf_counter()
    if method == "lbfgsb":
        res = ho.lbfgsb(J, J.zero(tau0), gtol=1e-6, max_iter=max_iter)
    else:
        steps = "blockwise" if method == "bb-blockwise" else "joint"
        bb_step = "abbmin" if method == "bb-abbmin" else "bb1"
        res = ho.barzilai_borwein(J, J.zero(tau0), gtol=1e-6, max_iter=max_iter, options=ho.BBOptions(steps, bb_step))
    wall = time.perf_counter() - t0
    g = res.history["grad_norm"]
    return {"h": h, "dt": dt, "tau0": tau0, "method": method, "iterations": res.iterations,
            "converged": bool(res.converged), "tau": float(res.point.tau), "J": float(res.objective),
            "G0": float(g[0]), "G_final_rel": float(g[-1] / g[0]),
            "state_solves": res.evaluations["state_solves"], "adjoint_solves": res.evaluations["adjoint_solves"],
            "failed_trials": res.failed_trials, "wall_s": wall, "grad_norm_history": [float(x) for x in g]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--diagonal", action="store_true", help="only the pairs (h, dt) refined together")
    ap.add_argument("--max-iter", type=int, default=300)
    ap.add_argument("--methods", default="bb,bb-abbmin,bb-blockwise,lbfgsb")
    ap.add_argument("--json", default=None)
    ap.add_argument("--alpha", type=float, default=ALPHA, help="control cost weight (default %(default)s)")
    ap.add_argument("--starts", default=None,
                    help="comma-separated tau0 values: instead of refining, rerun on the middle grid from each start "
                         "(the spread of iteration counts at a fixed grid, to compare with the spread across grids)")
    ap.add_argument("--grid-starts", default=None,
                    help="comma-separated tau0 values: run every grid from each start and compare the per-grid medians")
    args = ap.parse_args()
    grids = list(zip(HS, DTS)) if args.diagonal else [(h, dt) for h in HS for dt in DTS]
    pairs, starts = grids, [TAU0] * len(grids)
    if args.starts:
        starts = [float(t) for t in args.starts.split(",")]
        pairs = [(HS[1], DTS[1])] * len(starts)
    if args.grid_starts:
        tau0s = [float(t) for t in args.grid_starts.split(",")]
        pairs = [g for g in grids for _ in tau0s]
        starts = tau0s * len(grids)
    from results import command_line, table, write_results

    rows = []
    print(f"{'method':12s} {'tau0':>5s} {'h':>6s} {'dt':>6s} {'iters':>6s} {'conv':>5s} {'tau':>9s} "
          f"{'J':>12s} {'|G|/|G0|':>9s} "
          f"{'states':>7s} {'adjoints':>8s} {'failed':>6s} {'wall s':>7s}", flush=True)
    for method in args.methods.split(","):
        for (h, dt), tau0 in zip(pairs, starts):
            r = run(h, dt, method, args.max_iter, args.alpha, tau0)
            rows.append(r)
            print(f"{method:12s} {tau0:5.2f} {h:6.3f} {dt:6.3f} {r['iterations']:6d} "
                  f"{str(r['converged']):>5s} {r['tau']:9.5f} "
                  f"{r['J']:12.6e} {r['G_final_rel']:9.2e} {r['state_solves']:7d} {r['adjoint_solves']:8d} "
                  f"{r['failed_trials']:6d} {r['wall_s']:7.1f}", flush=True)
    print()
    for method in args.methods.split(","):
        its = np.array([r["iterations"] for r in rows if r["method"] == method])
        conv = all(r["converged"] for r in rows if r["method"] == method)
        print(f"{method}: iterations {its.min()}..{its.max()}, max/min = {its.max() / its.min():.2f} "
              f"({'within' if its.max() <= 1.3 * its.min() else 'NOT within'} 30%), all converged: {conv}")
    if args.grid_starts:
        print_medians(rows, args.methods.split(","), grids)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    tables = [table(f"Iterations to ||G|| <= 1e-6 ||G0|| on vibrating_bar (alpha = {args.alpha:g}, at most "
                    f"{args.max_iter} iterations) per method, start and grid",
                    ["method", "tau0", "h", "dt", "iterations", "converged", "tau", "J", "|G| / |G0|",
                     "state solves", "adjoint solves", "failed trials", "wall time (s)"],
                    [[r["method"], tau0, h, dt, r["iterations"], bool(r["converged"]), round(r["tau"], 5),
                      float(f"{r['J']:.6e}"), float(f"{r['G_final_rel']:.2e}"), r["state_solves"], r["adjoint_solves"],
                      r["failed_trials"], round(r["wall_s"], 1)]
                     for r, ((h, dt), tau0) in zip(rows, list(zip(pairs, starts)) * len(args.methods.split(",")))])]
    if args.grid_starts:
        tables.append(table("Median iterations over the starts, per grid",
                            ["method", *(f"h = {h:g}, dt = {dt:g}" for h, dt in grids), "max / min of the medians"],
                            [[m, *med, round(max(med) / min(med), 2)]
                             for m, med in medians(rows, args.methods.split(","), grids)]))
    write_results("bench_mesh_independence", command_line(), tables)


def medians(rows: list, methods: list, grids: list) -> list:
    """Per method: the median iteration count over the starts on each grid."""
    return [(m, [float(np.median([r["iterations"] for r in rows if r["method"] == m and (r["h"], r["dt"]) == g]))
                 for g in grids]) for m in methods]


def print_medians(rows: list, methods: list, grids: list) -> None:
    """Per method: the median iteration count over the starts on each grid, and their spread."""
    print()
    for method in methods:
        med = [float(np.median([r["iterations"] for r in rows if r["method"] == method and (r["h"], r["dt"]) == g]))
               for g in grids]
        cells = ", ".join(f"h={h:g} dt={dt:g}: {m:g}" for (h, dt), m in zip(grids, med))
        print(f"{method}: median over starts per grid [{cells}]; max/min of the medians = {max(med) / min(med):.2f} "
              f"({'within' if max(med) <= 1.3 * min(med) else 'NOT within'} 30%)")


if __name__ == "__main__":
    main()

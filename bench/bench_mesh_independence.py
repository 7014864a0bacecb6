"""Iterations of Algorithm 1 (Barzilai-Borwein) and L-BFGS-B to reach ||G|| <= 1e-6 ||G0|| under h and dt refinement.

Well-posed 1D case (the one of tests/test_optimize.py, refined): neo-Hookean (mu = lambda = 0.05),
kappa = 2e-3, body-force control on omega = [0.25, 0.5] (away from Gamma_N), ControlCost(alpha = 0.1),
phi1 = p(tau), T = 3, start (xi = 0, tau = 1), time transform ``TimeTransform.for_step(T, dt, tau0)``.
(On the paper's omega = [0.75, 1] with SVK the problem has no interior optimum: see the README.)

    python bench/bench_mesh_independence.py                    # full 3 x 3 table (h x dt), both methods
    python bench/bench_mesh_independence.py --diagonal         # only (h, dt) refined together
    python bench/bench_mesh_independence.py --json out.json    # also write the raw results

Prints, per (h, dt): iterations, converged flag, final tau and J, state/adjoint solve counts,
wall time; then the spread max/min of the iteration counts per method.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import hyperoc as ho
from hyperoc.objectives import ControlCost, PressureAt

T, TAU0, ALPHA = 3.0, 1.0, 0.1
HS = (0.02, 0.01, 0.005)
DTS = (0.04, 0.02, 0.01)


def reduced(h: float, dt: float, alpha: float = ALPHA) -> ho.ReducedFunctional:
    n = int(round(1.0 / h))
    model = ho.StateModel(ho.interval(n), ho.NeoHookean(0.05, 0.05), kappa=2e-3,
                          control=ho.BodyForce(ho.Region("box", lower=(0.25,), upper=(0.5,))))
    return ho.ReducedFunctional(model, ho.TimeTransform.for_step(T, dt, TAU0),
                                ho.Objective(running=(ControlCost(alpha),), at_tau=PressureAt()))


def run(h: float, dt: float, method: str, max_iter: int, alpha: float = ALPHA) -> dict:
    J = reduced(h, dt, alpha)
    opt = ho.barzilai_borwein if method == "bb" else ho.lbfgsb
    t0 = time.perf_counter()
    res = opt(J, J.zero(TAU0), gtol=1e-6, max_iter=max_iter)
    wall = time.perf_counter() - t0
    g = res.history["grad_norm"]
    return {"h": h, "dt": dt, "method": method, "iterations": res.iterations, "converged": bool(res.converged),
            "tau": float(res.point.tau), "J": float(res.objective), "G0": float(g[0]), "G_final_rel": float(g[-1] / g[0]),
            "state_solves": res.evaluations["state_solves"], "adjoint_solves": res.evaluations["adjoint_solves"],
            "failed_trials": res.failed_trials, "wall_s": wall, "grad_norm_history": [float(x) for x in g]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--diagonal", action="store_true", help="only the pairs (h, dt) refined together")
    ap.add_argument("--max-iter", type=int, default=300)
    ap.add_argument("--methods", default="bb,lbfgsb")
    ap.add_argument("--json", default=None)
    ap.add_argument("--alpha", type=float, default=ALPHA, help="control cost weight (default %(default)s)")
    args = ap.parse_args()
    pairs = list(zip(HS, DTS)) if args.diagonal else [(h, dt) for h in HS for dt in DTS]
    rows = []
    print(f"{'method':7s} {'h':>6s} {'dt':>6s} {'iters':>6s} {'conv':>5s} {'tau':>9s} {'J':>12s} {'|G|/|G0|':>9s} "
          f"{'states':>7s} {'adjoints':>8s} {'failed':>6s} {'wall s':>7s}", flush=True)
    for method in args.methods.split(","):
        for h, dt in pairs:
            r = run(h, dt, method, args.max_iter, args.alpha)
            rows.append(r)
            print(f"{method:7s} {h:6.3f} {dt:6.3f} {r['iterations']:6d} {str(r['converged']):>5s} {r['tau']:9.5f} "
                  f"{r['J']:12.6e} {r['G_final_rel']:9.2e} {r['state_solves']:7d} {r['adjoint_solves']:8d} "
                  f"{r['failed_trials']:6d} {r['wall_s']:7.1f}", flush=True)
    print()
    for method in args.methods.split(","):
        its = np.array([r["iterations"] for r in rows if r["method"] == method])
        conv = all(r["converged"] for r in rows if r["method"] == method)
        print(f"{method}: iterations {its.min()}..{its.max()}, max/min = {its.max() / its.min():.2f} "
              f"({'within' if its.max() <= 1.3 * its.min() else 'NOT within'} 30%), all converged: {conv}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()

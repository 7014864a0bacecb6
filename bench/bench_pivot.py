"""Pivot threshold of the sparse LU (`hyperoc.solvers.linsolve.SparseSolver`, ``pivot_thresh=``): SuperLU keeps
the diagonal pivot while ``|K_jj| >= pivot_thresh * max_i |K_ij|``, else swaps a row in, which breaks
the nested-dissection structure and adds fill. Compared: 0.1 (threshold partial pivoting) and 0
(the default: the diagonal unless exactly zero, threshold pivoting only as the fallback when
refinement falls short), on the first Newton matrix of Land problem 2 (`bench_ordering.step_blocks`:
tangent at rest plus the follower stiffness at 10 kPa; idealized LV, curved P2, clamped base, nested
meshes of h0 = 6) in two formulations:

- ``pointwise``: P2 displacement, Guccione with the penalty's bulk modulus 1000 kPa (positive definite at rest);
- ``taylor-hood``: P2-P1 (`hyperoc.mechanics.mixed.TaylorHoodModel`), isochoric Guccione at bulk modulus inf, whose
  pressure block is zero: a saddle point.

For each it prints the factorization times, the stored L + U entries, the off-diagonal pivots and the
backward error, then the ratios 0 / 0.1 measured in the same process. ``--solves LEVELS``: also the
whole Taylor-Hood solve (20 increments to 10 kPa, `hyperoc.dynamics.statics.solve_static`) with each threshold:
Newton iterations, summed factorization seconds, and the fill and off-diagonal pivots of the last
factorization (the loaded state, where K_uu is indefinite too).

    nice taskset -c 0 python bench/bench_pivot.py                   # levels 0, 1
    nice taskset -c 0 python bench/bench_pivot.py --levels 0,1,2    # + 80k dofs (about 10 min)
    nice taskset -c 0 python bench/bench_pivot.py --levels 0 --solves 1   # + whole solves, 12k dofs

Writes ``bench/results/bench_pivot.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse
import math
import time

from bench_ordering import measure, step_blocks
from hyperoc.cardiac.land import VENTRICLE, node_position, ventricle_problem
from hyperoc.dynamics.statics import StaticOptions, solve_static
from hyperoc.solvers.linsolve import SparseSolver
from results import Table, command_line, write_results

THRESHOLDS = (0.1, 0.0)  # threshold partial pivoting; diagonal pivots (the default)
FORMULATIONS = {"pointwise": {"bulk_modulus": 1000.0},
                "taylor-hood": {"bulk_modulus": math.inf, "volumetric": "taylor-hood", "isochoric": True}}


def whole_solve(level: int, h0: float, thresh: float) -> dict:
    """Problem 2, Taylor-Hood at bulk modulus inf, isochoric, clamped: the solve with ``pivot_thresh``."""
    model, follower = ventricle_problem(h0, refinements=level, **FORMULATIONS["taylor-hood"])
    solver = SparseSolver(model, "lu", pivot_thresh=thresh)
    t0 = time.perf_counter()
    sol = solve_static(model, follower=follower, constraint="none",
                       options=StaticOptions(steps=20, solver=solver, line_search=False, cutbacks=40))
    return {"n": model.n, "seconds": time.perf_counter() - t0, "newton": sum(sol.newton_iterations),
            "z_endo": float(node_position(model, sol.u, VENTRICLE["endo_apex"])[2]), **solver.stats}


def solves_table(levels, h0: float) -> Table:
    out = Table("Whole Taylor-Hood solves of problem 2 (20 increments to 10 kPa) with each threshold",
                ["level", "dofs", "pivot_thresh", "Newton iterations", "z_endo (mm)", "solve (s)",
                 "factorizations (s, sum)", "last stored L+U entries", "last off-diagonal pivots", "fallbacks"],
                "Rows 'ratio 0 / 0.1' divide the solve time, factorization time and fill of threshold 0 by "
                "those of 0.1.")
    for level in levels:
        rows = {t: whole_solve(level, h0, t) for t in THRESHOLDS}
        for t, r in rows.items():
            out.add(level, r["n"], t, r["newton"], round(r["z_endo"], 5), round(r["seconds"], 1),
                    round(r["factor_s"], 1), r["fill"], r["off_diagonal_pivots"], r["pivoting_fallbacks"])
        new, old = rows[THRESHOLDS[1]], rows[THRESHOLDS[0]]
        out.add(level, "ratio 0 / 0.1", None, None, None, round(new["seconds"] / old["seconds"], 2),
                round(new["factor_s"] / old["factor_s"], 2), round(new["fill"] / old["fill"], 2), None, None)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--h0", type=float, default=6.0, help="Gmsh size of the coarsest LV mesh (mm)")
    ap.add_argument("--levels", default="0,1", help="uniform refinements, comma separated")
    ap.add_argument("--solves", default="", help="levels of whole Taylor-Hood solves (none by default)")
    args = ap.parse_args()
    runs = Table(f"Sparse LU of the first Newton matrix of Land problem 2 (curved P2 LV, h0 = {args.h0:g} mm, "
                 "clamped base) with each pivot threshold",
                 ["level", "formulation", "dofs", "pivot_thresh", "1st factor (s)", "refactor (s)",
                  "stored L+U entries", "off-diagonal pivots", "fallbacks", "backward error"],
                 "pointwise: P2 displacement, Guccione with bulk modulus 1000 kPa; taylor-hood: P2-P1, isochoric "
                 "Guccione at bulk modulus inf (a saddle point with a zero pressure block).")
    ratios = Table("Diagonal pivots (threshold 0) against threshold 0.1, same process",
                   ["level", "formulation", "dofs", "refactor time 0 / 0.1", "fill 0 / 0.1"])
    for level in (int(v) for v in args.levels.split(",")):
        for name, options in FORMULATIONS.items():
            model, follower = ventricle_problem(args.h0, refinements=level, **options)
            blocks = step_blocks(model, follower)
            rows = {t: measure(model, blocks, pivot_thresh=t) for t in THRESHOLDS}
            for t, r in rows.items():
                runs.add(level, name, model.n, t, round(r["factor_s"], 2), round(r["refactor_s"], 2), r["fill"],
                         r["off_diagonal_pivots"], r["pivoting_fallbacks"], float(f"{r['backward_error']:.1e}"))
            new, old = rows[THRESHOLDS[1]], rows[THRESHOLDS[0]]
            ratios.add(level, name, model.n, round(new["refactor_s"] / old["refactor_s"], 2),
                       round(new["fill"] / old["fill"], 2))
    tables = [runs.as_dict(), ratios.as_dict()]
    if args.solves:
        tables.append(solves_table([int(v) for v in args.solves.split(",")], args.h0).as_dict())
    write_results("bench_pivot", command_line(), tables)


if __name__ == "__main__":
    main()

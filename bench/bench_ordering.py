"""Fill-reducing ordering of the sparse LU (`hyperoc.solvers.linsolve.SparseSolver`, ``ordering=``): METIS
nested dissection (``"nd"``, the default) against SuperLU's minimum degree on ``K + K^T``
(``"mmd"``), on the step matrix of Land problem 2 (idealized LV, Guccione with
bulk modulus 1000 kPa, curved P2, clamped base) on a nested sequence of meshes.

The matrix is the tangent at rest plus the follower-pressure stiffness at the full 10 kPa, the matrix
of the first Newton iteration of `hyperoc.cardiac.land.ventricle_apex`. For each level and ordering the script
prints the ordering time, the first factorization (``lu``: a fresh one at every call, as in Newton),
a second factorization with the kept ordering, the entries SuperLU stores for L and U (``SuperLU.nnz``,
supernodal) and the backward error of the solve; then the ratio nd / mmd of the factorization time and
of the fill, measured in the same process.

    nice taskset -c 0 python bench/bench_ordering.py                   # levels 0, 1 of h0 = 6
    nice taskset -c 0 python bench/bench_ordering.py --levels 0,1,2    # + 80k dofs (about 4 min)

Writes ``bench/results/bench_ordering.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse

import jax.numpy as jnp
import numpy as np

from hyperoc.cardiac.land import ventricle_problem
from hyperoc.solvers.linsolve import SparseSolver
from results import Table, command_line, write_results


def step_blocks(model, follower):
    """Element blocks of the first Newton matrix of problem 2 (u = 0, full pressure)."""
    u = jnp.zeros(model.n)
    return np.asarray(follower.add_stiffness(model.tangent_blocks(u, 1.0, 0.0), u, 1.0), dtype=np.float64)


def measure(model, blocks, ordering: str = "nd", method: str = "lu", **solver_options) -> dict:
    """Three solves with fresh factorizations (the later two reuse the ordering); times in seconds.
    ``method``, ``solver_options``: the `SparseSolver` method and further keywords (``pivot_thresh``)."""
    rng = np.random.default_rng(0)
    r_u, col = rng.standard_normal(model.n), rng.standard_normal(model.n)
    solver = SparseSolver(model, method, ordering=ordering, **solver_options)
    solver.host_solve(blocks, col, col, r_u, 0.0)
    factor_first = solver.stats["factor_s"]
    solver.host_solve(blocks, col, col, r_u, 0.0)
    K = model.pattern.matrix(blocks.reshape(model.pattern.element_shape))
    x = solver.host_solve(blocks, col, col, r_u, 0.0)
    residual = K @ x[:-1] + col * x[-1] - r_u
    err = np.abs(residual).max() / (abs(K).sum(axis=1).max() * np.abs(x).max() + np.abs(r_u).max())
    return {"order_s": solver.stats["order_s"], "factor_s": factor_first,
            "refactor_s": (solver.stats["factor_s"] - factor_first) / 2, "fill": solver.stats["fill"],
            "off_diagonal_pivots": solver.stats["off_diagonal_pivots"],
            "pivoting_fallbacks": solver.stats["pivoting_fallbacks"], "backward_error": float(err)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--h0", type=float, default=6.0, help="Gmsh size of the coarsest LV mesh (mm)")
    ap.add_argument("--levels", default="0,1", help="uniform refinements, comma separated")
    args = ap.parse_args()
    runs = Table(f"Sparse LU of the first Newton matrix of Land problem 2 (curved P2 LV, h0 = {args.h0:g} mm, "
                 "bulk modulus 1000 kPa, clamped base) with each ordering",
                 ["level", "dofs", "nnz(K)", "ordering", "order (s)", "1st factor (s)", "refactor (s)",
                  "stored L+U entries", "backward error"],
                 "nd: METIS nested dissection (the default); mmd: SuperLU's minimum degree on K + K^T.")
    ratios = Table("Nested dissection against minimum degree, same process",
                   ["level", "dofs", "refactor time nd / mmd", "fill nd / mmd"])
    for level in (int(v) for v in args.levels.split(",")):
        model, follower = ventricle_problem(args.h0, bulk_modulus=1000.0, refinements=level)
        blocks = step_blocks(model, follower)
        rows = {o: measure(model, blocks, o) for o in ("mmd", "nd")}
        for o, r in rows.items():
            runs.add(level, model.n, model.pattern.nnz, o, round(r["order_s"], 2), round(r["factor_s"], 2),
                     round(r["refactor_s"], 2), r["fill"], float(f"{r['backward_error']:.1e}"))
        ratios.add(level, model.n, round(rows["nd"]["refactor_s"] / rows["mmd"]["refactor_s"], 2),
                   round(rows["nd"]["fill"] / rows["mmd"]["fill"], 2))
    write_results("bench_ordering", command_line(), [runs.as_dict(), ratios.as_dict()])


if __name__ == "__main__":
    main()

"""State solves on the sparse (host-solver) path: chord Newton against full Newton, on a 2D annulus.

The case: annulus 0.5 < r < 1 with structured cells (40 radial x 128 angular), the outer circle
clamped, Saint Venant-Kirchhoff mu = lambda = 0.05, damping 2e-4 (the paper's constants), T = 15,
dt = 0.02 (750 steps), a body force on the ring 0.5 < r < 0.6 pushing outwards-diagonally with the
smooth profile 0.05 sin^2(pi t / 5) (one push-release cycle per 5 time units). P1: 10,240 free
dofs; P2 on the same mesh: 41,216.

Variants, each the whole solve after an untimed first step (JIT compilation, the ordering):

- ``full/lu``: full Newton, a fresh SuperLU factorization per iteration (the baseline: the default
  before chord Newton);
- ``full/lu_reuse``: full Newton, each tangent solved by refinement with a kept factorization;
- ``chord/lu``: chord Newton (the default on the sparse path): the whole Jacobian of an earlier
  iterate, refreshed when the contraction rate exceeds 0.1 (`hyperoc.solvers.newton.CHORD_RATE`);
- ``chord/lu_blas``: ``chord/lu`` with OpenBLAS left at its own thread count during the host solves
  (every other variant runs them with one OpenBLAS thread, `SparseSolver.blas_threads`);
- ``chord/pardiso``: the same with MKL PARDISO's ``L D L^T`` (needs ``pip install mkl``).

Per variant: wall and CPU seconds, Newton iterations, factorizations, and per Newton iteration the
split between assembly (blocks -> matrix), factorization and solves (host) and the JAX part
(element kernels, residuals, line search, callbacks); ``p rel. diff`` is
``max_t |p - p_base| / max_t |p_base|`` against the baseline's pressure.

    python bench/bench_sparse_path.py    # P1, 750 steps, every variant
    taskset -c 0 python bench/bench_sparse_path.py    # the same on one core
    python bench/bench_sparse_path.py --degree 2 --steps 150

Writes ``bench/results/bench_sparse_path_p<degree>.json``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import hyperoc as ho
from hyperoc.fem.geometry import annulus

#: name: (Newton variant, linear solver, OpenBLAS threads during the host solves; None: the library's own)
VARIANTS = {"full/lu": ("full", "lu", 1), "full/lu_reuse": ("full", "lu_reuse", 1), "chord/lu": ("auto", "lu", 1),
            "chord/lu_blas": ("auto", "lu", None), "chord/pardiso": ("auto", "pardiso", 1)}


def case(degree: int):
    mesh = annulus(0.5, 1.0, structured=True, n_radial=40, n_theta=128)
    control = ho.BodyForce(ho.Region("sector", r_range=(0.5, 0.6), theta_range=(-np.pi, np.pi)))
    return ho.StateModel(mesh, ho.SaintVenantKirchhoff(0.05, 0.05), degree=degree, damping=2e-4, control=control)


def run(model, grid, xi, newton: str, solver: str, blas_threads: int | None) -> dict:
    st = ho.TimeStepper(model, ho.Scheme(newton=newton), solver)
    st.solver.blas_threads = blas_threads
    st.run(ho.TimeGrid(grid.t[:2]), xi[:2], diagnose=False)  # compilation and the ordering
    st.solver._release()  # no factorization carried into the timed run
    st.solver.reset_stats()
    wall, cpu = time.perf_counter(), time.process_time()
    sol = st.run(grid, xi, diagnose=False)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    s = st.solver.stats
    its = int(np.sum(sol.newton_iterations))
    per_it = lambda seconds: 1e3 * seconds / its
    return {"wall": wall, "cpu": cpu, "its": its, "factorizations": s["factorizations"], "pressure": sol.pressure,
            "assembly": per_it(s["assembly_s"]), "factor": per_it(s["factor_s"]), "solve": per_it(s["solve_s"]),
            "jax": per_it(wall - s["host_s"]), "per_it": per_it(wall)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--degree", type=int, default=1, choices=(1, 2))
    ap.add_argument("--steps", type=int, default=750)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    args = ap.parse_args()
    model = case(args.degree)
    grid = ho.uniform_grid(T=0.02 * args.steps, dt=0.02)
    xi = 0.05 * np.sin(np.pi * grid.t / 5)[:, None] ** 2 * np.ones((1, model.control.size))
    print(f"annulus P{args.degree}: {model.n} free dofs, {model.mesh.num_cells} cells, {args.steps} steps", flush=True)
    names = args.variants.split(",")
    results = {}
    for name in names:
        results[name] = r = run(model, grid, xi, *VARIANTS[name])
        print(f"  {name:14s} wall {r['wall']:7.1f} s  CPU {r['cpu']:7.1f} s  {r['its']} Newton its, "
              f"{r['factorizations']} factorizations", flush=True)
    base = results[names[0]]
    scale = np.max(np.abs(base["pressure"]))
    columns = ["variant", "wall (s)", "CPU (s)", "Newton iterations", "factorizations", "ms / iteration",
               "assembly (ms/it)", "factorization (ms/it)", "solves (ms/it)", "JAX (ms/it)",
               f"CPU / {names[0]}", "p rel. diff"]
    rows = [[name, r["wall"], r["cpu"], r["its"], r["factorizations"], r["per_it"], r["assembly"], r["factor"],
             r["solve"], r["jax"], r["cpu"] / base["cpu"],
             float(np.max(np.abs(r["pressure"] - base["pressure"])) / scale)] for name, r in results.items()]
    print(f"\n{'variant':14s} " + " ".join(f"{c:>12.12s}" for c in columns[1:]))
    for row in rows:
        print(f"{row[0]:14s} " + " ".join(f"{v:12.4g}" for v in row[1:]))
    from results import command_line, table, write_results

    write_results(f"bench_sparse_path_p{args.degree}", command_line(), [table(
        f"2D annulus P{args.degree}, {model.n} free dofs, {args.steps} steps of dt = 0.02: state solve per variant",
        columns, rows,
        f"Baseline: {names[0]} in the same run. Per-iteration split: host assembly, factorization and solves "
        "(SparseSolver.stats), JAX = wall minus host (element kernels, residuals, callbacks).")])


if __name__ == "__main__":
    main()

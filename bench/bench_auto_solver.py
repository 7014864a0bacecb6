"""Where the dense LU beats the sparse LU: what ``solver = "auto"`` should pick, compilation included.

For 2D annulus meshes (P1 and P2) of growing size, one short state solve (``--steps`` steps of the
annulus example's dynamics, active stress on a sector) per solver, each in a fresh process, so that
the time includes JAX's compilation, as a user's first run does; then the time of the same solve
again in that process (compiled: the per-run cost of an optimization's later evaluations).

    python bench/bench_auto_solver.py                 # n_theta in 8, 16, 32, 48; P1 and P2; 20 steps
    python bench/bench_auto_solver.py --steps 50
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

from results import command_line, table, write_results

CHILD = """
import json, sys, time
t0 = time.perf_counter()
import numpy as np
import hyperoc as ho
from hyperoc.fem.geometry import annulus
n_theta, degree, solver, steps = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], int(sys.argv[4])
mesh = annulus(0.5, 1.0, structured=True, n_radial=max(2, n_theta // 8), n_theta=n_theta)
region = ho.Region("sector", r_range=(0.5, 1.0), theta_range=(-0.8, 0.8))
model = ho.StateModel(mesh, ho.NeoHookean(1.0, 5.0), degree=degree, damping=0.01,
                      control=ho.ActiveStress(region))
grid = ho.uniform_grid(T=0.02 * steps, dt=0.02)
xi = 0.2 * np.sin(np.pi * grid.t / 2)[:, None] ** 2 * np.ones((1, model.control.size))
t1 = time.perf_counter()
ho.solve_state(model, grid, xi, solver=solver)
t2 = time.perf_counter()
sol = ho.solve_state(model, grid, xi, solver=solver)
t3 = time.perf_counter()
print(json.dumps({"n": model.n, "setup": t1 - t0, "first": t2 - t1, "again": t3 - t2,
                  "p_end": float(sol.pressure[-1])}))
"""


def measure(n_theta: int, degree: int, solver: str, steps: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(n_theta), str(degree), solver, str(steps)],
                         check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="8,16,32,48", help="n_theta of the annulus meshes")
    ap.add_argument("--steps", type=int, default=20)
    args = ap.parse_args()
    rows = []
    for degree in (1, 2):
        for n_theta in (int(v) for v in args.sizes.split(",")):
            dense, lu = measure(n_theta, degree, "dense", args.steps), measure(n_theta, degree, "lu", args.steps)
            row = [degree, dense["n"], dense["first"], lu["first"], dense["first"] / lu["first"], dense["again"],
                   lu["again"], dense["again"] / lu["again"], abs(dense["p_end"] - lu["p_end"]) / abs(lu["p_end"])]
            print(row, flush=True)
            rows.append(row)
    write_results("bench_auto_solver", command_line(), [table(
        f"Dense LU against sparse LU on the annulus ({args.steps} steps)",
        ["degree", "dofs", "dense: first solve (s)", "lu: first solve (s)", "dense / lu (first)",
         "dense: again (s)", "lu: again (s)", "dense / lu (again)", "relative difference of p(T)"], rows,
        "first: the solve in a fresh process, compilation included; again: the same solve once compiled")])


if __name__ == "__main__":
    main()

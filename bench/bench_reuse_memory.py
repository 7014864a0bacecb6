"""Memory and time of the sparse LU with and without a kept factorization (`SparseSolver` ``"lu"``
against ``"lu_reuse"``) over a whole quasi-static solve: Land problem 2, Taylor-Hood P2-P1 at kappa =
inf, isochoric Guccione, clamped base, nested level ``--level`` of h0 = 6 mm.

Each method runs in a fresh subprocess (memory is not returned between runs); the child wraps the
solver's ``host_solve`` to record the resident set size (``VmRSS``) after every call. Printed per
method: Newton iterations, factorizations, solve seconds, RSS after the first call and at the end,
and the RSS growth per factorization after the first (least-squares slope); then the ratios
lu_reuse / lu. A factorization that is not released shows up as a growth of about its size
(``fill`` entries x 8 bytes plus indices) per factorization.

    nice taskset -c 1 python bench/bench_reuse_memory.py              # level 1 (11,569 unknowns), ~4 min
    nice taskset -c 1 python bench/bench_reuse_memory.py --level 2    # 84,078 unknowns, ~1.5 h
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time

import numpy as np


def rss_gb() -> float:
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS")) / 1e6


def child(method: str, level: int, steps: int) -> dict:
    from hyperoc.benchmarks import ventricle_problem
    from hyperoc.linsolve import SparseSolver
    from hyperoc.statics import solve_static

    model, load = ventricle_problem(6.0, kappa=math.inf, volumetric="taylor-hood", isochoric=True, refinements=level)
    lin = SparseSolver(model, method)
    solve, trace = lin.host_solve, []

    def traced(*args):
        out = solve(*args)
        trace.append((lin.stats["factorizations"], rss_gb()))
        return out

    lin.host_solve = traced
    t0 = time.perf_counter()
    sol = solve_static(model, follower=load, constrained=False, steps=steps, solver=lin, line_search=False, cutbacks=8)
    seconds = time.perf_counter() - t0
    f, r = np.array(trace).T
    growth = np.polyfit(f[f > 1], r[f > 1], 1)[0] if np.ptp(f[f > 1]) > 0 else 0.0
    return {"method": method, "dofs": model.n, "newton": int(sol.newton_iterations.sum()),
            "factorizations": lin.stats["factorizations"], "fill": lin.stats["fill"], "seconds": seconds,
            "rss_first": float(r[0]), "rss_end": float(r[-1]), "rss_max": float(r.max()), "growth_per_factor": growth}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--level", type=int, default=1, help="uniform refinements of the h0 = 6 mm ventricle")
    ap.add_argument("--steps", type=int, default=20, help="load increments to 10 kPa")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.level, args.steps)))
        return
    rows = {}
    for method in ("lu", "lu_reuse"):
        out = subprocess.run([sys.executable, __file__, "--child", method, "--level", str(args.level),
                              "--steps", str(args.steps)], capture_output=True, text=True, check=True).stdout
        rows[method] = json.loads(out.strip().splitlines()[-1])
    print(f"level {args.level}, {rows['lu']['dofs']} unknowns, {args.steps} load increments\n")
    print("| method | Newton its | factorizations | solve (s) | RSS after 1st call (GB) | RSS at end (GB) | "
          "growth per factorization (MB) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows.values():
        print(f"| {r['method']} | {r['newton']} | {r['factorizations']} | {r['seconds']:.1f} | {r['rss_first']:.2f} | "
              f"{r['rss_end']:.2f} | {1e3 * r['growth_per_factor']:.1f} |")
    a, b = rows["lu_reuse"], rows["lu"]
    print(f"| ratio lu_reuse / lu | | {a['factorizations'] / b['factorizations']:.2f} | {a['seconds'] / b['seconds']:.2f} | "
          f"| {a['rss_max'] / b['rss_max']:.2f} (peak) | |")


if __name__ == "__main__":
    main()

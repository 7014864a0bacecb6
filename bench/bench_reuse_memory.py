"""Memory and time of the sparse direct solvers over a whole quasi-static solve (`SparseSolver`
methods, default ``"lu"`` against ``"lu_reuse"``: SuperLU with and without a kept factorization;
``--methods lu_reuse,pardiso_reuse``: SuperLU's LU against MKL PARDISO's symmetric LDL^T): Land problem
2, Taylor-Hood P2-P1 at bulk modulus inf, isochoric Guccione, clamped base, nested level ``--level`` of h0 = 6 mm.

Each method runs in a fresh subprocess (memory is not returned between runs); the child wraps the
solver's ``host_solve`` to record the resident set size (``VmRSS``) after every call. Printed per
method: Newton iterations, factorizations, seconds of the whole solve and of the factorizations,
stored factor entries (SuperLU: L and U; PARDISO: L), RSS after the first call, at the end and the
process's peak (``ru_maxrss``), the RSS growth per factorization after the first (least-squares slope),
and the apex z values (equal across methods up to Newton's tolerance); then the ratios to the first
method. A factorization that is not released shows up as a growth of about its size per factorization.
The children inherit the CPU affinity (PARDISO runs one thread per allowed core; SuperLU one).

    nice taskset -c 1 python bench/bench_reuse_memory.py              # level 1 (11,569 unknowns), ~4 min
    nice taskset -c 1 python bench/bench_reuse_memory.py --level 2    # 84,078 unknowns, ~1.5 h
    nice python bench/bench_reuse_memory.py --methods lu_reuse,pardiso_reuse --level 2

Writes ``bench/results/bench_reuse_memory.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time

import numpy as np

from results import Table, command_line, write_results


def rss_gb() -> float:
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS")) / 1e6


def child(method: str, level: int, steps: int) -> dict:
    from hyperoc.cardiac.land import VENTRICLE, node_position, ventricle_problem
    from hyperoc.dynamics.statics import StaticOptions, solve_static
    from hyperoc.solvers.linsolve import SparseSolver

    model, load = ventricle_problem(6.0, bulk_modulus=math.inf, volumetric="taylor-hood", isochoric=True,
                                    refinements=level)
    lin = SparseSolver(model, method)
    solve, trace = lin.host_solve, []

    def traced(*args):
        out = solve(*args)
        trace.append((lin.stats["factorizations"], rss_gb()))
        return out

    lin.host_solve = traced
    t0 = time.perf_counter()
    sol = solve_static(model, follower=load, constraint="none",
                       options=StaticOptions(steps=steps, solver=lin, line_search=False, cutbacks=8))
    seconds = time.perf_counter() - t0
    f, r = np.array(trace).T
    growth = np.polyfit(f[f > 1], r[f > 1], 1)[0] if np.ptp(f[f > 1]) > 0 else 0.0
    z = {key: float(node_position(model, sol.u, VENTRICLE[key + "_apex"])[2]) for key in ("endo", "epi")}
    return {"method": method, "dofs": model.n, "newton": int(sol.newton_iterations.sum()),
            "factorizations": lin.stats["factorizations"], "fill": lin.stats["fill"], "seconds": seconds,
            "factor_s": lin.stats["factor_s"], "cores": len(os.sched_getaffinity(0)),
            "rss_first": float(r[0]), "rss_end": float(r[-1]), "rss_max": float(r.max()),
            "peak_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, "growth_per_factor": growth,
            "z_endo": z["endo"], "z_epi": z["epi"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--level", type=int, default=1, help="uniform refinements of the h0 = 6 mm ventricle")
    ap.add_argument("--steps", type=int, default=20, help="load increments to 10 kPa")
    ap.add_argument("--methods", default="lu,lu_reuse", help="SparseSolver methods; ratios are to the first")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.level, args.steps)))
        return
    rows = {}
    for method in args.methods.split(","):
        out = subprocess.run([sys.executable, __file__, "--child", method, "--level", str(args.level),
                              "--steps", str(args.steps)], capture_output=True, text=True, check=True).stdout
        rows[method] = json.loads(out.strip().splitlines()[-1])
        print(json.dumps(rows[method]), flush=True)
    first = next(iter(rows.values()))
    out = Table(f"Whole Taylor-Hood solve of Land problem 2 (level {args.level}, {first['dofs']} unknowns, "
                f"{args.steps} load increments, {first['cores']} core(s)) with each solver",
                ["method", "Newton iterations", "factorizations", "solve (s)", "factorizations (s)",
                 "factor entries (M)", "RSS after 1st call (GB)", "RSS at end (GB)", "peak RSS (GB)",
                 "growth per factorization (MB)", "z_endo (mm)", "z_epi (mm)"],
                "Ratio rows divide by the first method. A factorization that is not released shows as a growth "
                "of about its size per factorization.")
    for r in rows.values():
        out.add(r["method"], r["newton"], r["factorizations"], round(r["seconds"], 1), round(r["factor_s"], 1),
                round(r["fill"] / 1e6, 1), round(r["rss_first"], 2), round(r["rss_end"], 2), round(r["peak_rss"], 2),
                round(1e3 * r["growth_per_factor"], 1), round(r["z_endo"], 6), round(r["z_epi"], 6))
    for r in list(rows.values())[1:]:
        ratio = lambda key: round(r[key] / first[key], 2)
        out.add(f"ratio {r['method']} / {first['method']}", None, ratio("factorizations"), ratio("seconds"),
                ratio("factor_s"), ratio("fill"), None, None, ratio("peak_rss"), None, None, None)
    write_results("bench_reuse_memory", command_line(), [out.as_dict()])


if __name__ == "__main__":
    main()

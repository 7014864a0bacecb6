"""One factorization of the Taylor-Hood saddle point with SuperLU (`SparseSolver` ``"lu"``: L and U, METIS
nested dissection, diagonal pivots) and with MKL PARDISO (``"pardiso"``: symmetric indefinite L D L^T of
one triangle, `hyperoc.solvers.pardiso`), per nested level of the idealized LV (h0 = 6 mm, Land problem 2,
P2-P1 at bulk modulus inf, isochoric Guccione, clamped base): the first Newton matrix (`bench_ordering.step_blocks`).

Each (level, method) runs in a fresh subprocess, so its peak resident set (``ru_maxrss``) is its own:
printed are the unknowns, the seconds of the first factorization (with PARDISO's METIS analysis) and of a
refactorization, the stored factor entries, the backward error of the refined solve, the RSS before the
first solve (current: mesh, model and element blocks) and the process's peak; then per level the ratios
pardiso / lu. The children inherit the CPU affinity: PARDISO runs one thread per allowed core, SuperLU one.
``--lu-levels``: the levels where SuperLU runs too (its level-3 factor, about 24 GB extrapolated from
levels 0-2, does not fit a 23 GB machine).

    nice taskset -c 1 python bench/bench_pardiso.py --levels 0,1,2            # one core
    nice python bench/bench_pardiso.py --levels 3 --lu-levels ""               # two cores, ~670k unknowns, PARDISO only
    nice taskset -c 1 python bench/bench_pardiso.py --levels 0,1              # small: about a minute

Writes ``bench/results/bench_pardiso.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys

from results import Table, command_line, write_results


def rss_gb() -> float:
    """Current resident set (VmRSS), GB."""
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS")) / 1e6


def child(level: int, method: str) -> dict:
    from bench_ordering import measure, step_blocks
    from hyperoc.cardiac.land import ventricle_problem

    model, follower = ventricle_problem(6.0, bulk_modulus=math.inf, volumetric="taylor-hood", isochoric=True,
                                        refinements=level)
    blocks = step_blocks(model, follower)
    before = rss_gb()
    row = measure(model, blocks, method=method)
    return {"level": level, "method": method, "n": model.n, "nnz": int(model.pattern.nnz), **row,
            "rss_before": before, "peak_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
            "cores": len(os.sched_getaffinity(0))}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--levels", default="0,1,2", help="uniform refinements of the h0 = 6 mm ventricle")
    ap.add_argument("--lu-levels", default=None, help="levels where SuperLU runs too (default: all)")
    ap.add_argument("--child", nargs=2, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(int(args.child[0]), args.child[1])))
        return
    levels = [int(v) for v in args.levels.split(",")]
    lu_levels = levels if args.lu_levels is None else [int(v) for v in args.lu_levels.split(",") if v]
    rows = []
    for level in levels:
        for method in (("lu",) if level in lu_levels else ()) + ("pardiso",):
            out = subprocess.run([sys.executable, __file__, "--child", str(level), method], capture_output=True,
                                 text=True, check=True).stdout
            rows.append(json.loads(out.strip().splitlines()[-1]))
            print(json.dumps(rows[-1]), flush=True)
    runs = Table("One factorization of the Taylor-Hood saddle point (Land problem 2, h0 = 6 mm nested, "
                 f"bulk modulus inf), {rows[0]['cores']} core(s)",
                 ["level", "unknowns", "nnz(K)", "method", "1st factor (s)", "refactor (s)", "factor entries (M)",
                  "backward error", "RSS before (GB)", "peak RSS (GB)"],
                 "lu: SuperLU (L and U, nested dissection, diagonal pivots); pardiso: MKL PARDISO's symmetric "
                 "indefinite L D L^T. Each (level, method) in a fresh process.")
    for r in rows:
        runs.add(r["level"], r["n"], r["nnz"], r["method"], round(r["factor_s"], 2), round(r["refactor_s"], 2),
                 round(r["fill"] / 1e6, 1), float(f"{r['backward_error']:.1e}"), round(r["rss_before"], 2),
                 round(r["peak_rss"], 2))
    ratios = Table("PARDISO / SuperLU", ["level", "refactor time", "factor entries", "peak RSS above the model"])
    for level in lu_levels:
        lu, pa = ([r for r in rows if r["level"] == level and r["method"] == m][0] for m in ("lu", "pardiso"))
        extra = lambda r: r["peak_rss"] - r["rss_before"]
        ratios.add(level, round(pa["refactor_s"] / lu["refactor_s"], 2), round(pa["fill"] / lu["fill"], 2),
                   round(extra(pa) / extra(lu), 2))
    write_results("bench_pardiso", command_line(), [runs.as_dict()] + ([ratios.as_dict()] if ratios.rows else []))


if __name__ == "__main__":
    main()

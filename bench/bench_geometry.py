"""Building the nested curved ventricle (`hyperoc.geometry.ventricle(h0, refinements=k)`): wall time
and peak memory, with the harmonic extension of the curved edge nodes (`hyperoc.assembly.solve_dirichlet`)
solved by AMG-preconditioned CG above `DIRECT_LIMIT` free dofs (the default) or by a sparse LU at every
size (the baseline, ``DIRECT_LIMIT`` raised). Each build runs in its own subprocess, so the peak RSS
(`resource.getrusage` of the child) is that build's alone; the ratio column is AMG / LU of the same level.

    nice taskset -c 0 python bench/bench_geometry.py --levels 1,2,3 --lu-levels 1,2
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = """
import json, resource, sys, time
import numpy as np
import hyperoc.assembly as assembly
from hyperoc.geometry import ventricle
h0, level, direct = float(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "lu"
if direct:
    assembly.DIRECT_LIMIT = sys.maxsize
t0 = time.perf_counter()
mesh = ventricle(h0, refinements=level)
seconds = time.perf_counter() - t0
print(json.dumps({"cells": int(len(mesh.cells)), "seconds": seconds,
                  "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
                  "checksum": float(np.abs(mesh.curved_points).sum())}))
"""


def build(h0: float, level: int, method: str) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(h0), str(level), method], check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--h0", type=float, default=6.0)
    ap.add_argument("--levels", default="1,2,3")
    ap.add_argument("--lu-levels", default="1,2", help="levels also built with the sparse LU baseline")
    args = ap.parse_args()
    lu_levels = {int(v) for v in args.lu_levels.split(",") if v}
    print("| level | cells | method | s | peak RSS (GB) | s ratio AMG / LU | peak ratio | sum |curved points| |")
    print("|---|---|---|---|---|---|---|---|")
    for level in (int(v) for v in args.levels.split(",")):
        amg = build(args.h0, level, "amg")
        lu = build(args.h0, level, "lu") if level in lu_levels else None
        for name, row in (("LU", lu), ("AMG-CG", amg)):
            if row is None:
                continue
            ratios = f"{amg['seconds'] / lu['seconds']:.2f} | {amg['peak_gb'] / lu['peak_gb']:.2f}" \
                if lu is not None and name == "AMG-CG" else " | "
            print(f"| {level} | {row['cells']} | {name} | {row['seconds']:.1f} | {row['peak_gb']:.2f} | {ratios} "
                  f"| {row['checksum']:.10g} |", flush=True)


if __name__ == "__main__":
    main()

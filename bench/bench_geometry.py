"""Building the nested curved ventricle (`hyperoc.fem.geometry.ventricle(h0, refinements=k)`): wall time
and peak memory, with the harmonic extension of the curved edge nodes (`hyperoc.fem.assembly.solve_dirichlet`)
solved by AMG-preconditioned CG above `DIRECT_LIMIT` free dofs (the default) or by a sparse LU at every
size (the baseline, ``DIRECT_LIMIT`` raised). Each build runs in its own subprocess, so the peak RSS
(`resource.getrusage` of the child) is that build's alone; the ratio column is AMG / LU of the same level.

    nice taskset -c 0 python bench/bench_geometry.py --levels 1,2,3 --lu-levels 1,2
    nice taskset -c 0 python bench/bench_geometry.py --levels 1,2              # small: under a minute

Writes ``bench/results/bench_geometry.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

from results import Table, command_line, write_results

CHILD = """
import json, resource, sys, time
import numpy as np
import hyperoc.fem.assembly as assembly
from hyperoc.fem.geometry import ventricle
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
    out = Table(f"Building the nested curved ventricle (h0 = {args.h0:g} mm), each build in its own process",
                ["level", "cells", "method", "wall time (s)", "peak RSS (GB)", "time AMG / LU", "peak AMG / LU",
                 "sum of |curved points| (mm)"],
                "The last column is a checksum: equal across methods means the same mesh.")
    for level in (int(v) for v in args.levels.split(",")):
        amg = build(args.h0, level, "amg")
        lu = build(args.h0, level, "lu") if level in lu_levels else None
        for name, row in (("LU", lu), ("AMG-CG", amg)):
            if row is None:
                continue
            ratios = [round(amg["seconds"] / lu["seconds"], 2), round(amg["peak_gb"] / lu["peak_gb"], 2)] \
                if lu is not None and name == "AMG-CG" else [None, None]
            out.add(level, row["cells"], name, round(row["seconds"], 1), round(row["peak_gb"], 2), *ratios,
                    float(f"{row['checksum']:.10g}"))
    write_results("bench_geometry", command_line(), [out.as_dict()])


if __name__ == "__main__":
    main()

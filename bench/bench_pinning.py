"""One Algorithm 1 run of the paper's 1D problem, with its outputs, on all CPUs vs bound to one CPU.

Why `hyperoc reproduce paper-1d` binds each of its processes to one CPU (`hyperoc.app.paper._pin_to_cpu`):
if one process takes the same wall time on one CPU as on all of them, its extra threads only spin,
and two such processes side by side slow each other down.

    python bench/bench_pinning.py              # 2 rounds, each variant in a fresh process
    python bench/bench_pinning.py --rounds 3

Writes ``bench/results/bench_pinning.json`` (`bench/results.py`).

Prints per run: wall seconds and CPU seconds (user + system) of the child, then the medians and
their ratios against the all-CPU baseline of the same script.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile

from results import Table, command_line, write_results


def child(pinned: bool) -> None:
    import os
    import resource
    import time
    from pathlib import Path

    if pinned:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # before any thread exists
    from hyperoc.app.paper import paper_config
    from hyperoc.app.workflows import optimize_single, write_optimization_outputs

    start = time.perf_counter()
    cfg = paper_config()
    with tempfile.TemporaryDirectory() as out:
        J, res = optimize_single(cfg, float(cfg["optimize"]["tau0"]), cache_dir=Path(out) / "cache")
        write_optimization_outputs(Path(out), cfg, J, res)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"wall": time.perf_counter() - start, "cpu": usage.ru_utime + usage.ru_stime,
                      "iterations": res.iterations, "tau": res.point.tau}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--child", choices=("all", "one"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child == "one")
        return
    runs = {"all": [], "one": []}
    for _ in range(args.rounds):
        for variant in runs:  # interleaved, so that load drifts hit both variants alike
            out = subprocess.run([sys.executable, __file__, "--child", variant], capture_output=True, text=True,
                                 check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            runs[variant].append(r)
            print(f"{variant:4s} CPUs: wall {r['wall']:6.2f} s, CPU {r['cpu']:6.2f} s, {r['iterations']} iterations, "
                  f"tau = {r['tau']:.6f}", flush=True)
    base = {k: statistics.median(r[k] for r in runs["all"]) for k in ("wall", "cpu")}
    out = Table(f"Algorithm 1 on the paper's 1D problem with its outputs, medians of {args.rounds} runs per variant",
                ["CPUs", "median wall time (s)", "wall / all CPUs", "median CPU time (s)", "CPU / all CPUs",
                 "iterations"], "Each run is a fresh process; the variants alternate.")
    for variant, rs in runs.items():
        wall, cpu = (statistics.median(r[k] for r in rs) for k in ("wall", "cpu"))
        out.add({"all": "all", "one": "one"}[variant], round(wall, 2), round(wall / base["wall"], 2), round(cpu, 2),
                round(cpu / base["cpu"], 2), rs[-1]["iterations"])
    write_results("bench_pinning", command_line(), [out.as_dict()])


if __name__ == "__main__":
    main()

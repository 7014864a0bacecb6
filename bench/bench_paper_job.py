"""The main job, `hyperoc reproduce paper-1d`, end to end from a cold start: wall time, and what each run
reports next to the paper's values.

    python bench/bench_paper_job.py              # the whole job (headline, the other formulations, the profile)
    python bench/bench_paper_job.py --quick      # the value profile and the headline only
    python bench/bench_paper_job.py --cold-only  # without the second (warm) run

Runs the job twice in fresh processes into a temporary folder, with an empty persistent compilation
cache (cold: imports and every compilation included) and then with the cache the first run filled
(warm), then tabulates the first run's ``summary.json``: per run (the headline, then the other formulations
of ``runs``) tau, J, iterations, whether the stopping test was met, the final relative gradient
(projected, for the bounded run), the least det F, the largest |xi|, when the control switches off and
the times and values of the largest pressure maxima; and the paper's reported values. The split of the
cold run: the imports (``import hyperoc.app.paper``, what the job's own process imports, and
``import hyperoc.app.workflows``, what each worker imports before its run: JAX, SciPy, the solvers; each
in a fresh process), and per run the compilation
(tracing, lowering and XLA, from JAX's monitoring events), the optimization without it, and the outputs
(figures, ParaView series, summaries); and the value profile J*(tau). The runs and the two halves of the
profile share two worker processes, longest first.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from results import command_line, table, write_results

COLUMNS = ["run", "h", "dt", "tau", "J", "iterations", "converged", "relative gradient", "min det F", "max |xi|",
           "control off from t", "pressure maxima at t", "pressure maxima"]


def run_job(quick: bool, cache: Path, out: Path) -> tuple[dict, float]:
    """``(summary, wall time in s)`` of one run of the job in a fresh process, compilation cache ``cache``."""
    cmd = ([sys.executable, "-m", "hyperoc.app.cli", "reproduce", "paper-1d", "--out", str(out)]
           + (["--quick"] if quick else []))
    started = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                   env={**os.environ, "HYPEROC_CACHE_DIR": str(cache)})
    wall = time.perf_counter() - started
    return json.loads((out / "summary.json").read_text()), wall


def import_seconds(module: str) -> float:
    """Wall time of ``import module`` in a fresh process."""
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", f"import {module}"], check=True)
    return time.perf_counter() - started


def split_rows(summary: dict) -> list:
    """Per run of the job: compilation (s and count), optimization without compilation, outputs; and the
    value profile's solves (compilation included)."""
    rows = [[r["label"], r["timings"]["compilation_s"], r["timings"]["compilations"], r["timings"]["optimization_s"],
             r["timings"]["outputs_s"]] for r in summary["runs"]]
    q = summary["profile"]
    return rows + [["value profile (both halves, compilation included)", None, None, sum(q["wall_time_s"]), None]]


def rows_of(summary: dict) -> list:
    rows = [[r["label"], r["h"], r["dt"], r["tau"], r["objective"], r["iterations"], r["converged"],
             r["relative_gradient"], r["min_det_F"], r["max_abs_xi"], r["control_off_from_t"],
             ", ".join(f"{t:.2f}" for t in r["pressure_local_maxima_t"]),
             ", ".join(f"{p:.4f}" for p in r["pressure_local_maxima_p"])] for r in summary["runs"]]
    p = summary["paper"]
    rows.append(["paper (reported)", 0.01, 0.02, p["tau"], None, None, None, None, None, None, p["control_off_from_t"],
                 ", ".join(str(t) for t in p["pressure_maxima_near_t"]), None])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the value profile and the headline only")
    ap.add_argument("--cold-only", action="store_true", help="without the warm run")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        summary, cold = run_job(args.quick, Path(tmp) / "cache", Path(tmp) / "cold")
        warm_summary, warm = ({"wall_time_s": None, "workers": None}, None) if args.cold_only else run_job(
            args.quick, Path(tmp) / "cache", Path(tmp) / "warm")
    imports, worker_imports = import_seconds("hyperoc.app.paper"), import_seconds("hyperoc.app.workflows")
    rows, split = rows_of(summary), split_rows(summary)
    for r in rows + split:
        print(r)
    print(f"imports: the job {imports:.2f} s, a worker {worker_imports:.2f} s")
    print(f"wall time cold {cold:.1f} s, warm {warm} s (job clock {summary['wall_time_s']:.1f} s)")
    q = summary["profile"]
    profile = [table(
        f"Value profile J*(tau) of the headline's formulation (h = {q['h'][0]:g}; tau fixed, warm starts)",
        ["tau", "dt", "J*", "converged", "KKT (rel. projected gradient)", "iterations", "min det F", "max |xi|"],
        [[q[k][i] for k in ("tau", "dt", "J", "converged", "relative_gradient", "iterations", "min_det_F",
                            "max_abs_xi")] for i in range(len(q["tau"]))],
        f"parabola through the largest value and its neighbours: maximum at tau = {q['tau_refined']:.3f}, "
        f"J* = {q['J_refined']:.6g}")]
    maxima = table("The headline's free-tau runs from the profile's largest maxima (the best is the headline)",
                   ["tau0", "tau*", "J*", "iterations", "converged", "relative gradient"],
                   [[m[k] for k in ("tau0", "tau", "objective", "iterations", "converged", "relative_gradient")]
                    for m in q["maxima"]])
    write_results("bench_paper_job", command_line(), [
        table("hyperoc reproduce paper-1d: the runs and the paper's values", COLUMNS, rows,
              "relative gradient: the stopping test's measure (the projected gradient with bounds; in the H^1-in-time "
              "metric for alpha = beta = 10) over that of the zero control at the run's starting tau; min det F over "
              "all levels"),
        *profile, maxima,
        table("Wall time of the job (fresh processes)",
              ["compilation cache", "wall time (s)", "job clock (s)", "workers"],
              [["empty (cold)", cold, summary["wall_time_s"], summary["workers"]],
               ["filled by the cold run (warm)", warm, warm_summary["wall_time_s"], warm_summary["workers"]]],
              "job clock: from the job's start to its summary, imports excluded"),
        table("Where the cold run's time goes", ["run", "compilation (s)", "compilations", "optimization (s)",
              "outputs (s)"], split,
              f"imports: {imports:.2f} s before the job starts, then {worker_imports:.2f} s in each worker before its "
              "first run; the runs and the profile's halves share two workers, longest first; optimization "
              "excludes compilation"),
    ])


if __name__ == "__main__":
    main()

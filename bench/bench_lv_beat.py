"""The second main job, `hyperoc reproduce lv-beat`, end to end from a cold start: what it reports and its cost.

    python bench/bench_lv_beat.py

Runs the job once in a fresh process into a temporary folder with an empty persistent compilation cache
(imports and every compilation included, as a first run on a fresh machine), then tabulates its
``summary.json``: tau*, J*, whether the stopping test (relative projected gradient <= gtol) was met, the
relative projected gradient and the iterations it ended with, the rate of pressure rise at tau* with and
without the control and the gain, the uncontrolled beat's largest rate, the least control value, the cavity
volume's largest relative drift, and the wall times (the optimization, the whole job). Writes
``bench/results/bench_lv_beat.json``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from results import Table, command_line, write_results

COLUMNS = ["tau* (ms)", "J* (Pa/s)", "converged", "relative projected gradient", "iterations",
           "dp/dt at tau*, controlled (kPa/s)", "dp/dt at tau*, uncontrolled (kPa/s)", "gain (%)",
           "uncontrolled max dp/dt (kPa/s)", "min xi (kPa)", "cavity volume drift", "optimization (s)", "job (s)"]


def run_job(out: Path, cache: Path) -> tuple[dict, float]:
    """``(summary, wall time in s)`` of the job in a fresh process with the compilation cache ``cache``."""
    cmd = [sys.executable, "-m", "hyperoc.app.cli", "reproduce", "lv-beat", "--out", str(out), "--no-progress"]
    started = time.perf_counter()
    subprocess.run(cmd, check=True, env={**os.environ, "HYPEROC_CACHE_DIR": str(cache)})
    return json.loads((out / "summary.json").read_text()), time.perf_counter() - started


def row(summary: dict, wall: float) -> list:
    rise = summary["pressure_rise_at_tau"]
    return [1e3 * summary["tau"], summary["objective"], summary["converged"], summary["relative_gradient"],
            summary["iterations"], 1e-3 * rise["optimized"], 1e-3 * rise["uncontrolled"],
            100.0 * summary["pressure_rise_gain"], 1e-3 * summary["uncontrolled_max_pressure_rise"]["value"],
            1e-3 * summary["control_min"], max(summary["cavity_volume_error"].values()),
            summary["optimization_wall_time_s"], wall]


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        summary, wall = run_job(Path(tmp) / "lv-beat", Path(tmp) / "cache")
    results = Table("hyperoc reproduce lv-beat, cold (fresh process, empty compilation cache)", COLUMNS,
                    notes=f"{summary['dofs']} unknowns, {summary['steps']} steps; job (s) is the process's wall "
                          "time, imports and compilation included.")
    results.add(*row(summary, wall))
    write_results("bench_lv_beat", command_line(), [results.as_dict()], {"summary": summary})


if __name__ == "__main__":
    main()

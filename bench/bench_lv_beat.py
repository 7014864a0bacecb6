"""The second main job, `hyperoc reproduce lv-beat`, end to end from a cold start: what it reports and its cost.

    python bench/bench_lv_beat.py

Runs the job in a fresh process into a temporary folder with an empty persistent compilation cache
(imports and every compilation included, as a first run on a fresh machine), then the same problem
without the bound on xi (``optimize.xi_bounds`` removed: `hyperoc.app.lv_beat.reproduce_lv_beat` with
that entry, in a fresh process), and tabulates each ``summary.json``: tau*, J*, whether the stopping test
(relative projected gradient <= gtol) was met, the relative projected gradient and the iterations it ended
with, the rate of pressure rise at tau* with and without the control and the gain, the uncontrolled beat's
largest rate, the least and largest control values, the cavity volume's largest relative drift, and the wall times (the
optimization, the whole job). Writes ``bench/results/bench_lv_beat.json``.
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

COLUMNS = ["xi bounds (kPa)", "tau* (ms)", "J* (Pa/s)", "converged", "relative projected gradient", "iterations",
           "dp/dt at tau*, controlled (kPa/s)", "dp/dt at tau*, uncontrolled (kPa/s)", "gain (%)",
           "uncontrolled max dp/dt (kPa/s)", "min xi (kPa)", "max xi (kPa)", "cavity volume drift",
           "optimization (s)", "job (s)"]


#: The variants: the job as shipped, and its problem without the bound on xi.
VARIANTS = {"[-30, 0]": None, "none": {"optimize.xi_bounds": None}}


def run_job(out: Path, cache: Path, entries: dict | None) -> tuple[dict, float]:
    """``(summary, wall time in s)`` of the job (its config's ``entries`` changed) in a fresh process with the
    compilation cache ``cache``."""
    if entries is None:
        cmd = [sys.executable, "-m", "hyperoc.app.cli", "reproduce", "lv-beat", "--out", str(out), "--no-progress"]
    else:
        code = (f"from hyperoc.app.lv_beat import reproduce_lv_beat; "
                f"reproduce_lv_beat({str(out)!r}, entries={entries!r})")
        cmd = [sys.executable, "-c", code]
    started = time.perf_counter()
    subprocess.run(cmd, check=True, env={**os.environ, "HYPEROC_CACHE_DIR": str(cache)})
    return json.loads((out / "summary.json").read_text()), time.perf_counter() - started


def row(bounds: str, summary: dict, wall: float) -> list:
    rise = summary["pressure_rise_at_tau"]
    return [bounds, 1e3 * summary["tau"], summary["objective"], summary["converged"], summary["relative_gradient"],
            summary["iterations"], 1e-3 * rise["optimized"], 1e-3 * rise["uncontrolled"],
            100.0 * summary["pressure_rise_gain"], 1e-3 * summary["uncontrolled_max_pressure_rise"]["value"],
            1e-3 * summary["control_min"], 1e-3 * summary["control_max"],
            max(summary["cavity_volume_error"].values()),
            summary["optimization_wall_time_s"], wall]


def main() -> None:
    results = Table("hyperoc reproduce lv-beat, cold (fresh process, empty compilation cache)", COLUMNS,
                    notes="The coarse benchmark ventricle (1,398 unknowns), 60 steps; job (s) is the process's wall "
                          "time, imports and compilation included; xi bounds none: the same problem without the "
                          "bound (its maximizer pushes where the prescribed tension is zero).")
    summaries = {}
    for bounds, entries in VARIANTS.items():
        with tempfile.TemporaryDirectory() as tmp:
            summaries[bounds], wall = run_job(Path(tmp) / "lv-beat", Path(tmp) / "cache", entries)
        results.add(*row(bounds, summaries[bounds], wall))
    write_results("bench_lv_beat", command_line(), [results.as_dict()], {"summaries": summaries})


if __name__ == "__main__":
    main()

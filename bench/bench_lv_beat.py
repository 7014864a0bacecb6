"""The second main job, `hyperoc reproduce lv-beat`, end to end from a cold start: what it reports, its cost, and
the mesh independence of its iteration count.

    python bench/bench_lv_beat.py

Runs the job in a fresh process into a temporary folder with an empty persistent compilation cache
(imports and every compilation included, as a first run on a fresh machine) on its coarse mesh of the
benchmark ventricle, then the same problem on the medium mesh (``mesh.variant = "medium"``: 3,494 cells against
1,402; `hyperoc.app.lv_beat.reproduce_lv_beat` with that entry, in a fresh process), and tabulates each
``summary.json``: tau*, J*, whether the stopping test (relative projected gradient <= gtol) was met, the relative
projected gradient and the iterations it ended with, the rate of pressure rise at tau* with and without the
control and the gain, the uncontrolled beat's largest rate, the least and largest control values, the stroke
volume of each beat, the largest relative volume change over the isovolumic steps, and the wall times (the
optimization, the whole job); then the ratio of the iteration counts (medium over coarse). Writes
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

COLUMNS = ["mesh", "unknowns", "tau* (ms)", "J* (Pa/s)", "converged", "relative projected gradient", "iterations",
           "dp/dt at tau*, controlled (kPa/s)", "dp/dt at tau*, uncontrolled (kPa/s)", "gain (%)",
           "uncontrolled max dp/dt (kPa/s)", "min xi", "max xi", "stroke volume, uncontrolled (mL)",
           "stroke volume, optimized (mL)", "isovolumic volume change",
           "optimization (s)", "job (s)"]


#: The variants: the job as shipped (coarse mesh), and its problem on the medium mesh.
VARIANTS = {"coarse": None, "medium": {"mesh.variant": "medium"}}


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


def row(mesh: str, summary: dict, wall: float) -> list:
    rise = summary["pressure_rise_at_tau"]
    return [mesh, summary["dofs"], 1e3 * summary["tau"], summary["objective"], summary["converged"],
            summary["relative_gradient"], summary["iterations"], 1e-3 * rise["optimized"], 1e-3 * rise["uncontrolled"],
            100.0 * summary["pressure_rise_gain"], 1e-3 * summary["uncontrolled_max_pressure_rise"]["value"],
            summary["control_min"], summary["control_max"],
            *(1e6 * stroke_volume(summary["beat"][name]) for name in ("uncontrolled", "optimized")),
            max(beat["isovolumic_volume_change"] for beat in summary["beat"].values()),
            summary["optimization_wall_time_s"], wall]


def stroke_volume(beat: dict) -> float | None:
    """The stroke volume (m^3) of a beat's first ejection that closes; None if there is none."""
    closed = [e for e in beat["ejections"] if e["end"] is not None]
    return closed[0]["stroke_volume"] if closed else None


def main() -> None:
    results = Table("hyperoc reproduce lv-beat, cold (fresh process, empty compilation cache)", COLUMNS,
                    notes="The benchmark ventricle, one beat closed by a Windkessel (500 steps of 1 ms); xi is "
                          "the fraction of the prescribed tension T_a the control adds (a contraction between 0 "
                          "and 2 T_a: xi in [-1, 1]); job (s) is the process's wall time, imports and compilation "
                          "included.")
    summaries = {}
    for mesh, entries in VARIANTS.items():
        with tempfile.TemporaryDirectory() as tmp:
            summaries[mesh], wall = run_job(Path(tmp) / "lv-beat", Path(tmp) / "cache", entries)
        results.add(*row(mesh, summaries[mesh], wall))
    ratio = summaries["medium"]["iterations"] / summaries["coarse"]["iterations"]
    print(f"iterations medium / coarse: {ratio:.2f}")
    write_results("bench_lv_beat", command_line(), [results.as_dict()],
                  {"summaries": summaries, "iteration_ratio_medium_over_coarse": ratio})


if __name__ == "__main__":
    main()

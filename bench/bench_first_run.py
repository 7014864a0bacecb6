"""What a user waits for on a first run: ``hyperoc --help``, and the forward solves of the examples
``simulate-1d.toml`` (the paper's bar, 750 steps), ``annulus-2d.toml`` (P2, 100 steps) and ``ventricle-3d.toml``
(40 steps) with an empty and then a filled compilation cache.

    python bench/bench_first_run.py

Each command runs in a fresh process; ``--repeat`` times each and keeps the fastest. For the solve the table
gives the process's wall time and the solve's own (``wall_time_s`` of its summary: tracing, compilation
or the cache's read, and the steps), cold (empty cache) against warm (the cache a cold run filled).
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

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
CONFIGS = ("simulate-1d.toml", "annulus-2d.toml", "ventricle-3d.toml")


def timed(args: list, env: dict) -> float:
    """Wall time of ``python -m hyperoc.app.cli ARGS`` in a fresh process."""
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "hyperoc.app.cli", *args], check=True, env={**os.environ, **env},
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - started


def simulate(config: str, cache: Path, out: Path) -> tuple[float, float]:
    """(process wall time, the solve's wall time) of one simulate run of the example ``config`` with the
    compilation cache ``cache``."""
    wall = timed(["simulate", str(EXAMPLES / config), "--out", str(out), "--no-progress"],
                 {"HYPEROC_CACHE_DIR": str(cache)})
    return wall, json.loads((out / "summary.json").read_text())["wall_time_s"]


def cold_and_warm(config: str, repeat: int) -> list:
    """The table's rows of ``config``: the best of ``repeat`` cold runs (an empty cache) and of the warm runs
    that follow them (the cache each cold run filled)."""
    cold, warm = [], []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as tmp:
            cache = Path(tmp) / "cache"
            cold.append(simulate(config, cache, Path(tmp) / "cold"))
            warm.append(simulate(config, cache, Path(tmp) / "warm"))
    (cold_wall, cold_solve), (warm_wall, warm_solve) = min(cold), min(warm)
    return [[f"simulate examples/{config}, empty cache (cold)", round(cold_wall, 2), round(cold_solve, 3), 1.0],
            [f"simulate examples/{config}, cache filled (warm)", round(warm_wall, 2), round(warm_solve, 3),
             round(warm_solve / cold_solve, 3)]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    help_s = min(timed(["--help"], {}) for _ in range(args.repeat))
    rows = [["hyperoc --help", round(help_s, 3), None, None],
            *(row for config in CONFIGS for row in cold_and_warm(config, args.repeat))]
    for r in rows:
        print(r)
    write_results("bench_first_run", command_line(), [table(
        f"First runs in fresh processes (best of {args.repeat})",
        ["command", "process wall time (s)", "solve (s)", "solve / cold solve"], rows,
        "solve: the summary's wall_time_s (tracing, compilation or the cache's read, and the steps); "
        "the process time adds Python's start, imports and the outputs (figures, ParaView series)")])


if __name__ == "__main__":
    main()

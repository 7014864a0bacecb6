"""What a contributor waits for: the fast test tier (the README's ``python -m pytest -q``) with an empty
compilation cache and then with the cache the first run filled.

    python bench/bench_test_tier.py

The suite keeps the programs JAX compiles in pytest's cache folder (``tests/conftest.py``); here that folder is
a temporary one (``-o cache_dir=...``), so the checkout's own cache is neither read nor changed. The table gives
each run's wall time, its outcome and the size of the compiled programs the cold run left, and the warm run's
time as a ratio of the cold one's (the baseline: every run of a suite without a kept cache is cold).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from results import command_line, table, write_results

ROOT = Path(__file__).resolve().parents[1]


def run_tier(cache_dir: Path, extra: list[str]) -> tuple[float, str]:
    """(wall time in s, pytest's summary line) of the fast tier with pytest's cache in ``cache_dir``."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-o", f"cache_dir={cache_dir}", *extra], cwd=ROOT,
                          capture_output=True, text=True)
    wall = time.perf_counter() - started
    lines = [ln for ln in done.stdout.splitlines() if re.search(r"\d+ (passed|failed)", ln)]
    if done.returncode != 0:
        sys.exit(f"the test tier failed ({lines[-1] if lines else done.returncode}):\n{done.stdout[-3000:]}")
    return wall, lines[-1].strip("= ")


def folder_mb(folder: Path) -> float:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) / 2**20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pytest_args", nargs="*", help="further arguments for pytest (e.g. a test file)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cache_dir = Path(tmp) / "pytest-cache"
        cold, cold_outcome = run_tier(cache_dir, args.pytest_args)
        size = folder_mb(cache_dir / "d" / "hyperoc-jax")
        warm, warm_outcome = run_tier(cache_dir, args.pytest_args)
    rows = [["empty compilation cache (cold)", round(cold, 1), cold_outcome, 1.0],
            ["the cold run's cache (warm)", round(warm, 1), warm_outcome, round(warm / cold, 3)]]
    for r in rows:
        print(r)
    write_results("bench_test_tier", command_line(), [table(
        "The fast test tier (python -m pytest -q), one worker per CPU",
        ["run", "wall time (s)", "outcome", "time / cold time"], rows,
        f"the compiled programs the cold run kept: {size:.0f} MB (tests/conftest.py; pytest's cache folder)")])


if __name__ == "__main__":
    main()

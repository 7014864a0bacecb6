"""hyperoc on the cardiac elastodynamics benchmark (monoventricular problem 1), against its ten participating codes.

    python bench/bench_cardiac_benchmark.py --steps 0A,0B,1 --degrees 1
    python bench/bench_cardiac_benchmark.py --steps 1 --degrees 2 --work runs/benchmark   # resumable, hours
    python bench/bench_cardiac_benchmark.py --steps 1 --degrees 2 --dt 0.005 --end-time 0.5   # P2 to the peak
    python bench/bench_cardiac_benchmark.py --steps 1 --degrees 2 --dt 0.005 --solver pardiso   # MKL, 2 threads

Source of the comparison: R. Aróstica et al., "A software benchmark for cardiac elastodynamics", Comput.
Methods Appl. Mech. Engrg. 435 (2025) 117485; the codes' curves (4C, Ambit, CARPentry, CHeart, CHimeRA,
COMSOL, lifex, Simula, SimVascular P1 and P2) and the reference mesh are from the repository
Reidmen/cardiac_benchmark_toolkit (MIT licence), shipped in ``hyperoc/data/cardiac_benchmark`` (``NOTICE.md``:
commit, licence; conversion: ``bench/reference/convert_cardiac_benchmark.py``).

Each run is the user's command ``hyperoc benchmark cardiac-elastodynamics --step S --degree D --out
WORK/step-S-pD --resume`` in a fresh process (its time and peak memory are the process's; an interrupted
bench resumes each run from its last checkpoint). The runs are merged into
``bench/results/cardiac_benchmark.json``: the top-level keys ``"0A"``, ``"0B"``, ``"1"`` hold the most
accurate run of each step (the highest degree, the whole beat): ``t`` (s, every 10 ms), ``p0``, ``p1`` ([ux,
uy, uz] per time, m), ``volume`` (m^3), ``pressure``, ``tension`` (Pa), the mesh, degree, time step, scheme,
wall time (s), peak memory (MiB), Newton iterations and the comparison with the codes' band; ``runs`` holds
every run (a run of another invocation is kept unless this one solves the same problem as far or further).
The tables give each step's peak displacements and smallest cavity volume, code by code with hyperoc as the
eleventh row, and the cost.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from hyperoc.cardiac.benchmark_curves import reference_curves
from results import RESULTS_DIR, Table, command_line, write_results

NAME = "cardiac_benchmark"


def run(step: str, degree: int, mesh: str, work: Path, end_time: float | None, dt: float | None,
        solver: str) -> dict:
    """One run through the CLI (resumed if its folder holds checkpoints); its ``benchmark.json``."""
    out = work / (f"step-{step}-p{degree}-{mesh}" + ("" if dt is None else f"-dt{dt:g}"))
    cmd = ["hyperoc", "benchmark", "cardiac-elastodynamics", "--step", step, "--degree", str(degree),
           "--mesh", mesh, "--solver", solver, "--out", str(out), "--resume", "--no-progress"]
    if end_time is not None:
        cmd += ["--end-time", str(end_time)]
    if dt is not None:
        cmd += ["--dt", str(dt)]
    subprocess.run([sys.executable, "-m", "hyperoc.app.cli", *cmd[1:]], check=True)
    entry = json.loads((out / "benchmark.json").read_text())
    entry["command"] = " ".join(cmd[:-1] if cmd[-1] == "--no-progress" else cmd)
    return entry


def problem(entry: dict) -> tuple:
    """What a run solves: the step, degree, mesh and time step (its end time aside)."""
    return entry["step"], entry["degree"], entry["mesh"]["variant"], entry["dt"]


def key(entry: dict) -> tuple:
    return *problem(entry), entry["t"][-1]


def merged_runs(new: list[dict]) -> list[dict]:
    """The runs of the committed results file, with those of this invocation replacing the ones they cover:
    a run of the same problem that ends no later (its curves are the start of the new run's, the solve being
    deterministic)."""
    path = RESULTS_DIR / f"{NAME}.json"
    old = json.loads(path.read_text())["runs"] if path.exists() else []
    covered = lambda e: any(problem(e) == problem(n) and e["t"][-1] <= n["t"][-1] for n in new)
    return sorted([e for e in old if not covered(e)] + new, key=key)


def best(runs: list[dict], step: str) -> dict | None:
    """The most accurate whole-beat run of ``step`` on the reference mesh: the highest degree, then the
    smallest time step."""
    full = [e for e in runs if e["step"] == step and e["mesh"]["variant"] == "reference" and e["t"][-1] >= 1.0 - 1e-9]
    return max(full, key=lambda e: (e["degree"], -e["dt"])) if full else None


def peaks(p0, p1, volume) -> list:
    """Peak |p0|, |p1| (mm) and the smallest and largest cavity volume (mL)."""
    norm = lambda p: 1e3 * float(np.max(np.linalg.norm(np.asarray(p), axis=1)))
    v = None if volume is None else 1e6 * np.asarray(volume)
    return [norm(p0), norm(p1), None if v is None else float(v.min()), None if v is None else float(v.max())]


def step_table(step: str, entry: dict) -> dict:
    table = Table(f"Step {step}: peaks of the ten codes and hyperoc (P{entry['degree']}, reference mesh)",
                  ["code", "peak |p0| (mm)", "peak |p1| (mm)", "min volume (mL)", "max volume (mL)"], echo=False)
    for code, c in reference_curves(step).items():
        table.add(code, *peaks(c["p0"], c["p1"], c["volume"]))
    table.add("hyperoc", *peaks(entry["p0"], entry["p1"], entry["volume"]))
    c = entry["comparison"]
    table.notes = ("Inside the codes' band at their sampling times (every 10 ms): "
                   + ", ".join(f"{q} {100 * c[q]['inside']:.0f} % (worst {100 * c[q]['worst']:.2g} % outside)"
                               for q in c) + ". Source: Aróstica et al. (2025), toolkit curves (MIT).")
    return table.as_dict()


def cost_table(runs: list[dict]) -> dict:
    table = Table("Every run: peaks, cost (2 cores; wall time includes compilation) and the share of sampling "
                  "times inside the codes' band",
                  ["step", "degree", "mesh", "dt (ms)", "end (s)", "unknowns", "peak |p0| (mm)", "peak |p1| (mm)",
                   "time steps", "Newton iterations", "wall time (s)", "peak memory (MiB)", "|p0| inside band",
                   "|p1| inside band", "volume inside band"], echo=False)
    for e in runs:
        c = e["comparison"]
        table.add(e["step"], e["degree"], e["mesh"]["variant"], 1e3 * e["dt"], e["t"][-1], e["unknowns"],
                  *peaks(e["p0"], e["p1"], None)[:2], int(round(e["t"][-1] / e["dt"])),
                  e["newton_iterations"]["total"], e["wall_time"], e["peak_memory_mib"], c["|p0|"]["inside"],
                  c["|p1|"]["inside"], c["volume"]["inside"])
    return table.as_dict()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", default="0A,0B,1")
    ap.add_argument("--degrees", default="1")
    ap.add_argument("--mesh", default="reference", choices=["reference", "coarse"])
    ap.add_argument("--end-time", type=float, default=None, help="stop each run at this time (s)")
    ap.add_argument("--dt", type=float, default=None, help="time step (s; default the benchmark's, 1 ms)")
    ap.add_argument("--work", type=Path, default=Path("runs/cardiac-benchmark"),
                    help="folder of the runs' outputs and checkpoints")
    ap.add_argument("--solver", default="lu", choices=["lu", "pardiso"],
                    help="sparse direct solver of the steps (pardiso: MKL, multithreaded)")
    args = ap.parse_args()
    new = [run(step, int(d), args.mesh, args.work, args.end_time, args.dt, args.solver)
           for d in args.degrees.split(",") for step in args.steps.split(",")]
    runs = merged_runs(new)
    chosen = {step: best(runs, step) for step in ("0A", "0B", "1")}
    tables = [step_table(step, e) for step, e in chosen.items() if e is not None] + [cost_table(runs)]
    write_results(NAME, command_line(), tables, data={**{s: e for s, e in chosen.items() if e}, "runs": runs})


if __name__ == "__main__":
    main()

"""The distributed static solve (`hyperoc.distributed`, MPI + PETSc, MUMPS) against the serial JAX path.

Land et al. (2015) problem 2: the idealized LV, Taylor-Hood P2-P1, incompressible, Guccione on the
isochoric strain, curved P2 cells, base clamped, h = 6 mm with ``--refinements`` uniform refinements
(0: 1,706 unknowns, 1: 11,569, 2: 84,078), endocardial pressure 10 kPa as a follower load in 20
load steps, full Newton steps (`hyperoc.cardiac.land`). Each row is one process tree running
``python -m hyperoc.app.distributed_statics``: the serial path (`hyperoc.dynamics.statics.solve_static`, its
default sparse LU) and the distributed path on 1 and on 2 ranks (``mpiexec -n``). Reported: the
wall time of the set-up (mesh, model, partition, PETSc objects) and of the solve (JIT compilation
included) and, on the distributed path, its split into the JAX kernels, the assembly (ghost
scatters, COO values) and the factorizations and solves (the largest over the ranks), the Newton
iterations, the largest peak resident memory over the ranks, and the largest
difference of the displacement and of the apex positions from the serial path, relative to the
largest displacement. Needs the ``mpi`` extra (docs/distributed.md); run it with that environment's
python, whose bin/ holds mpiexec.

    venv-mpi/bin/python bench/bench_distributed.py --refinements 0,1

    venv-mpi/bin/python bench/bench_distributed.py --refinements 2 --ranks 2 --no-serial --results bench_distributed_L2

Writes ``bench/results/bench_distributed.json`` (`bench/results.py`), or ``--results NAME``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from results import Table, command_line, run_json, write_results

COLUMNS = ["level", "unknowns", "path", "ranks", "set-up (s)", "solve (s)", "speed-up vs 1 rank", "Newton iterations",
           "peak RSS per rank, max (MB)",
           "kernels / assembly / factor + solves (s)", "max |u - u_serial| / max |u|", "max |z_apex - z_serial| (mm)"]


def run(refinements: int, ranks: int | None, folder: Path) -> dict:
    """One ``hyperoc.app.distributed_statics`` solve: serial (ranks None) or on ``ranks`` MPI ranks."""
    out = folder / f"L{refinements}-{ranks or 'serial'}.json"
    cmd = [sys.executable, "-m", "hyperoc.app.distributed_statics", "--problem", "ventricle", "--refinements",
           str(refinements), "--out", str(out)]
    return run_json(cmd, out, ranks)


def differences(record: dict, serial: dict | None) -> tuple:
    """``(max |u - u_serial| / max |u_serial|, max |z_apex - z_apex,serial|)``, (None, None) without a serial run."""
    if serial is None:
        return None, None
    u, u_ref = np.asarray(record["u"]), np.asarray(serial["u"])
    dz = max(abs(record["values"][k] - serial["values"][k]) for k in serial["values"])
    return float(np.abs(u - u_ref).max() / np.abs(u_ref).max()), dz


def split(record: dict) -> str | None:
    """The distributed solve's split (`hyperoc.distributed.statics.DistributedSolution`), largest over the ranks."""
    parts = record.get("split_seconds") or {}
    return " / ".join(f"{parts[k]:.1f}" for k in ("kernels", "assembly", "solve")) if parts else None


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--refinements", default="0,1", help="comma-separated levels")
    parser.add_argument("--ranks", default="1,2", help="comma-separated rank counts of the distributed path")
    parser.add_argument("--no-serial", action="store_true",
                        help="distributed runs only (no differences reported), e.g. for a level the serial path "
                             "takes too long at")
    parser.add_argument("--results", default="bench_distributed", help="results file stem")
    args = parser.parse_args()
    table = Table("Land problem 2 (Taylor-Hood, incompressible): serial JAX path vs MPI + PETSc (MUMPS)", COLUMNS,
                  "Speed-up: solve time on 1 rank over solve time on this many. Differences against the serial path "
                  "(its own row: 0).")
    with tempfile.TemporaryDirectory() as tmp:
        for level in map(int, args.refinements.split(",")):
            serial = None if args.no_serial else run(level, None, Path(tmp))
            records = [serial] * (serial is not None) + [run(level, int(r), Path(tmp)) for r in args.ranks.split(",")]
            one = next((r for r in records if not r["serial"] and r["ranks"] == 1), None)
            for r in records:
                speedup = None if r["serial"] or one is None else one["solve_seconds"] / r["solve_seconds"]
                table.add(level, r["unknowns"], "serial" if r["serial"] else "distributed", r["ranks"],
                          r["setup_seconds"], r["solve_seconds"], speedup, int(sum(r["newton_iterations"])),
                          max(r["peak_mb"]), split(r), *differences(r, serial))
    write_results(args.results, command_line(), [table.as_dict()])


if __name__ == "__main__":
    main()

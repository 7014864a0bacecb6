"""The dynamic optimal-control gradient on MPI ranks (`hyperoc.distributed.dynamics`) against the serial path.

The ventricle example (examples/ventricle-3d.toml: P1, Guccione with rule-based fibres, active stress
on the apical cap, objective the pressure rise at tau, T = 20 ms, dt = 0.5 ms) on a finer mesh
(``--h``, default 1.25 mm: 6,717 unknowns, all 40 steps (``optimize.horizon = "full"``: the cost of the
whole horizon; the default would solve the 23 up to tau + eps) at tau = 10 ms), at the control point of
``python -m hyperoc.app.distributed_gradient`` (xi uniform in [-2, 2] kPa, seed 1). Each row is one process
tree running that command: the serial path (the config's solver, `ReducedFunctional`) and the distributed
one (Newton and the adjoint's solves on PETSc) on 1 and 2 ranks, with each of ``--solvers`` (MUMPS's LU, and
``gamg``: GMRES with algebraic multigrid to a relative residual of 1e-13). Reported: the wall time of the
first value-and-gradient (JIT compilation included) and of a second one at a nearby point (an optimizer's
iteration), its split on the distributed path (JAX kernels, assembly, factorizations and solves; the
largest over the ranks), the Newton iterations, the largest peak resident memory over the ranks, the
relative differences of J, dJ/dtau and dJ/dxi from the serial path, and with ``--taylor`` the Taylor
test's observed rate on the largest rank count (joint (xi, tau) direction). Needs the ``mpi`` extra
(docs/distributed.md); run it with that environment's python, whose bin/ holds mpiexec.

    venv-mpi/bin/python bench/bench_distributed_gradient.py --taylor

Writes ``bench/results/bench_distributed_gradient.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from results import Table, command_line, run_json, write_results

CONFIG = Path(__file__).resolve().parents[1] / "examples" / "ventricle-3d.toml"
COLUMNS = ["unknowns", "steps", "path", "solver", "ranks", "value + gradient, first (s)", "value + gradient (s)",
           "speed-up vs 1 rank", "Newton iterations", "peak RSS per rank, max (MB)",
           "kernels / assembly / factor + solves (s)", "J rel. diff.", "dJ/dtau rel. diff.",
           "max |dJ/dxi diff.| / max |dJ/dxi|", "Taylor rate"]


def run(h: float, ranks: int | None, solver: str, taylor: bool, folder: Path) -> dict:
    """One ``hyperoc.app.distributed_gradient`` run: serial (ranks None) or on ``ranks`` MPI ranks with ``solver``."""
    out = folder / f"{ranks or 'serial'}-{solver}.json"
    cmd = [sys.executable, "-m", "hyperoc.app.distributed_gradient", str(CONFIG), "--set", f"mesh.h={h}",
           "--set", "optimize.horizon=full", "--solver", solver, "--out", str(out)] + ["--taylor"] * taylor
    return run_json(cmd, out, ranks)


def differences(record: dict, serial: dict) -> tuple:
    """Relative differences of J, dJ/dtau and dJ/dxi (max norm) from the serial run."""
    rel = lambda a, b: abs(a - b) / abs(b)
    dxi, ref = np.asarray(record["dJ_dxi"]), np.asarray(serial["dJ_dxi"])
    return (rel(record["J"], serial["J"]), rel(record["dJ_dtau"], serial["dJ_dtau"]),
            float(np.abs(dxi - ref).max() / np.abs(ref).max()))


def split(record: dict) -> str | None:
    parts = record.get("split_seconds") or {}
    return " / ".join(f"{parts[k]:.1f}" for k in ("kernels", "assembly", "solve")) if parts else None


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--h", type=float, default=1.25, help="mesh size (mm); the example's is 2.5")
    parser.add_argument("--ranks", default="1,2", help="comma-separated rank counts of the distributed path")
    parser.add_argument("--solvers", default="mumps,gamg", help="comma-separated PETSc solvers of the distributed path")
    parser.add_argument("--taylor", action="store_true", help="Taylor test on the largest rank count, first solver")
    args = parser.parse_args()
    ranks, solvers = [int(r) for r in args.ranks.split(",")], args.solvers.split(",")
    table = Table(f"Ventricle example, h = {args.h} mm: the dynamic gradient, serial JAX path vs MPI + PETSc (MUMPS)",
                  COLUMNS, "Speed-up: the second value + gradient on 1 rank over the same on this many (same solver). "
                  "Differences against the serial path (its own row: 0).")
    with tempfile.TemporaryDirectory() as tmp:
        serial = run(args.h, None, "mumps", False, Path(tmp))
        taylor = lambda r, solver: args.taylor and r == max(ranks) and solver == solvers[0]
        records = [serial] + [run(args.h, r, solver, taylor(r, solver), Path(tmp)) for solver in solvers for r in ranks]
    for r in records:
        one = next((o for o in records if not o["serial"] and o["ranks"] == 1 and o["solver"] == r["solver"]), None)
        speedup = None if r["serial"] or one is None else one["seconds"] / r["seconds"]
        rate = r["taylor"]["rate"] if "taylor" in r else None
        table.add(r["unknowns"], r["steps"], "serial" if r["serial"] else "distributed",
                  "config's" if r["serial"] else r["solver"], r["ranks"], r["seconds_first"],
                  r["seconds"], speedup, r["newton_iterations"], max(r["peak_mb"]), split(r),
                  *differences(r, serial), rate)
    write_results("bench_distributed_gradient", command_line(), [table.as_dict()])


if __name__ == "__main__":
    main()

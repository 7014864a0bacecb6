"""Command line: one static solve of a Land et al. (2015) problem, distributed or serial, written as JSON.

    mpiexec -n 2 python -m hyperoc.app.distributed_statics --problem ventricle --refinements 0 --out p2.json
    python -m hyperoc.app.distributed_statics --problem ventricle --refinements 0 --serial --out p2-serial.json
    mpiexec -n 2 python -m hyperoc.app.distributed_statics --problem beam --n 1 --constrained --out beam.json
    mpiexec -n 2 python -m hyperoc.app.distributed_statics --problem contraction --refinements 0 --out p3.json
    mpiexec -n 2 python -m hyperoc.app.distributed_statics --problem beam --constrained --robin top=2:normal \
        --out r.json

``ventricle``: problem 2 (`hyperoc.cardiac.land.ventricle_problem`), Taylor-Hood P2-P1, incompressible,
Guccione on the isochoric strain, base clamped, h = 6 mm with ``refinements`` uniform refinements, no
volume constraint. ``contraction``: problem 3 (`hyperoc.cardiac.land.contraction_problem`) in the same
formulation, the endocardial pressure and the active fibre tension. ``beam``: problem 1
(`hyperoc.cardiac.land.beam_problem`, n), P2, bulk modulus 1000 kPa; ``--constrained`` adds the global
volume constraint (volume kept at the reference one). ``--robin NAME=K[:normal]`` (repeatable) adds
springs of stiffness K (kPa/mm) on the boundary NAME, on every component or along the normal only
(`hyperoc.dynamics.terms.RobinBoundary`). All: full Newton steps with load stepping, as
`hyperoc.cardiac.land`. The JSON (written by rank 0) holds the solution u (serial numbering), the
multiplier p, the z of the benchmark's points, Newton iterations, the wall time of the set-up and of the
solve (JIT compilation included), and the peak resident memory of each rank (MB), and on the distributed
path the solve's split (`hyperoc.distributed.statics.DistributedSolution.split`).
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import sys
import time

import numpy as np

from ..cardiac.land import BEAM, VENTRICLE, beam_problem, contraction_problem, node_position, ventricle_problem
from ..dynamics.statics import StaticOptions, solve_static
from ..dynamics.terms import RobinBoundary
from ..errors import InputError
from ..io import write_json


def problem(args):
    """``(model, follower, {name: point})`` of the command line."""
    if args.problem in ("ventricle", "contraction"):
        build = ventricle_problem if args.problem == "ventricle" else contraction_problem
        model, load = build(6.0, bulk_modulus=math.inf, volumetric="taylor-hood", isochoric=True,
                            refinements=args.refinements)
        return model, load, {"z_endo": VENTRICLE["endo_apex"], "z_epi": VENTRICLE["epi_apex"]}
    model, load = beam_problem(args.n, bulk_modulus=1000.0)
    return model, load, {"z_tip": BEAM["point"]}


def springs(model, specs) -> tuple:
    """The `RobinBoundary` springs of ``--robin NAME=K[:DIRECTION]`` entries (direction "full" by default)."""
    terms = []
    for spec in specs or ():
        name, sep, value = spec.partition("=")
        stiffness, _, direction = value.partition(":")
        try:
            k = float(stiffness)
        except ValueError:
            k = None
        if not sep or k is None:
            raise InputError(f"--robin: expected NAME=STIFFNESS[:normal|full], got {spec!r}")
        terms.append(RobinBoundary(model, name, k, direction=direction or "full"))
    return tuple(terms)


def refused(err: InputError) -> int:
    """Exit status 2 for bad input, its message one line on standard error from the first rank (mpiexec's
    rank: the communicator may not exist yet)."""
    if os.environ.get("PMI_RANK", "0") == "0":
        print(f"error: {err}", file=sys.stderr)
    return 2


def peak_mb() -> float:
    """This process's peak resident memory, MB (Linux reports kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hyperoc.app.distributed_statics",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--problem", choices=("ventricle", "contraction", "beam"), default="ventricle")
    parser.add_argument("--refinements", type=int, default=0, help="ventricle: uniform refinements of h = 6 mm")
    parser.add_argument("--n", type=int, default=1, help="beam: 10 n x n x n cubes")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--cutbacks", type=int, default=40)
    parser.add_argument("--constrained", action="store_true", help="global volume constraint")
    parser.add_argument("--serial", action="store_true", help="the serial JAX path (solve_static), one process")
    parser.add_argument("--solver", default="mumps", help="PETSc direct solver package (distributed path)")
    parser.add_argument("--robin", action="append", metavar="NAME=K[:normal]",
                        help="springs of stiffness K (kPa/mm) on the boundary NAME (repeatable)")
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    model, load, points = problem(args)
    try:
        robin = springs(model, args.robin)
    except InputError as err:  # nothing written
        return refused(err)
    setup = time.perf_counter() - t0
    if args.serial:
        t0 = time.perf_counter()
        sol = solve_static(model, follower=load, robin=robin, constraint=None if args.constrained else "none",
                           options=StaticOptions(steps=args.steps, line_search=False, cutbacks=args.cutbacks))
        u, p, iters, rejected, seconds = sol.u, sol.p, sol.newton_iterations, sol.rejected_iterations, \
            time.perf_counter() - t0
        rank, size, memory, split = 0, 1, [peak_mb()], {}
    else:
        from mpi4py import MPI

        from ..distributed.statics import DistributedStatics

        comm = MPI.COMM_WORLD
        t0 = time.perf_counter()
        dist = DistributedStatics(model, load, robin=robin, comm=comm, constrained=args.constrained,
                                  solver=args.solver)
        setup += time.perf_counter() - t0
        sol = dist.solve(steps=args.steps, cutbacks=args.cutbacks)
        u, p, iters, rejected, seconds = sol.u, sol.p, sol.newton_iterations, sol.rejected_iterations, sol.seconds
        split = sol.split
        rank, size, memory = comm.rank, comm.size, comm.gather(peak_mb())
        setup = comm.allreduce(setup, op=MPI.MAX)
    if rank == 0:
        values = {name: float(node_position(model, u, X)[2]) for name, X in points.items()}
        record = {"problem": args.problem, "refinements": args.refinements, "n": args.n,
                  "constrained": args.constrained, "robin": args.robin or [], "serial": args.serial, "ranks": size,
                  "unknowns": int(model.n),
                  "values": values, "p": float(p), "newton_iterations": np.asarray(iters).tolist(),
                  "rejected_iterations": int(rejected), "setup_seconds": setup, "solve_seconds": seconds,
                  "peak_mb": memory, "split_seconds": split, "u": np.asarray(u).tolist()}
        write_json(args.out, record)
    return 0


if __name__ == "__main__":
    sys.exit(main())

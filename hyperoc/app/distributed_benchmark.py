"""The cardiac elastodynamics benchmark on MPI ranks: ``hyperoc benchmark cardiac-elastodynamics`` with its
steps solved by `hyperoc.distributed.dynamics.DistributedStepper` (Newton on PETSc; no volume constraint).

    mpiexec -n 2 python -m hyperoc.app.distributed_benchmark --step 1 --out beat
    mpiexec -n 2 python -m hyperoc.app.distributed_benchmark --step 1 --out beat --resume   # after an interruption

The options are the command's (``--step``, ``--degree``, ``--mesh``, ``--end-time``, ``--dt``, ``--resume``) but
``--solver``: the PETSc solver (mumps, superlu_dist or gamg). Every rank solves its share and saves the same
checkpoint segments (every 50 steps); rank 0 writes the command's outputs (``benchmark.json`` with ``ranks`` and
``solver``, ``curves.npz``, the figures) and prints its comparison with the codes. A resumed run ends equal to an
uninterrupted one to Newton's tolerance (the ranks' sums follow MUMPS's arrival order). Bad input: one line on
standard error, exit status 2, nothing written.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import InputError
from .distributed_simulate import config_stepper, make_run_folder
from .distributed_statics import refused


def parse(argv):
    from .cli import add_benchmark_arguments

    parser = argparse.ArgumentParser(prog="python -m hyperoc.app.distributed_benchmark",
                                     description=__doc__.split("\n")[0])
    add_benchmark_arguments(parser)
    parser.add_argument("--solver", default="mumps", help="mumps, superlu_dist (PETSc LU) or gamg (GMRES + AMG)")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    try:
        args = parse(argv)
        from .cli import checked_benchmark

        out, cfg, model = checked_benchmark(args, None)
        stepper = config_stepper(cfg, model, args.solver)
        comm = stepper.layout.comm
    except InputError as err:
        return refused(err)
    from .cardiac_benchmark import run_benchmark
    from .cardiac_benchmark_report import write_benchmark_outputs
    from .cli import print_comparison

    make_run_folder(comm, out)
    record = run_benchmark(args.step, out, degree=args.degree, mesh=args.mesh, T=args.end_time, dt=args.dt,
                           stepper=stepper)
    record.update(ranks=comm.size, solver=args.solver)
    if comm.rank == 0:
        write_benchmark_outputs(out, record)
        print_comparison(record, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

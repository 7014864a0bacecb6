"""Command line: the forward solve of a config's problem, as ``hyperoc simulate``, on MPI ranks.

    mpiexec -n 2 python -m hyperoc.app.distributed_simulate examples/ventricle-3d.toml --out run
    mpiexec -n 2 python -m hyperoc.app.distributed_simulate examples/ventricle-3d.toml --set mesh.h=1.5 --out run
    mpiexec -n 2 python -m hyperoc.app.distributed_simulate --resume run      # continue a checkpointed run

The config's problem with its prescribed control (``[control]``), step terms (``[[dynamics.robin]]``,
``[dynamics] pressure, activation``, ``[material] viscosity``) and constraint (``[dynamics] constraint``:
"tissue_volume", "cavity_volume" or "circulation"; "none" is refused), stepped by
`hyperoc.distributed.dynamics.DistributedStepper` (Newton on PETSc; ``--solver`` mumps, superlu_dist or
gamg). Rank 0 writes ``hyperoc simulate``'s outputs (config.toml, summary.json, results.npz, the figures, the
ParaView series) and ``distributed.json``: the ranks, the solver, the unknowns, the wall time of the solve
(compilation included), the Newton iterations and each rank's peak resident memory (MB). With ``[output]
checkpoint_every`` the solve is saved in segments (``OUT/segments``, each written atomically by every rank:
the ranks hold the same states) and ``--resume OUT`` continues it from the last one, ending equal to an
uninterrupted run to Newton's tolerance (MUMPS's sums over the ranks follow the order their contributions
arrive in, so two runs on several ranks differ in round-off). Bad input: one line on standard error (from
rank 0), exit status 2, nothing written.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ..errors import InputError
from ..io import atomic_write_text, write_json
from .distributed_gradient import require_distributed_constraint
from .distributed_statics import peak_mb, refused


def parse(argv):
    parser = argparse.ArgumentParser(prog="python -m hyperoc.app.distributed_simulate",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("config", nargs="?", help="a hyperoc TOML config")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="config override")
    parser.add_argument("--out", help="output folder (created if missing)")
    parser.add_argument("--resume", metavar="DIR", help="continue the checkpointed run in DIR")
    parser.add_argument("--solver", default="mumps", help="mumps, superlu_dist (PETSc LU) or gamg (GMRES + AMG)")
    return parser.parse_args(argv)


def checked(args):
    """``(cfg, model, out)`` of a new run (CONFIG --out DIR) or a resumed one (--resume DIR); `InputError`
    before anything is written."""
    from .cli import _refuse_checkpointed, _run_folder
    from .config import load_config
    from .preflight import check_inputs, check_output_dir
    from .workflows import check_run

    out, config = _run_folder(args, "simulate")
    if args.resume and args.set:
        raise InputError("--resume continues the recorded solve: --set would change it")
    _refuse_checkpointed(check_output_dir(out), args.resume, f"--resume {out}")
    cfg = load_config(config, args.set)
    if args.resume and not cfg["output"].get("checkpoint_every"):
        raise InputError(f"--resume: {config} has no [output] checkpoint_every, so {out} holds no checkpoints")
    require_distributed_constraint(cfg, "forward run")
    return cfg, check_run(cfg, "simulate", check_inputs(cfg, "simulate", False)), out


def config_stepper(cfg, model, solver: str):
    """The `hyperoc.distributed.dynamics.DistributedStepper` of the config's problem on MPI.COMM_WORLD: its
    scheme, step terms and constraint, with the PETSc ``solver``."""
    from mpi4py import MPI

    from ..distributed.dynamics import DistributedStepper

    return DistributedStepper(model, cfg.scheme(), comm=MPI.COMM_WORLD, solver=solver, terms=cfg.step_terms(model),
                              constraint=cfg.constraint(model, cfg.grid().t))


def make_run_folder(comm, out, config: str | None = None) -> None:
    """Rank 0 creates the output folder ``out`` (and writes the run's ``config`` TOML there); every rank returns
    once it exists, before any claims a checkpoint segment."""
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        if config is not None:
            atomic_write_text(out / "config.toml", config)
    comm.Barrier()


def main(argv=None) -> int:
    try:
        args = parse(argv)
        cfg, model, out = checked(args)
        stepper = config_stepper(cfg, model, args.solver)
        comm = stepper.layout.comm
    except InputError as err:
        return refused(err)
    from .workflows import run_title, solve_prescribed, write_simulation

    make_run_folder(comm, out, cfg.to_toml())
    start = time.perf_counter()
    sol = solve_prescribed(cfg, out, stepper)
    seconds, memory = time.perf_counter() - start, comm.gather(peak_mb())
    if comm.rank == 0:
        summary = write_simulation(cfg, out, sol, model, f"{run_title(cfg)}, {comm.size} MPI ranks")
        write_json(out / "distributed.json", {
            "ranks": comm.size, "solver": args.solver, "unknowns": int(model.n), "steps": int(len(sol.t) - 1),
            "seconds": seconds, "newton_iterations": int(np.sum(sol.newton_iterations)), "peak_mb": memory})
        print(f"max p = {summary['pressure_max']:.6g} at t = {summary['t_pressure_max']:.6g}; {comm.size} ranks, "
              f"{seconds:.1f} s -> {out / 'summary.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Command line: the reduced functional J(xi, tau) of a config's problem and its exact gradient, on MPI
ranks or in one process, written as JSON.

    mpiexec -n 2 python -m hyperoc.app.distributed_gradient examples/ventricle-3d.toml --set mesh.h=1.5 --out g.json
    python -m hyperoc.app.distributed_gradient examples/ventricle-3d.toml --set mesh.h=1.5 --serial --out g1.json
    mpiexec -n 2 python -m hyperoc.app.distributed_gradient examples/ventricle-3d.toml --taylor --out t.json
    mpiexec -n 2 python -m hyperoc.app.distributed_gradient examples/ventricle-3d.toml --optimize --out o.json

The point: tau = ``optimize.tau0`` (or ``--tau``), xi uniform in [-a, a] at every node and s-level
(``--amplitude`` a, ``--seed``), the same on every rank. The distributed path solves with
`hyperoc.distributed.dynamics.DistributedStepper` (Newton on PETSc, MUMPS) and
`DistributedAdjoint`; ``--serial`` with the package's serial `ReducedFunctional` (the config's solver). Both
take the config's step terms (``[[dynamics.robin]]``, ``[dynamics] pressure, activation``, ``[material]
viscosity``) and its constraint (``[dynamics] constraint``: "tissue_volume", "cavity_volume" with
``[dynamics.cavity]``, "circulation" with ``[dynamics.circulation]``); "none" is refused.
``--snapshots s``: binomial checkpointing with s snapshots (`hyperoc.control.revolve.Binomial`).
``--taylor``: the Taylor test along the joint (xi, tau) direction of
`hyperoc.control.verification.random_directions`. ``--optimize``: then the config's optimization from
(0, tau) (`hyperoc.app.workflows.optimize_single`: its method, ``max_iter`` and bounds), the optimizer
running unchanged on every rank with the same values. The JSON (rank 0) holds J, the gradient (dJ/dxi as a
dual vector, dJ/dtau), the state at the point (the step multipliers p, the last kept level's displacement),
the wall time of the value and gradient (compilation included) and of each later evaluation, the Newton
iterations, the peak resident memory of each rank (MB), the Taylor result, the optimization's iterates (J, tau)
and result, and on the distributed path the split of the two evaluations
(`hyperoc.distributed.layout.Layout.split`).
Bad input: one line on standard error (from rank 0), exit status 2, nothing written.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ..errors import InputError
from ..io import write_json
from .distributed_statics import peak_mb, refused


def parse(argv):
    parser = argparse.ArgumentParser(prog="python -m hyperoc.app.distributed_gradient",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("config", help="a hyperoc TOML config with [control] and [objective]")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="config override")
    parser.add_argument("--tau", type=float, help="default: optimize.tau0")
    parser.add_argument("--amplitude", type=float, default=2.0, help="xi uniform in [-a, a] (control units)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--snapshots", type=int, help="binomial checkpointing with this many snapshots")
    parser.add_argument("--taylor", action="store_true", help="Taylor test along a random (xi, tau) direction")
    parser.add_argument("--optimize", action="store_true", help="then the config's optimization from (0, tau)")
    parser.add_argument("--serial", action="store_true", help="the serial path, one process")
    parser.add_argument("--solver", default="mumps",
                        help="distributed path: mumps, superlu_dist (PETSc LU) or gamg (GMRES + algebraic multigrid)")
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    if args.amplitude < 0:
        raise InputError(f"--amplitude must be >= 0, got {args.amplitude}")
    return args


def require_distributed_constraint(cfg, what: str) -> None:
    """`InputError` when the config's constraint has no distributed form, before any rank starts a solve: the
    cavity's lid through the deformed rim's centroid (``apex = "rim"`` in ``[dynamics.cavity]`` or
    ``[dynamics.circulation]``: its stiffness's dense part does not split over the ranks' cells); ``what``: the
    command's name in the message."""
    d = cfg["dynamics"]
    section = {"cavity_volume": "cavity", "circulation": "circulation"}.get(d["constraint"])
    if section is not None and (d.get(section) or {}).get("apex", "fixed") != "fixed":
        raise InputError(f'the distributed {what} does not yet take [dynamics.{section}] apex = "rim" (the moving '
                         f'apex\'s dense stiffness does not split over the ranks): use apex = "fixed"')


def reduced_functional(args):
    """``(J, m, comm, cfg)``: the config's `ReducedFunctional` (distributed unless ``--serial``), the point,
    the communicator (None serial) and the config."""
    from ..control.reduced import ControlPoint, ReducedFunctional
    from ..control.revolve import checkpoint_schedule
    from .config import load_config

    cfg = load_config(args.config, args.set)
    tau = float(cfg["optimize"].get("tau0", cfg["dynamics"]["T"] / 2)) if args.tau is None else args.tau
    transform = cfg.transform(tau)
    model = cfg.model()
    terms = cfg.step_terms(model)
    require_distributed_constraint(cfg, "gradient")
    constraint = cfg.constraint(model, transform.grid(tau).t)  # a volume change not finite on the grid: here
    comm, options = None, {"schedule": checkpoint_schedule(snapshots=args.snapshots),
                           "horizon": cfg["optimize"]["horizon"]}
    if args.serial:
        from ..control.adjoint import Adjoint
        from ..dynamics.stepper import TimeStepper

        options["adjoint"] = Adjoint(TimeStepper(model, cfg.scheme(), cfg["dynamics"]["solver"], terms=terms,
                                                 constraint=constraint))
    else:
        from mpi4py import MPI

        from ..distributed.dynamics import DistributedAdjoint, DistributedStepper

        comm = MPI.COMM_WORLD
        options["adjoint"] = DistributedAdjoint(DistributedStepper(model, cfg.scheme(), comm=comm,
                                                                   solver=args.solver, terms=terms,
                                                                   constraint=constraint))
    J = ReducedFunctional(model, transform, cfg.objective(), **options)
    xi = np.random.default_rng(args.seed).uniform(-args.amplitude, args.amplitude, (J.N + 1, model.control.size))
    return J, ControlPoint(xi, tau), comm, cfg


def optimization(cfg, J, tau: float) -> dict:
    """The config's optimization from (0, tau): its iterates' J and tau and how it ended."""
    from .workflows import optimize_single

    t0 = time.perf_counter()
    _, res = optimize_single(cfg, tau, J=J)
    return {"method": cfg["optimize"]["method"], "objective": res.objective, "tau": res.point.tau,
            "iterations": res.iterations, "converged": res.converged, "seconds": time.perf_counter() - t0,
            "history_objective": list(res.history["objective"]), "history_tau": list(res.history["tau"])}


def evaluate(J, m) -> dict:
    """J(m), its derivative and the state (the step multipliers, the last kept level's displacement, the
    constraint's carried states at the levels: for the circulation ``(p, Pa, phase)``), timed
    (first evaluation: compilation included; then a second one at a new point next to m, the cost of an
    optimizer's iteration)."""
    t0 = time.perf_counter()
    value, d = J.value_and_derivative(m)
    first = time.perf_counter() - t0
    state = J.record(m)  # the solve of the evaluation, cached
    state = {"p_steps": state.p_steps.tolist(), "state_level": int(state.levels[-1]), "state": state.y0[-1].tolist(),
             "carried": np.asarray(state.carried).tolist()}
    t0 = time.perf_counter()
    J.value_and_derivative(m * (1 + 1e-6))
    again = time.perf_counter() - t0
    rec = J.record(m * (1 + 1e-6))
    return {"J": value, "dJ_dtau": d.tau, "dJ_dxi": d.xi.ravel().tolist(), "dJ_dxi_norm": float(np.linalg.norm(d.xi)),
            "seconds_first": first, "seconds": again, "newton_iterations": int(np.sum(rec.newton_iterations)), **state}


def main(argv=None) -> int:
    try:
        args = parse(argv)
        J, m, comm, cfg = reduced_functional(args)
    except InputError as err:
        return refused(err)
    record = {"config": args.config, "overrides": args.set, "serial": args.serial, "solver": args.solver,
              "ranks": 1 if comm is None else comm.size, "unknowns": int(J.model.n), "steps": int(J.steps_solved),
              "controls": int(J.model.control.size), "tau": m.tau, "amplitude": args.amplitude, "seed": args.seed,
              "snapshots": args.snapshots, **evaluate(J, m)}
    if comm is not None:
        record["split_seconds"] = J.stepper.layout.slowest_split()
    if args.taylor:
        from ..control.verification import random_directions, taylor_test

        record["taylor"] = taylor_test(J, m, random_directions(J, m, args.seed)["joint"]).as_dict()
    if args.optimize:
        record["optimization"] = optimization(cfg, J, m.tau)
    record["peak_mb"] = [peak_mb()] if comm is None else comm.gather(peak_mb())
    if comm is None or comm.rank == 0:
        write_json(args.out, record)
    return 0


if __name__ == "__main__":
    sys.exit(main())

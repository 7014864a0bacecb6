"""J, its gradient and a Taylor test of the ventricle example without a volume constraint, under an objective
that reads the state: the injectivity penalty with its threshold above every det F, so that every cell and
level enter J (with ``constraint = "none"`` the pressure is 0, and the config's objectives read only it).

    mpiexec -n 2 python tests/distributed_unconstrained_gradient.py OUT.json     # on the ranks
    `gradient(distributed=False)`                                                # serial, in a test

Run by tests/test_distributed.py, which compares both.
"""

import json
import sys
from pathlib import Path

import numpy as np

CONFIG = Path(__file__).resolve().parents[1] / "examples" / "ventricle-3d.toml"
SETTINGS = ["mesh.h=5.0", "dynamics.T=4.0", 'dynamics.constraint="none"']
TAU, AMPLITUDE, SEED = 2.0, 2.0, 1


def reduced_functional(distributed: bool):
    """``(J, m)``: the `ReducedFunctional` on the serial path or on the ranks of MPI.COMM_WORLD, and the point."""
    from hyperoc.app.config import load_config
    from hyperoc.control.adjoint import Adjoint
    from hyperoc.control.objectives import ControlCost, InjectivityPenalty, Objective
    from hyperoc.control.reduced import ControlPoint, ReducedFunctional
    from hyperoc.dynamics.stepper import TimeStepper

    cfg = load_config(str(CONFIG), SETTINGS)
    model = cfg.model()
    terms = cfg.step_terms(model)
    if distributed:
        from mpi4py import MPI

        from hyperoc.distributed.dynamics import DistributedAdjoint, DistributedStepper

        adjoint = DistributedAdjoint(DistributedStepper(model, cfg.scheme(), comm=MPI.COMM_WORLD, terms=terms,
                                                        constraint="none"))
    else:
        adjoint = Adjoint(TimeStepper(model, cfg.scheme(), "lu", terms=terms, constraint="none"))
    objective = Objective(running=(ControlCost(5e-5), InjectivityPenalty(gamma=1.0, delta=1.05)))
    J = ReducedFunctional(model, cfg.transform(TAU), objective, adjoint=adjoint)
    xi = np.random.default_rng(SEED).uniform(-AMPLITUDE, AMPLITUDE, (J.N + 1, model.control.size))
    return J, ControlPoint(xi, TAU)


def gradient(distributed: bool, taylor: bool = False) -> dict:
    """J, dJ/dtau, dJ/dxi and, with ``taylor``, the Taylor test's record along a random joint direction."""
    from hyperoc.control.verification import random_directions, taylor_test

    J, m = reduced_functional(distributed)
    value, d = J.value_and_derivative(m)
    record = {"J": value, "dJ_dtau": d.tau, "dJ_dxi": d.xi.ravel().tolist()}
    if taylor:
        record["taylor"] = taylor_test(J, m, random_directions(J, m, SEED)["joint"]).as_dict()
    return record


if __name__ == "__main__":
    from mpi4py import MPI

    result = gradient(distributed=True, taylor=True)
    if MPI.COMM_WORLD.rank == 0:
        Path(sys.argv[1]).write_text(json.dumps(result))

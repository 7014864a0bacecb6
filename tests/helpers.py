"""Test problems shared by several test files, each built once per test process (with pytest-xdist a
worker builds a problem the first time one of its tests asks for it, and later tests reuse it).

JAX compiles a model's kernels once per model and a time loop once per reduced functional, so a
shared model saves its construction and its compiled kernels, and a shared reduced functional also
saves its compiled forward and adjoint loops. A reduced functional keeps evaluation counts and its
last solves, so it is shared only by tests that compare values and gradients, or count solves as
differences at points no other test evaluates; `checkpointing_problem` hands it out with the
checkpointing settings reset.
"""

from dataclasses import dataclass
from functools import cache

import jax.numpy as jnp

from hyperoc import (
    BodyForce,
    ControlPoint,
    Objective,
    PressureAt,
    PressureRise,
    ReducedFunctional,
    Region,
    SaintVenantKirchhoff,
    StateModel,
    TimeTransform,
    box,
    interval,
)
from hyperoc.control.objectives import Terminal
from hyperoc.control.revolve import StoreAll
from hyperoc.control.verification import random_directions


@cache
def bar(cells: int, damping: float = 2e-3, omega: tuple = (0.75, 1.0),
        material=SaintVenantKirchhoff(0.05, 0.05)) -> StateModel:
    """The paper's 1D bar on [0, 1] (``cells`` P1 cells, damping ``damping``, Saint Venant-Kirchhoff
    mu = lambda = 0.05 unless another material is given) with a body-force control on ``omega``."""
    return StateModel(interval(cells), material, damping=damping,
                      control=BodyForce(Region("box", lower=omega[:1], upper=omega[1:])))


@dataclass(frozen=True)
class LevelReads(Terminal):
    """Reads single levels, as a term must for checkpointing: y1 at T and y0 at tau."""

    def value(self, traj):
        v = traj.y1[-1]
        return -0.5 * v @ (traj.mass @ v) + 0.3 * jnp.sum(traj.y0[traj.tau_index])


def control_point(J: ReducedFunctional, tau: float, amplitude: float, seed: int = 3) -> ControlPoint:
    """A smooth random control of the given amplitude (`random_directions`) at ``tau``."""
    return ControlPoint(amplitude * random_directions(J, J.zero(tau), seed=seed)["xi"].xi, tau)


@cache
def _checkpointing_problem(kind: str) -> ReducedFunctional:
    if kind == "traced-1d":  # tridiagonal solver: the stored forward is a compiled lax.scan
        return ReducedFunctional(bar(20), TimeTransform.for_step(1.75, 0.25, 0.75, 0.25),
                                 Objective(at_tau=PressureRise(0.25), terminal=(LevelReads(),)))
    if kind == "sparse-3d":  # sparse LU: every path runs the jitted step from Python
        model = StateModel(box(1, dirichlet="left"), SaintVenantKirchhoff(1.0, 1.0), damping=0.05,
                           control=BodyForce(Region("box", lower=(0.5, 0.0, 0.0), upper=(1.0, 1.0, 1.0))))
        # horizon "full": all 7 steps, the length the schedules are checked on (3 does not divide it)
        return ReducedFunctional(model, TimeTransform.for_step(0.7, 0.1, 0.3), Objective(at_tau=PressureAt()),
                                 solver="lu", horizon="full")
    raise ValueError(kind)


def checkpointing_problem(kind: str) -> ReducedFunctional:
    """The reduced functionals on which `tests/test_checkpointed_adjoint.py` and `tests/test_revolve.py`
    compare checkpointed and stored adjoints (``"traced-1d"``: 7 steps of the bar with 20 cells, an
    objective reading y0(tau) and y1(T); ``"sparse-3d"``: 7 steps of a clamped unit cube), with
    checkpointing switched off (`StoreAll`)."""
    J = _checkpointing_problem(kind)
    J.schedule = StoreAll()
    return J


def small_1d_toml(*, n: int = 20, dt: float = 0.05, lower: float = 0.75, value: str | None = "0.05 * sin(pi * t)",
                  max_iter: int = 4) -> str:
    """The TOML text of a small 1D run (SVK bar, T = 2, body force on [lower, 1]); ``value`` the prescribed
    control's expression (None: none)."""
    control = f'\nvalue = "{value}"' if value is not None else ""
    return f"""
[mesh]
kind = "interval"
n = {n}
[material]
law = "svk"
mu = 0.05
lambda = 0.05
[dynamics]
T = 2.0
dt = {dt}
damping = 2e-3
[control]
kind = "body_force"
region = {{ kind = "box", lower = [{lower}], upper = [1.0] }}{control}
[objective]
alpha = 2e-3
[optimize]
tau0 = 1.0
max_iter = {max_iter}
"""

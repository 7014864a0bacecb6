"""Ready-made optimal control problems for studies and tests.

`vibrating_bar`: a 1D problem with an interior, nondegenerate maximizer in (xi, tau), for
measuring optimizers (mesh independence). The paper's own 1D setup (`hyperoc.app.paper`) has no
finite optimum at fine resolution, and with zero initial data the optimal value does not
decrease with tau (time-shift property), so tau drifts to the end of the interval; here an
initial velocity makes p(t) peak at an interior time and a strong control cost keeps the
control small.
"""

from __future__ import annotations

import numpy as np

from ..dynamics.timegrid import TimeTransform
from ..fem.mesh import interval
from ..mechanics.controls import BodyForce, Region
from ..mechanics.materials import NeoHookean
from ..mechanics.model import StateModel
from .objectives import ControlCost, ControlRateCost, Objective, PressureAt
from .reduced import ReducedFunctional

__all__ = ["vibrating_bar"]


def vibrating_bar(h: float, dt: float, *, T: float = 4.0, tau0: float = 2.0, alpha: float = 10.0,
                  damping: float = 1e-2, amplitude: float = 0.05, beta: float = 0.0) -> ReducedFunctional:
    """``max p(tau) - alpha/2 ||xi||^2`` for a bar on [0, 1] vibrating in its first mode.

    Neo-Hookean (mu = lambda = 0.05, dimensionless), damping kappa = ``damping``, u0 = 0 and
    ``v0(x) = amplitude sin(pi x)`` (v0(1) = 0: compatible with the volume constraint, which in 1D
    fixes u(1, t)), body-force control on omega = [0.25, 0.5]. The free pressure is
    ``p(t) ~ (lambda + 2 mu) (amplitude pi / w) sin(w t)`` with ``w = pi sqrt(lambda + 2 mu)``: first
    maximum near t = 1.3, period ~ 5.2, so with T = 4 the maximizing tau is interior. Mesh size h,
    time step dt (the transform's grid puts tau0 on a level); ``beta > 0`` adds the cost
    ``beta/2 ||d xi/dt||^2`` (`ControlRateCost`, controls H^1 in time).
    """
    model = StateModel(interval(int(round(1.0 / h))), NeoHookean(0.05, 0.05), damping=damping,
                       control=BodyForce(Region("box", lower=(0.25,), upper=(0.5,))))
    v0 = model.interpolate(lambda x: amplitude * np.sin(np.pi * x))
    return ReducedFunctional(model, TimeTransform.for_step(T, dt, tau0),
                             Objective(running=(ControlCost(alpha),) + ((ControlRateCost(beta),) if beta > 0 else ()),
                                       at_tau=PressureAt()), v0=v0)

"""The reduced functional ``J(m)``, ``m = (xi~, tau)``, of the hybrid optimal control problem.

The control ``xi~`` lives on the fixed s-grid of a `TimeTransform` (nodal values on the control
nodes at every s-level, shape (N+1, n_ctrl)); tau sets the t-grid through the step sizes. The
gradient is the exact gradient of the discrete J (`hyperoc.adjoint`), its xi-part returned as the
Riesz representative in ``L2(0, 2; L2(omega))`` (trapezoid weights in s times the L2(omega) Gram
matrix), so that optimizers see mesh- and step-independent quantities.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

from . import _jax  # noqa: F401
from .adjoint import Adjoint
from .dynamics import Scheme, StateSolution, TimeStepper
from .errors import InputError
from .model import StateModel
from .objectives import Objective, Trajectory
from .timegrid import TimeTransform, trapezoid_weights

__all__ = ["ControlPoint", "ReducedFunctional"]


@dataclass(frozen=True, eq=False)
class ControlPoint:
    """A point (or direction) ``m = (xi, tau)``: xi (N+1, n_ctrl) on the s-levels, tau scalar."""

    xi: np.ndarray
    tau: float

    def __add__(self, other: "ControlPoint") -> "ControlPoint":
        return ControlPoint(self.xi + other.xi, self.tau + other.tau)

    def __sub__(self, other: "ControlPoint") -> "ControlPoint":
        return ControlPoint(self.xi - other.xi, self.tau - other.tau)

    def __mul__(self, a: float) -> "ControlPoint":
        return ControlPoint(a * self.xi, a * self.tau)

    __rmul__ = __mul__

    def flat(self) -> np.ndarray:
        return np.concatenate([self.xi.ravel(), [self.tau]])


class ReducedFunctional:
    """``J(m)`` and its exact gradient for a model, a time transform and an objective (maximized).

    Parameters
    ----------
    model : StateModel with a control operator.
    transform : TimeTransform (its eps must match the objective's when the objective uses one).
    objective : Objective.
    scheme, solver : time-stepping options (multiplier "step").
    u0, v0 : initial state (reduced vectors), zero by default.
    gradient : "exact" (gradient of the discrete J, default) or "continuous" (the paper's
        optimize-then-discretize gradient, `hyperoc.continuous_adjoint`; for comparison).
    """

    def __init__(self, model: StateModel, transform: TimeTransform, objective: Objective, *,
                 scheme: Scheme = Scheme(), solver="auto", u0=None, v0=None, gradient: str = "exact"):
        if gradient not in ("exact", "continuous"):
            raise InputError(f"gradient must be 'exact' or 'continuous', got {gradient!r}")
        self.gradient_method = gradient
        if model.control is None:
            raise InputError("the optimal control problem needs a model with a control operator")
        if objective.eps and abs(transform.eps - objective.eps) > 1e-14:
            raise InputError(f"time transform eps = {transform.eps} differs from the objective's eps = {objective.eps}")
        self.model, self.transform, self.objective = model, transform, objective
        self.stepper = TimeStepper(model, scheme, solver)
        self.adjoint = Adjoint(self.stepper)
        self.u0 = np.zeros(model.n) if u0 is None else np.asarray(u0, float)
        self.v0 = np.zeros(model.n) if v0 is None else np.asarray(v0, float)
        self.N = transform.num_steps
        self.counts = {"state": 0, "adjoint": 0}
        self._cache_key, self._cache = None, None
        from jax.experimental import sparse as jsparse

        # Built eagerly: a cached property first touched inside a traced function would leak tracers.
        self._control_mass = jsparse.BCOO.from_scipy_sparse(model.control.mass.tocoo())

    # --- geometry of the control space -----------------------------------------------------------
    @cached_property
    def s_weights(self) -> np.ndarray:
        """Trapezoid weights of the s-levels, (N+1,)."""
        return trapezoid_weights(self.transform.ds())

    @cached_property
    def _control_mass_lu(self):
        return spla.splu(self.model.control.mass.tocsc())

    def zero(self, tau: float) -> ControlPoint:
        return ControlPoint(np.zeros((self.N + 1, self.model.control.size)), float(tau))

    def inner(self, a: ControlPoint, b: ControlPoint) -> float:
        """``<a, b> = int_0^2 (a.xi, b.xi)_{L2(omega)} ds + a.tau b.tau`` (trapezoid in s)."""
        return float(np.sum(a.xi * self.dual(b).xi) + a.tau * b.tau)

    def norm(self, a: ControlPoint) -> float:
        return float(np.sqrt(max(self.inner(a, a), 0.0)))

    def riesz(self, dual: ControlPoint) -> ControlPoint:
        """Riesz representative of a derivative (dual vector) for `inner`."""
        xi = self._control_mass_lu.solve(np.ascontiguousarray(dual.xi.T)).T / self.s_weights[:, None]
        return ControlPoint(xi, dual.tau)

    def dual(self, g: ControlPoint) -> ControlPoint:
        """Inverse of `riesz`: the dual vector ``d`` with ``d.xi . v.xi + d.tau v.tau = <g, v>``."""
        Mx = (self.model.control.mass @ g.xi.T).T
        return ControlPoint(self.s_weights[:, None] * Mx, g.tau)

    # --- evaluation ------------------------------------------------------------------------------
    def _check(self, m: ControlPoint) -> None:
        if m.xi.shape != (self.N + 1, self.model.control.size):
            raise InputError(f"control must have shape {(self.N + 1, self.model.control.size)}, got {m.xi.shape}")
        self.transform.check_tau(m.tau)

    def state(self, m: ControlPoint) -> StateSolution:
        """The state for m (cached for the last point)."""
        self._check(m)
        key = (m.tau, m.xi.tobytes())
        if key != self._cache_key:
            grid = self.transform.grid(m.tau)
            sol = self.stepper.run(grid, m.xi, u0=self.u0, v0=self.v0, diagnose=False)
            self.counts["state"] += 1
            self._cache_key, self._cache = key, sol
        return self._cache

    def trajectory(self, sol: StateSolution) -> Trajectory:
        n1, n2, _ = self.transform.steps
        return Trajectory(jnp.asarray(sol.y0), jnp.asarray(sol.y1), jnp.asarray(sol.p_steps), jnp.asarray(sol.xi),
                          jnp.asarray(sol.dt), n1, n1 + n2, self._control_mass, self.stepper._M)

    @cached_property
    def _objective_and_partials(self):
        n1, n2, _ = self.transform.steps

        def value(y0, y1, p, xi, dt):
            traj = Trajectory(y0, y1, p, xi, dt, n1, n1 + n2, self._control_mass, self.stepper._M)
            return self.objective.value(traj)

        return jax.jit(value), jax.jit(jax.value_and_grad(value, argnums=(0, 1, 2, 3, 4)))

    def __call__(self, m: ControlPoint) -> float:
        sol = self.state(m)
        value, _ = self._objective_and_partials
        return float(value(*self._arrays(sol)))

    def _arrays(self, sol):
        return jnp.asarray(sol.y0), jnp.asarray(sol.y1), jnp.asarray(sol.p_steps), jnp.asarray(sol.xi), jnp.asarray(sol.dt)

    def value_and_derivative(self, m: ControlPoint) -> tuple[float, ControlPoint]:
        """J(m) and dJ(m) as a dual vector: ``dJ.dm = sum(d.xi * dm.xi) + d.tau dm.tau``."""
        sol = self.state(m)
        _, vg = self._objective_and_partials
        J, (gY0, gY1, gP, gXi, gdt) = vg(*self._arrays(sol))
        F = self.stepper.external_loads(None, self.transform.grid(m.tau))
        V0 = float(sol.volume[0])
        gXi_state, gdt_state = self.adjoint.backward(jnp.asarray(sol.y0), jnp.asarray(sol.y1), jnp.asarray(sol.p_steps),
                                                     jnp.asarray(sol.xi), jnp.asarray(F), jnp.asarray(sol.dt), V0,
                                                     gY0, gY1, gP)
        self.counts["adjoint"] += 1
        dxi = np.asarray(gXi) + gXi_state
        ddt = np.asarray(gdt) + gdt_state
        dtau = float(ddt @ self.transform.ddt_dtau())
        return float(J), ControlPoint(dxi, dtau)

    def derivative(self, m: ControlPoint) -> ControlPoint:
        return self.value_and_derivative(m)[1]

    def value_and_gradient(self, m: ControlPoint) -> tuple[float, ControlPoint]:
        """J(m) and its Riesz gradient (L2(0,2; L2(omega)) x R), exact or continuous (see ``gradient``)."""
        if self.gradient_method == "continuous":
            from .continuous_adjoint import continuous_gradient

            return self(m), continuous_gradient(self, m)
        J, d = self.value_and_derivative(m)
        return J, self.riesz(d)

    def gradient(self, m: ControlPoint) -> ControlPoint:
        return self.value_and_gradient(m)[1]

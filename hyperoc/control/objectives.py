"""Objective functionals ``J = int_0^T c(u, u_t, xi) dt + phi1(u, u_t)(tau) + phi2(u, u_t)(T)`` (maximized).

Each term is a small object whose ``value(traj)`` is a JAX-traceable function of the discrete
trajectory, so that its partial derivatives come from autodiff and the adjoint handles the rest.
Writing a new term takes a few lines::

    class FinalKineticEnergy(Terminal):
        def value(self, traj):
            v = traj.y1[-1]
            return -0.5 * v @ (traj.mass @ v)

Time integrals use the trapezoid rule on the (possibly non-uniform) t-grid; pressures at time
levels are the second-order level values of `hyperoc.dynamics.stepper.level_pressure`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp

from ..dynamics.stepper import level_pressure, level_pressure_steps
from ..errors import InputError
from ..mechanics.materials import det

OBSERVATIONS = ("centred", "causal")  # how `PressureAt` reads p(tau) from the step multipliers

__all__ = ["Trajectory", "Objective", "ControlCost", "ControlRateCost", "PressureAt", "PressureMean", "PressureRise",
           "Terminal", "objective_from_config"]


@dataclass(frozen=True)
class Trajectory:
    """What objective terms see (JAX arrays).

    y0, y1 : (N+1, n) displacement and velocity at the levels; p_steps : (N,) step multipliers;
    xi : (N+1, n_ctrl) control; dt : (N,) steps; tau_index / eps_index : level indices of tau and
    tau + eps; control_mass : (n_ctrl, n_ctrl) L2(omega) Gram matrix (JAX sparse); mass : state mass;
    model : the `hyperoc.mechanics.model.StateModel` (for terms that read strains, e.g. `InjectivityPenalty`).
    """

    y0: Any
    y1: Any
    p_steps: Any
    xi: Any
    dt: Any
    tau_index: int
    eps_index: int
    control_mass: Any = None
    mass: Any = None
    model: Any = None

    @property
    def pressure(self):
        """Level pressures (N+1,)."""
        return level_pressure(self.p_steps, self.dt)


class Term:
    def value(self, traj: Trajectory):  # pragma: no cover - interface
        raise NotImplementedError

    def steps_read(self, tau_index: int, eps_index: int, num_steps: int) -> int:
        """How many leading time steps the term reads the results of: k means that ``value`` depends on
        the level states ``y0, y1`` at the levels 0 .. k and the multipliers ``p_steps[:k]`` only (0: on
        no state). The forward solve of a gradient stops after the largest k of the objective's terms.
        By default every step (``num_steps``): a term that reads less may say so."""
        return num_steps


class Running(Term):
    """``int_0^T c dt`` with ``density(traj) -> (N+1,)`` the integrand at the levels (trapezoid rule)."""

    def density(self, traj: Trajectory):  # pragma: no cover - interface
        raise NotImplementedError

    def value(self, traj):
        c = self.density(traj)
        return jnp.sum(0.5 * traj.dt * (c[:-1] + c[1:]))


class AtTau(Term):
    """phi1 evaluated at tau (and tau + eps)."""


class Terminal(Term):
    """phi2 evaluated at T."""


@dataclass(frozen=True)
class ControlCost(Running):
    """``c = -alpha/2 ||xi||^2_{L2(omega)}`` (the paper's cost)."""

    alpha: float = 2e-3

    def density(self, traj):
        Mxi = (traj.control_mass @ traj.xi.T).T
        return -0.5 * self.alpha * jnp.sum(traj.xi * Mxi, axis=1)

    def steps_read(self, tau_index, eps_index, num_steps):
        return 0


@dataclass(frozen=True)
class ControlRateCost(Term):
    """``-beta/2 int_0^T ||d xi/dt||^2_{L2(omega)} dt``, discretized as
    ``-beta/2 sum_n (xi_{n+1} - xi_n) . M (xi_{n+1} - xi_n) / dt_n`` (difference quotients on the
    t-grid, M the L2(omega) Gram matrix; exact for xi piecewise linear in time).

    On the transformed grid ``dt_n = mu_dot(s_n, tau) ds_n``, so the cost depends on tau; its
    tau-derivative comes with the rest of ``dJ/d(dt_n)``. Why it is there: it makes the controls
    H^1 in time, on which the observation ``p(tau)`` is continuous, so that the problem has a
    maximizer (the paper's L2 cost alone does not give one).
    """

    beta: float = 0.0

    def value(self, traj):
        dxi = traj.xi[1:] - traj.xi[:-1]
        Mdxi = (traj.control_mass @ dxi.T).T
        return -0.5 * self.beta * jnp.sum(jnp.sum(dxi * Mdxi, axis=1) / traj.dt)

    def steps_read(self, tau_index, eps_index, num_steps):
        return 0


@dataclass(frozen=True)
class InjectivityPenalty(Running):
    """``-gamma int_0^T int_Omega max(0, delta - det F)^3 dx dt``: keeps det F above delta.

    A smooth (C^2) exterior penalty for the local injectivity condition ``det F >= delta``. Why: the
    pressure, a boundary reaction, grows as the material next to the wall is compressed, so a
    maximizer of p(tau) drives an element towards det F = 0, where the state ceases to exist (for
    Saint Venant-Kirchhoff the compressive stress even softens below det F = 1/sqrt(3) in 1D). The
    penalty makes the set of controls whose state exists on [0, T] a region the optimizer can see.
    """

    gamma: float = 1.0
    delta: float = 0.6

    def density(self, traj):
        model = traj.model
        def excess(u):  # int_Omega max(0, delta - det F)^3 dx at one level
            shortfall = jnp.maximum(self.delta - det(model.deformation_gradient(u)), 0.0)
            return jnp.sum(model.quad.wdx * shortfall**3)
        return -self.gamma * jax.vmap(excess)(traj.y0)


@dataclass(frozen=True)
class PressureAt(AtTau):
    """``phi1 = p(tau)`` (the paper's 1D experiment), observed from the step multipliers ``p_{n+1/2}``
    (mid-step values, at ``t_n + dt_n / 2``).

    ``observation = "centred"``: the level value of `level_pressure`, the interpolation of the mid-step
    values on both sides of tau, ``(dt_k p_{k-1/2} + dt_{k-1} p_{k+1/2}) / (dt_{k-1} + dt_k)`` (k the level of
    tau). ``"causal"``: the linear extrapolation of the two mid-step values before tau,
    ``p_{k-1/2} + (p_{k-1/2} - p_{k-3/2}) dt_{k-1} / (dt_{k-1} + dt_{k-2})``. Both are second order in dt for a
    smooth pressure. Why the causal one: ``p_{k+1/2}`` depends on the control on ``[tau, tau + dt]``, so
    the centred value lets a control after tau move p(tau); the causal value reads the states at the levels
    0 .. k and the controls at times up to tau only, as the paper's p(tau).
    """

    observation: str = "centred"

    def __post_init__(self):
        if self.observation not in OBSERVATIONS:
            raise InputError(f"objective: unknown observation {self.observation!r} ({', '.join(OBSERVATIONS)})")

    def value(self, traj):
        if self.observation == "centred":
            return traj.pressure[traj.tau_index]
        k = traj.tau_index  # the last level of `level_pressure` on the steps before tau is its extrapolation
        return level_pressure(traj.p_steps[:k], traj.dt[:k])[-1]

    def steps_read(self, tau_index, eps_index, num_steps):
        if self.observation == "centred":
            return level_pressure_steps(tau_index, num_steps)
        return max(tau_index, 2)


@dataclass(frozen=True)
class PressureMean(AtTau):
    """``phi1 = (1/eps) int_tau^{tau + eps} p dt``, the mean pressure over a window after tau.

    Discretized as ``(1/eps) sum_n dt_n p_n`` over the steps of ``[tau, tau + eps]`` (p_n the step
    multipliers, which are mid-step values: the midpoint rule). Why: the integral is the impulse of
    the constraint's reaction, which depends continuously on the control in L2, while the pointwise
    value p(tau) does not.
    """

    eps: float = 0.1

    def value(self, traj):
        window = slice(traj.tau_index, traj.eps_index)
        return jnp.sum(traj.dt[window] * traj.p_steps[window]) / self.eps

    def steps_read(self, tau_index, eps_index, num_steps):
        return eps_index


@dataclass(frozen=True)
class PressureRise(AtTau):
    """``phi1 = (p(tau + eps) - p(tau)) / eps`` (the paper's main objective, ``sysmainpressure``)."""

    eps: float = 0.1

    def value(self, traj):
        p = traj.pressure
        return (p[traj.eps_index] - p[traj.tau_index]) / self.eps

    def steps_read(self, tau_index, eps_index, num_steps):
        return level_pressure_steps(eps_index, num_steps)


@dataclass(frozen=True)
class Objective:
    """Sum of terms: running costs, one phi1 at tau, optional terminal phi2."""

    running: tuple = (ControlCost(),)
    at_tau: AtTau = field(default_factory=PressureAt)
    terminal: tuple = ()

    @property
    def eps(self) -> float:
        return getattr(self.at_tau, "eps", 0.0)

    @property
    def control_weights(self) -> tuple[float, float]:
        """``(alpha, beta)``: the summed weights of the `ControlCost` and `ControlRateCost` terms."""
        terms = self.running + self.terminal
        return (float(sum(t.alpha for t in terms if isinstance(t, ControlCost))),
                float(sum(t.beta for t in terms if isinstance(t, ControlRateCost))))

    def value(self, traj: Trajectory):
        total = self.at_tau.value(traj)
        for term in self.running + self.terminal:
            total = total + term.value(traj)
        return total

    def steps_read(self, tau_index: int, eps_index: int, num_steps: int) -> int:
        """The most leading steps any term reads (`Term.steps_read`): the state after them changes neither
        J nor its gradient."""
        return max(t.steps_read(tau_index, eps_index, num_steps) for t in (self.at_tau, *self.running, *self.terminal))

    def parts(self, traj: Trajectory) -> dict:
        """Each term's value (JAX scalars, traceable), by its class name, for reports."""
        return {type(term).__name__: term.value(traj) for term in (self.at_tau, *self.running, *self.terminal)}


def objective_from_config(cfg: dict) -> Objective:
    """``{"phi1": "pressure" | "pressure_mean" | "pressure_rise", "eps": 0.1, "alpha": 2e-3, "beta": 0.0,
    "observation": "centred" | "causal"}`` -> Objective; beta > 0 adds the `ControlRateCost` (controls H^1
    in time); ``observation`` is how `PressureAt` reads p(tau)."""
    cfg = dict(cfg or {})
    phi1 = cfg.pop("phi1", "pressure")
    observation = cfg.pop("observation", "centred")
    alpha = cfg.pop("alpha", 2e-3)
    beta = cfg.pop("beta", 0.0)
    eps = cfg.pop("eps", 0.0)
    if cfg:
        raise InputError(f"objective: unknown key(s) {sorted(cfg)}")
    for name, v in (("alpha", alpha), ("beta", beta), ("eps", eps)):
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise InputError(f"objective: {name} must be a finite number, got {v!r}")
    for name, v in (("alpha", alpha), ("beta", beta)):
        if v < 0:
            raise InputError(f"objective: {name} must be >= 0, got {v}")
    running = (ControlCost(float(alpha)),) + ((ControlRateCost(float(beta)),) if beta > 0 else ())
    if phi1 == "pressure":
        if eps:
            raise InputError("objective: eps is only used with phi1 = 'pressure_rise'")
        return Objective(running=running, at_tau=PressureAt(observation))
    if observation != "centred":
        raise InputError("objective: observation is only used with phi1 = 'pressure'")
    windowed = {"pressure_rise": PressureRise, "pressure_mean": PressureMean}
    if phi1 in windowed:
        if not eps > 0:
            raise InputError(f"objective: phi1 = {phi1!r} needs eps > 0")
        return Objective(running=running, at_tau=windowed[phi1](float(eps)))
    raise InputError(f"objective: unknown phi1 {phi1!r} (pressure, pressure_mean, pressure_rise)")

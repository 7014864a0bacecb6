"""The paper's optimize-then-discretize gradient, kept for comparison with the exact one.

Semi-discrete (FE in space) state: ``y0' = y1``, ``M y1' = B xi + f - kappa K y1 - R(y0) - p G(y0)``,
``vol(y0) = V0``, with the damping kappa = ``model.damping``. Its continuous adjoint (the paper's adjoint
system and optimality conditions):

    M zeta1' = -zeta0 + kappa K zeta1 - c_y1,   zeta0' = (K_T + p H) zeta1 - pi G - c_y0,   G^T zeta1 = 0,

backwards from zero terminal values (phi2 = 0), with jumps at tau (and tau + eps) given by the
derivatives of phi1 = p(tau) [or the pressure rise] through the consistent pressure
``p(y0, y1, xi) = (G^T M^-1 (B xi + f - kappa K y1 - R) + y1^T H y1) / (G^T M^-1 G)``.
It is integrated with implicit Euler backwards on the state's time levels (as in the paper), and

    dJ/dxi(t) = c_xi + B^T zeta1  (+ the direct dependence of p(tau) on xi(tau)),
    dJ/dtau   = int_0^T (mu_tau o mu^-1)/mu_dot H dt = (1/tau) int_0^tau H - (1/(T - tau - eps)) int_{tau+eps}^T H,

with ``H = c + zeta0 . y1 + zeta1 . (B xi + f - kappa K y1 - R(y0) - p G(y0))``. This gradient is
*not* the gradient of the discrete J; its deviation from `ReducedFunctional.gradient` is first
order in dt at best, and is measured in ``tests/test_continuous_adjoint.py``.

`ContinuousReducedFunctional` is a `ReducedFunctional` whose `value_and_gradient` returns this gradient
(its `value_and_derivative` stays the exact derivative of the discrete J).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from ..dynamics.timegrid import trapezoid_weights
from ..errors import InputError
from ..solvers.linsolve import SparseSolver
from .objectives import ControlCost, PressureAt, PressureRise
from .reduced import ControlPoint, ReducedFunctional
from .revolve import Schedule, StoreAll

__all__ = ["ContinuousReducedFunctional", "continuous_gradient"]


class ContinuousReducedFunctional(ReducedFunctional):
    """``J(m)`` with the paper's optimize-then-discretize gradient (`continuous_gradient`), for comparison
    with the exact one. Same parameters as `ReducedFunctional`; the running cost must not penalize
    ``d xi/dt`` (``beta = 0``) and the schedule is `StoreAll` (the gradient reads the whole `state`)."""

    def __init__(self, *args, **options):
        super().__init__(*args, **options)
        if self.objective.control_weights[1] > 0:
            raise InputError("the continuous gradient does not include the cost of d xi/dt (beta > 0): "
                             "use ReducedFunctional, the exact gradient")
        if self.model.control.profile is not None:
            raise InputError("the continuous gradient does not include a control's time profile: "
                             "use ReducedFunctional, the exact gradient")

    @ReducedFunctional.schedule.setter
    def schedule(self, schedule: Schedule) -> None:
        if not isinstance(schedule, StoreAll):
            raise InputError(f"checkpointing ({schedule!r}) is implemented for the exact gradient only")
        ReducedFunctional.schedule.fset(self, schedule)

    def __call__(self, m: ControlPoint) -> float:
        """J(m) from the whole `state`, the solve its gradient reads."""
        value, _ = self._objective_pair
        return float(value(*self._solution_arrays(self.state(m))))

    def value_and_gradient(self, m: ControlPoint) -> tuple[float, ControlPoint]:
        """J(m) and the continuous-adjoint gradient as a Riesz representative (`continuous_gradient`)."""
        return self(m), continuous_gradient(self, m)


def _running_cost_parts(J: ReducedFunctional):
    """The paper's running cost: only -alpha/2 ||xi||^2 is supported (c_y0 = c_y1 = 0)."""
    alpha = 0.0
    for term in J.objective.running:
        if not isinstance(term, ControlCost):
            raise InputError("the continuous-adjoint gradient supports the running cost -alpha/2 ||xi||^2 only")
        alpha += term.alpha
    if J.objective.terminal:
        raise InputError("the continuous-adjoint gradient supports phi2 = 0 only")
    return alpha


def continuous_gradient(J: ReducedFunctional, m: ControlPoint) -> ControlPoint:
    """Optimize-then-discretize gradient at m, as a Riesz representative like `ReducedFunctional.gradient`."""
    alpha = _running_cost_parts(J)
    at_tau = J.objective.at_tau
    if not isinstance(at_tau, (PressureAt, PressureRise)):
        raise InputError("the continuous-adjoint gradient supports phi1 = p(tau) or the pressure rise only")
    sol = J.state(m)
    model, st = J.model, J.stepper
    dt = sol.dt
    N = dt.size
    n1, n2, _ = J.transform.steps
    f = st.external_loads(None, J.transform.grid(m.tau))
    p_lev = sol.pressure
    dp = jax.jit(jax.grad(st.consistent_pressure, argnums=(0, 1, 2)))
    jumps = {n1: -1.0 / at_tau.eps, n1 + n2: 1.0 / at_tau.eps} if isinstance(at_tau, PressureRise) else {n1: 1.0}
    B = model.control.load
    solver = SparseSolver(model)
    tangent = jax.jit(model.tangent_blocks)
    vol_grad = model.jitted["volume_gradient"]
    force = model.jitted["internal_force"]
    zeta0 = np.zeros(model.n)
    w1 = np.zeros(model.n)  # M zeta1 at the later level
    zeta1_levels = np.zeros((N + 1, model.n))
    zeta0_levels = np.zeros((N + 1, model.n))
    direct = np.zeros_like(sol.xi)  # d phi1 / d xi(tau), the explicit dependence of p on xi
    for n in range(N, -1, -1):
        if n in jumps:
            g0, g1, gx = (np.asarray(a) for a in dp(jnp.asarray(sol.y0[n]), jnp.asarray(sol.y1[n]),
                                                     jnp.asarray(sol.xi[n]), jnp.asarray(f[n])))
            zeta0 = zeta0 + jumps[n] * g0
            w1 = w1 + jumps[n] * g1
            direct[n] += jumps[n] * gx
        if n == N:
            zeta1 = _project_terminal(model, sol.y0[n], w1)
        else:
            h = dt[n]
            y0 = jnp.asarray(sol.y0[n])
            KpH = np.asarray(tangent(y0, 1.0, p_lev[n]))  # element form of K_T + p H
            blocks = model.mass_blocks / h + model.damping * model.laplace_blocks + h * KpH
            G = np.asarray(vol_grad(y0))
            sol_u = solver.host_solve(blocks, -h * G, G, w1 / h + zeta0, 0.0)
            zeta1, pi = sol_u[:-1], sol_u[-1]
            KpH_z = model.pattern.matrix(KpH) @ zeta1
            zeta0 = zeta0 - h * (KpH_z - pi * G)
        zeta1_levels[n], zeta0_levels[n] = zeta1, zeta0
        w1 = model.mass @ zeta1
    # xi-part: c_xi + B^T zeta1 in t, as a dual vector with the state's trapezoid weights.
    wt = trapezoid_weights(dt)
    Mw = model.control.mass
    dual_xi = wt[:, None] * (-alpha * (Mw @ sol.xi.T).T + (B.T @ zeta1_levels.T).T) + direct
    # tau-part through the Hamiltonian.
    H = np.array([_hamiltonian(model, sol, f, zeta0_levels[k], zeta1_levels[k], k, alpha, force, vol_grad)
                  for k in range(N + 1)])
    T, eps, tau = J.transform.T, J.transform.eps, m.tau
    first = trapezoid_weights(dt[:n1]) @ H[: n1 + 1] / tau
    last = trapezoid_weights(dt[n1 + n2:]) @ H[n1 + n2:] / (T - tau - eps)
    return J.riesz(ControlPoint(dual_xi, first - last))


def _project_terminal(model, y0, w1):
    """zeta1(T) from M zeta1 = w1 with G^T zeta1 = 0 (projection of the terminal jump, if any)."""
    if not np.any(w1):
        return np.zeros(model.n)
    G = np.asarray(model.volume_gradient(jnp.asarray(y0)))
    a, b = model.mass_lu.solve(w1), model.mass_lu.solve(G)
    return a - b * (G @ a) / (G @ b)


def _hamiltonian(model, sol, f, zeta0, zeta1, k, alpha, force, vol_grad) -> float:
    y0, y1, xi = sol.y0[k], sol.y1[k], sol.xi[k]
    rhs = (model.control.load @ xi + f[k] - model.damping * (model.laplace @ y1)
           - np.asarray(force(jnp.asarray(y0))) - sol.pressure[k] * np.asarray(vol_grad(jnp.asarray(y0))))
    c = -0.5 * alpha * xi @ (model.control.mass @ xi)
    return float(c + zeta0 @ y1 + zeta1 @ rhs)

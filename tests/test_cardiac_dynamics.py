"""The cardiac elastodynamics terms of the step (`hyperoc.dynamics.terms`), the constraint family
(`hyperoc.dynamics.constraint`) and the time laws (`hyperoc.dynamics.laws`).

- Energy balance: with Robin springs and dashpots, viscosity, kappa damping, a follower pressure and an
  active tension that vary in time, ``KE + Pi + E_springs`` at T minus at 0, plus the dissipated energy,
  minus the work of the loads, is the error of the theta = 1/2 scheme (second order) and of the trapezoid
  rule on the rates (second order): it must fall like dt^2 (observed rate within 0.15 of 2 at the finest
  pair, where the higher-order terms have decayed).
- The viscous tangent in closed form is the autodiff derivative of the viscous force, to round-off.
- A free body under a uniform body force translates rigidly, ``u = g t^2 / 2`` (the scheme integrates a
  quadratic exactly), with or without the volume constraint (the multiplier is then 0): to Newton's
  tolerance. Under a follower pressure the constrained body keeps its volume, the unconstrained one does not.
- Exact gradients with the terms present: Taylor rates 2.00 +- 0.05 in xi, tau and jointly; with the
  follower pressure on an open surface the adjoint must transpose the blocks (the Taylor rate drops to
  about 1 without).
- Time laws: the ODE law against an independent integration to 1e-6 relative, its t-derivative against
  the ODE's right-hand side; a table out of order is an `InputError`.
"""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from hyperoc import (
    BodyForce,
    ControlPoint,
    NeoHookean,
    Objective,
    PressureAt,
    ReducedFunctional,
    Region,
    StateModel,
    TimeTransform,
    taylor_test,
)
from hyperoc.control.adjoint import Adjoint
from hyperoc.control.objectives import AtTau
from hyperoc.control.verification import random_directions
from hyperoc.dynamics.laws import BESTEL_PRESSURE, ExpressionLaw, Table, bestel_activation, bestel_pressure
from hyperoc.dynamics.stepper import Scheme, TimeStepper
from hyperoc.dynamics.terms import DynamicPressure, PrescribedTension, RobinBoundary, Viscosity
from hyperoc.dynamics.timegrid import uniform_grid
from hyperoc.errors import InputError
from hyperoc.fem.mesh import box, rectangle


def turning(x):
    """Fibres turning in the (x, y) plane, a frame (f, s, n) per point."""
    a = x[..., 0] + 2.0 * x[..., 1]
    f = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)
    s = np.broadcast_to([0.0, 0.0, 1.0], f.shape)
    return np.stack([f, s, np.cross(f, s)], axis=-2)


def turning_2d(x):
    a = x[..., 0] + 2.0 * x[..., 1]
    f = np.stack([np.cos(a), np.sin(a)], axis=-1)
    return np.stack([f, np.stack([-f[..., 1], f[..., 0]], axis=-1)], axis=-2)


# --- Robin boundary matrix -----------------------------------------------------------------------------

@pytest.mark.parametrize("degree", [1, 2])
def test_robin_energy_of_rigid_translations(degree):
    """A unit translation a on a face of area |Gamma| stores k/2 |Gamma| |a|^2 ("full") or k/2 |Gamma| (a.N)^2
    ("normal"): exact integrals of N_a N_b on flat facets."""
    model = StateModel(box(2, 2, 2, size=(1.0, 0.7, 0.5)), NeoHookean(1.0, 1.0), degree=degree, dirichlet=None)
    area, k = 1.0 * 0.5, 3.0  # the top face y = 0.7
    for direction in ("full", "normal"):
        robin = RobinBoundary(model, "top", k, 0.0, direction)
        for a, along_normal in (([0.0, 1.0, 0.0], 1.0), ([0.6, 0.0, 0.8], 0.0)):
            u = jnp.asarray(model.interpolate(lambda x: np.tile(a, (len(x), 1))))
            expected = 0.5 * k * area * (1.0 if direction == "full" else along_normal)
            assert abs(float(robin.stored_energy(u)) - expected) < 1e-14, (direction, a)


# --- viscous tangent -----------------------------------------------------------------------------------

@pytest.mark.parametrize("dim, degree", [(2, 1), (2, 2), (3, 1), (3, 2)])
def test_viscous_tangent_in_closed_form_is_the_derivative_of_the_viscous_force(dim, degree):
    """`Viscosity`'s element tangent ``a dA/du + b dA/dv`` in closed form equals ``jax.jacfwd`` of its element
    force at a generic state (no symmetry: random displacements and velocities), for the step's weights and each
    part alone: the same derivative, summed in another order, so equal to round-off (1e-14 of the largest
    entry, about 50 eps)."""
    mesh = rectangle(2, 2, size=(1.0, 0.7)) if dim == 2 else box(2, 1, 1, size=(1.0, 0.7, 0.5))
    model = StateModel(mesh, NeoHookean(1.0, 1.0), degree=degree, dirichlet=None)
    viscosity = Viscosity(model, 0.05)
    rng = np.random.default_rng(2)
    cells = viscosity._cells(0.1 * rng.standard_normal(model.n), rng.standard_normal(model.n))
    for a, b in ((0.3, 1.0), (1.0, 0.0), (0.0, 1.0)):
        def by_autodiff(*xs):
            du, dv = jax.jacfwd(viscosity._element_force, argnums=(0, 1))(*xs)
            return a * du + b * dv

        expected = jax.vmap(by_autodiff)(*cells)
        closed = jax.vmap(lambda *xs: viscosity._element_tangent(*xs, a, b))(*cells)
        scale = float(jnp.max(jnp.abs(expected)))
        assert scale > 0
        np.testing.assert_allclose(closed, expected, rtol=0, atol=1e-14 * scale)


# --- energy balance -----------------------------------------------------------------------------------

def _energy_problem():
    model = StateModel(box(2, 1, 1, size=(1.0, 0.7, 0.5)), NeoHookean(1.0, 1.0), damping=0.01, frames=turning,
                       dirichlet=None)
    robin = (RobinBoundary(model, "left", 5.0, 0.5, "full"), RobinBoundary(model, "right", 3.0, 0.2, "normal"))
    pressure = DynamicPressure(model, "top", ExpressionLaw("0.2*sin(3*t)"))
    tension = PrescribedTension(model, ExpressionLaw("0.1*t"))
    viscosity = Viscosity(model, 0.05)
    return model, robin, pressure, tension, viscosity


def _balance_error(dt, T=1.0):
    model, robin, pressure, tension, viscosity = _energy_problem()
    st = TimeStepper(model, Scheme(theta=0.5), "lu", terms=(*robin, pressure, tension, viscosity), constraint="none")
    v0 = model.interpolate(lambda x: np.stack([0.3 * x[:, 1], -0.2 * x[:, 0], 0.1 * x[:, 0] * x[:, 1]], axis=1))
    grid = uniform_grid(T, dt)
    sol = st.run(grid, v0=v0, diagnose=False)

    @jax.jit
    def rates(y0, y1, t):
        load = pressure.power(y0, y1, t) - tension.force(y0, y1, t) @ y1
        dissipated = (model.damping * y1 @ (st._K @ y1) + sum(r.dissipation_rate(y1) for r in robin)
                      + viscosity.dissipation_rate(y0, y1))
        return load, dissipated

    @jax.jit
    def stored(y0, y1):
        return 0.5 * y1 @ (st.mass @ y1) + model.strain_energy(y0) + sum(r.stored_energy(y0) for r in robin)

    P = np.array([rates(jnp.asarray(a), jnp.asarray(b), t) for a, b, t in zip(sol.y0, sol.y1, sol.t)])
    work, dissipated = (np.sum(0.5 * grid.dt * (c[:-1] + c[1:])) for c in P.T)
    E = [float(stored(jnp.asarray(sol.y0[k]), jnp.asarray(sol.y1[k]))) for k in (0, -1)]
    return E[1] - E[0] + dissipated - work, work, dissipated


@pytest.mark.slow
def test_energy_balance_is_second_order():
    """The observed rates approach 2 from above as dt falls (3.5, 2.9, 2.3, 2.1 from dt = 0.1 to 0.00625:
    the higher-order terms of the scheme and of the trapezoid rule dominate at the larger steps), so the
    test compares the two finest steps."""
    errors = []
    for dt in (0.0125, 0.00625):
        err, work, dissipated = _balance_error(dt)
        errors.append(abs(err))
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    print(f"\nbalance errors {errors}, rates {rates}, work {work:.4g}, dissipated {dissipated:.4g}")
    assert dissipated > 1e-3 and abs(work) > 1e-3  # every term takes part
    assert abs(rates[-1] - 2.0) < 0.15, (errors, rates)


# --- the constraint family -----------------------------------------------------------------------------

@pytest.mark.parametrize("constraint", ["tissue_volume", "none"])
def test_free_body_translates_rigidly(constraint):
    model = StateModel(box(2, 1, 1), NeoHookean(1.0, 1.0), dirichlet=None, pin_rigid=False, density=2.0)
    g = np.array([0.3, -0.1, 0.2])
    f = model.load_vector(body_force=g)
    grid = uniform_grid(0.5, 0.05)
    sol = TimeStepper(model, Scheme(), "dense", constraint=constraint).run(grid, external=lambda t: f,
                                                                           diagnose=False)
    exact = 0.5 * (g / model.density)[None, None, :] * grid.t[:, None, None] ** 2
    u = sol.displacement()
    np.testing.assert_allclose(u, np.broadcast_to(exact, u.shape), rtol=0, atol=1e-10)
    assert np.max(np.abs(sol.pressure)) < 1e-9


def test_constraint_none_lets_the_volume_change():
    model = StateModel(box(2, 1, 1), NeoHookean(1.0, 5.0), damping=0.1)
    terms = (DynamicPressure(model, "right", ExpressionLaw("0.5*t")),)
    grid = uniform_grid(0.5, 0.05)
    drift = {}
    for kind in ("tissue_volume", "none"):
        sol = TimeStepper(model, Scheme(), "dense", terms=terms, constraint=kind).run(grid, diagnose=False)
        drift[kind] = sol.volume_drift()
        if kind == "none":
            assert np.all(sol.pressure == 0.0)
    assert drift["tissue_volume"] < 1e-10 < 1e-4 < drift["none"]


def test_theta_multiplier_needs_a_multiplier():
    model = StateModel(box(1, 1, 1), NeoHookean(1.0, 1.0))
    with pytest.raises(InputError, match="multiplier"):
        TimeStepper(model, Scheme(multiplier="theta"), "dense", constraint="none")
    with pytest.raises(InputError, match="constraint must be one of"):
        TimeStepper(model, Scheme(), "dense", constraint="cavity")


# --- exact gradients -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class DisplacementAt(AtTau):
    """``c . y0(tau)``: a state functional at tau (the objective of the unconstrained test)."""

    weights: tuple

    def value(self, traj):
        return jnp.asarray(self.weights) @ traj.y0[traj.tau_index]


def _gradient_problem(constraint="tissue_volume", viscous=True, transpose=True):
    model = StateModel(rectangle(3, 2, size=(1.0, 0.6)), NeoHookean(1.0, 2.0), damping=0.05, frames=turning_2d,
                       control=BodyForce(Region("box", lower=(0.5, 0.0), upper=(1.0, 0.6))))
    pressure = DynamicPressure(model, "top", ExpressionLaw("0.3*sin(2*t) + 0.1*t"))
    if not transpose:
        pressure.symmetric = True  # the adjoint then solves with the untransposed blocks
    terms = [RobinBoundary(model, "right", 2.0, 0.3, "normal"), RobinBoundary(model, "bottom", 1.0, 0.2, "full"),
             pressure, PrescribedTension(model, bestel_activation(1.0, {"sigma_0": 0.4, "gamma": 0.05}))]
    if viscous:
        terms.append(Viscosity(model, 0.02))
    stepper = TimeStepper(model, Scheme(), "dense", terms=terms, constraint=constraint)
    at_tau = PressureAt() if constraint == "tissue_volume" else DisplacementAt(
        tuple(np.random.default_rng(0).standard_normal(model.n)))
    return ReducedFunctional(model, TimeTransform.for_step(1.0, 0.05, 0.5), Objective(at_tau=at_tau),
                             adjoint=Adjoint(stepper))


def _point(J, tau, amplitude, seed=3):
    base = random_directions(J, J.zero(tau), seed=seed)["xi"].xi
    return ControlPoint(amplitude * base, tau)


@pytest.mark.parametrize("constraint", ["tissue_volume", "none"])
def test_taylor_with_cardiac_terms(constraint):
    J = _gradient_problem(constraint)
    m = _point(J, 0.5, 0.5)
    for name, dm in random_directions(J, m, seed=5).items():
        r = taylor_test(J, m, dm)
        print(name, r.as_dict())
        assert r.remainder.size >= 3, (name, r.as_dict())
        assert abs(r.rate - 2.0) <= 0.05, (name, r.as_dict())


def test_open_surface_pressure_needs_the_transpose():
    """Without the transposed blocks the gradient is wrong: the Taylor rate falls to about 1."""
    J = _gradient_problem(viscous=False, transpose=False)
    m = _point(J, 0.5, 0.5)
    dm = random_directions(J, m, seed=5)["xi"]
    J0, d = J.value_and_derivative(m)
    slope = float(np.sum(d.xi * dm.xi))
    hs = 1e-2 / 2.0 ** np.arange(4)
    r = np.array([abs(J(m + dm * h) - J0 - h * slope) for h in hs])
    rates = np.log2(r[:-1] / r[1:])
    assert np.all(np.abs(rates - 1.0) < 0.2), rates


# --- time laws -------------------------------------------------------------------------------------------

def test_ode_law_matches_an_independent_integration():
    law = bestel_pressure(1.0)
    p = BESTEL_PRESSURE

    def rhs(t, q):
        s = lambda x, sign: 0.5 * (1 + sign * np.tanh(x / p["gamma"]))
        g_pre = s(t - p["t_dias_pre"], -1)
        f_pre = s(t - p["t_sys_pre"], 1) * g_pre
        b = p["a_max"] * f_pre + p["a_min"] * (1 - f_pre) + p["alpha_pre"] * g_pre + p["alpha_mid"]
        return -abs(b) * q + p["sigma_mid"] * max(b, 0.0) + p["sigma_pre"] * max(g_pre, 0.0)

    t = np.linspace(0.0, 1.0, 997)[1:-1]  # off the law's nodes
    ref = solve_ivp(rhs, (0.0, 1.0), [0.0], method="DOP853", rtol=1e-12, atol=1e-9, t_eval=t, max_step=1e-3)
    scale = np.max(np.abs(ref.y[0]))
    assert scale > 1e4  # kPa-scale pressure in Pa
    np.testing.assert_allclose(law.values(t), ref.y[0], rtol=0, atol=1e-6 * scale)
    # the derivative of the C^1 Hermite interpolant is the ODE's right-hand side to the same accuracy / h
    slopes = np.array([rhs(s, q) for s, q in zip(t, ref.y[0])])
    np.testing.assert_allclose(law.rate(t), slopes, rtol=0, atol=1e-3 * np.max(np.abs(slopes)))


def test_table_and_expression_laws():
    law = Table([0.0, 0.1, 0.3], [0.0, 2.0, 1.0])
    np.testing.assert_allclose(law.values([0.05, 0.2, 1.0]), [1.0, 1.5, 1.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(law.rate([0.05, 0.2]), [20.0, -5.0], rtol=1e-12)
    with pytest.raises(InputError, match="strictly increasing"):
        Table([0.0, 0.2, 0.1], [0.0, 1.0, 2.0])
    expr = ExpressionLaw("3*t**2 + sin(t)")
    np.testing.assert_allclose(expr.rate([0.5]), [3.0 + np.cos(0.5)], rtol=1e-14)

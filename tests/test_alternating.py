"""No alternating (period 2 dt) mode in the pressure with the step multiplier.

The paper's 1D case (SVK mu = lam = 0.05, damping kappa = 2e-4, h = 0.01, dt = 0.02, body force on
[0.75, 1]). The spatial profile of the control is ``b(x) = sin(pi (x - 0.75) / 0.5)^2``, with
``b(1) = 1``: a load at x = 1 is felt at once by the reaction p (an optimizer puts load there).

Exact discrete structure in 1D (used below): ``vol = 1 + u(1)`` so ``G = e_N`` is constant and
``G^T y1 = 0`` at every level. Multiplying the momentum line of a theta = 1/2 step by
``G^T M^-1`` eliminates the state increment and leaves, for the multiplier combination ``q`` of the
step (``q = p_{n+1/2}`` for "step", ``q = (p_n + p_{n+1}) / 2`` for "theta"),

    q = (phat_n + phat_{n+1}) / 2,   phat_n = G^T M^-1 (L(xi_n) - kappa K y1_n - R(y0_n)) / (G^T M^-1 G),

``phat_n`` being the consistent pressure of level n (reaction to the level state and the level
load). The state is the same for both weightings. Hence

- "step": the level pressure ``(p_{n-1/2} + p_{n+1/2}) / 2 = (phat_{n-1} + 2 phat_n + phat_{n+1}) / 4``,
  a filter that annihilates ``(-1)^n``: no alternating mode, whatever the control does;
- "theta": ``p_{n+1} - phat_{n+1} = -(p_n - phat_n)``: an undamped alternating mode of amplitude
  ``|p_0 - phat_0|``. With the consistent ``p_0`` (what hyperoc computes) it is not excited in 1D,
  but ``p_n = phat_n`` follows the level value of the control instantly: a control that flips sign
  every step makes the reported p(t) flip by the full reaction to the control, an artefact an
  objective ``p(tau)`` can exploit; and any inconsistency in ``p_0`` (the paper's / GetFEM's start
  ``p_0 = 0``) rings undamped for ever.

Measure of the alternating component: ``a_n = (p_{n+1} - 2 p_n + p_{n-1}) / 4`` (equal to the
amplitude c for ``p = c (-1)^n``). For a smooth p, ``a_n = dt^2 p''(t_n) / 4 + O(dt^4)``; the
same stencil on 2 dt, ``b_n = (p_{n+2} - 2 p_n + p_{n-2}) / 4 = dt^2 p'' + O(dt^4)``, is blind to
``(-1)^n``. So a smooth p has ``max|a| ~ max|b| / 4``, and an alternating mode adds to a only.
"""

from functools import lru_cache

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as spla

from hyperoc.dynamics.stepper import Scheme, TimeStepper
from hyperoc.dynamics.timegrid import uniform_grid
from hyperoc.fem.mesh import interval
from hyperoc.mechanics.controls import BodyForce, Region
from hyperoc.mechanics.materials import SaintVenantKirchhoff
from hyperoc.mechanics.model import StateModel

# Every test shares a 300-step run of the paper's bar at h = 0.01: the slow tier.
pytestmark = pytest.mark.slow

T, DT, A = 6.0, 0.02, 0.05
GRID = uniform_grid(T, DT)
N = GRID.num_steps
LAST_THIRD = slice(2 * N // 3, N + 1)
CONTROL_PHASE = slice(0, N // 3)  # levels where the control acts

# Smoothness bound for the free-vibration phase: the waves of the bar (c = sqrt(lam + 2 mu) = 0.39,
# length 1, control width 0.5) vary on periods >~ 1 s; allowing periods down to 0.5 s,
# |p''| <= (4 pi)^2 max|p| and |a| <= dt^2 |p''| / 4 <= 0.016 max|p| (measured: 1e-3).
SMOOTH_REL = (4 * np.pi * DT) ** 2 / 4

# Discrete identities hold up to the Newton tolerance (rtol 1e-11 on the increments) and round-off:
# per step, STEP_TOL of max|p| (measured 1.2e-11). In the "theta" weighting (and in y1, which CN
# also advances by y1' = 2 (y0' - y0) / dt - y1) these per-step errors feed an undamped
# alternating mode and add up over the N steps: N * STEP_TOL (measured 1.4e-8 after 300 steps).
STEP_TOL = 1e-9
ACCUMULATED_TOL = N * STEP_TOL


def second_difference(p, stride=1):
    """``(p_{n+s} - 2 p_n + p_{n-s}) / 4`` at the levels n = s .. N - s (padded with NaN to N + 1)."""
    out = np.full(p.shape, np.nan)
    out[stride:-stride] = (p[2 * stride :] - 2 * p[stride:-stride] + p[: -2 * stride]) / 4
    return out


@lru_cache(maxsize=None)
def model():
    return StateModel(interval(100), SaintVenantKirchhoff(mu=0.05, lam=0.05), degree=1, damping=2e-4,
                      control=BodyForce(Region("box", lower=(0.75,), upper=(1.0,))))


def profile():
    m = model()
    x = m.control.coordinates(m.space)[:, 0]
    return np.sin(np.pi * (x - 0.75) / 0.5) ** 2


def flipping_control():
    """``A ((-1)^n + sin(3 pi t / T)^2) b(x)`` on [0, T/3), then 0: a smooth drive (so that p is not
    trivial after the control stops) plus a part that flips sign every step."""
    n = np.arange(N + 1)
    env = np.where(GRID.t < T / 3 - 1e-12, (-1.0) ** n + np.sin(3 * np.pi * GRID.t / T) ** 2, 0.0)
    return A * env[:, None] * profile()[None, :]


@lru_cache(maxsize=None)
def stepper(multiplier):
    return TimeStepper(model(), Scheme(theta=0.5, multiplier=multiplier))


@lru_cache(maxsize=None)
def flipping_run(multiplier):
    return stepper(multiplier).run(GRID, flipping_control())


def consistent_pressure(sol, xi):
    """phat_n at every level, from the level state (independent of the stepper's code)."""
    m = model()
    lu = spla.splu(m.mass.tocsc())
    G = np.zeros(m.n)
    G[-1] = 1.0  # 1D: dvol/du = e_N (the dof at x = 1)
    np.testing.assert_allclose(np.asarray(m.jitted["volume_gradient"](jnp.asarray(sol.y0[-1]))), G, atol=1e-14)
    MinvG = lu.solve(G)
    R = np.array([np.asarray(m.jitted["internal_force"](jnp.asarray(y))) for y in sol.y0])
    rhs = (m.control.load @ xi.T).T - m.damping * (m.laplace @ sol.y1.T).T - R
    return (lu.solve(rhs.T).T @ G) / (G @ MinvG)


def reaction_to_profile():
    """Instantaneous reaction of p to the load ``A b`` on the body at rest: phat for u = v = 0."""
    m = model()
    lu = spla.splu(m.mass.tocsc())
    G = np.zeros(m.n)
    G[-1] = 1.0
    return float(lu.solve(m.control.load @ (A * profile())) @ G / (lu.solve(G) @ G))


# ---- the default: multiplier = "step" -------------------------------------------------------------


def test_step_multiplier_pressure_has_no_alternating_mode_after_flipping_control():
    sol = flipping_run("step")
    p = sol.pressure
    a, b = second_difference(p), second_difference(p, 2)
    p_max = np.max(np.abs(p[LAST_THIRD]))
    assert p_max > 0.2 * np.max(np.abs(p))  # free vibration with a real pressure signal
    a_max, b_max = np.nanmax(np.abs(a[LAST_THIRD])), np.nanmax(np.abs(b[LAST_THIRD]))
    assert a_max <= SMOOTH_REL * p_max, f"alternating component {a_max / p_max:.3g} of max|p|"
    assert a_max <= 0.5 * b_max  # smooth: a ~ b / 4 (measured 0.25); an alternating mode adds to a only
    # the flipping control really acted: the theta weighting below shows it in p
    assert np.nanmax(np.abs(second_difference(flipping_run("theta").pressure)[CONTROL_PHASE])) > 10 * a_max


def test_step_level_pressure_is_the_alternation_free_filter_of_the_consistent_pressure():
    """1D identity: p_level_n = (phat_{n-1} + 2 phat_n + phat_{n+1}) / 4 at interior levels."""
    sol = flipping_run("step")
    phat = consistent_pressure(sol, flipping_control())
    np.testing.assert_allclose(sol.p_steps, 0.5 * (phat[1:] + phat[:-1]), rtol=0, atol=STEP_TOL * np.abs(phat).max())
    filtered = (phat[:-2] + 2 * phat[1:-1] + phat[2:]) / 4
    np.testing.assert_allclose(sol.pressure[1:-1], filtered, rtol=0, atol=STEP_TOL * np.abs(phat).max())
    # phat itself flips with the control during the control phase (the reaction to the level load):
    # the filter is what removes it from the reported pressure.
    assert np.nanmax(np.abs(second_difference(phat)[CONTROL_PHASE])) > 0.5 * abs(reaction_to_profile())


# ---- the comparison variant: multiplier = "theta" -------------------------------------------------


def test_theta_multiplier_pressure_follows_the_flipping_control():
    """Same states as "step" (1D: only p_n + p_{n+1} enters), p_n = phat_n: the reported pressure flips
    by the full reaction to the control every step while the control flips (why it is not the default)."""
    sol_t, sol_s = flipping_run("theta"), flipping_run("step")
    np.testing.assert_allclose(sol_t.y0, sol_s.y0, rtol=0, atol=1e-12 * np.abs(sol_s.y0).max())
    pt = sol_t.p_steps  # level values p_0 .. p_N
    np.testing.assert_allclose(pt[:-1] + pt[1:], 2 * sol_s.p_steps, rtol=0, atol=STEP_TOL * np.abs(pt).max())
    react = abs(reaction_to_profile())
    a = second_difference(sol_t.pressure)
    assert np.nanmax(np.abs(a[CONTROL_PHASE])) > 0.9 * react
    # ... ten times what the step weighting shows over the same levels
    assert react > 10 * np.nanmax(np.abs(second_difference(sol_s.pressure)[CONTROL_PHASE]))
    # with the consistent p_0 the mode is not excited in 1D: smooth again once the control stops
    p_max = np.max(np.abs(sol_t.pressure[LAST_THIRD]))
    assert np.nanmax(np.abs(a[LAST_THIRD])) <= SMOOTH_REL * p_max


def test_theta_multiplier_alternating_mode_persists_undamped_from_an_inconsistent_start():
    """The paper's start p_0 = 0 (instead of the consistent phat_0): |p_n - phat_n| = |phat_0| for all n."""
    st = stepper("theta")  # same compiled time loop: p_0 is one of its inputs
    st.initial_pressure = lambda *args: 0.0  # inconsistent initial multiplier, as in the paper's code
    xi = flipping_control()
    try:
        sol = st.run(GRID, xi)
    finally:
        del st.initial_pressure  # back to the method
    phat = consistent_pressure(sol, xi)
    p0 = phat[0]
    assert abs(p0) == pytest.approx(abs(reaction_to_profile()), rel=1e-12)
    err = sol.pressure - phat
    np.testing.assert_allclose(err, -p0 * (-1.0) ** np.arange(N + 1), rtol=0, atol=ACCUMULATED_TOL * np.abs(phat).max())
    # in the measure of the brief: large over the last third, long after the control stopped
    p = sol.pressure
    a, b = second_difference(p), second_difference(p, 2)
    p_max = np.max(np.abs(p[LAST_THIRD]))
    a_max = np.nanmax(np.abs(a[LAST_THIRD]))
    assert a_max > 2 * SMOOTH_REL * p_max and a_max > 5 * np.nanmax(np.abs(b[LAST_THIRD]))
    assert np.nanmin(np.abs(a[LAST_THIRD])) > 0.9 * abs(p0)  # undamped: present at every level


def test_theta_multiplier_starts_from_the_consistent_pressure_without_oscillation():
    """Smooth control, nonzero at t = 0, and nonzero initial displacement and velocity."""
    m = model()
    u0 = m.interpolate(lambda x: 0.01 * np.sin(np.pi * x) ** 2)  # u0(1) = 0, v0(1) = 0: G^T v0 = 0
    v0 = m.interpolate(lambda x: 0.01 * np.sin(np.pi * x) ** 2)
    xi = A * np.cos(np.pi * GRID.t / T)[:, None] ** 2 * profile()[None, :]
    sol = stepper("theta").run(GRID, xi, u0=u0, v0=v0)
    # p(0) from the consistent initial acceleration, computed here independently
    lu = spla.splu(m.mass.tocsc())
    R0 = np.asarray(m.jitted["internal_force"](jnp.asarray(u0)))
    e = np.zeros(m.n)
    e[-1] = 1.0
    p0 = lu.solve(m.control.load @ xi[0] - m.damping * (m.laplace @ v0) - R0)[-1] / lu.solve(e)[-1]
    assert abs(p0) > 1e-4
    assert sol.pressure[0] == pytest.approx(p0, rel=1e-12)
    # no oscillation from the start: p_n is the consistent value at every level (1D identity), so
    # p is as smooth as the state
    phat = consistent_pressure(sol, xi)
    np.testing.assert_allclose(sol.pressure, phat, rtol=0, atol=ACCUMULATED_TOL * np.abs(phat).max())
    a, b = second_difference(sol.pressure), second_difference(sol.pressure, 2)
    assert np.nanmax(np.abs(a[2:])) <= 0.5 * np.nanmax(np.abs(b))
    assert np.nanmax(np.abs(a)) <= SMOOTH_REL * np.max(np.abs(sol.pressure))

"""Time order of the theta-scheme, by self-convergence in dt.

Smooth control ``xi(x, t) = A sin(pi t / T)^2 b(x)`` with a smooth spatial bump b, so that the exact
solution of the semi-discrete (space-discretized) system is smooth in time. For a method of order
q, the successive differences of three halvings ``dt, dt/2, dt/4`` satisfy
``|y_dt - y_dt/2| / |y_dt/2 - y_dt/4| = 2^q + O(dt)``, so the observed rate
``log2(...)`` must tend to q: 2 for theta = 1/2 (Crank-Nicolson, and the step multiplier at the
mid-step), 1 for theta = 1 (implicit Euler). The grids are chosen in the asymptotic range (checked
once with one more halving: the rates move by less than 0.03 between consecutive triples), so the
tolerance 0.1 on the rate is the O(dt) drift of the estimator, not slack.

Measured quantities: the displacement at t = T (L2 norm through the mass matrix, the space is
fixed) and the level pressure p(t_k) at the times ``t_k = k T / 8`` (levels on every grid), max
over k. The non-uniform grid of the time transformation (`TimeTransform.grid(tau)`, different step
sizes on both sides of tau) must keep order 2 for p(tau), which needs the weighted interpolation
of the two adjacent step multipliers (the plain mean is only first order there, checked too).

Compilation dominates the cost (one compiled ``lax.scan`` per stepper and number of steps), so all
grids of a study are padded to the same number of steps: the levels beyond T only extend the run
(zero control there) and are not used.
"""

from functools import lru_cache

import numpy as np
import pytest

from hyperoc.dynamics.stepper import Scheme, TimeStepper
from hyperoc.dynamics.timegrid import TimeGrid, TimeTransform
from hyperoc.fem.geometry import annulus
from hyperoc.fem.mesh import interval
from hyperoc.mechanics.controls import ActiveStress, BodyForce, Region
from hyperoc.mechanics.materials import SaintVenantKirchhoff
from hyperoc.mechanics.model import StateModel

# Step sequences chosen to reach the asymptotic range: the slow tier.
pytestmark = pytest.mark.slow

# Order tolerance: the rate estimator carries an O(dt) bias; on the grids used it is below 0.05.
RATE_TOL = 0.1


def observed_rates(values, norm):
    """log2 of the ratios of successive differences of a sequence of approximations."""
    d = np.array([norm(values[i] - values[i + 1]) for i in range(len(values) - 1)])
    assert np.all(d > 0)
    return np.log2(d[:-1] / d[1:])


def padded_levels(t, num_steps):
    """Extend the levels ``t`` with steps of the last size up to ``num_steps`` steps."""
    extra = num_steps - (t.size - 1)
    assert extra >= 0
    return np.concatenate([t, t[-1] + (t[-1] - t[-2]) * np.arange(1, extra + 1)])


# ---- 1D: the paper's bar, SVK mu = lam = 0.05, damping kappa = 1e-2 (smooth), body force on [0.75, 1] ----
T1 = 4.0
A1 = 0.05  # min det F ~ 0.96: genuinely nonlinear, no fronts


@lru_cache(maxsize=None)
def model_1d():
    return StateModel(interval(100), SaintVenantKirchhoff(mu=0.05, lam=0.05), degree=1, damping=1e-2,
                      control=BodyForce(Region("box", lower=(0.75,), upper=(1.0,))))


@lru_cache(maxsize=None)
def stepper_1d(theta):
    return TimeStepper(model_1d(), Scheme(theta=theta))


def control_1d(t):
    m = model_1d()
    x = m.control.coordinates(m.space)[:, 0]
    bump = np.sin(np.pi * (x - 0.75) / 0.25) ** 2
    return A1 * np.sin(np.pi * np.minimum(t, T1) / T1)[:, None] ** 2 * bump[None, :]


def run_1d(theta, t, num_steps):
    t = padded_levels(np.asarray(t, dtype=np.float64), num_steps)
    return stepper_1d(theta).run(TimeGrid(t), control_1d(t))


# theta = 1/2: three halvings from dt = T/40; theta = 1: from T/320 (implicit Euler reaches its
# asymptotic range later: its O(dt^2) term is large, the rate is 0.90 at T/80..T/320).
STEPS_1D = {0.5: (40, 80, 160), 1.0: (320, 640, 1280)}
PAD_1D = {0.5: 320, 1.0: 1280}  # theta = 1/2 shares the compiled scan with the transformed grids


@lru_cache(maxsize=None)
def uniform_runs_1d(theta):
    return [(n, run_1d(theta, np.linspace(0.0, T1, n + 1), PAD_1D[theta])) for n in STEPS_1D[theta]]


# ---- 2D: structured annulus (P1), active stress along circumferential fibres ------------------
T2 = 2.0
A2 = 0.01


@lru_cache(maxsize=None)
def model_2d():
    mesh = annulus(0.5, 1.0, structured=True, n_radial=2, n_theta=16)
    return StateModel(mesh, SaintVenantKirchhoff(mu=0.05, lam=0.05), degree=1, damping=1e-2,
                      control=ActiveStress(Region()))


def control_2d(t):
    m = model_2d()
    x = m.control.coordinates(m.space)
    r, ang = np.hypot(x[:, 0], x[:, 1]), np.arctan2(x[:, 1], x[:, 0])
    bump = np.cos(ang / 2) ** 2 * np.sin(np.pi * (r - 0.5) / 0.5) ** 2  # smooth, not axisymmetric
    return A2 * np.sin(np.pi * np.minimum(t, T2) / T2)[:, None] ** 2 * bump[None, :]


STEPS_2D = {0.5: (40, 80, 160), 1.0: (160, 320, 640)}


@lru_cache(maxsize=None)
def uniform_runs_2d(theta):
    stepper = TimeStepper(model_2d(), Scheme(theta=theta))
    nmax = max(STEPS_2D[theta])
    out = []
    for n in STEPS_2D[theta]:
        t = padded_levels(np.linspace(0.0, T2, n + 1), nmax)
        out.append((n, stepper.run(TimeGrid(t), control_2d(t))))
    return out


CASES = {"1d": (uniform_runs_1d, model_1d, T1), "2d": (uniform_runs_2d, model_2d, T2)}


def mass_norm(model):
    M = model.mass
    return lambda e: float(np.sqrt(e @ (M @ e)))


@pytest.mark.parametrize("case", ["1d", "2d"])
@pytest.mark.parametrize("theta, order", [(0.5, 2.0), (1.0, 1.0)])
def test_displacement_at_final_time_converges_at_the_scheme_order(case, theta, order):
    runs, model, T = CASES[case]
    sols = runs(theta)
    for n, s in sols:
        assert s.t[n] == pytest.approx(T, rel=1e-14)
        assert s.volume_drift() < 1e-12  # the constraint holds at every level (Newton tolerance)
    uT = [s.y0[n] for n, s in sols]
    rate = observed_rates(uT, mass_norm(model()))[-1]
    assert abs(rate - order) <= RATE_TOL, f"{case}, theta = {theta}: observed order {rate:.3f} for u(T)"


@pytest.mark.parametrize("case", ["1d", "2d"])
@pytest.mark.parametrize("theta, order", [(0.5, 2.0), (1.0, 1.0)])
def test_level_pressure_converges_at_the_scheme_order(case, theta, order):
    runs, _, T = CASES[case]
    sols = runs(theta)
    k = np.arange(1, 9)  # t_k = k T / 8, a level of every grid (n is a multiple of 8)
    pk = []
    for n, s in sols:
        idx = k * n // 8
        np.testing.assert_allclose(s.t[idx], k * T / 8, rtol=1e-13)
        pk.append(s.pressure[idx])
    pk = np.array(pk)
    assert np.max(np.abs(pk[-1])) > 1e-4  # a pressure signal well above the differences measured
    rate = observed_rates(pk, lambda e: np.max(np.abs(e)))[-1]
    assert abs(rate - order) <= RATE_TOL, f"{case}, theta = {theta}: observed order {rate:.3f} for p(t_k)"


def test_transformed_nonuniform_grid_keeps_order_two_for_pressure_at_tau():
    """p(tau) on ``TimeTransform.grid(tau)``: steps tau/N1 before tau, (T - tau)/N3 after (ratio 2.6)."""
    tau, steps = 2.9, (40, 80, 160)
    weighted, naive, dts = [], [], []
    for k in steps:
        grid = TimeTransform(T=T1, steps=(k, 0, k)).grid(tau)
        assert grid.t[k] == tau
        s = run_1d(0.5, grid.t, PAD_1D[0.5])
        dts.append((s.dt[k - 1], s.dt[k]))
        weighted.append(s.pressure[k])
        naive.append(0.5 * (s.p_steps[k - 1] + s.p_steps[k]))  # unweighted mean of the two mid-steps
    dt_before, dt_after = dts[0]
    assert dt_before / dt_after == pytest.approx(2.9 / 1.1)
    rates = observed_rates(np.array(weighted), abs)
    assert abs(rates[-1] - 2.0) <= RATE_TOL, f"level pressure at tau: observed order {rates[-1]:.3f}"
    # The plain mean sits at (t_{k-1/2} + t_{k+1/2}) / 2 != tau: an O(dt_before - dt_after) error,
    # first order. That the weighted value is second order is what the assertion above checks.
    naive_rates = observed_rates(np.array(naive), abs)
    assert naive_rates[-1] < 1.5

"""The control space with controls regular in time: the H^1 Riesz map, optimizer coordinates, the cost
``beta/2 ||d xi/dt||^2`` and its tau-dependence, and the optimizers working in that metric."""

import numpy as np
import pytest

from hyperoc.control.control_space import ControlSpace, s_time_scale
from hyperoc.control.objectives import ControlRateCost, objective_from_config
from hyperoc.control.optimize import barzilai_borwein, lbfgsb
from hyperoc.control.problems import vibrating_bar
from hyperoc.control.reduced import ControlPoint
from hyperoc.control.verification import random_directions, taylor_test
from hyperoc.errors import InputError


@pytest.fixture(scope="module")
def bar():
    """`vibrating_bar` with beta > 0: coarse, and an interior maximizer."""
    return vibrating_bar(0.05, 0.05, beta=1.0)


def _dense_time_operator(space: ControlSpace) -> np.ndarray:
    upper, diag = space.time_bands
    return np.diag(diag) + np.diag(upper[1:], 1) + np.diag(upper[1:], -1)


def test_time_operator_is_the_h1_gram_matrix_of_piecewise_linears():
    """``A_t = W + l^2 K``: for nodal vectors a, b, ``a.A_t b`` is the trapezoid rule of ``a b`` plus
    ``l^2 int a' b'`` (exact for piecewise linears), on a non-uniform grid."""
    ds = np.array([0.1, 0.3, 0.2, 0.4])
    space = ControlSpace(ds, np.eye(1), np.ones(1), time_scale=0.7)
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal(5), rng.standard_normal(5)
    trapezoid = np.sum(ds * (a[:-1] * b[:-1] + a[1:] * b[1:]) / 2)
    stiffness = np.sum(np.diff(a) * np.diff(b) / ds)
    assert a @ _dense_time_operator(space) @ b == pytest.approx(trapezoid + 0.49 * stiffness, rel=1e-14)


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_riesz_map_solves_the_kronecker_system(bar, beta):
    """``riesz(d)`` solves ``(A_t (x) M) g = d`` (checked against a dense solve) and `dual` inverts it."""
    J = bar if beta else vibrating_bar(0.05, 0.05)
    space = J.space
    assert space.regular_in_time == (beta > 0)
    A = np.kron(_dense_time_operator(space), J.model.control.mass.toarray())
    rng = np.random.default_rng(1)
    d = ControlPoint(rng.standard_normal((J.N + 1, J.model.control.size)), 0.3)
    g = J.riesz(d)
    assert np.allclose(g.xi.ravel(), np.linalg.solve(A, d.xi.ravel()), rtol=1e-12, atol=1e-12 * np.abs(g.xi).max())
    assert g.tau == d.tau
    assert np.allclose(J.dual(g).xi, d.xi, rtol=1e-12, atol=1e-12 * np.abs(d.xi).max())
    v = ControlPoint(rng.standard_normal(d.xi.shape), -0.2)
    assert J.inner(g, v) == pytest.approx(np.sum(d.xi * v.xi) + d.tau * v.tau, rel=1e-12)


def test_coordinates_make_the_lumped_metric_euclidean(bar):
    """``z = U xi D^(1/2)``: ``|z|^2 = xi : (A_t xi D)``, `from_coordinates` inverts it, and
    `coordinate_gradient` is the chain rule (``dJ/dxi : dxi = dJ/dz : dz``)."""
    space = bar.space
    rng = np.random.default_rng(2)
    xi = rng.standard_normal((bar.N + 1, bar.model.control.size))
    z = space.to_coordinates(xi)
    lumped = np.kron(_dense_time_operator(space), np.diag(bar.model.control.lumped_mass))
    assert z.ravel() @ z.ravel() == pytest.approx(xi.ravel() @ lumped @ xi.ravel(), rel=1e-12)
    assert np.allclose(space.from_coordinates(z), xi, rtol=1e-12, atol=1e-12)
    d = rng.standard_normal(xi.shape)
    assert np.sum(d * xi) == pytest.approx(np.sum(space.coordinate_gradient(d) * z), rel=1e-12)


def test_time_scale_balances_the_two_costs_at_half_time():
    """At tau = T/2 (mu_dot = T/2), ``alpha T/4 (||xi||_s^2 + l_s^2 ||xi_s||_s^2)`` is the cost:
    l_s = (2/T) sqrt(beta/alpha)."""
    assert s_time_scale(2e-3, 2e-3 * 0.25, 15.0) == pytest.approx(2 / 15 * 0.5)
    assert s_time_scale(2e-3, 0.0, 15.0) == 0.0


def test_rate_cost_is_exact_for_controls_linear_in_time(bar):
    """For ``xi(t, x) = a t`` the cost is ``-beta/2 a^2 T |omega|`` whatever the (non-uniform) t-grid."""
    tau, a = 1.3, 0.7
    t = bar.transform.grid(tau).t
    xi = a * t[:, None] * np.ones((1, bar.model.control.size))
    traj = bar.trajectory(bar.state(ControlPoint(xi, tau)))
    omega = bar.model.control.mass.sum()  # |omega| = 0.25
    assert float(ControlRateCost(1.0).value(traj)) == pytest.approx(-0.5 * a**2 * bar.transform.T * omega, rel=1e-12)


@pytest.mark.parametrize("direction", [pytest.param("xi", marks=pytest.mark.slow),
                                       pytest.param("tau", marks=pytest.mark.slow), "joint"])
def test_taylor_rates_with_the_rate_cost(bar, direction):
    """The exact gradient includes the rate cost's dependence on xi and, through dt_n = mu_dot ds_n, on tau."""
    rng = np.random.default_rng(3)
    m = ControlPoint(0.02 * rng.standard_normal((bar.N + 1, bar.model.control.size)).cumsum(axis=0) / 5, 1.7)
    result = taylor_test(bar, m, random_directions(bar, m)[direction])
    assert abs(result.rates[-1] - 2.0) <= 0.05


def test_objective_config_builds_the_rate_cost():
    objective = objective_from_config({"phi1": "pressure", "alpha": 2e-3, "beta": 1e-3})
    assert objective.control_weights == (2e-3, 1e-3)
    assert objective_from_config({"alpha": 2e-3}).control_weights == (2e-3, 0.0)
    for bad in (-1.0, float("nan"), float("inf"), "1"):
        with pytest.raises(InputError, match="beta"):
            objective_from_config({"beta": bad})


def test_continuous_gradient_refuses_the_rate_cost():
    J = vibrating_bar(0.1, 0.1, beta=1.0)
    from hyperoc.control.continuous_adjoint import ContinuousReducedFunctional

    with pytest.raises(InputError, match="continuous"):
        ContinuousReducedFunctional(J.model, J.transform, J.objective)


@pytest.fixture(scope="module")
def optima(bar):
    """Algorithm 1 and L-BFGS-B on the regularized bar, to the relative H^1 gradient norm 1e-6."""
    runs = {}
    for name, method in (("bb", barzilai_borwein), ("lbfgsb", lbfgsb)):
        J = vibrating_bar(0.05, 0.05, beta=1.0)
        runs[name] = method(J, J.zero(2.0), gtol=1e-6, max_iter=100)
    return runs


@pytest.mark.parametrize("name", ["bb", "lbfgsb"])
def test_optimizers_reach_the_kkt_tolerance_in_the_h1_metric(optima, name):
    res = optima[name]
    assert res.converged and res.iterations <= 100
    g = res.history["grad_norm"]
    assert g[-1] <= 1e-6 * g[0]


def test_both_optimizers_find_the_same_maximizer(optima):
    """A relative H^1 gradient of 1e-6 at a nondegenerate maximizer: J agrees to ~ (1e-6)^2 relative,
    tau to ~1e-6 times its scale."""
    a, b = optima["bb"], optima["lbfgsb"]
    assert a.objective == pytest.approx(b.objective, rel=1e-9)
    assert a.point.tau == pytest.approx(b.point.tau, abs=1e-5)


def test_h1_metric_is_the_hessian_of_the_control_cost_at_half_time(bar):
    """With beta > 0 the xi-part of the metric is ``alpha T/2 (W + l_s^2 K) (x) M``: at tau = T/2 the control
    cost ``alpha/2 ||xi||^2 + beta/2 ||xi_t||^2`` (quadratic in xi) is exactly half the squared norm."""
    T = bar.transform.T
    rng = np.random.default_rng(5)
    v = ControlPoint(rng.standard_normal((bar.N + 1, bar.model.control.size)), 0.0)
    traj = bar.trajectory(bar.state(ControlPoint(v.xi, T / 2)))
    cost = -sum(float(term.value(traj)) for term in bar.objective.running)
    assert cost == pytest.approx(0.5 * bar.inner(v, v), rel=1e-12)

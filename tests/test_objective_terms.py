"""Objective terms for well-posed variants of the paper's problem: the windowed mean pressure, the causal
observation of p(tau) and the local injectivity penalty (values and exact gradients)."""

import numpy as np
import pytest

from hyperoc.control.objectives import (
    ControlCost,
    InjectivityPenalty,
    Objective,
    PressureAt,
    PressureMean,
    objective_from_config,
)
from hyperoc.control.reduced import ControlPoint, ReducedFunctional
from hyperoc.control.verification import random_directions, taylor_test
from hyperoc.dynamics.timegrid import TimeTransform
from hyperoc.fem.mesh import interval
from hyperoc.mechanics.controls import BodyForce, Region
from hyperoc.mechanics.materials import SaintVenantKirchhoff
from hyperoc.mechanics.model import StateModel


def _bar(at_tau, running=()):
    """A short, coarse version of the paper's bar (SVK, omega = [0.75, 1]) with the given terms."""
    model = StateModel(interval(10), SaintVenantKirchhoff(0.05, 0.05), damping=2e-3,
                       control=BodyForce(Region("box", lower=(0.75,), upper=(1.0,))))
    eps = getattr(at_tau, "eps", 0.0)
    transform = TimeTransform.for_step(3.0, 0.1, 1.5, eps)
    return ReducedFunctional(model, transform, Objective(running=(ControlCost(2e-3),) + running, at_tau=at_tau))


@pytest.fixture(scope="module")
def windowed():
    return _bar(PressureMean(0.3))


def _control(J, scale):
    rng = np.random.default_rng(4)
    return scale * rng.standard_normal((J.N + 1, J.model.control.size)).cumsum(axis=0) / np.sqrt(J.N)


def test_pressure_mean_is_the_impulse_over_the_window(windowed):
    """``(1/eps) sum dt_n p_n`` over the steps of [tau, tau + eps] (midpoint rule of the impulse)."""
    m = ControlPoint(_control(windowed, 0.05), 1.2)
    sol = windowed.state(m)
    t = sol.t
    window = (t[:-1] >= 1.2 - 1e-12) & (t[1:] <= 1.5 + 1e-12)
    expected = np.sum(np.diff(t)[window] * sol.p_steps[window]) / 0.3
    assert float(PressureMean(0.3).value(windowed.trajectory(sol))) == pytest.approx(expected, rel=1e-13)
    assert np.count_nonzero(window) == windowed.transform.steps[1]


@pytest.mark.parametrize("direction", [pytest.param("xi", marks=pytest.mark.slow),
                                       pytest.param("tau", marks=pytest.mark.slow), "joint"])
def test_taylor_rates_of_the_windowed_pressure(windowed, direction):
    m = ControlPoint(_control(windowed, 0.05), 1.2)
    assert abs(taylor_test(windowed, m, random_directions(windowed, m)[direction]).rates[-1] - 2.0) <= 0.05


def test_injectivity_penalty_vanishes_above_delta():
    """Under a small load det F stays above 0.6 everywhere: the penalty is exactly zero."""
    J = _bar(PressureMean(0.3), running=(InjectivityPenalty(1e4, 0.6),))
    sol = J.state(ControlPoint(_control(J, 0.01), 1.2))
    assert sol.min_det_F.min() > 0.6
    assert float(InjectivityPenalty(1e4, 0.6).value(J.trajectory(sol))) == 0.0


@pytest.mark.parametrize("direction", [pytest.param("xi", marks=pytest.mark.slow),
                                       pytest.param("tau", marks=pytest.mark.slow), "joint"])
def test_taylor_rates_with_an_active_injectivity_penalty(direction):
    """delta above 1 makes the penalty active wherever the bar is compressed (C^2 there)."""
    J = _bar(PressureMean(0.3), running=(InjectivityPenalty(10.0, 1.05),))
    m = ControlPoint(_control(J, 0.2), 1.2)
    sol = J.state(m)
    assert float(InjectivityPenalty(10.0, 1.05).value(J.trajectory(sol))) < 0
    assert abs(taylor_test(J, m, random_directions(J, m)[direction]).rates[-1] - 2.0) <= 0.05


def test_config_builds_the_windowed_pressure():
    objective = objective_from_config({"phi1": "pressure_mean", "eps": 0.5, "alpha": 2e-3, "beta": 1e-3})
    assert isinstance(objective.at_tau, PressureMean) and objective.eps == 0.5
    assert objective.control_weights == (2e-3, 1e-3)


@pytest.fixture(scope="module")
def causal():
    return _bar(PressureAt("causal"))


@pytest.mark.parametrize("observation", ["centred", "causal"])
def test_only_the_causal_observation_ignores_the_control_after_tau(observation):
    """Changing xi at the levels after tau's leaves the causal p(tau) unchanged to the last bit; the centred
    value, which interpolates the multiplier of the step after tau, moves with it."""
    J = _bar(PressureAt(observation))
    m = ControlPoint(_control(J, 0.05), 1.2)
    k = J.transform.tau_index
    later = m.xi.copy()
    later[k + 1:] += 0.05
    before, after = J(m), J(ControlPoint(later, m.tau))
    cost = ControlCost(2e-3)
    change = (before - after) - (float(cost.value(J.trajectory(J.state(m))))
                                 - float(cost.value(J.trajectory(J.state(ControlPoint(later, m.tau))))))
    if observation == "causal":
        assert change == pytest.approx(0.0, abs=1e-15)
    else:
        assert abs(change) > 1e-6


def test_causal_observation_is_the_extrapolation_of_the_steps_before_tau(causal):
    """p_{k-1/2} + (p_{k-1/2} - p_{k-3/2}) dt_{k-1} / (dt_{k-1} + dt_{k-2}), k the level of tau."""
    m = ControlPoint(_control(causal, 0.05), 1.2)
    sol = causal.state(m)
    k, dt, p = causal.transform.tau_index, np.diff(sol.t), sol.p_steps
    expected = p[k - 1] + (p[k - 1] - p[k - 2]) * dt[k - 1] / (dt[k - 1] + dt[k - 2])
    assert float(PressureAt("causal").value(causal.trajectory(sol))) == pytest.approx(expected, rel=1e-13)


@pytest.mark.parametrize("direction", [pytest.param("xi", marks=pytest.mark.slow),
                                       pytest.param("tau", marks=pytest.mark.slow), "joint"])
def test_taylor_rates_of_the_causal_observation(causal, direction):
    m = ControlPoint(_control(causal, 0.05), 1.2)
    assert abs(taylor_test(causal, m, random_directions(causal, m)[direction]).rates[-1] - 2.0) <= 0.05


def test_config_builds_the_causal_observation():
    assert objective_from_config({"phi1": "pressure", "observation": "causal"}).at_tau == PressureAt("causal")

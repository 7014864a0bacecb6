"""The forward solve of J stops after the last step the objective reads (``horizon="objective"``).

Causality of the time stepping makes J and its exact gradient on the first K steps equal to those of
the whole solve; the only difference is which controls are admissible (a state failing after step K).
"""

from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import bar, control_point
from hyperoc.control.adjoint import Adjoint
from hyperoc.control.objectives import (
    ControlCost,
    ControlRateCost,
    InjectivityPenalty,
    Objective,
    PressureAt,
    PressureMean,
    PressureRise,
    Trajectory,
)
from hyperoc.control.reduced import ControlPoint, ReducedFunctional
from hyperoc.control.revolve import Binomial, EveryK
from hyperoc.dynamics.stepper import TimeStepper
from hyperoc.dynamics.timegrid import TimeTransform
from hyperoc.errors import SolverError

N, N1, N2 = 12, 5, 2  # steps, level of tau, steps of [tau, tau + eps]
TERMS = [PressureAt(), PressureRise(0.1), PressureMean(0.1), ControlCost(1.0), ControlRateCost(1.0),
         InjectivityPenalty(1.0, 2.0)]


def _reads(term, rng):
    """Which levels' (y0, y1) and which step multipliers ``term.value`` depends on, from its gradient at a
    random trajectory of the bar with 4 cells: (levels (N+1,) bool, steps (N,) bool)."""
    model = bar(4)
    y0, y1 = rng.standard_normal((2, N + 1, model.n)) * 0.01
    p, dt, xi = rng.standard_normal(N), 0.1 + rng.random(N), rng.standard_normal((N + 1, model.control.size))
    mass = jax.experimental.sparse.BCOO.fromdense(jnp.eye(model.control.size))

    def value(y0, y1, p):
        return term.value(Trajectory(y0, y1, p, xi, dt, N1, N1 + N2, mass, None, model))

    g0, g1, gp = jax.grad(value, argnums=(0, 1, 2))(y0, y1, p)
    return (np.abs(g0).sum(axis=1) + np.abs(g1).sum(axis=1)) > 0, gp != 0


@pytest.mark.parametrize("term", TERMS, ids=lambda t: type(t).__name__)
def test_steps_read_is_what_the_term_depends_on(term):
    """No dependence after the declared steps; some on the last one (the declaration is not loose)."""
    k = term.steps_read(N1, N1 + N2, N)
    levels, steps = _reads(term, np.random.default_rng(0))
    assert not levels[k + 1:].any() and not steps[k:].any()
    if k > 0:
        assert levels[k] or steps[k - 1]
    else:
        assert not levels.any() and not steps.any()


@cache
def _adjoint():
    """The state solver and adjoint of the bar with 10 cells, shared by the functionals of this file, so
    that its step and loops compile once (the horizons and schedules differ in what they run, not in it)."""
    return Adjoint(TimeStepper(bar(10)))


def _functional(at_tau, horizon, **kwargs):
    eps = getattr(at_tau, "eps", 0.0)
    adjoint = _adjoint()
    return ReducedFunctional(adjoint.stepper.model, TimeTransform.for_step(3.0, 0.1, 1.2, eps),
                             Objective(running=(ControlCost(2e-3), ControlRateCost(1e-3)), at_tau=at_tau),
                             horizon=horizon, adjoint=adjoint, **kwargs)


@pytest.mark.parametrize("at_tau, checkpoints", [
    (PressureAt(), {}), (PressureRise(0.3), {}), (PressureMean(0.3), {}),
    (PressureRise(0.3), {"schedule": EveryK(4)}), (PressureAt(), {"schedule": Binomial(3)})],
    ids=["at-stored", "rise-stored", "mean-stored", "rise-every-4", "at-binomial-3"])
def test_value_and_gradient_equal_those_of_the_whole_solve(at_tau, checkpoints):
    """Same compiled step, same inputs: equal to round-off (bitwise in practice)."""
    short, whole = _functional(at_tau, "objective", **checkpoints), _functional(at_tau, "full", **checkpoints)
    n1, n2, _ = short.transform.steps
    assert short.steps_solved == at_tau.steps_read(n1, n1 + n2, short.N) < whole.steps_solved == short.N
    m = control_point(short, 1.1, 0.05)
    (j_short, g_short), (j_whole, g_whole) = short.value_and_gradient(m), whole.value_and_gradient(m)
    assert j_short == pytest.approx(j_whole, rel=1e-14, abs=1e-16)
    scale = np.abs(g_whole.xi).max()
    np.testing.assert_allclose(g_short.xi, g_whole.xi, rtol=0, atol=1e-13 * scale)
    assert g_short.tau == pytest.approx(g_whole.tau, rel=1e-12, abs=1e-13 * scale)
    assert short.record(m).grid.num_steps == short.steps_solved


def test_state_still_covers_the_horizon():
    J = _functional(PressureAt(), "objective")
    m = control_point(J, 1.1, 0.05)
    J.value_and_gradient(m)
    assert J.state(m).t.size == J.N + 1 and J.state(m).t[-1] == pytest.approx(3.0)


def test_a_state_failing_after_the_objective_is_admissible_only_there():
    """A control that inverts the bar after tau: J is defined with the objective's horizon; the whole solve
    rejects it (the paper's admissible set)."""
    short, whole = _functional(PressureAt(), "objective"), _functional(PressureAt(), "full")
    xi = np.zeros((short.N + 1, short.model.control.size))
    xi[short.steps_solved + 2:] = -50.0  # a compressive kick long after tau
    m = ControlPoint(xi, 1.2)
    assert np.isfinite(short(m))
    with pytest.raises(SolverError):
        whole(m)
    with pytest.raises(SolverError):
        short.state(m)


def test_unknown_horizon_is_input_error():
    from hyperoc.errors import InputError

    with pytest.raises(InputError, match="horizon"):
        _functional(PressureAt(), "tau")


def test_solver_error_reaches_a_parent_process_intact():
    """The paper job's workers raise it across a process boundary (pickled)."""
    import pickle

    err = pickle.loads(pickle.dumps(SolverError(7, 0.5, "detF", "an element inverts")))
    assert (err.step, err.time, err.cause, err.detail) == (7, 0.5, "detF", "an element inverts")
    assert str(err) == str(SolverError(7, 0.5, "detF", "an element inverts"))


def test_outputs_of_an_end_point_failing_after_the_objective_name_the_remedy(tmp_path):
    """The reports solve [0, T]; an end point that is admissible only up to the objective's steps fails there
    with the step, the cause and the option that keeps such points out."""
    from hyperoc.app.workflows import _whole_state

    J = _functional(PressureAt(), "objective")
    xi = np.zeros((J.N + 1, J.model.control.size))
    xi[J.steps_solved + 2:] = -50.0
    with pytest.raises(SolverError, match='horizon = "full"') as info:
        _whole_state(J, ControlPoint(xi, 1.2))
    assert info.value.step >= J.steps_solved

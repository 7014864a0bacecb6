"""`hyperoc.solvers.newton.newton` on two unknowns ``x = (u, p)``, solved densely.

The residual ``log(u) + c`` is undefined for ``u <= 0``, like the log det F terms of the hyperelastic
laws for an inverted element; the multiplier p is decoupled (``r_p = p``) or, in the bordered
problem, fixes u through the constraint ``u = u_p``.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.solvers.newton import NewtonOptions, NewtonStatus, newton


class DenseBordered:
    """Solves ``[[K, col], [row^T, 0]] [du; dp] = [ru; rp]`` with K given as a dense block."""

    def solve(self, K, col, row, ru, rp):
        A = jnp.block([[K, col[:, None]], [row[None, :], jnp.zeros((1, 1))]])
        x = jnp.linalg.solve(A, jnp.concatenate([ru, jnp.atleast_1d(rp)]))
        return x[:-1], x[-1]


class Decoupled:
    """Solves ``K du = ru`` and ``dp = rp`` (the multiplier's row is the identity)."""

    def solve(self, K, col, row, ru, rp):
        return jnp.linalg.solve(K, ru), rp


def solve_log(c, *, max_iter=30, line_search=True, calls=None):
    """Newton on ``log(u) + c = 0, p = 0`` from (1, 0); returns (x, iterations, status, steps taken).
    With ``calls`` (a list), the u of every point where the residual is evaluated is appended to it."""
    residual = lambda x: jnp.array([jnp.log(x[0]) + c, x[1]])
    if calls is not None:
        residual = counted(residual, calls)
    parts = lambda x: (jnp.array([[1.0 / x[0]]]), jnp.zeros(1), jnp.zeros(1))
    steps = []
    record = lambda *values: steps.append(float(values[4]))  # the step length taken
    monitor = lambda *values: jax.debug.callback(record, *values)
    x, it, status = newton(residual, parts, Decoupled(), jnp.array([1.0, 0.0]),
                           NewtonOptions(1e-12, 0.0, max_iter, line_search=line_search, monitor=monitor))
    jax.effects_barrier()
    return np.asarray(x), int(it), NewtonStatus(int(status)), steps


def counted(residual, calls):
    """``residual`` that appends the point's u to ``calls`` each time it is evaluated (traced or not)."""
    def wrapped(x):
        jax.debug.callback(lambda v: calls.append(float(v[0])), x)
        return residual(x)
    return wrapped


def test_bordered_solve_converges_to_the_root():
    residual = lambda x: jnp.array([jnp.log(x[0]) + 0.5 + x[1], x[0] - 2.0])
    parts = lambda x: (jnp.array([[1.0 / x[0]]]), jnp.ones(1), jnp.ones(1))
    x, it, status = newton(residual, parts, DenseBordered(), jnp.array([1.0, 0.0]), rtol=1e-12, atol=0.0,
                           max_iter=20)
    assert int(status) == NewtonStatus.CONVERGED
    np.testing.assert_allclose(np.asarray(x), [2.0, -0.5 - np.log(2.0)], rtol=1e-14)


@pytest.mark.parametrize("line_search", [True, False])
def test_the_residual_is_evaluated_once_per_iteration(line_search):
    """Without backtracking, k iterations evaluate the residual k + 1 times: at the start and once
    at each new iterate (the line search's evaluation at the accepted point is the next iteration's
    residual). ``log(u) + 0.5`` from u = 1: full Newton steps decrease |r| all the way."""
    calls = []
    x, it, status, steps = solve_log(0.5, line_search=line_search, calls=calls)
    assert status == NewtonStatus.CONVERGED and it >= 3 and steps == [1.0] * it
    np.testing.assert_allclose(x[0], np.exp(-0.5), rtol=1e-14)
    assert len(calls) == it + 1


def test_backtracking_adds_one_evaluation_per_halving():
    """c = 3 (below): the first iteration tries the full and the half step (NaN) before it takes the
    quarter step, so the first points evaluated are u = 1, 1 - 3, 1 - 3/2, 1 - 3/4; over the solve
    the evaluations are the iterations + 1 plus one per halving (step length 2^-k: k halvings)."""
    calls = []
    x, it, status, steps = solve_log(3.0, calls=calls)
    halvings = sum(round(-np.log2(step)) for step in steps)
    assert status == NewtonStatus.CONVERGED and len(steps) == it and halvings >= 2
    assert calls[:4] == [1.0, -2.0, -0.5, 0.25]
    assert len(calls) == it + 1 + halvings


def test_backtracks_from_nan_trials_into_the_domain_of_the_residual():
    """c = 3: the full step goes to u = 1 - 3 < 0 and the half step to -0.5 (NaN residuals); the
    quarter step to 0.25 decreases |r| from 3 to 1.61 and is taken; Newton then converges to e^-3."""
    x, it, status, steps = solve_log(3.0)
    assert status == NewtonStatus.CONVERGED and steps[0] == 0.25
    np.testing.assert_allclose(x[0], np.exp(-3.0), rtol=1e-14)


def test_a_residual_nan_at_every_line_search_step_fails_in_that_iteration():
    """c = 5000: even the smallest step 2^-12 lands at u = 1 - 5000/4096 < 0, so every trial residual
    is NaN: status NON_FINITE after the first iteration, not a 2^-12 step into NaN first."""
    _, it, status, steps = solve_log(5000.0)
    assert status == NewtonStatus.NON_FINITE and it == 1 and steps == [2.0**-12]


@pytest.mark.parametrize("line_search", [True, False])
def test_a_failed_linear_solve_is_non_finite_at_once(line_search):
    residual = lambda x: jnp.array([x[0] - 1.0, x[1]])
    parts = lambda x: (jnp.zeros((1, 1)), jnp.zeros(1), jnp.zeros(1))  # singular K: the solve gives NaN/Inf
    _, it, status = newton(residual, parts, Decoupled(), jnp.array([0.0, 0.0]),
                           NewtonOptions(1e-12, 0.0, 20, line_search=line_search))
    assert int(status) == NewtonStatus.NON_FINITE and int(it) == 1


def test_monitor_reports_displacement_and_pressure_field_apart():
    """``x = (u, q, p)`` with a displacement u, a pressure field q (``n_u = 1``) and the multiplier p;
    the linear residual ``(u - 2, q - 30, p)`` from 0 is solved in one step (du = 2, dq = 30), the
    second iteration's increment is 0 and converges. The monitor gets each part's residual and
    increment: (2, 2) and (30, 30), then zeros."""
    residual = lambda x: jnp.array([x[0] - 2.0, x[1] - 30.0, x[2]])
    parts = lambda x: (jnp.eye(2), jnp.zeros(2), jnp.zeros(2))
    records = []
    record = lambda *values: records.append(tuple(float(v) for v in values))
    monitor = lambda *values: jax.debug.callback(record, *values)
    _, it, status = newton(residual, parts, Decoupled(), jnp.zeros(3),
                           NewtonOptions(1e-12, 0.0, 5, monitor=monitor, n_u=1))
    assert int(status) == NewtonStatus.CONVERGED and int(it) == 2
    # (iteration, |r_u|, |r_p|, |du|, step, converged, |r_q|, |dq|)
    assert records == [(1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 30.0, 30.0), (2.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0)]


@pytest.mark.parametrize("n_u, converged_u", [(None, False), (1, True)])
def test_each_block_of_unknowns_stops_against_its_own_scale(n_u, converged_u):
    """``x = (u, q, p)``: ``log(u / 1e-3) = 0`` in mm and a field equation ``q = 1e6`` in kPa, from
    u = 2e-3. A test over all unknowns measures |du| against |q| = 1e6, stops once |du| <= 1e-6,
    about 1e-3 of u, and leaves u with the error of the next quadratic step, far above rtol. With
    ``n_u`` each block is measured against itself and u converges to rtol."""
    rtol, u_star = 1e-12, 1e-3
    residual = lambda x: jnp.array([jnp.log(x[0] / u_star), x[1] - 1e6, x[2]])
    parts = lambda x: (jnp.diag(jnp.array([1.0 / x[0], 1.0])), jnp.zeros(2), jnp.zeros(2))
    x, _, status = newton(residual, parts, Decoupled(), jnp.array([2 * u_star, 0.0, 0.0]),
                          NewtonOptions(rtol, 0.0, 30, n_u=n_u))
    assert int(status) == NewtonStatus.CONVERGED and float(x[1]) == 1e6
    assert (abs(float(x[0]) / u_star - 1.0) <= rtol) == converged_u

"""Binomial checkpointing (`hyperoc.control.revolve`, ``ReducedFunctional(..., schedule=Binomial(s))``).

(a) The schedule, run on an abstract machine that tracks levels only: every step is reversed exactly
once, in the order N-1, ..., 0, each from the state at its level and the state of the level above;
never more than s snapshots are held; the advanced steps number exactly Griewank's minimum
``t(N, s) = r N - beta(s + 1, r - 1)`` and no step is advanced more than r times. The closed form
itself is checked against the optimum of the split recursion computed by exhaustive search.

(b) Value and gradient equal the store-everything ones. On the sparse path both run the same jitted
step (and the revolve adjoint the same jitted adjoint step as the stored one), so only the sparse LU's
backward error (1e-13 per solve, another ordering for a solver's first factorization) separates
them, as in `tests/test_checkpointed_adjoint.py`. On the traced path the stored forward is a compiled
lax.scan and the revolve path the standalone jitted step: XLA rounds the same step differently,
and the states then differ by ~1e-13 relative (measured: y0, p 1e-13, J 3.2e-13 of the sum of its
terms' magnitudes, gradient 4e-15; unchanged with Newton rtol 1e-14 and the same iteration counts:
round-off of the converged steps, some 500 ulps of the small states, not the stopping test). We
allow ``RTOL = 1e-12`` relative on both paths, for J against the sum of the magnitudes of its terms
and for the gradient in the Riesz norm. Sharper, within the revolve
path a recomputed state is the forward state bit for bit (same jitted step, same inputs, same
Newton warm start ``p_{a-1/2}``): on the traced path the gradients for s = 1, 2, 3, N are equal
exactly (s = N recomputes nothing, s = 2, 3 restart from interior levels, so a wrong warm start
would show), and the counted step evaluations are ``t(N, s) + 1``.

(c) Bad ``checkpoint_snapshots`` values raise `InputError`; in a config they exit the CLI with status 2.
"""

from collections import Counter
from functools import cache

import pytest

from helpers import bar, checkpointing_problem, control_point
from hyperoc import Objective, PressureAt, ReducedFunctional, TimeTransform
from hyperoc.app.cli import main
from hyperoc.app.config import parse_config
from hyperoc.app.workflows import build_reduced
from hyperoc.control.continuous_adjoint import ContinuousReducedFunctional
from hyperoc.control.revolve import (
    Advance,
    Binomial,
    EveryK,
    Free,
    Restore,
    Reverse,
    Store,
    checkpoint_schedule,
    minimal_advances,
    repetitions,
    schedule,
)
from hyperoc.errors import InputError

RTOL = 1e-12


def _run_abstract(N: int, s: int):
    """Executes ``schedule(N, s)`` on levels; returns (reversed steps in order, advances per step,
    most snapshots held, actions before the first reversal)."""
    current, above, held, most = 0, N, set(), 0
    reversed_steps, advanced = [], Counter()
    forward = None
    for i, action in enumerate(schedule(N, s)):
        match action:
            case Advance(a, b):
                assert a == current and a < b < above, action
                advanced.update(range(a, b))
                current = b
            case Store(k):
                assert k == current and k not in held, action
                held.add(k)
                most = max(most, len(held))
            case Restore(k):
                assert k in held, action
                current = k
            case Free(k):
                held.remove(k)
            case Reverse(n):
                assert n == current and n + 1 == above, action  # needs x_n and x_{n+1}
                forward = i if forward is None else forward
                reversed_steps.append(n)
                above = n
    assert not held
    return reversed_steps, advanced, most, schedule(N, s)[:forward]


@pytest.mark.parametrize("s", range(1, 7))
def test_schedule_reverses_every_step_once_with_the_fewest_advances(s):
    for N in range(1, 61):
        reversed_steps, advanced, most, forward = _run_abstract(N, s)
        assert reversed_steps == list(reversed(range(N))), (N, s)
        assert most <= s, (N, s, most)
        assert sum(advanced.values()) == minimal_advances(N, s), (N, s)
        assert max(advanced.values(), default=0) <= repetitions(N, s), (N, s)
        assert all(isinstance(a, (Store, Advance)) for a in forward), (N, s)
    assert minimal_advances(60, 1) == 60 * 59 // 2 and minimal_advances(60, 59) == 59


def test_more_snapshots_than_steps():
    """s >= N - 1 stores every level (N - 1 advances); the schedule is built without deep recursion."""
    reversed_steps, advanced, most, _ = _run_abstract(2000, 3000)
    assert reversed_steps == list(reversed(range(2000))) and most == 1999 and sum(advanced.values()) == 1999


@cache
def _optimum(L: int, s: int) -> int:
    """Least advances of the split recursion (advance j, reverse the right part with s - 1
    snapshots, the left part with s), by exhaustive search over the split j."""
    if L == 1:
        return 0
    if s == 1:
        return L * (L - 1) // 2
    return min(j + _optimum(L - j, s - 1) + _optimum(j, s) for j in range(1, L))


def test_closed_form_is_the_optimum_of_the_recursion():
    assert all(minimal_advances(N, s) == _optimum(N, s) for N in range(1, 41) for s in range(1, 6))


def test_schedule_arguments():
    for N, s in ((0, 2), (5, 0), (5, 1.5), (True, 2)):
        with pytest.raises(InputError, match="revolve"):
            schedule(N, s)


def _counting_steps(J):
    """Counts the stepper's jitted step evaluations (the revolve path steps only through it)."""
    step, calls = J.stepper.advance, Counter()

    def counted(*args):
        calls["steps"] += 1
        return step(*args)

    J.stepper.__dict__["advance"] = counted
    return calls


def _assert_same(J, m, snapshots, exact_between_s):
    value, grad = J.value_and_gradient(m)
    scale = sum(abs(v) for v in J.objective.parts(J.trajectory(J.state(m))).values())
    calls = _counting_steps(J)
    grads = []
    for s in snapshots:
        J.schedule = Binomial(s)
        calls.clear()
        vs, gs = J.value_and_gradient(m)
        assert calls["steps"] == minimal_advances(J.N, s) + 1, (s, calls)
        rec = J.record(m)
        assert len(set(rec.levels) - {J.N - 1, J.N, *J.objective_levels}) <= s
        assert rec.stored_states <= s + 2 + len(J.objective_levels)
        assert abs(vs - value) <= RTOL * scale, (s, vs, value, scale)
        assert J.norm(gs - grad) <= RTOL * J.norm(grad), (s, J.norm(gs - grad) / J.norm(grad))
        assert abs(gs.tau - grad.tau) <= RTOL * J.norm(grad), s
        grads.append(gs)
    if exact_between_s:
        assert all((g.xi == grads[0].xi).all() and g.tau == grads[0].tau for g in grads), "recomputation not bitwise"


@pytest.mark.slow
def test_traced_1d():
    """Tridiagonal solver (the stored path is a compiled lax.scan), objective reading y0(tau), y1(T)."""
    J = checkpointing_problem("traced-1d")
    assert J.stepper.solver.traced and J.N == 7 and J.objective_levels == (3, 7)
    _assert_same(J, control_point(J, 0.75, 0.05), snapshots=(1, 2, 3, J.N), exact_between_s=True)


@pytest.mark.slow
def test_python_loop_3d_sparse():
    """Sparse LU solver (jitted step driven from Python in every path) on a 3D box."""
    J = checkpointing_problem("sparse-3d")
    assert not J.stepper.solver.traced and J.N == 7
    _assert_same(J, control_point(J, 0.3, 0.5), snapshots=(2, J.N), exact_between_s=False)


def test_bad_snapshots_are_refused(tmp_path):
    model = bar(8)
    for bad in (0, -3, 1.5, True, "4"):
        with pytest.raises(InputError, match="checkpoint_snapshots"):
            Binomial(bad)
    with pytest.raises(InputError, match="exclude each other"):
        checkpoint_schedule(2, 3)
    with pytest.warns(DeprecationWarning, match="schedule=EveryK"):
        old = ReducedFunctional(model, TimeTransform.for_step(1.0, 0.25, 0.5), Objective(at_tau=PressureAt()),
                                checkpoint_snapshots=3)
    assert old.schedule == Binomial(3) and old.checkpointed
    with pytest.raises(InputError, match="schedule must be"):
        ReducedFunctional(model, TimeTransform.for_step(1.0, 0.25, 0.5), Objective(at_tau=PressureAt()), schedule=3)
    with pytest.raises(InputError, match="exact gradient"):
        ContinuousReducedFunctional(model, TimeTransform.for_step(1.0, 0.25, 0.5), Objective(at_tau=PressureAt()),
                                    schedule=Binomial(3))
    assert parse_config({"optimize": {"checkpoint_snapshots": 4}})["optimize"]["checkpoint_snapshots"] == 4
    for bad in ({"checkpoint_snapshots": 0}, {"checkpoint_snapshots": 2.5}, {"checkpoint_snapshots": True},
                {"checkpoint_snapshots": 3, "checkpoint_every": 2}):
        with pytest.raises(InputError, match=r"config: \[optimize\] checkpoint_"):
            parse_config({"optimize": bad})
    path = tmp_path / "bad.toml"
    path.write_text("[optimize]\ncheckpoint_snapshots = 0\n")
    assert main(["check-gradient", str(path)]) == 2


def test_config_keys_reach_the_reduced_functional():
    """``[optimize] checkpoint_snapshots`` / ``checkpoint_every`` are passed on by `build_reduced`."""
    base = {"mesh": {"kind": "interval", "n": 8}, "dynamics": {"T": 1.0, "dt": 0.25}, "optimize": {"tau0": 0.5}}
    for key, value, expected in (("checkpoint_snapshots", 3, Binomial(3)), ("checkpoint_every", 2, EveryK(2))):
        cfg = parse_config({**base, "optimize": {"tau0": 0.5, key: value}})
        assert build_reduced(cfg, 0.5).schedule == expected

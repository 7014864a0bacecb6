"""Binomial checkpointing: the optimal reversal schedule of Griewank (1992) and Griewank & Walther
(2000, ACM TOMS Algorithm 799, "revolve"), as a list of actions.

A forward recursion of N steps ``x_{n+1} = step_n(x_n)`` is reversed (adjoint steps N-1, ..., 0,
in that order) while at most s states are held as snapshots, the initial state x_0 included.
Reversing step n needs the states x_n and x_{n+1}; the executor keeps x_{n+1} from the reversal
before (x_N from the forward pass), so a reversal costs no forward step and the only forward
evaluations are the schedule's advances.

With ``beta(s, r) = C(s + r, s)``, s snapshots and at most r evaluations of every step reverse at
most ``beta(s, r)`` steps. For N steps let r be the repetition number, the least r with
``beta(s, r) >= N``; the least number of advanced steps is (Griewank 1992)

    t(N, s) = r N - beta(s + 1, r - 1)

(with ``beta(s, -1) = 0``; ``t(N, 1) = N (N - 1) / 2``, ``t(N, s) = N - 1`` for ``s >= N - 1``).
`schedule` attains it: on ``[a, b)`` with the snapshot of ``x_a`` and s snapshots in all it
advances to a split ``m = a + j``, stores ``x_m``, reverses ``[m, b)`` with s - 1 snapshots, frees
``x_m``, restores ``x_a`` and reverses ``[a, m)`` with s. The cost ``g(j) = j + t(j, s) +
t(L - j, s - 1)`` of the split (L = b - a) is convex in j because t is convex in N (its increment
``t(N, s) - t(N - 1, s)`` is r(N, s), nondecreasing), and its least value is t(L, s); the smallest
minimizer is found by bisection on the increment ``g(j + 1) - g(j) = 1 + r(j + 1, s) - r(L - j, s - 1)``.

Cost of a gradient with this schedule: t(N, s) + 1 step evaluations (the first sweep of the
schedule, x_0 -> x_{N-1}, is the forward pass, which also takes the last step to x_N), against N
when every state is stored; memory s snapshots, the current state and x_{n+1}: s + 2 states (the
adjoint needs only the displacement part of x_{n+1}).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

from ..errors import InputError

__all__ = ["Advance", "Store", "Restore", "Free", "Reverse", "binomial", "repetitions", "minimal_advances", "schedule"]


@dataclass(frozen=True)
class Advance:
    """Take the steps ``start .. stop - 1``: the current state goes from level start to level stop."""

    start: int
    stop: int


@dataclass(frozen=True)
class _SnapshotAction:
    level: int


class Store(_SnapshotAction):
    """Keep the current state (at ``level``) as a snapshot."""


class Restore(_SnapshotAction):
    """Make the snapshot at ``level`` the current state (the snapshot stays)."""


class Free(_SnapshotAction):
    """Drop the snapshot at ``level``."""


@dataclass(frozen=True)
class Reverse:
    """Adjoint of step ``step``: needs the current state at level step and the state at step + 1."""

    step: int


def binomial(snapshots: int, reps: int) -> int:
    """``beta(s, r) = C(s + r, s)``: steps reversible with s snapshots and r repetitions (0 for r < 0)."""
    return comb(snapshots + reps, snapshots) if reps >= 0 else 0


def repetitions(steps: int, snapshots: int) -> int:
    """The repetition number: the least r >= 0 with ``beta(s, r) >= N``."""
    r = 0
    while binomial(snapshots, r) < steps:
        r += 1
    return r


def minimal_advances(steps: int, snapshots: int) -> int:
    """``t(N, s) = r N - beta(s + 1, r - 1)``: the least number of forward steps that reverse N steps
    with s snapshots (Griewank 1992), the first sweep x_0 -> x_{N-1} included."""
    _check(steps, snapshots)
    r = repetitions(steps, snapshots)
    return r * steps - binomial(snapshots + 1, r - 1)


def _check(steps: int, snapshots: int) -> None:
    for name, value in (("steps", steps), ("snapshots", snapshots)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise InputError(f"revolve: {name} must be an integer >= 1, got {value!r}")


def _split(length: int, snapshots: int) -> int:
    """Smallest j in [1, length - 1] minimizing ``j + t(j, s) + t(length - j, s - 1)`` (s >= 2, length >= 2)."""
    lo, hi = 1, length - 1
    while lo < hi:  # least j whose increment g(j + 1) - g(j) is >= 0 (g convex)
        j = (lo + hi) // 2
        if 1 + repetitions(j + 1, snapshots) - repetitions(length - j, snapshots - 1) >= 0:
            hi = j
        else:
            lo = j + 1
    return lo


def _reverse_from(a: int, b: int, snapshots: int) -> list:
    """Reversing the steps ``a .. b - 1`` from the current state at level a with ``snapshots`` snapshots
    free: store level a, `_reverse`, free it (a single step is reversed at once, without a snapshot).
    Returns what to do, in order: actions and ``(a, b, snapshots)`` subproblems for `_reverse`."""
    return [Reverse(a)] if b - a == 1 else [Store(a), (a, b, snapshots), Free(a)]


def _reverse(a: int, b: int, snapshots: int) -> list:
    """Reversing the steps ``a .. b - 1``, given the current state and a snapshot at level a and
    ``snapshots`` snapshots in all (that one included); ends with the current state at level a.
    Returns what to do, in order (as `_reverse_from`)."""
    if snapshots == 1 or b - a == 1:
        out = []
        for n in reversed(range(a, b)):
            out += [Restore(a)] if n < b - 1 else []
            out += [Advance(a, n)] if n > a else []
            out.append(Reverse(n))
        return out
    m = a + _split(b - a, snapshots)
    return [Advance(a, m), *_reverse_from(m, b, snapshots - 1), Restore(a), (a, m, snapshots)]


def schedule(steps: int, snapshots: int) -> tuple:
    """The binomial reversal schedule of N = ``steps`` steps with s = ``snapshots`` snapshots: a tuple of
    `Advance`, `Store`, `Restore`, `Free`, `Reverse` actions starting from the current state at level 0
    (``Store(0)`` first when N > 1) and ending with every snapshot freed. It advances
    ``minimal_advances(N, s)`` steps, reverses every step once (N - 1 first) and never holds more than
    s snapshots; a level followed by a single step to reverse is not stored. The actions before the
    first `Reverse` are the forward pass: stores and advances from level 0 to N - 1.
    """
    _check(steps, snapshots)
    out, todo = [], _reverse_from(0, steps, snapshots)[::-1]  # a stack: the recursion is as deep as s
    while todo:
        item = todo.pop()
        if isinstance(item, tuple):
            todo += _reverse(*item)[::-1]
        else:
            out.append(item)
    return tuple(out)

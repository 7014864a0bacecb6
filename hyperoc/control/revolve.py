"""Checkpointing schedules of the adjoint: what its forward pass keeps and how its reverse pass gets the
states, for `hyperoc.control.adjoint.Adjoint` (`Adjoint.record`, `Adjoint.backward`).

A schedule gives the bounds of the forward pass's loops and the levels whose states it keeps
(`Schedule.forward`), and the reverse pass as actions (`Schedule.reverse`) run from those states:
`Advance`, `Store`, `Restore`, `Free` and `Reverse`, the adjoint of a range of steps. The reverse pass
starts at level N with the totals of J there; reversing the steps ``a .. b - 1`` needs the states at
the levels ``a .. b``: the current state at a, the state at b left by the reversal before (at first
the forward's state at N) and the ones in between, kept or recomputed from the current state.

- `StoreAll`: keeps every level state and reverses all steps in one loop.
- `EveryK(k)`: keeps the states at ``0, k, 2k, ...`` and reverses the segments between them last to
  first, each recomputed from its start. Memory ``ceil(N/k) + k + 1`` level states; cost one more
  forward solve.
- `Binomial(s)`: the optimal schedule with s snapshots below (Griewank's revolve), one step at a time.

Binomial checkpointing: the optimal reversal schedule of Griewank (1992) and Griewank & Walther
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
from functools import lru_cache
from math import comb
from numbers import Integral
from typing import ClassVar, Protocol

from ..errors import InputError

__all__ = ["Advance", "Store", "Restore", "Free", "Reverse", "Schedule", "StoreAll", "EveryK", "Binomial", "binomial",
           "repetitions", "minimal_advances", "schedule", "checkpoint_schedule"]


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
    """Adjoint of the steps ``start .. stop - 1``, in one loop: needs the current state at level start, the
    state at level stop and the states in between."""

    start: int
    stop: int


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
        _check_count(f"revolve: {name}", value)


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
    return [Reverse(a, b)] if b - a == 1 else [Store(a), (a, b, snapshots), Free(a)]


def _reverse(a: int, b: int, snapshots: int) -> list:
    """Reversing the steps ``a .. b - 1``, given the current state and a snapshot at level a and
    ``snapshots`` snapshots in all (that one included); ends with the current state at level a.
    Returns what to do, in order (as `_reverse_from`)."""
    if snapshots == 1 or b - a == 1:
        out = []
        for n in reversed(range(a, b)):
            out += [Restore(a)] if n < b - 1 else []
            out += [Advance(a, n)] if n > a else []
            out.append(Reverse(n, n + 1))
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


class Schedule(Protocol):
    """What the adjoint's forward pass keeps and how its reverse pass gets the states.

    compiled : the loops of both passes over a range of steps: the stepper's own loop and the
        compiled adjoint loop (each a `jax.lax.scan` when the solver is traced), or one jitted step
        at a time (one compilation whatever the lengths).
    """

    compiled: ClassVar[bool]

    def forward(self, steps: int) -> tuple[tuple[int, ...], set[int]]:
        """The bounds ``0 = b_0 < ... < b_J = N`` of the forward pass's loops and the levels it keeps."""

    def reverse(self, steps: int) -> tuple:
        """The actions of the reverse pass, from the kept states; they reverse every step once, last first."""


@dataclass(frozen=True)
class StoreAll:
    """Every level state kept; one loop reverses all steps."""

    compiled: ClassVar[bool] = True

    def forward(self, steps: int) -> tuple[tuple[int, ...], set[int]]:
        return (0, steps), set(range(steps + 1))

    def reverse(self, steps: int) -> tuple:
        return Restore(0), Reverse(0, steps)


@dataclass(frozen=True)
class EveryK:
    """The level states at ``0, k, 2k, ...`` kept; the segments between them reversed last to first, each
    recomputed from its start with the loop of the forward pass (hence the same states)."""

    k: int
    compiled: ClassVar[bool] = True

    def __post_init__(self):
        _check_count("EveryK: k (checkpoint_every)", self.k)

    def forward(self, steps: int) -> tuple[tuple[int, ...], set[int]]:
        bounds = (*range(0, steps, self.k), steps)
        return bounds, set(bounds[:-1])

    def reverse(self, steps: int) -> tuple:
        bounds = self.forward(steps)[0]
        segments = reversed(list(zip(bounds[:-1], bounds[1:])))
        return tuple(action for a, b in segments for action in (Restore(a), Reverse(a, b)))


@dataclass(frozen=True)
class Binomial:
    """`schedule` with ``snapshots`` snapshots, one step at a time: the forward pass keeps the snapshots of
    the schedule's first sweep and the states at N - 1 and N; the reverse pass restores N - 1 and runs
    the actions from the first `Reverse` on."""

    snapshots: int
    compiled: ClassVar[bool] = False

    def __post_init__(self):
        _check_count("Binomial: snapshots (checkpoint_snapshots)", self.snapshots)

    def forward(self, steps: int) -> tuple[tuple[int, ...], set[int]]:
        return (0, steps), {*_binomial_passes(steps, self.snapshots)[0], steps - 1, steps}

    def reverse(self, steps: int) -> tuple:
        return Restore(steps - 1), *_binomial_passes(steps, self.snapshots)[1]


def _check_count(name: str, value) -> None:
    """Refuses a count that is not an integer >= 1 (`InputError` naming it)."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < 1:
        raise InputError(f"{name} must be an integer >= 1, got {value!r}")


def checkpoint_schedule(every: int | None = None, snapshots: int | None = None) -> Schedule:
    """The schedule of the configuration's spelling ``[optimize] checkpoint_every = k`` (`EveryK`) or
    ``checkpoint_snapshots = s`` (`Binomial`), `StoreAll` when both are None; both set is an `InputError`."""
    if every is not None and snapshots is not None:
        raise InputError(f"checkpoint_every = {every} and checkpoint_snapshots = {snapshots} exclude each other "
                         "(equidistant or binomial checkpoints: set one to None)")
    if snapshots is not None:
        return Binomial(snapshots)
    return StoreAll() if every is None else EveryK(every)


@lru_cache(maxsize=4)
def _binomial_passes(steps: int, snapshots: int) -> tuple[frozenset[int], tuple]:
    """The levels `schedule` stores before its first `Reverse`, and its actions from there on."""
    actions = schedule(steps, snapshots)
    start = next(i for i, a in enumerate(actions) if isinstance(a, Reverse))
    return frozenset(a.level for a in actions[:start] if isinstance(a, Store)), actions[start:]

"""Newton's method driven from the host: the iteration of `hyperoc.solvers.newton`'s traced loop on NumPy
values, for linear solvers that run on the host (`hyperoc.solvers.linsolve.SparseSolver` in one process,
PETSc on MPI ranks: `hyperoc.distributed.newton`).

The caller's residual and Jacobian are jitted functions without host callbacks, so that the persistent
compilation cache keeps them (JAX does not store a program that holds a ``jax.pure_callback``); the
linear solves, the decisions and the reductions run here. The decisions are the traced loop's pure policy
functions (`hyperoc.solvers.newton.chord_stopping_test`, ``chord_accepts``, ``chord_next``,
``chord_counts``, ``sufficient_decrease``, ``small_increment``), so both loops take the same iterations.

The unknown is ``x = (u (m,), p)`` with p the multiplier of a constraint (``constrained``), or ``u`` alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import jax
import numpy as np

from .newton import (
    NewtonOptions,
    NewtonStatus,
    block_norms,
    chord_accepts,
    chord_counts,
    chord_next,
    chord_stopping_test,
    small_increment,
    sufficient_decrease,
)

__all__ = ["Reductions", "host_newton", "solver_steps"]


@dataclass(frozen=True)
class Reductions:
    """The reductions over the unknowns u (m,) that a Newton iteration needs: in one process NumPy's (the
    defaults), on MPI ranks the sums and maxima over the ranks of their owned parts (`Layout`).

    m : the number of entries of u in x (before the multiplier); n_u : with a pressure field among the
    unknowns, the number of displacements among the m (the blocks of `small_increment`), else None."""

    m: int
    n_u: int | None = None
    #: not BLAS's dot: OpenBLAS would split it over threads that then spin beside XLA's (`SparseSolver.blas_threads`)
    dot: Callable = lambda u, v: float(np.sum(u * v))
    inf_norm: Callable = lambda v: float(np.max(np.abs(v), initial=0.0))
    all_finite: Callable = lambda v: bool(np.isfinite(v).all())


# a diverging iterate's merit overflows to inf, as in the traced loop: the loop's tests decide, not a warning
@np.errstate(over="ignore", invalid="ignore")
def host_newton(residual, fresh, kept, x0: np.ndarray, options: NewtonOptions, reductions: Reductions, *,
                constrained: bool = True, chord: bool = False, refresh: bool = True):
    """Solve ``residual(x) = 0`` from x0 (m + 1,) or (m,); returns ``(x, iterations, NewtonStatus)``.

    ``residual(x)``: the residual (m + 1,) (momentum rows and the constraint's row) or (m,).
    ``fresh(x, r)``: the Newton step dx with the Jacobian at x, assembled and factored now (and kept, for
    chord Newton); NaN entries when the linear solve failed. ``kept(r)``: the step with the kept Jacobian;
    NaN entries when there is none (which asks for a refresh, not counted as an iteration).

    Full Newton (``chord`` False) takes ``fresh`` steps and stops when ``|du_b|_inf <= rtol |u_b + du_b|_inf
    + atol`` on each block b. Chord Newton (the traced loop's ``chord=True``) starts with the kept Jacobian
    unless ``refresh`` and refreshes it after a rejected step or a slow contraction. With
    ``options.line_search`` a fresh step that does not decrease ``|r|^2`` enough is halved, at most 12
    times, as in the traced loop; ``max_iter`` bounds the counted iterations. ``options.monitor``, if given,
    is called after every iteration with the traced loop's values (`hyperoc.solvers.newton.newton`), on
    NumPy floats (one process: its norms are not reduced over ranks).
    """
    m, red = reductions.m, reductions
    rtol, atol, max_iter = options.rtol, options.atol, int(options.max_iter)
    merit = lambda r: red.dot(r[:m], r[:m]) + (float(r[m]) ** 2 if constrained else 0.0)
    small = lambda u, v, rt, at: bool(small_increment(u, v, red.n_u, rt, at, inf_norm=red.inf_norm, xp=np))
    x = np.array(x0, dtype=np.float64)
    r, previous, it, refresh = residual(x), np.inf, 0, refresh or not chord
    while it < max_iter:
        dx = fresh(x, r) if refresh else kept(r)
        du, number = dx[:m], it + 1
        solved = red.all_finite(dx)
        it += 1 if chord_counts(refresh, solved, xp=np) else 0
        increment = red.inf_norm(du) if solved else np.inf
        if chord:
            p, dp = (float(x[m]), float(dx[m])) if constrained else (0.0, 0.0)
            settled, rate = chord_stopping_test(x[:m], du, p, dp, increment, previous, small, tol=(rtol, atol), xp=np)
        else:
            settled, rate = solved and small(x[:m], du, rtol, atol), np.inf
        converged = solved and bool(settled)
        m0 = merit(r)
        if converged or not solved:
            alpha, r1 = 1.0, None
        elif refresh and options.line_search:
            alpha, r1 = _backtrack(residual, merit, x, dx, m0)
        else:  # a chord step is taken whole or rejected
            alpha, r1 = 1.0, residual(x + dx)
        decreased = r1 is not None and bool(sufficient_decrease(merit(r1), m0, alpha))
        accepted = bool(chord_accepts(solved, converged, decreased, refresh, xp=np))
        if options.monitor is not None:
            res, inc, *field = block_norms(r[:m], du, solved, red.n_u, xp=np)
            # the step taken: a chord loop reports 0 for a rejected one, full Newton its length (the traced loops')
            step = alpha if accepted or not chord else 0.0
            options.monitor(number, res, abs(float(r[m])) if constrained else 0.0, inc, step, converged, *field)
        if converged:
            return x + dx, it, NewtonStatus.CONVERGED
        if refresh and not solved:
            return x, it, NewtonStatus.NON_FINITE
        if accepted:
            x, r = x + alpha * dx, r1
            if not red.all_finite(r):
                return x, it, NewtonStatus.NON_FINITE
        refresh_next, previous = chord_next(accepted, rate, increment, xp=np)
        refresh, previous = not chord or bool(refresh_next), float(previous)
    return x, it, NewtonStatus.MAX_ITERATIONS


def _backtrack(residual, merit, x, dx, m0: float):
    """``(alpha, r(x + alpha dx))``: the full step halved while it does not decrease the merit ``m0`` enough,
    at most 12 times (the traced loop's ``_backtrack``)."""
    alpha, r1 = 1.0, residual(x + dx)
    while not sufficient_decrease(merit(r1), m0, alpha) and alpha > 2.0**-12:
        alpha /= 2
        r1 = residual(x + alpha * dx)
    return alpha, r1


def solver_steps(solver, jacobian, chord: bool):
    """``(fresh, kept)`` of `host_newton` for one process's host solver (`hyperoc.solvers.linsolve.SparseSolver`):
    ``fresh(x, r)`` solves with the bordered Jacobian ``jacobian(x)`` (the jitted parts ``(blocks, col, row[,
    corner, low_rank])``), keeping it for chord Newton; ``kept(r)`` solves with the kept one. NaN on failure."""
    def fresh(x, r):
        blocks, col, row, *rest = jax.device_get(jacobian(x))
        return solver.try_solve(blocks, col, row, -r[:-1], -r[-1], *rest, keep=chord)

    return fresh, lambda r: solver.try_kept_solve(-r[:-1], -r[-1])

"""Newton's method on a `Layout`: the bordered step by the serial Schur elimination with inner
products over the ranks, the serial stopping test with maxima over the ranks, and, as in the serial
time stepper, chord Newton with a kept factorization.

The unknown is ``x = (owned values (m_o,), q)`` with q the multiplier of the volume constraint
(``constrained``) or ``x = owned values`` alone. Each iteration solves

    [ K     col  ] [du]   [ -r_u ]
    [ row^T  c   ] [dq] = [ -r_c ]

as `hyperoc.solvers.linsolve.eliminate_border` does (``K a = -r_u``, ``K b = col`` against one factorization),
unconstrained ``K du = -r_u``; the corner c (``dr_c/dq``, 0 but for a row that reads q) is constant in a solve.
Full Newton (``kept=None``) factors K at every iteration, takes full steps and stops when
``|du_b|_inf <= rtol |u_b + du_b|_inf + atol`` on each block b (displacements, then Taylor-Hood pressures:
`hyperoc.solvers.newton.small_increment`). Chord Newton (a `KeptJacobian`) is the serial
``newton(..., chord=True)`` (`hyperoc.solvers.newton`): it solves with the Jacobian of an earlier
iterate, of this solve or of an earlier one, takes the step if it decreases ``|r|^2`` (sufficient
decrease 1e-4), refreshes the Jacobian after a rejected step or when the contraction rate exceeds
`hyperoc.solvers.newton.CHORD_RATE`, and stops when the error left after the update, of u and of the
multiplier, is small. Its decisions are the serial loop's pure policy functions
(`hyperoc.solvers.newton.chord_stopping_test`, ``chord_accepts``, ``chord_next``, ``chord_counts``) on
NumPy values. Every rank makes the same sequence of collective calls: the decisions are taken on reduced
values, equal on all ranks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..solvers.linsolve import eliminate_border
from ..solvers.newton import (
    NewtonOptions,
    NewtonStatus,
    chord_accepts,
    chord_counts,
    chord_next,
    chord_stopping_test,
    small_increment,
    sufficient_decrease,
)

if TYPE_CHECKING:  # the loop needs only the layout's methods; importing it needs PETSc
    from .layout import Layout

__all__ = ["KeptJacobian", "newton"]


@dataclass
class KeptJacobian:
    """The Jacobian chord Newton keeps between iterations and solves: the layout's factorization number
    it was factored as (`Layout.factorizations`; another factorization since, e.g. an adjoint step's,
    makes it stale) and the owned parts of ``K^-1 col`` and ``row`` of its border (None unconstrained)."""

    factorization: int = -1
    b: np.ndarray | None = None
    row: np.ndarray | None = None

    def current(self, layout: Layout) -> bool:
        return self.factorization == layout.factorizations


def newton(residual, jacobian, layout: Layout, x0: np.ndarray, options: NewtonOptions, *, constrained: bool = True,
           kept: KeptJacobian | None = None, corner: float = 0.0):
    """Solve ``residual(x) = 0`` from x0; ``(x, iterations, NewtonStatus)``. ``options``: the tolerances
    ``rtol``, ``atol`` and ``max_iter`` of `hyperoc.solvers.newton.NewtonOptions` (its other fields are the
    serial loop's).

    ``residual(xl, q)`` and ``jacobian(xl, q)`` take the local values xl (m,) of the iterate's owned
    part (ghosts filled) and its multiplier q (0 unconstrained). ``residual`` returns the owned rows
    r_u (m_o,) and, constrained, the constraint's value r_c (so (m_o + 1,)); ``jacobian`` the element
    blocks (nc_local, k, k) of K on the rank's cells and the owned parts of ``col`` and ``row`` (None
    unconstrained). ``kept``: chord Newton with this kept Jacobian (updated in place), else full Newton.
    ``corner``: the bordered Jacobian's corner ``dr_c/dq``.
    """
    m_o, (rtol, atol, max_iter) = layout.owned_size, (options.rtol, options.atol, options.max_iter)
    x = np.array(x0, dtype=np.float64)
    at = lambda x: (layout.local_of_owned(x[:m_o]), x[m_o] if constrained else 0.0)
    merit = lambda r: layout.dot(r[:m_o], r[:m_o]) + (r[m_o] ** 2 if constrained else 0.0)
    r, previous, it = residual(*at(x)), np.inf, 0
    refresh = kept is None or not kept.current(layout)
    while it < max_iter:
        if refresh:
            dx = _fresh_step(jacobian, layout, at(x), r, constrained, kept, corner)
        else:
            dx = _kept_step(layout, r, constrained, kept, corner)
        du = dx[:m_o]
        solved = layout.all_finite(dx)
        it += 1 if chord_counts(refresh, solved, xp=np) else 0
        if refresh and not solved:
            return x, it, NewtonStatus.NON_FINITE
        increment = layout.inf_norm(du) if solved else np.inf
        chord = kept is not None
        small = lambda u, v, rt, at: bool(small_increment(u, v, layout.n_u, rt, at, inf_norm=layout.inf_norm))
        if chord:
            p, dp = (x[m_o], dx[m_o]) if constrained else (0.0, 0.0)
            settled, rate = chord_stopping_test(x[:m_o], du, p, dp, increment, previous, small, tol=(rtol, atol),
                                                xp=np)
        else:
            settled, rate = small(x[:m_o], du, rtol, atol), np.inf
        converged = solved and bool(settled)
        if converged:
            return x + dx, it, NewtonStatus.CONVERGED
        r1 = residual(*at(x + dx)) if solved else None
        decreased = solved and bool(sufficient_decrease(merit(r1), merit(r)))  # a chord step is taken whole
        accepted = bool(chord_accepts(solved, converged, decreased, refresh, xp=np))
        if accepted:
            x, r = x + dx, r1
            if not layout.all_finite(r):
                return x, it, NewtonStatus.NON_FINITE
        refresh_next, previous = chord_next(accepted, rate, increment, xp=np)
        refresh, previous = not chord or bool(refresh_next), float(previous)
    return x, max_iter, NewtonStatus.MAX_ITERATIONS


def _fresh_step(jacobian, layout: Layout, xl_q, r, constrained: bool, kept: KeptJacobian | None,
                corner: float) -> np.ndarray:
    """The Newton step with the Jacobian at the iterate, factored now (and kept, for chord Newton)."""
    m_o = layout.owned_size
    blocks, col, row = jacobian(*xl_q)
    layout.factor(blocks)
    if kept is not None:
        kept.factorization = layout.factorizations
    if not constrained:
        return layout.solve(-r)[:, 0]
    ab = layout.solve(-r[:m_o], col)
    if kept is not None:
        kept.b, kept.row = ab[:, 1].copy(), row
    du, dq = eliminate_border(ab, row, -r[m_o], dot=layout.dot, corner=corner)
    return np.append(du, dq)


def _kept_step(layout: Layout, r, constrained: bool, kept: KeptJacobian, corner: float) -> np.ndarray:
    """The chord step with the kept factorization and border."""
    m_o = layout.owned_size
    a = layout.solve(-r[:m_o])
    if not constrained:
        return a[:, 0]
    du, dq = eliminate_border(np.column_stack([a[:, 0], kept.b]), kept.row, -r[m_o], dot=layout.dot, corner=corner)
    return np.append(du, dq)

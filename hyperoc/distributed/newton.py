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
multiplier, is small. The iteration is `hyperoc.solvers.host_newton.host_newton`, the loop of the serial host
solvers too, whose decisions are the traced loop's pure policy functions on NumPy values. Every rank makes
the same sequence of collective calls: the decisions are taken on reduced
values, equal on all ranks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..solvers.host_newton import Reductions, host_newton
from ..solvers.linsolve import eliminate_border
from ..solvers.newton import NewtonOptions

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
    ``rtol``, ``atol`` and ``max_iter`` of `hyperoc.solvers.newton.NewtonOptions`; the steps are taken whole
    (no line search).

    ``residual(xl, q)`` and ``jacobian(xl, q)`` take the local values xl (m,) of the iterate's owned
    part (ghosts filled) and its multiplier q (0 unconstrained). ``residual`` returns the owned rows
    r_u (m_o,) and, constrained, the constraint's value r_c (so (m_o + 1,)); ``jacobian`` the element
    blocks (nc_local, k, k) of K on the rank's cells and the owned parts of ``col`` and ``row`` (None
    unconstrained). ``kept``: chord Newton with this kept Jacobian (updated in place), else full Newton.
    ``corner``: the bordered Jacobian's corner ``dr_c/dq``. The loop is `hyperoc.solvers.host_newton`'s,
    with the reductions over the ranks.
    """
    m_o = layout.owned_size
    at = lambda x: (layout.local_of_owned(x[:m_o]), x[m_o] if constrained else 0.0)
    reductions = Reductions(m_o, layout.n_u, layout.dot, layout.inf_norm, layout.all_finite)
    return host_newton(lambda x: residual(*at(x)),
                       lambda x, r: _fresh_step(jacobian, layout, at(x), r, constrained, kept, corner),
                       lambda r: _kept_step(layout, r, constrained, kept, corner),
                       x0, NewtonOptions(options.rtol, options.atol, options.max_iter, line_search=False), reductions,
                       constrained=constrained, chord=kept is not None,
                       refresh=kept is None or not kept.current(layout))


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

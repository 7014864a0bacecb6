"""Newton's method on a `Layout`: full steps, the bordered step by the serial Schur elimination with
inner products over the ranks, the serial stopping test with maxima over the ranks.

The unknown is ``x = (owned values (m_o,), q)`` with q the multiplier of the volume constraint
(``constrained``) or ``x = owned values`` alone. Each iteration solves

    [ K     col ] [du]   [ -r_u ]
    [ row^T  0  ] [dq] = [ -r_c ]

as `hyperoc.solvers.linsolve._eliminate` does (``K a = -r_u``, ``K b = col`` against one factorization),
unconstrained ``K du = -r_u``, and stops when ``|du_b|_inf <= rtol |u_b + du_b|_inf + atol`` on each block b
(displacements, then Taylor-Hood pressures: `hyperoc.solvers.newton._small`). Every rank makes the same
sequence of collective calls: the decisions are taken on reduced values, equal on all ranks.
"""

from __future__ import annotations

import numpy as np

from ..solvers.linsolve import _eliminate
from ..solvers.newton import NewtonStatus, _small
from .layout import Layout

__all__ = ["newton"]


def newton(residual, jacobian, layout: Layout, x0: np.ndarray, *, rtol: float, atol: float, max_iter: int,
           constrained: bool = True):
    """Solve ``residual(x) = 0`` from x0; ``(x, iterations, NewtonStatus)``.

    ``residual(xl, q)`` and ``jacobian(xl, q)`` take the local values xl (m,) of the iterate's owned
    part (ghosts filled) and its multiplier q (0 unconstrained). ``residual`` returns the owned rows
    r_u (m_o,) and, constrained, the constraint's value r_c (so (m_o + 1,)); ``jacobian`` the element
    blocks (nc_local, k, k) of K on the rank's cells and the owned parts of ``col`` and ``row`` (None
    unconstrained).
    """
    m_o = layout.owned_size
    x = np.array(x0, dtype=np.float64)
    for it in range(1, max_iter + 1):
        xl, q = layout.local_of_owned(x[:m_o]), (x[m_o] if constrained else 0.0)
        r = residual(xl, q)
        blocks, col, row = jacobian(xl, q)
        layout.factor(blocks)
        if constrained:
            du, dq = _eliminate(layout.solve(-r[:m_o], col), row, -r[m_o], dot=layout.dot)
            dx = np.append(du, dq)
        else:
            dx = du = layout.solve(-r)[:, 0]
        if not layout.all_finite(dx):
            return x, it, NewtonStatus.NON_FINITE
        converged = bool(_small(x[:m_o], du, layout.n_u, rtol, atol, inf_norm=layout.inf_norm))
        x = x + dx
        if converged:
            return x, it, NewtonStatus.CONVERGED
    return x, max_iter, NewtonStatus.MAX_ITERATIONS

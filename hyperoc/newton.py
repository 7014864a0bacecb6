"""Newton's method with backtracking for the bordered systems of hyperoc, as a traced JAX loop.

The unknown is ``x = (u, p)`` (n displacement dofs and one multiplier). The caller gives the
residual ``r(x)`` (n+1,) and the Jacobian parts ``(blocks, col, row)`` of
``[[K, col], [row^T, 0]]``, K by element blocks, which a solver from `hyperoc.linsolve` inverts.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from . import _jax  # noqa: F401

__all__ = ["newton"]


def newton(residual, jacobian_parts, solver, x0, *, rtol: float, atol: float, max_iter: int,
           line_search: bool = True):
    """Solve ``residual(x) = 0``; returns ``(x, iterations, status)``.

    Convergence: ``|du|_inf <= rtol |u|_inf + atol`` for the Newton increment du; with quadratic
    convergence the error after that update is far below the test. Status 0 = converged,
    1 = not converged in ``max_iter`` iterations, 2 = non-finite iterate. When the full step does
    not decrease ``|r|^2`` (sufficient decrease 1e-4), it is halved (at most 12 times);
    ``line_search=False`` always takes the full step (penalty-stiff static problems with load
    stepping, where the merit of the first full step can grow although Newton then converges).
    """
    merit = lambda r: jnp.sum(r * r)

    def body(state):
        x, it, _, _ = state
        r = residual(x)
        blocks, col, row = jacobian_parts(x)
        du, dp = solver.solve(blocks, col, row, -r[:-1], -r[-1])
        dx = jnp.concatenate([du, dp[None]])
        m0 = merit(r)

        def shrink(ls):
            alpha, _ = ls
            return alpha / 2, merit(residual(x + alpha / 2 * dx))

        def keep_shrinking(ls):
            alpha, m1 = ls
            return (~(m1 <= (1 - 1e-4 * alpha) * m0)) & (alpha > 2.0**-12)

        # An increment below the tolerance is taken whole: its merit is at round-off level and
        # backtracking on it would only stall.
        scale = jnp.max(jnp.abs(x[:-1] + du))
        converged = jnp.max(jnp.abs(du)) <= rtol * scale + atol
        if line_search:
            alpha, _ = jax.lax.cond(converged, lambda: (1.0, 0.0),
                                    lambda: jax.lax.while_loop(keep_shrinking, shrink, (1.0, merit(residual(x + dx)))))
        else:
            alpha = 1.0
        x_new = x + alpha * dx
        finite = jnp.all(jnp.isfinite(x_new))
        status = jnp.where(~finite, 2, jnp.where(converged, 0, 1))
        return x_new, it + 1, status, finite

    def cond(state):
        _, it, status, finite = state
        return (status == 1) & (it < max_iter) & finite

    x, it, status, _ = jax.lax.while_loop(cond, body, (x0, 0, 1, True))
    return x, it, status

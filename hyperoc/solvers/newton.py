"""Newton's method with backtracking for the bordered systems of hyperoc, as a traced JAX loop.

The unknown is ``x = (u, p)`` (n displacement dofs and one multiplier). The caller gives the
residual ``r(x)`` (n+1,) and the Jacobian parts ``(blocks, col, row)`` of
``[[K, col], [row^T, 0]]``, K by element blocks, which a solver from `hyperoc.solvers.linsolve` inverts.

The loop is compiled, so it prints nothing while it runs; a long solve (a fine 3D mesh, minutes per
iteration) is followed through ``monitor``, a hook called once per iteration inside the loop, which
the caller turns into a host callback (`hyperoc.dynamics.statics.solve_static`'s ``monitor``,
`NewtonIteration`, `NewtonLog`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import IntEnum

import jax
import jax.numpy as jnp

from .. import _jax  # noqa: F401

__all__ = ["newton", "NewtonStatus", "NewtonIteration", "NewtonLog", "NewtonOptions", "CHORD_RATE", "CHORD_MARGIN",
           "chord_stopping_test", "chord_accepts", "chord_next", "chord_counts", "sufficient_decrease",
           "small_increment", "block_norms"]

#: Contraction rate above which a chord iteration refreshes the factorization: below it a kept
#: factorization gains a digit or more per solve; a slower one would need more solves to reach the
#: tolerance than a refresh (a factorization costs about ten solves on 2D meshes) saves.
CHORD_RATE = 0.1
#: The chord iteration stops when what is left of u is below this fraction of full Newton's tolerance:
#: the multiplier p, a reaction, amplifies what is left of u, and a linearly converging iteration does
#: not leave the round-off that a quadratically converging one does.
CHORD_MARGIN = 0.01


class NewtonStatus(IntEnum):
    """How `newton` ended, its third result (a traced int; compare on the host as ``NewtonStatus``)."""

    CONVERGED = 0
    #: not converged in ``max_iter`` iterations
    MAX_ITERATIONS = 1
    #: a non-finite iterate, or a residual that is non-finite at every line-search step
    NON_FINITE = 2


@dataclass(frozen=True)
class NewtonIteration:
    """One Newton iteration, as seen by a monitor.

    load : the load factor in (0, 1] of the load step (static solves).
    iteration : 1, 2, ... within this Newton solve.
    residual : ``|r_u|_2`` of the iterate the step starts from (the force balance over the
        displacement unknowns).
    constraint : ``|r_p|`` of that iterate (the volume constraint, or the gauge when unconstrained).
    increment : ``|du|_inf`` of the full Newton increment over the displacement unknowns (mm in the
        benchmarks); NaN when the linear solve failed (the solver's ``last_failure`` says why).
    step : the step length taken, ``2^-k`` after k halvings (1 for a full step).
    converged : whether this increment passed the stopping test (each block of unknowns against its
        own scale: displacements, and the pressure field if there is one).
    field_residual, field_increment : with a pressure field among the unknowns
        (`hyperoc.mechanics.mixed.TaylorHoodModel`: kPa), ``|r_q|_2`` of its equations (``J - 1 - q/bulk_modulus``
        tested against P1) and ``|dq|_inf`` of its increment; None without one.
    """

    load: float
    iteration: int
    residual: float
    constraint: float
    increment: float
    step: float
    converged: bool
    field_residual: float | None = None
    field_increment: float | None = None


@dataclass
class NewtonLog:
    """A monitor that keeps every `NewtonIteration` (``records``) and, given a ``stream``, prints one
    line per iteration as it ends, with the wall time since the previous line or the log's creation
    (a factorization and the line search; the first line also holds the compilation).
    ``NewtonLog(sys.stderr)`` follows a long solve live."""

    stream: object = None
    records: list = field(default_factory=list)
    _last: float = field(default_factory=time.perf_counter, repr=False)

    def __call__(self, record: NewtonIteration) -> None:
        now = time.perf_counter()
        self.records.append(record)
        if self.stream is not None:
            field = ("" if record.field_residual is None else
                     f" |r_q| {record.field_residual:.3e} |dq| {record.field_increment:.3e}")
            print(f"newton: load {record.load:.4g} it {record.iteration:2d} |r| {record.residual:.3e} "
                  f"|r_p| {record.constraint:.2e} |du| {record.increment:.3e}{field} step {record.step:.4g}"
                  f"{' converged' if record.converged else ''} ({now - self._last:.1f} s)",
                  file=self.stream, flush=True)
        self._last = now


@dataclass(frozen=True)
class NewtonOptions:
    """The options of one Newton solve (`newton`): tolerances ``rtol``, ``atol`` of the increment test,
    ``max_iter`` (may be traced), ``line_search``, the per-iteration ``monitor`` and ``n_u`` (the
    displacement unknowns before a pressure field, None without one); `newton` says what each does."""

    rtol: float
    atol: float
    max_iter: object
    line_search: bool = True
    monitor: object = None
    n_u: int | None = None


def newton(residual, jacobian_parts, solver, x0, options: NewtonOptions | None = None, *, rtol: float | None = None,
           atol: float | None = None, max_iter=None, chord: bool = False):
    """Solve ``residual(x) = 0``; returns ``(x, iterations, status)``.

    ``options``: the `NewtonOptions` of the solve; or, without them, the tolerances ``rtol``, ``atol``,
    ``max_iter`` as keywords, the other options at their defaults.

    ``jacobian_parts(x)``: the bordered Jacobian at x as ``(blocks, col, row)``, ``(blocks, col, row,
    corner)`` or ``(blocks, col, row, corner, low_rank)`` (`hyperoc.solvers.linsolve`; the corner is 0 and the
    low-rank part ``(U, W)`` None when not given), passed to the solver's solves.

    Convergence: ``|du|_inf <= rtol |u + du|_inf + atol`` for the Newton increment du; with
    quadratic convergence the error after that update is far below the test. With ``n_u`` (a
    pressure field q among the unknowns) the test is made on each block apart,
    ``|du|_inf <= rtol |u + du|_inf + atol`` and ``|dq|_inf <= rtol |q + dq|_inf + atol``, so that
    neither block's stopping depends on the other's units (mm and kPa). ``status`` is a
    `NewtonStatus` as a traced int. ``max_iter`` may be traced (0: no iteration, x0 returned with
    status ``MAX_ITERATIONS``). When the full step does not decrease ``|r|^2``
    (sufficient decrease 1e-4), it is halved (at most 12 times); ``line_search=False`` always
    takes the full step (penalty-stiff static problems with load stepping, where the merit of the
    first full step can grow although Newton then converges).

    ``monitor(iteration, residual, constraint, increment, step, converged[, field_residual,
    field_increment])``, if given, is called on traced scalars at the end of every iteration (the
    fields of `NewtonIteration` but the load). ``n_u``: the first n_u of the n unknowns are
    displacements, the others a pressure field (Taylor-Hood); the monitor then gets the two
    parts' residuals and increments apart.

    ``chord``: chord (modified) Newton with a kept Jacobian, for a solver with ``refresh_solve``
    and ``kept_solve`` (`hyperoc.solvers.linsolve.SparseSolver`). An iteration solves with the
    whole Jacobian (the factored tangent K_0 and the border) of an earlier iterate, of this solve
    or of an earlier one (a time step starts from the previous step's), and takes the step whole
    if it decreases ``|r|^2`` (sufficient decrease 1e-4); otherwise the step is rejected. The
    Jacobian is assembled and factored again (``refresh_solve``: a full Newton iteration with the
    line search above) after a rejected step, when the kept solve failed (no factorization yet, or
    a singular one) or when the contraction rate ``theta = |du_k|_inf / |du_{k-1}|_inf`` exceeds
    `CHORD_RATE`. It stops by `chord_stopping_test`: on the error left after the update, estimated from
    theta, for u and, on its own scale, for the multiplier p, with the tolerances scaled by
    `CHORD_MARGIN`; or at the round-off floor.
    """
    options = options or NewtonOptions(rtol, atol, max_iter)
    if chord:
        return _chord_newton(residual, jacobian_parts, solver, x0, options)
    rtol, atol, max_iter, n_u, monitor = options.rtol, options.atol, options.max_iter, options.n_u, options.monitor

    def body(state):
        # r = residual(x) is carried: the line search evaluates it at the point it accepts, which
        # is the next iterate, so each iteration evaluates the residual once (plus backtracking).
        x, r, it, _, _ = state
        blocks, col, row, *corner = jacobian_parts(x)
        du, dp = solver.solve(blocks, col, row, -r[:-1], -r[-1], *corner)
        dx = jnp.concatenate([du, dp[None]])
        # A failed linear solve returns NaN, whose max is not NaN in XLA's reduction (-inf on CPU):
        # test for it first, so that it is neither "converged" nor backtracked on 12 times.
        solved = jnp.all(jnp.isfinite(dx))
        # An increment below the tolerance is taken whole: its merit is at round-off level and
        # backtracking on it would only stall.
        converged = solved & small_increment(x[:-1], du, n_u, rtol, atol)
        r_full = residual(x + dx)
        if options.line_search:
            alpha, r1 = _backtrack(residual, x, dx, _merit(r), r_full, ~(converged | ~solved))
        else:
            alpha, r1 = 1.0, r_full
        x_new = x + alpha * dx
        if monitor is not None:
            res, inc, *field = block_norms(r[:-1], du, solved, n_u)
            monitor(it + 1, res, jnp.abs(r[-1]), inc, alpha, converged, *field)
        # A residual that is NaN even at the smallest step (e.g. log det F of an inverted element
        # all along the Newton direction) is a failure now, not one iteration later; after a
        # converged step the residual is not used, and not tested.
        finite = jnp.all(jnp.isfinite(x_new)) & (converged | jnp.isfinite(_merit(r1)))
        return x_new, r1, it + 1, _status(finite, converged), finite

    def cond(state):
        _, _, it, status, finite = state
        return _running(status, it, finite, max_iter)

    x, _, it, status, _ = jax.lax.while_loop(cond, body, (x0, residual(x0), 0, int(NewtonStatus.MAX_ITERATIONS), True))
    return x, it, status


def _chord_newton(residual, jacobian_parts, solver, x0, options: NewtonOptions):
    """`newton` with ``chord=True`` (its docstring); returns ``(x, iterations, status)``. The decisions are
    the pure policy functions shared with the distributed loop (`chord_stopping_test`, `chord_accepts`,
    `chord_next`, `chord_counts`)."""
    rtol, atol, n_u, monitor = options.rtol, options.atol, options.n_u, options.monitor

    def fresh(x, r):
        blocks, col, row, *corner = jacobian_parts(x)
        return solver.refresh_solve(blocks, col, row, -r[:-1], -r[-1], *corner)

    def kept(x, r):
        return solver.kept_solve(-r[:-1], -r[-1])

    def body(state):
        x, r, it, _, _, refresh, previous = state
        du, dp = jax.lax.cond(refresh, fresh, kept, x, r)
        dx = jnp.concatenate([du, dp[None]])
        m0 = _merit(r)
        solved = jnp.all(jnp.isfinite(dx))
        increment = jnp.where(solved, jnp.max(jnp.abs(du)), jnp.inf)
        small = lambda u, v, rt, at: small_increment(u, v, n_u, rt, at)
        settled, rate = chord_stopping_test(x[:-1], du, x[-1], dp, increment, previous, small, tol=(rtol, atol))
        converged = solved & settled
        r_full = residual(x + dx)
        # A fresh (full Newton) step backtracks (with ``line_search``); a chord step is taken whole or rejected.
        alpha, r1 = _backtrack(residual, x, dx, m0, r_full, refresh & ~converged & solved & options.line_search)
        accepted = chord_accepts(solved, converged, sufficient_decrease(_merit(r1), m0, alpha), refresh)
        x_new = jnp.where(accepted, x + alpha * dx, x)
        r_new = jnp.where(accepted, r1, r)
        if monitor is not None:
            res, inc, *field = block_norms(r[:-1], du, solved, n_u)
            monitor(it + 1, res, jnp.abs(r[-1]), inc, jnp.where(accepted, alpha, 0.0), converged, *field)
        finite = ~refresh | solved  # a failed kept solve only asks for a refresh
        finite = finite & jnp.all(jnp.isfinite(x_new)) & (converged | jnp.isfinite(_merit(r_new)))
        status = _status(finite, converged)
        refresh_next, previous_next = chord_next(accepted, rate, increment)
        counted = it + jnp.where(chord_counts(refresh, solved), 1, 0)
        return x_new, r_new, counted, status, finite, refresh_next, previous_next

    def cond(state):
        _, _, it, status, finite, *_ = state
        return _running(status, it, finite, options.max_iter)

    init = (x0, residual(x0), 0, int(NewtonStatus.MAX_ITERATIONS), True, jnp.asarray(False),
            jnp.asarray(jnp.inf, dtype=x0.dtype))
    x, _, it, status, *_ = jax.lax.while_loop(cond, body, init)
    return x, it, status


def chord_stopping_test(u, du, p, dp, increment, previous, small, *, tol: tuple, xp=jnp):
    """The stopping test of a chord iteration and its contraction rate, ``(settled, rate)``, on JAX or
    NumPy values (``xp``): the one policy of the serial and the distributed chord Newton.

    ``u, du``: the iterate's displacements and their increment; ``p, dp``: its multiplier and increment
    (0 and 0 unconstrained); ``increment = |du|_inf`` and ``previous``, the last accepted one (inf if
    none); ``tol = (rtol, atol)``: the tolerances of the increment test; ``small(u, du, rtol, atol)``: the block
    test of `small_increment`. A linearly converging iteration
    leaves an error of about ``left |dx|`` after the update dx, ``left = rate / (1 - rate)``,
    ``rate = increment / previous`` (1 while the rate is unknown or above `CHORD_RATE`). Settled: what
    is left of u meets the tolerances scaled by `CHORD_MARGIN`, and what is left of p meets
    ``rtol |p + dp|``: p is a reaction, far more sensitive than u to what is left (a chord iteration
    stopped on u alone can leave p wrong in its eighth digit), so it gets its own test on its own scale.
    Or the increment meets the unscaled test while the contraction fails: the iteration is at
    round-off (which also ends it when p is 0 to round-off)."""
    rtol, atol = tol
    rate = increment / previous
    left = xp.where(xp.isfinite(previous) & (rate < CHORD_RATE), rate / (1 - rate), 1.0)
    u_settled = small(u, left * du, CHORD_MARGIN * rtol, CHORD_MARGIN * atol)
    p_settled = xp.abs(left * dp) <= rtol * xp.abs(p + dp)
    at_floor = (rate > CHORD_RATE) & small(u, du, rtol, atol)
    return (u_settled & p_settled) | at_floor, rate


def chord_accepts(solved, converged, decreased, refresh, xp=jnp):
    """Whether a chord iteration takes its step: the solve succeeded, and the step converged, decreased
    ``|r|^2`` enough (`sufficient_decrease`) or is a fresh (full Newton) step, taken after its line search."""
    return xp.logical_and(solved, xp.logical_or(xp.logical_or(converged, decreased), refresh))


def chord_next(accepted, rate, increment, xp=jnp):
    """``(refresh, previous)`` for the next chord iteration: the Jacobian is assembled and factored again
    after a rejected step or when the contraction rate exceeds `CHORD_RATE` (a kept factorization then
    gains less than a digit per solve); the rate is next measured against this increment if the step
    was taken, else it is unknown (``previous = inf``)."""
    return xp.logical_or(xp.logical_not(accepted), rate > CHORD_RATE), xp.where(accepted, increment, xp.inf)


def chord_counts(refresh, solved, xp=jnp):
    """Whether a chord iteration counts as one: a kept solve that failed (no factorization yet, or a
    singular one) is no iteration, only the refresh it asks for."""
    return xp.logical_or(refresh, solved)


def sufficient_decrease(m1, m0, alpha=1.0):
    """Whether a step of length ``alpha`` took the merit ``m0 = |r|^2`` to ``m1`` with enough decrease
    (Armijo with 1e-4)."""
    return m1 <= (1 - 1e-4 * alpha) * m0


def _merit(r):
    """``|r|^2``, the merit function of the line search."""
    return jnp.sum(r * r)


def _backtrack(residual, x, dx, m0, r_full, search):
    """``(alpha, r(x + alpha dx))``: the full step's ``r_full`` halved while it does not decrease the
    merit ``m0`` enough, at most 12 times; with ``search`` False (traced) the full step as it is."""
    def shrink(ls):
        alpha, _ = ls
        return alpha / 2, residual(x + alpha / 2 * dx)

    def keep_shrinking(ls):
        alpha, r1 = ls
        return search & ~sufficient_decrease(_merit(r1), m0, alpha) & (alpha > 2.0**-12)

    return jax.lax.while_loop(keep_shrinking, shrink, (1.0, r_full))


def _status(finite, converged):
    """The traced `NewtonStatus` of an iteration."""
    return jnp.where(~finite, int(NewtonStatus.NON_FINITE),
                     jnp.where(converged, int(NewtonStatus.CONVERGED), int(NewtonStatus.MAX_ITERATIONS)))


def _running(status, it, finite, max_iter):
    """The loop condition: not converged, below ``max_iter`` iterations, finite."""
    return (status == int(NewtonStatus.MAX_ITERATIONS)) & (it < max_iter) & finite


def _blocks(n_u):
    """The blocks of the unknowns (the multiplier excluded): all of them, or with ``n_u`` the
    displacements ``[:n_u]`` and the pressure field ``[n_u:]``."""
    return [slice(None)] if n_u is None else [slice(None, n_u), slice(n_u, None)]


def small_increment(u, du, n_u, rtol, atol, inf_norm=None, xp=jnp):
    """Whether ``|du_b|_inf <= rtol |u_b + du_b|_inf + atol`` on every block b (`_blocks`), on JAX or NumPy
    values (``xp``). ``inf_norm(v)``: the max norm (default ``max |v|``; a distributed solve passes the maximum
    over the ranks of their parts')."""
    norm = inf_norm or (lambda v: xp.max(xp.abs(v)))
    small = [norm(du[b]) <= rtol * norm(u[b] + du[b]) + atol for b in _blocks(n_u)]
    return xp.all(xp.stack(small))


def block_norms(r_u, du, solved, n_u, xp=jnp):
    """``(|r_b|_2, |du_b|_inf)`` of each block b (`_blocks`), one after the other, on JAX or NumPy values
    (``xp``); increments NaN if not ``solved``."""
    norms = lambda r, d: (xp.linalg.norm(r), xp.where(solved, xp.max(xp.abs(d)), xp.nan))
    return tuple(value for b in _blocks(n_u) for value in norms(r_u[b], du[b]))

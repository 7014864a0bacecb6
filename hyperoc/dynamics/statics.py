"""Quasi-static equilibrium (no inertia, no damping), with or without the volume constraint.

Constrained (default): find ``(u, p)`` with

    R(u) + sum_k k_k S_k u + p G(u) = B xi + f + sum_j f_j(u),      c(u) = V,

the same residual and Newton as a time step with ``M = 0`` and no damping, with a constraint of the
family of the time step (`hyperoc.dynamics.constraint`): the tissue volume (default, ``c = vol``,
``G = dvol/du``) or the cavity volume (``c = V_cav``, ``G = -dV_cav/du``: p is the cavity pressure, its
stiffness ``-p d2V_cav/du2`` in the tangent); ``V`` defaults to the initial value of c. ``f_j(u)`` are
loads that depend on the state: follower pressures (`hyperoc.mechanics.follower.FollowerPressure`), which
act on the deformed boundary, and active fibre tension (`hyperoc.mechanics.active.FibreTension`); their
stiffness ``-df_j/du`` enters the Newton tangent. ``k_k S_k u`` are the springs of Robin boundaries
(`hyperoc.dynamics.terms.RobinBoundary`: the static part of the step's term, its force ``A(u, 0, t)`` and
tangent ``dA/dy0``; the dashpot has no static part): part of the stiffness, not ramped. Springs make a body
without Dirichlet boundary statically determinate (the benchmark's unclamped ventricle).

Unconstrained (``constraint="none"``, e.g. the Land et al. 2015 benchmarks, where only the material's
volumetric penalty controls the volume): find u with ``R(u) + sum_k k_k S_k u = B xi + f + sum_j f_j(u)``. The bordered
solvers of `hyperoc.solvers.linsolve` are reused exactly: the unknown is written ``u = w + t e`` with the
fixed unit vector ``e = (1, ..., 1) / sqrt(n)`` and the gauge ``e . w = 0``, so Newton solves

    [ K(u)   K(u) e ] [dw]   [-r(u)  ]
    [ e^T       0   ] [dt] = [-e . w ],

whose Schur complement ``e^T K^-1 K e = 1`` never vanishes, and ``du = dw + dt e`` is the plain
Newton step ``K du = -r``. (Newton's stopping test looks at ``dw`` only; ``dt`` is the mean of
``du`` times sqrt(n).)

All loads (``load``, ``xi``, the state-dependent loads) are ramped linearly over ``steps`` load steps
(`StaticOptions`), as is the target volume; each step starts from the previous equilibrium. With
``cutbacks > 0`` a failed increment is halved and retried (adaptive load stepping).

Newton globalization. `hyperoc.solvers.newton.newton` backtracks on ``|r|^2``. For nearly incompressible
laws (``bulk_modulus >> C``) that merit is badly suited: a Newton step of size ``|du|`` leaves a
volumetric residual ``~ bulk_modulus |grad du|^2`` that can exceed the residual it corrects by orders of
magnitude although the next iterate is much closer to the solution (Land problem 1: ``bulk_modulus / C =
500``, |r| grows 2000x after the first step, after which Newton converges quadratically), so the
backtracking stalls at its smallest step. ``StaticOptions(line_search=False)`` takes full Newton steps
instead (`hyperoc.solvers.newton.NewtonOptions`), as is common in cardiac mechanics codes with load stepping.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from ..errors import InputError, SolverError
from ..mechanics.model import StateModel
from ..solvers.host_newton import Reductions, host_newton, solver_steps
from ..solvers.linsolve import make_solver
from ..solvers.newton import NewtonIteration, NewtonOptions, NewtonStatus, newton
from .constraint import NoConstraint, TissueVolume
from .stepper import Scheme, StepStatus
from .terms import RobinBoundary

__all__ = ["StaticSolution", "StaticOptions", "solve_static"]


@dataclass(frozen=True)
class StaticOptions:
    """How `solve_static` walks the load from 0 to 1 and solves each increment.

    steps : nominal load increments (the load factor grows by ``1 / steps``).
    cutbacks : how many times in total a failed load increment may be halved and retried from the
        last equilibrium (the increment then grows back, doubling after each success, up to
        ``1 / steps``); 0 = fail at once.
    predictor : Newton's starting point at each load increment: ``"previous"`` (default), the last
        equilibrium; ``"secant"``, the linear extrapolation of the last two equilibria (u and p) to
        the new load factor, first-order accurate in the increment where the previous one is
        zeroth-order: fewer Newton iterations on a smooth path, but on a response that stiffens
        along the path it overshoots (Land problem 2: more halved increments).
    line_search : backtracking Newton (`hyperoc.solvers.newton.newton`, default) or full Newton steps (see the
        module docstring: needed for nearly incompressible penalties).
    scheme : the `Scheme` whose Newton tolerances (``rtol``, ``atol``, ``max_iter``) and chord policy apply.
    solver : a linear solver or its name (`hyperoc.solvers.linsolve.make_solver`: made once per model and name,
        and reused by later solves, with its compiled Newton solve); with follower pressures the
        tangent is not symmetric, so ``"minres"`` is refused.
    monitor : a callable given a `hyperoc.solvers.newton.NewtonIteration` after every Newton iteration, of
        the guess and of every load increment, rejected ones included (``NewtonLog(sys.stderr)``
        prints them as they come). With a traced solver a host callback from the compiled loop (the solve is
        compiled once with it, for any monitor, and once without); with a host solver a call from the host loop.
    """

    steps: int = 1
    cutbacks: int = 0
    predictor: str = "previous"
    line_search: bool = True
    scheme: Scheme = Scheme()
    solver: object = "auto"
    monitor: object = None


@dataclass(eq=False)
class StaticSolution:
    """Equilibrium ``u`` (n,) reduced, multiplier ``p`` (0 when unconstrained), volume ``int det F``,
    Newton iterations per accepted load step; ``from_guess``: reached by one Newton solve at the full
    load from ``solve_static``'s ``guess`` (then ``newton_iterations`` has that one entry);
    ``rejected_iterations``: Newton iterations of the attempts thrown away (a guess Newton failed
    from, halved load increments), so the work done is ``newton_iterations.sum() + rejected_iterations``;
    ``guess_failure``: why Newton from the guess failed (cause and detail, e.g. the linear solver's
    message), None when there was no guess or it converged."""

    model: StateModel
    u: np.ndarray
    p: float
    volume: float
    newton_iterations: np.ndarray
    from_guess: bool = False
    rejected_iterations: int = 0
    guess_failure: str | None = None

    def displacement(self) -> np.ndarray:
        return self.model.expand(self.u)


def _compiled_solve(model: StateModel, lin, scheme: Scheme, followers: tuple, constrained: bool,
                    line_search: bool, monitored: bool = False, constraint=None, robin: tuple = ()):
    """The jitted Newton solve of one load step and its monitor slot, cached on the model per (linear
    solver instance, scheme, follower loads, constraint on/off, line search on/off, monitored or not,
    constraint object: None for the tissue volume, Robin boundaries).

    ``solve(x0, fk, Vk, s, fit_multiplier=False)`` takes the unknown ``x`` ((u, p), or (w, t)
    unconstrained), the fixed load ``fk`` (n,), the volume ``Vk`` and the load factor ``s`` of the
    follower pressures; ``fit_multiplier`` replaces x0's multiplier by the least-squares one of the
    force balance at x0's displacement (a guess carries no multiplier). When
    ``monitored``, every Newton iteration calls ``slot[0]`` on the host with a `NewtonIteration`;
    the caller sets the slot, so one compilation serves every monitor.
    """
    cache = model.__dict__.setdefault("_static_solves", {})
    key = (id(lin), scheme, tuple(map(id, followers)), constrained, line_search, monitored, id(constraint),
           tuple(map(id, robin)))
    if key in cache:  # lin lives in the cache, loads and constraint in its solve's closure: their ids stay their own
        return cache[key]
    con = TissueVolume(model) if constraint is None else constraint
    slot = [None]
    e = jnp.full(model.n, model.n ** -0.5)
    chord = scheme.chord_with(lin, auto=False)

    def displacement(x):
        return x[:-1] if constrained else x[:-1] + x[-1] * e

    def force_balance(u, fk, s):
        """``R(u) + sum_k k_k S_k u - fk - sum_j f_j(u)`` (n,): the residual without the multiplier term."""
        return (model.internal_force(u) + spring_force(robin, u) - fk
                - sum((fol.force(u, s) for fol in followers), jnp.zeros(model.n)))

    def residual(x, fk, Vk, s):
        u = displacement(x)
        if constrained:
            r = force_balance(u, fk, s) + x[-1] * con.force_direction(u)
            return jnp.concatenate([r, (con.value(u) - Vk)[None]])
        return jnp.concatenate([force_balance(u, fk, s), (e @ x[:-1])[None]])

    def jacobian_parts(x, fk, s):
        u = displacement(x)
        blocks = model.tangent_blocks(u, 1.0, con.tangent_weight(x) if constrained else 0.0)
        for fol in followers:
            blocks = fol.add_stiffness(blocks, u, s)
        blocks = add_spring_tangent(robin, blocks, u)
        if constrained:
            return (con.add_tangent(blocks, x, 1.0), con.force_direction(u), con.value_gradient(u), 0.0,
                    con.low_rank(x, 1.0))
        Ke = jax.jvp(lambda v: force_balance(v, fk, s), (u,), (e,))[1]
        return blocks, Ke, e

    def report(load, iteration, *values):
        slot[0](NewtonIteration(float(load), int(iteration), *map(float, values[:4]), bool(values[4]),
                                *map(float, values[5:])))

    def fitted_multiplier(x, fk, s):
        """x with the multiplier that best balances the forces at its displacement u,
        ``p = argmin |r(u) + p G(u)|_2 = -G.r / G.G`` (the multiplier of the nearest equilibrium)."""
        u = displacement(x)
        r, G = force_balance(u, fk, s), con.force_direction(u)
        return x.at[-1].set(-(G @ r) / (G @ G))

    options = lambda monitor: NewtonOptions(scheme.rtol, scheme.atol, scheme.max_iter, line_search, monitor,
                                            getattr(model, "n_u", None))

    @jax.jit
    def solve(x0, fk, Vk, s, fit_multiplier=False):
        if constrained:  # traced flag: the guess path and the load steps share one compilation
            x0 = jax.lax.cond(fit_multiplier, lambda: fitted_multiplier(x0, fk, s), lambda: x0)
        monitor = (lambda *values: jax.debug.callback(report, s, *values)) if monitored else None
        x, it, status = newton(lambda x: residual(x, fk, Vk, s), lambda x: jacobian_parts(x, fk, s), lin, x0,
                               options(monitor), chord=chord)
        return x, it, status, model.min_det_F(displacement(x))

    kernels = {"residual": jax.jit(residual), "jacobian": jax.jit(jacobian_parts), "fit": jax.jit(fitted_multiplier),
               "min_det_F": jax.jit(lambda x: model.min_det_F(displacement(x)))}

    def host_solve(x0, fk, Vk, s, fit_multiplier=False):
        """`solve` for a host solver: Newton on the host (`hyperoc.solvers.host_newton`), the residual and
        the Jacobian parts jitted apart (no host callback in them, so the compilation cache keeps them)."""
        if constrained and fit_multiplier:
            x0 = kernels["fit"](x0, fk, s)
        x0 = np.asarray(x0, dtype=np.float64)

        fresh, kept = solver_steps(lin, lambda x: kernels["jacobian"](x, fk, s), chord)
        monitor = (lambda *values: report(s, *values)) if monitored else None
        x, it, status = host_newton(lambda x: np.asarray(kernels["residual"](x, fk, Vk, s)), fresh, kept, x0,
                                    options(monitor),
                                    Reductions(x0.size - 1, getattr(model, "n_u", None)), chord=chord, refresh=False)
        return x, it, status, float(kernels["min_det_F"](x))

    cache[key] = (solve if lin.traced else host_solve), slot
    return cache[key]


def robin_terms(model, robin, caller: str) -> tuple:
    """``robin`` (a `RobinBoundary` or a sequence of them) as a tuple, each a term of ``model``; else an
    `InputError` naming ``caller``."""
    robin = (robin,) if not isinstance(robin, (tuple, list)) else tuple(robin)
    if not all(isinstance(term, RobinBoundary) and term.n == model.n for term in robin):
        raise InputError(f"{caller}: robin must hold RobinBoundary terms of this model")
    return robin


def add_spring_tangent(robin, blocks, u):
    """The element blocks (nc, k, k) plus the springs' tangent ``k_k S_k`` of the Robin boundaries ``robin``
    (the step term's ``dA/dy0`` with a = 1, no dashpot: b = 0)."""
    for term in robin:
        blocks = term.add_tangent(blocks, u, jnp.zeros_like(u), 0.0, 1.0, 0.0)
    return blocks


def spring_force(robin, u):
    """``sum_k k_k S_k u`` (n,): the springs of the Robin boundaries ``robin`` at rest (velocity 0), the static
    part ``A(u, 0, t)`` of their step terms (`hyperoc.dynamics.terms.RobinBoundary.force`); minus their
    reaction on the body."""
    zero = jnp.zeros_like(u)
    return sum((term.force(u, zero, 0.0) for term in robin), zero)


def initial_unknown(model: StateModel, u: np.ndarray, constrained: bool) -> jnp.ndarray:
    """The Newton unknown (n + 1,) of the compiled solve for the displacement u (n,): ``(u, p = 0)``
    with the constraint, else ``(w, t)`` with ``u = w + t e``, ``e = n^-1/2 (1, ..., 1)``, ``e . w = 0``."""
    if constrained:
        return jnp.concatenate([jnp.asarray(u), jnp.zeros(1)])
    t = u.sum() * model.n ** -0.5
    return jnp.concatenate([jnp.asarray(u - t * model.n ** -0.5), jnp.full(1, t)])


def solve_static(model: StateModel, *, load=None, xi=None, volume: float | None = None, u0=None, follower=(),
                 robin=(), constraint=None, guess=None, options: StaticOptions = StaticOptions()) -> StaticSolution:
    """Equilibrium under the load vector ``load`` (n,), control ``xi`` and follower pressures, ramped in
    ``options.steps`` (`StaticOptions`: the load stepping, Newton, the linear solver and the monitor).

    Parameters
    ----------
    robin : a `hyperoc.dynamics.terms.RobinBoundary` or a sequence of them: their springs ``k S u`` (the
        dashpots have no static part), not ramped; with them the body needs no Dirichlet boundary.
    follower : a state-dependent load or a sequence of them: `hyperoc.mechanics.follower.FollowerPressure`
        (pressure on the deformed boundary), `hyperoc.mechanics.active.FibreTension` (active stress along the
        fibres); each is ramped as ``s * pressure`` (``s * tension``) at load step ``s = k / steps``.
    constraint : the global constraint ``c(u) = volume`` with multiplier p: None (default), the tissue volume
        ``int det F``; a `hyperoc.dynamics.constraint.CavityVolumeConstraint`, the cavity volume, p the cavity
        pressure (its volume change law is not read: ``volume`` is the target); or ``"none"`` (or a
        `hyperoc.dynamics.constraint.NoConstraint`): no constraint, no multiplier (``volume`` must then be None).
        ``volume`` defaults to c(u0).
    guess : a starting point (n,) for Newton directly at the full load, e.g. the solution on the
        next coarser mesh carried over by `StateModel.prolong` (nested iteration: the guess is off
        by the coarse discretization error only, so Newton converges in a few iterations and the
        load path is not walked again). This Newton always backtracks (``line_search`` concerns
        the load steps): with no small load increment to bound it, a full Newton step from such a
        guess can overshoot (Land problem 2, Taylor-Hood, level 1 -> 2: full steps diverge,
        backtracking converges in a few iterations). The multiplier starts at the
        least-squares balance of the forces at the guess, ``-G.r / G.G`` (one Newton iteration fewer
        than from 0 on the test plate from its 0.9-load equilibrium, as from the exact one). If
        Newton fails from it, a `RuntimeWarning` says why and the load stepping from ``u0`` runs as
        without a guess (``StaticSolution.from_guess`` and ``guess_failure`` tell what happened).
    options : `StaticOptions`. ``newton_iterations`` has one entry per accepted increment (the iterations
        of the rejected ones: ``rejected_iterations``).

    Raises
    ------
    SolverError
        Naming the load step (index of the failed increment, and its load factor as ``time``) when
        Newton fails or an element inverts (``det F <= 0``) and no cutback is left.
    """
    followers = (follower,) if not isinstance(follower, (tuple, list)) else tuple(follower)
    robin = robin_terms(model, robin, "solve_static")
    if options.predictor not in ("previous", "secant"):
        raise InputError(f"solve_static: predictor must be 'previous' or 'secant', got {options.predictor!r}")
    constrained, constraint = _constraint(constraint)
    if not constrained and volume is not None:
        raise InputError("solve_static: a target volume needs a constraint")
    lin = _static_solver(model, options.solver)
    scheme, monitor = options.scheme, options.monitor
    if followers and getattr(lin, "method", None) == "minres":
        raise InputError("solve_static: follower pressures make the tangent non-symmetric; MINRES does not apply")
    f = jnp.zeros(model.n) if load is None else jnp.asarray(load)
    if xi is not None:  # B only then: jax_operators also builds M and K, which a static solve never needs
        f = f + model.jax_operators[2] @ jnp.asarray(xi)
    u = np.zeros(model.n) if u0 is None else np.asarray(u0, dtype=np.float64)
    V_start = float(model.jitted["volume"](jnp.asarray(u)) if constraint is None else constraint.value(jnp.asarray(u)))
    V = V_start if volume is None else float(volume)

    slots = []

    def compiled(search: bool):
        solve, slot = _compiled_solve(model, lin, scheme, followers, constrained, search, monitor is not None,
                                      constraint, robin)
        slot[0] = monitor
        slots.append(slot)
        return solve

    try:
        rejected, guess_failure = 0, None
        if guess is not None:
            solution, rejected, guess_failure = _solve_from_guess(model, lin, compiled(True), guess, f, V, constrained)
            if solution is not None:
                return solution
            warnings.warn(f"solve_static: Newton from the guess failed ({guess_failure}); stepping the load instead",
                          RuntimeWarning, stacklevel=2)
        x, iters, cut = step_load(lin, compiled(options.line_search), initial_unknown(model, u, constrained), f,
                                  V_start, V, steps=options.steps, cutbacks=options.cutbacks,
                                  predictor=options.predictor)
        return _solution(model, x, constrained, iters, rejected=rejected + cut, guess_failure=guess_failure)
    finally:  # the cached solve must not keep the caller's monitor (and all it holds) alive
        for slot in slots:
            slot[0] = None


def _constraint(constraint) -> tuple[bool, object]:
    """``(constrained, constraint)`` of `solve_static`'s ``constraint``: ``"none"`` or a `NoConstraint` is
    ``(False, None)``, anything else is held by a multiplier (None: the tissue volume)."""
    if isinstance(constraint, str) and constraint != "none":
        raise InputError(f"solve_static: constraint must be None, 'none' or a constraint object, got {constraint!r}")
    if isinstance(constraint, (str, NoConstraint)):
        return False, None
    return True, constraint


def step_load(lin, solve, x, f, V_start: float, V: float, *, steps: int, cutbacks: int, predictor: str):
    """Walk the load factor s from 0 to 1 in ``steps`` nominal increments, each solved by ``solve``
    (`_compiled_solve`) from the predictor; a failed increment is halved while cutbacks are left.
    Returns ``(x at s = 1, Newton iterations per accepted increment, iterations of rejected ones)``."""
    iters, rejected, s_done, ds, cuts, k = [], 0, 0.0, 1.0 / steps, 0, 0
    last = None  # (x, s) of the equilibrium before the current one, for the secant predictor
    while s_done < 1.0:
        s = s_done + ds if s_done + ds < 1.0 - 1e-12 else 1.0
        failed = _failed_solves(lin)
        x0 = x if last is None or predictor == "previous" else x + (x - last[0]) * ((s - s_done) / (s_done - last[1]))
        x_new, it, status, mindet = solve(x0, s * f, V_start + s * (V - V_start), s)
        cause, detail = _failure(lin, failed, status, mindet)
        if cause is None:
            last, x, s_done, k = (x, s_done), x_new, s, k + 1
            iters.append(int(it))
            ds = min(2 * ds, 1.0 / steps)  # back towards the nominal increment after a success
        elif cuts < cutbacks:
            ds, cuts, rejected = ds / 2, cuts + 1, rejected + int(it)
        else:
            raise SolverError(k, s, cause, f"load step {k + 1} (load factor {s:.6g} of 1, {steps} nominal steps"
                              f"{f', after {cuts} cutbacks' if cuts else ''}), {detail}")
    return x, iters, rejected


def _static_solver(model: StateModel, solver):
    """The linear solver of the static solves: an instance as given; for a name, one instance per
    model and name, kept on the model, so repeated solves reuse its compiled Newton solves (a new
    instance would mean a new compilation) and its stats and failures are those of the solver the
    compiled solve calls."""
    if not isinstance(solver, str):
        return solver
    solvers = model.__dict__.setdefault("_static_solvers", {})
    if solver not in solvers:
        solvers[solver] = make_solver(model, solver)
    return solvers[solver]


def _failed_solves(lin) -> int:
    """How many host linear solves of ``lin`` have failed so far (0 for solvers that never fail)."""
    return getattr(lin, "stats", {}).get("failed", 0)


def _failure(lin, failed_before: int, status, mindet) -> tuple:
    """``(cause, detail)`` of a compiled Newton solve: cause None on success, else "newton" (no
    convergence or a failed linear solve, which returns NaN), "nonfinite" or "detF"."""
    status, detail = NewtonStatus(int(status)), f"min det F = {float(mindet):.3g}"
    if status == NewtonStatus.CONVERGED:
        cause = None if float(mindet) > 0 else StepStatus.DET_F.cause
    else:
        cause = StepStatus(status).cause
    if _failed_solves(lin) > failed_before:
        cause, detail = "newton", f"linear solve failed: {lin.last_failure}"
    return cause, detail


def _solution(model: StateModel, x, constrained: bool, iters, from_guess: bool = False,
              rejected: int = 0, guess_failure: str | None = None) -> StaticSolution:
    """The `StaticSolution` of the compiled solve's unknown x (`initial_unknown`'s layout)."""
    x = np.asarray(x)
    u = x[:-1] if constrained else x[:-1] + x[-1] * model.n ** -0.5
    p = float(x[-1]) if constrained else 0.0
    return StaticSolution(model, u, p, float(model.jitted["volume"](jnp.asarray(u))), np.array(iters), from_guess,
                          rejected, guess_failure)


def _solve_from_guess(model: StateModel, lin, solve, guess, f, V: float, constrained: bool):
    """Newton at the full load (s = 1) from ``guess`` (n,): ``(the StaticSolution, 0, None)``, or
    ``(None, its Newton iterations, "cause, Newton iteration k: detail")`` if Newton fails, a linear
    solve fails or an element inverts (the caller then steps the load)."""
    guess = np.asarray(guess, dtype=np.float64)
    if guess.shape != (model.n,):
        raise InputError(f"solve_static: guess must have shape ({model.n},), got {guess.shape}")
    failed = _failed_solves(lin)
    x, it, status, mindet = solve(initial_unknown(model, guess, constrained), f, V, 1.0, True)
    cause, detail = _failure(lin, failed, status, mindet)
    if cause is not None:
        return None, int(it), f"{cause}, Newton iteration {int(it)}: {detail}"
    return _solution(model, x, constrained, [int(it)], from_guess=True), 0, None

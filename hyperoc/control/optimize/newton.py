"""Projected truncated Newton-CG for ``max_{xi, tau} J(xi, tau)`` with bounds: second-order steps from
Hessian-vector products, CG preconditioned by the curvature pairs of the earlier solves."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...errors import SolverError
from ..reduced import ControlPoint, ReducedFunctional
from .box import BoxProblem, as_box
from .curvature import CurvaturePairs
from .result import OptimizationResult, Termination
from .run import Run
from .search import Backtracking

__all__ = ["newton_cg", "NewtonCGOptions"]


@dataclass(frozen=True)
class NewtonCGOptions:
    """The steps of `newton_cg`: at most ``max_cg`` Hessian-vector products per CG solve, tau's scale
    ``tau_scale`` in the metric, and the Armijo search's sufficient increase ``armijo`` and halvings
    ``max_backtracks``; `newton_cg` says what each does."""

    max_cg: int = 20
    tau_scale: float | str = 1.0
    armijo: float = 0.5
    max_backtracks: int = 30


def newton_cg(problem: ReducedFunctional | BoxProblem, m0: ControlPoint, *, xi_bounds=(None, None),
              gtol: float = 1e-6, gtol_abs: float = 0.0, max_iter: int = 100,
              options: NewtonCGOptions = NewtonCGOptions(), cache_dir=None, callback=None) -> OptimizationResult:
    """Projected truncated Newton-CG (the projected Newton method of Bertsekas, SIAM J. Control Optim.
    20, 1982, with CG stopped at nonconcavity as in Steihaug's method): second-order steps from
    Hessian-vector products.

    ``problem``: a reduced functional J with the bounds ``xi_bounds``, or a `BoxProblem`, as in
    `barzilai_borwein`; ``options``: CG's budget, tau's scale and the search (`NewtonCGOptions`).

    Each iteration splits the values into binding ones (within ``w`` of a bound that G pushes against,
    ``w`` the largest component of the projected step ``P(m + G) - m`` per block: Bertsekas's
    epsilon-active set, which shrinks to the active set at a KKT point) and free ones. On the free ones
    it solves ``-H d = G`` (H the Hessian of J, G the gradient, both in the metric of `ControlSpace.metric`)
    by conjugate gradients to the relative residual ``min(0.5, sqrt(||P(m + G) - m|| / ||.||_0))``
    (superlinear local convergence) or ``max_cg`` products; the binding values take the gradient step.
    CG is preconditioned by the curvature pairs of the earlier CG solves (`CurvaturePairs`): unpreconditioned
    CG resolves the Hessian's stiff directions first, so with that loose residual it leaves out the soft
    ones (the paper problem's curved ridge in (xi, tau), curvature ~1e-3 along it against ~1 across) and
    the iterates crawl along them; with the pairs, which hold those directions, the paper's problem takes
    29 iterations and 123 gradient evaluations instead of 46 and 285. With bounds on xi and an H^1-in-time cost
    (beta > 0) the pairs start from the inverse of the cost's Hessian (`BoxProblem.cost_inverse`): the lumped
    metric the bounds need lacks the cost's coupling in time, which CG would otherwise resolve product by
    product, and with it CG takes the steps it takes in the control space's own metric.
    The step ``P(m + alpha d)`` is searched by Armijo backtracking from alpha = 1, as in `barzilai_borwein`;
    where that fails (a poor curvature model: no ascent in ``max_backtracks`` halvings), the same search along G.

    Why: the bounded paper problem is not concave on its free values (J grows along some directions,
    so the maximizer sits on the bounds there) and ill-conditioned, where first-order steps make slow
    progress. When CG meets a direction p along which J is not concave (``<p, -H p> <= 0``) the
    direction is the CG iterate plus p, and a full step along it accepted by the search is doubled while
    J keeps increasing and the projection still moves the trial point (not a step of the fallback along G).

    The metric weighs tau by ``c^2`` (`BoxProblem.tau_weight`), c from ``tau_scale``: a number,
    ``"range"`` (`BoxProblem.tau_scale`), or ``"curvature"``: ``c^2 = |d^2 J / d tau^2|`` at the start,
    one forward difference of the gradient along tau (`hyperoc.control.control_space.TauWeighted` says
    why). Where the metric's xi-block is the cost's Hessian (an H^1-in-time cost, beta > 0), that gives
    both blocks unit scale; with c = 1 and tau's curvature ~1e9 larger (a cardiac problem in SI units),
    the CG residual is tau's alone, CG stops after one product with a step in tau only, and xi barely moves.

    Hessian-vector products are forward differences of the exact gradient, ``H v ~ (G(m + h v) - G(m)) / h``
    with ``h = sqrt(eps_mach) (1 + |m|_inf) / |v|_inf`` (relative error ~1e-8, which limits the local
    rate to linear with that factor); each costs one state and one adjoint solve, and is not cached
    (a resumed run recomputes them; the iterates, trial points and their evaluations are cached as in
    `barzilai_borwein`, so it ends where an uninterrupted run ends). Stops when the projected gradient
    norm is ``<= max(gtol ||G0||, gtol_abs)`` (``gtol_abs``: a warm start's test relative to a cold start's
    gradient). ``callback(k, m, J(m), measure)`` as in `barzilai_borwein`. ``evaluations`` counts the
    Hessian-vector products, the iterations where CG met nonconcavity and the gradient steps taken where the
    Newton direction's search failed.
    """
    box, tau_scale, max_cg = as_box(problem, m0.tau, xi_bounds), options.tau_scale, options.max_cg
    if tau_scale != "curvature":
        box = replace(box, tau_weight=box.tau_scale(tau_scale) ** 2)
    run = Run(box, cache_dir, callback)
    search = Backtracking(run, options.armijo, options.max_backtracks)
    counts = {"hessian_products": 0, "nonconcave_iterations": 0, "gradient_steps": 0}
    m, current, measure = run.start(m0)
    if tau_scale == "curvature":
        current, measure = run.rescale(m, current, replace(box, tau_weight=_tau_curvature(run, m, current, counts)))
    target, preconditioner = max(gtol * measure, gtol_abs), CurvaturePairs(run.box.metric, initial=run.box.cost_inverse)
    first, termination = measure, Termination.MAX_ITERATIONS
    for k in range(1, max_iter + 1):
        if measure <= target:
            break
        free = _free_values(run.box, m, current.G)
        d, nonconcave = _newton_direction(run.box, m, current.G, free, min(0.5, np.sqrt(measure / first)), max_cg,
                                          counts, preconditioner)
        step = search.step(m, current, (1.0, 1.0), current.value, direction=d)
        counts["nonconcave_iterations"] += nonconcave
        if step is None:  # the gradient is an ascent direction whatever the curvature model says
            counts["gradient_steps"] += 1
            step = search.step(m, current, (1.0, 1.0), current.value)
        elif nonconcave and step[2][0] == 1.0:  # only along d: nonconcavity says nothing about G
            step = _extend(run, m, d, step)
        if step is None:
            termination = Termination.LINE_SEARCH_FAILED
            break
        m, current, _, measure = run.take(k, step)
    if measure <= target:
        termination = Termination.CONVERGED
    return run.finish(m, current.value, termination, target, **counts)


def _free_values(box: BoxProblem, m: ControlPoint, G: ControlPoint, width: float = 0.01) -> ControlPoint:
    """1.0 where a value is free, 0.0 where it is binding: within ``eps`` of a bound that G pushes
    against, ``eps = min(w, width (hi - lo))`` per block (xi, tau), w the largest projected step
    ``|P(m + G) - m|`` of the block (Bertsekas's rule; without the cap, a first step as wide as the
    box would make every pushed value binding); tau is binding when it is fixed (empty range)."""
    w = box.projected_step(m, G)
    lo, hi = (b if b is not None else sign * np.inf for b, sign in zip(box.xi_bounds, (-1, 1)))

    def free(x, g, lo, hi, step):
        eps = min(step, width * (hi - lo))
        return np.where(((x <= lo + eps) & (g < 0)) | ((x >= hi - eps) & (g > 0)), 0.0, 1.0)

    tau_range = box.tau_range
    tau_free = 0.0 if tau_range[0] == tau_range[1] else float(free(m.tau, G.tau, *tau_range, abs(w.tau)))
    return ControlPoint(free(m.xi, G.xi, lo, hi, np.abs(w.xi).max(initial=0.0)), tau_free)


def _masked(v: ControlPoint, mask: ControlPoint) -> ControlPoint:
    return ControlPoint(v.xi * mask.xi, v.tau * mask.tau)


def _newton_direction(box: BoxProblem, m: ControlPoint, G: ControlPoint, free: ControlPoint, forcing: float,
                      max_cg: int, counts: dict, preconditioner: CurvaturePairs) -> tuple[ControlPoint, bool]:
    """``(d, nonconcave)``: d solves ``-H d = G`` on the free values by conjugate gradients in
    the box's metric, preconditioned by ``preconditioner`` (relative residual ``forcing``, at most ``max_cg``
    products), and is G on the binding ones; ``nonconcave`` when CG met a direction p with
    ``<p, -H p> <= 0`` (d is then the CG iterate plus p, an ascent direction since
    ``<G, p> = <r, z> > 0`` in preconditioned CG). The products' pairs ``(p, -H p)`` of positive
    curvature join the preconditioner's pairs for the next direction."""
    metric = box.metric
    r = _masked(G, free)
    z = _masked(preconditioner(r), free)
    x, p, rz = r * 0.0, z, metric.inner(r, z)
    stop, nonconcave, pairs = forcing * metric.norm(r), False, []
    for _ in range(max_cg if rz > 0 else 0):
        Hp = _hessian_product(box, m, G, p, counts)
        if Hp is None:  # the state solver fails at m + h p
            break
        Hp = _masked(Hp, free)
        curvature = metric.inner(p, Hp)
        if curvature <= 0:
            x, nonconcave = x + p, True
            break
        pairs.append((p, Hp, curvature))
        a = rz / curvature
        x, r = x + p * a, r - Hp * a
        if metric.norm(r) <= stop:
            break
        z = _masked(preconditioner(r), free)
        rz_next = metric.inner(r, z)
        p, rz = z + p * (rz_next / rz), rz_next
    preconditioner.add(pairs)
    if metric.norm(x) == 0.0:
        x = _masked(G, free)
    return x + _masked(G, ControlPoint(1.0 - free.xi, 1.0 - free.tau)), nonconcave


def _hessian_product(box: BoxProblem, m: ControlPoint, G: ControlPoint, v: ControlPoint,
                     counts: dict) -> ControlPoint | None:
    """``-H v`` (H the Hessian of J in the box's metric) by a forward difference of the gradient (not
    cached); None where the state solver fails at the difference point."""
    size = max(np.abs(v.xi).max(initial=0.0), abs(v.tau))
    h = np.sqrt(np.finfo(float).eps) * (1.0 + max(np.abs(m.xi).max(initial=0.0), abs(m.tau))) / size
    counts["hessian_products"] += 1
    try:
        _, g = box.J.value_and_gradient(m + v * h)
    except SolverError:
        return None
    return (box.metric.gradient(g) - G) * (-1.0 / h)


def _tau_curvature(run: Run, m: ControlPoint, current, counts: dict) -> float:
    """``|d^2 J / d tau^2|`` at m (``current`` its evaluation, in a metric of tau weight 1): the tau-part of
    the Hessian product along tau (`_hessian_product`); 1.0 where tau is fixed, the difference point fails
    or the curvature is not a positive finite number."""
    if run.box.tau_range[0] == run.box.tau_range[1]:
        return 1.0
    Hv = _hessian_product(run.box, m, current.G, ControlPoint(np.zeros_like(m.xi), 1.0), counts)
    curvature = abs(Hv.tau) if Hv is not None else 0.0
    return float(curvature) if np.isfinite(curvature) and curvature > 0 else 1.0


def _extend(run: Run, m: ControlPoint, d: ControlPoint, step: tuple, max_doublings: int = 20) -> tuple:
    """Double a full step ``(trial, evaluation, alpha)`` along a direction of nonconcavity d while J increases
    and the projected point moves."""
    trial, out, alpha = step
    for _ in range(max_doublings):
        wider = run.box.project(m + d * (2.0 * alpha[0]))
        if np.array_equal(wider.xi, trial.xi) and wider.tau == trial.tau:
            break
        wider_out = run.try_evaluate(wider)
        if wider_out is None or wider_out.value <= out.value:
            break
        trial, out, alpha = wider, wider_out, (2.0 * alpha[0], 2.0 * alpha[1])
    return trial, out, alpha

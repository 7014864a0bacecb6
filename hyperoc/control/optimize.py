"""Optimizers for ``max_{xi, tau} J(xi, tau)``: the paper's Algorithm 1 (and its spectral projected
gradient variant), L-BFGS-B, and projected Newton-CG, all with bounds.

All work on `ControlPoint` m = (xi~, tau) with the inner product of the control space
(`hyperoc.control.control_space.ControlSpace`: L2 or H^1 in time, times L2(omega), plus tau^2), keep
tau inside ``[tau_margin, T - eps - tau_margin]``, and treat a trial point where the state solver
fails as a rejected step (halved), never as a fatal error.

Checkpoint and resume: `EvaluationCache` stores every evaluation ``(m, J, gradient)`` atomically
in a folder. The optimizers are deterministic, so a resumed run starts again from the first
iterate and replays the cached evaluations (no PDE solve) up to where it stopped: it ends exactly
where an uninterrupted run ends.
"""

from __future__ import annotations

import hashlib
import time
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.optimize as sopt

from ..errors import InputError, SolverError
from ..io import read_npz, write_npz
from .control_space import ControlSpace
from .reduced import ControlPoint, ReducedFunctional

__all__ = ["OptimizationResult", "EvaluationCache", "BBStepRule", "barzilai_borwein", "lbfgsb", "newton_cg",
           "stationarity", "tau_scaling"]


@dataclass
class OptimizationResult:
    """Final point, objective, convergence flag (``message``: why it stopped) and per-iteration
    histories; ``best``: ``{"point", "objective", "iteration"}`` of an earlier iterate with a higher
    J than the final one (a non-monotone method can end below its best value), else None."""

    point: ControlPoint
    objective: float
    iterations: int
    converged: bool
    message: str
    history: dict = field(default_factory=lambda: {"objective": [], "grad_norm": [], "tau": [], "step": []})
    wall_time: float = 0.0
    evaluations: dict = field(default_factory=dict)
    failed_trials: int = 0
    best: dict | None = None

    def summary(self) -> dict:
        best = None if self.best is None else {"objective": float(self.best["objective"]),
                                               "iteration": int(self.best["iteration"]),
                                               "tau": float(self.best["point"].tau)}
        return {
            "tau": float(self.point.tau),
            "objective": float(self.objective),
            "iterations": int(self.iterations),
            "converged": bool(self.converged),
            "message": self.message,
            "grad_norm_history": [float(g) for g in self.history["grad_norm"]],
            "objective_history": [float(j) for j in self.history["objective"]],
            "tau_history": [float(t) for t in self.history["tau"]],
            "step_history": [float(s) for s in self.history["step"]],
            "wall_time_s": float(self.wall_time),
            "evaluations": dict(self.evaluations),
            "failed_trials": int(self.failed_trials),
            "best": best,
        }


class EvaluationCache:
    """``(J, Riesz gradient)`` of every evaluated point, on disk (one atomic NPZ per point) or in memory.

    An entry that cannot be read back (not an NPZ archive, arrays missing, non-finite, or a
    gradient of another shape than the point's) is reported (`RuntimeWarning`), deleted and
    recomputed: a damaged cache costs evaluations, never the run.
    """

    def __init__(self, J: ReducedFunctional, directory=None):
        self.J, self.dir = J, Path(directory) if directory is not None else None
        self.memory: dict = {}
        self.hits = 0
        if self.dir is not None:
            self.dir.mkdir(parents=True, exist_ok=True)

    @staticmethod
    def key(m: ControlPoint) -> str:
        h = hashlib.sha256(np.ascontiguousarray(m.xi, dtype=np.float64).tobytes())
        h.update(np.float64(m.tau).tobytes())
        return h.hexdigest()[:32]

    @staticmethod
    def read_entry(path: Path) -> tuple[float, ControlPoint]:
        """``(J, gradient)`` stored in ``path``; `ValueError` naming the damage if it is not a
        complete entry."""
        try:
            data = read_npz(path)
        except (OSError, EOFError, ValueError, zipfile.BadZipFile) as err:
            raise ValueError(f"unreadable: {type(err).__name__}") from None
        missing = {"J", "gxi", "gtau"} - set(data)
        if missing:
            raise ValueError(f"missing array(s) {sorted(missing)}")
        J, gxi, gtau = data["J"], data["gxi"], data["gtau"]
        if J.shape != () or gtau.shape != () or gxi.ndim != 2:
            raise ValueError("arrays of the wrong shape")
        if not (np.isfinite(J) and np.isfinite(gtau) and np.all(np.isfinite(gxi))):
            raise ValueError("non-finite values")
        return float(J), ControlPoint(gxi.astype(np.float64), float(gtau))

    @classmethod
    def scan(cls, directory) -> tuple[int, list]:
        """``(count, dropped)``: the readable entries of a cache folder, and ``(path, reason)`` for
        each damaged one, which is deleted (the run will recompute it)."""
        directory = Path(directory)
        if not directory.is_dir():
            return 0, []
        count, dropped = 0, []
        for path in sorted(directory.glob("*.npz")):
            try:
                cls.read_entry(path)
                count += 1
            except ValueError as err:
                path.unlink(missing_ok=True)
                dropped.append((path, str(err)))
        return count, dropped

    def __call__(self, m: ControlPoint) -> tuple[float, ControlPoint]:
        k = self.key(m)
        if k in self.memory:
            self.hits += 1
            return self.memory[k]
        path = self.dir / f"{k}.npz" if self.dir is not None else None
        out = self._cached(path, m) if path is not None and path.exists() else None
        if out is not None:
            self.hits += 1
        else:
            out = self.J.value_and_gradient(m)
            if path is not None:
                write_npz(path, J=np.float64(out[0]), gxi=out[1].xi, gtau=np.float64(out[1].tau))
        self.memory[k] = out
        return out

    def _cached(self, path: Path, m: ControlPoint) -> tuple[float, ControlPoint] | None:
        """The entry of ``m`` in ``path``, or None (reported, deleted) if it is damaged."""
        try:
            value, g = self.read_entry(path)
            if g.xi.shape != np.shape(m.xi):
                raise ValueError(f"gradient of shape {g.xi.shape}, the point has {np.shape(m.xi)}")
        except ValueError as err:
            warnings.warn(f"damaged evaluation cache entry {path} ({err}): dropped, recomputed", RuntimeWarning,
                          stacklevel=3)
            path.unlink(missing_ok=True)
            return None
        return value, g


def _project(J: ReducedFunctional, m: ControlPoint, tau_range, xi_bounds=(None, None)) -> ControlPoint:
    """Projection onto the admissible set: tau in tau_range = (lo, hi), xi in xi_bounds."""
    lo, hi = tau_range
    xi = (m.xi if xi_bounds == (None, None)
          else np.clip(m.xi, *(b if b is not None else s * np.inf for b, s in zip(xi_bounds, (-1, 1)))))
    return ControlPoint(xi, float(np.clip(m.tau, lo, hi)))


def stationarity(J: ReducedFunctional, m: ControlPoint, g: ControlPoint, tau_range, xi_bounds=(None, None)) -> float:
    """``|| P(m + G) - m ||`` in the optimizers' metric (`_metric`; G the gradient there, from J's
    gradient g): the projected gradient norm, zero exactly at the KKT points; ``||G||`` when no bound
    is active."""
    metric = _metric(J, xi_bounds)
    return _projected_norm(J, metric, m, metric.gradient(g), tau_range, xi_bounds)


def _metric(J: ReducedFunctional, xi_bounds):
    """`ControlSpace.metric` of J's control space: the lumped one when xi has a bound (so that
    projections are nodal clips), else the space's own."""
    return J.space.metric(bounded=tuple(xi_bounds) != (None, None))


def _projected_norm(J, metric, m: ControlPoint, G: ControlPoint, tau_range, xi_bounds) -> float:
    """``|| P(m + G) - m ||`` in ``metric``, G the gradient in ``metric``."""
    return metric.norm(_project(J, m + G, tau_range, xi_bounds) - m)


def _tau_range(J: ReducedFunctional, tau_margin: float | None, fix_tau: bool, tau0: float) -> tuple:
    """Admissible tau: ``[margin, T - eps - margin]`` (default margin: two mean steps), or ``tau0`` alone."""
    if fix_tau:
        return (float(tau0), float(tau0))
    margin = 2.0 * float(J.transform.T) / J.N if tau_margin is None else tau_margin
    return (margin, J.transform.T - J.transform.eps - margin)


def _record(res: OptimizationResult, value: float, m: ControlPoint, step: float, gnorm: float):
    res.history["objective"].append(float(value))
    res.history["grad_norm"].append(float(gnorm))
    res.history["tau"].append(float(m.tau))
    res.history["step"].append(float(step))


def _in_metric(cache: EvaluationCache, metric):
    """``evaluate(m) -> (J, J's gradient, the gradient in metric)`` through the cache."""
    def evaluate(m):
        value, g = cache(m)
        return value, g, metric.gradient(g)
    return evaluate


def _first_iterate(J, metric, evaluate, m0, tau_range, xi_bounds, res):
    """``(m, J(m), G, measure)`` at the projected start, recorded in res; `SolverError` if the state
    solver fails there."""
    m = _project(J, m0, tau_range, xi_bounds)
    first = _safe_eval(evaluate, m)
    if first is None:
        raise SolverError(0, 0.0, "initial point", "the state solver fails at the initial control")
    value, _, G = first
    gnorm = _projected_norm(J, metric, m, G, tau_range, xi_bounds)
    _record(res, value, m, 0.0, gnorm)
    return m, value, G, gnorm


def _take(J, metric, res, k, step, tau_range, xi_bounds, callback):
    """Move to an accepted ``step = (m, (J, g, G), alpha)``: record iteration k and call back.
    Returns ``(m, J(m), G, alpha, measure)``."""
    m, (value, _, G), alpha = step
    gnorm = _projected_norm(J, metric, m, G, tau_range, xi_bounds)
    res.iterations = k
    _record(res, value, m, alpha[0], gnorm)
    if callback is not None:
        callback(k, m, value, gnorm)
    return m, value, G, alpha, gnorm


def _evaluations(J: ReducedFunctional, cache_hits: int, **counts) -> dict:
    """``OptimizationResult.evaluations``: J's state and adjoint solves, the cache's hits, method counts."""
    return {"state_solves": J.counts["state"], "adjoint_solves": J.counts["adjoint"], "cache_hits": cache_hits,
            **counts}


def _safe_eval(evaluate, m):
    """Evaluation, or None when the state solver fails at m (the step is then rejected)."""
    try:
        return evaluate(m)
    except SolverError:
        return None


def barzilai_borwein(J: ReducedFunctional, m0: ControlPoint, *, gtol: float = 1e-6, gtol_abs: float = 0.0,
                     max_iter: int = 200, tau_margin: float | None = None, armijo: float = 0.5,
                     max_backtracks: int = 30, xi_bounds=(None, None), fix_tau: bool = False,
                     steps: str = "joint", bb_step: str = "bb1", nonmonotone: int = 0, cache_dir=None,
                     callback=None) -> OptimizationResult:
    """The paper's Algorithm 1 (maximization): one Armijo step along G0, then Barzilai-Borwein steps.

    With ``xi_bounds`` the iterates are projected onto the box (projected BB, the paper's Remark
    ``rk-box`` as a pointwise bound); ``||G||`` is then the projected gradient norm
    ``||P(m + G) - m||``, and G, the steps and the BB inner products are those of the lumped-mass
    metric (`hyperoc.control.control_space.LumpedMetric`: the nodal clip is the projection there, so
    the iteration's fixed points are the KKT points). Stops when it is ``<= max(gtol ||G0||, gtol_abs)``
    or after ``max_iter`` iterations. ``fix_tau`` optimizes the control only (tau stays at ``m0.tau``). The BB step
    is ``alpha = <s, s> / <s, -y>`` (s = m_k - m_{k-1}, y = G_k - G_{k-1}); when it is not positive
    (J locally not concave along s) the iteration takes an Armijo step from ``|s| / |y|``.
    A trial point where the state solver fails is rejected and its step halved.
    ``callback(k, m, J(m), measure)`` after iteration k, with the stopping test's measure (as recorded in
    ``history["grad_norm"]``).

    ``steps = "joint"`` is the paper's single step for (xi, tau). ``steps = "blockwise"`` takes one
    BB step for xi and one for tau (``<s_xi, s_xi> / <s_xi, -y_xi>`` and ``s_tau / -y_tau``): a
    diagonal preconditioner for the usual case where the curvature of J in tau (seconds^-2, from
    p'') and in xi (about alpha) differ by orders of magnitude, which the joint step can only
    resolve by many iterations.

    ``bb_step`` chooses between the two step lengths of Barzilai and Borwein (1988) (`BBStepRule`):
    ``"bb1"`` (the long step above, default), ``"bb2"`` (the short step ``<s, -y> / <y, y>``) or
    ``"abbmin"``, the adaptive alternation of Frassoldati, Zanni and Zanghirati (2008).

    ``nonmonotone = M > 0`` makes it the spectral projected gradient method of Birgin, Martinez and
    Raydan (SIAM J. Optim. 10, 2000): every BB step must pass the nonmonotone Armijo test of Grippo,
    Lampariello and Lucidi, ``J(trial) >= min(J_k, ..., J_{k-M+1}) + 1e-4 <G, trial - m>``, else it
    is halved. The paper's Algorithm 1 (``M = 0``) accepts every BB step where J is concave along s,
    so J can fall far below its best value; with SPG the least J over a window never decreases.
    (Birgin et al. prove convergence to stationary points on convex sets for BB steps kept in a
    fixed interval ``[a_min, a_max]``; the steps here are not clipped.)
    """
    if steps not in ("joint", "blockwise"):
        raise InputError(f"steps must be 'joint' or 'blockwise', got {steps!r}")
    rules = (BBStepRule(bb_step), BBStepRule(bb_step))
    if isinstance(nonmonotone, bool) or not isinstance(nonmonotone, int) or nonmonotone < 0:
        raise InputError(f"nonmonotone must be an integer >= 0 (0: the paper's Algorithm 1), got {nonmonotone!r}")
    start = time.perf_counter()
    tau_range = _tau_range(J, tau_margin, fix_tau, m0.tau)
    metric = _metric(J, xi_bounds)
    cache = EvaluationCache(J, cache_dir)
    evaluate = _in_metric(cache, metric)
    res = OptimizationResult(m0, np.nan, 0, False, "")
    m, value, G, gnorm = _first_iterate(J, metric, evaluate, m0, tau_range, xi_bounds, res)
    target = max(gtol * gnorm, gtol_abs)
    m_prev = G_prev = None
    alpha = (1.0, 1.0)
    for k in range(1, max_iter + 1):
        if gnorm <= target:
            res.converged, res.message = True, f"||G|| <= {target:.3g}"
            break
        concave = False
        if m_prev is not None:
            alpha, concave = _bb_steps(metric, m - m_prev, G - G_prev, steps == "blockwise", alpha, rules)
        window = res.history["objective"][-nonmonotone:] if nonmonotone else [value]
        reference = min(window) if nonmonotone or not concave else None
        step = _ascent_step(J, metric, evaluate, m, value, G, alpha, tau_range, xi_bounds, armijo, max_backtracks,
                            reference=reference, res=res)
        if step is None:
            res.message = "no admissible step (state solver fails or no ascent along G)"
            break
        m_prev, G_prev = m, G
        m, value, G, alpha, gnorm = _take(J, metric, res, k, step, tau_range, xi_bounds, callback)
    else:
        res.message = f"maximum number of iterations ({max_iter}) reached"
    res.point, res.objective = m, value
    res.converged = res.converged or gnorm <= target
    res.wall_time = time.perf_counter() - start
    res.evaluations = _evaluations(J, cache.hits)
    return res


class BBStepRule:
    """Step length of one block from ``ss = <s, s>``, ``sy = <s, y>``, ``yy = <y, y>`` (s = m_k - m_{k-1},
    y = G_k - G_{k-1}; maximization, so ``-sy > 0`` where J is concave along s).

    ``"bb1"``: ``a1 = ss / -sy``; ``"bb2"``: ``a2 = -sy / yy`` (``a2 <= a1`` by Cauchy-Schwarz);
    ``"abbmin"`` (ABBmin, Frassoldati, Zanni, Zanghirati, J. Ind. Manag. Optim. 4 (2008)): ``a1`` when
    ``a2 / a1 >= ratio``, else the smallest ``a2`` of the last ``memory`` iterations. A small ``a2 / a1``
    (the cosine squared between s and y) means s is far from an eigenvector of the Hessian; the
    short step then damps the components of the large eigenvalues that the long step amplifies,
    which is what makes plain BB1 irregular on stiff problems.
    """

    RULES = ("bb1", "bb2", "abbmin")

    def __init__(self, rule: str = "bb1", memory: int = 3, ratio: float = 0.8):
        if rule not in self.RULES:
            raise InputError(f"bb_step must be one of {', '.join(self.RULES)}, got {rule!r}")
        self.rule, self.memory, self.ratio = rule, memory, ratio
        self.short_steps: list[float] = []

    def __call__(self, ss: float, sy: float, yy: float, previous: float) -> tuple[float, bool]:
        """``(alpha, concave)``; where J is not concave along s, the scale-free ``|s| / |y|``."""
        if ss == 0.0:
            return previous, True
        if sy >= 0:
            return float(np.sqrt(ss / max(yy, 1e-300))), False
        long_step, short_step = ss / -sy, -sy / yy
        self.short_steps = (self.short_steps + [short_step])[-self.memory:]
        if self.rule == "bb1" or (self.rule == "abbmin" and short_step / long_step >= self.ratio):
            return long_step, True
        return (short_step if self.rule == "bb2" else min(self.short_steps)), True


def _bb_steps(metric, s: ControlPoint, y: ControlPoint, blockwise: bool, previous: tuple,
              rules: tuple) -> tuple[tuple[float, float], bool]:
    """Step sizes ``(alpha_xi, alpha_tau)`` from ``s = m_k - m_{k-1}``, ``y = G_k - G_{k-1}`` (inner
    products of ``metric``) by the
    `BBStepRule` pair ``rules`` (the first one alone for the joint step), and whether J is concave
    along s (every used curvature ``<s, -y>`` positive).

    Where J is not concave along s the step is the scale-free ``|s| / |y|`` (then searched
    monotonically); a block that did not move (tau fixed, xi held by its bounds) keeps its
    ``previous`` step.
    """
    if not blockwise:
        a, concave = rules[0](metric.inner(s, s), metric.inner(s, y), metric.inner(y, y), previous[0])
        return (a, a), concave
    sx, yx = ControlPoint(s.xi, 0.0), ControlPoint(y.xi, 0.0)
    a_xi, c_xi = rules[0](metric.inner(sx, sx), metric.inner(sx, yx), metric.inner(yx, yx), previous[0])
    a_tau, c_tau = rules[1](s.tau**2, s.tau * y.tau, y.tau**2, previous[1])
    return (a_xi, a_tau), c_xi and c_tau


def _ascent_step(J, metric, evaluate, m, value, G, alpha, tau_range, xi_bounds, armijo, max_backtracks, reference,
                 res, direction=None):
    """Trial ``P(m + (alpha_xi d_xi, alpha_tau d_tau))``, d = ``direction`` (default G, the gradient in
    ``metric``); backtrack both steps on solver failure, and, unless ``reference`` is None, on lack of
    ascent over it (Armijo: ``J(m) + increase >= reference + 1e-4 <G, s>``, s = trial - m, the increase
    ``J(trial) - J(m)`` as `increase` judges it from ``value = J(m)``; reference = J(m) is the monotone
    test). Returns ``(trial, evaluate(trial), alpha)`` or None."""
    a_xi, a_tau = alpha
    d = G if direction is None else direction
    for _ in range(max_backtracks):
        trial = _project(J, m + ControlPoint(a_xi * d.xi, a_tau * d.tau), tau_range, xi_bounds)
        out = _safe_eval(evaluate, trial)
        if out is None:
            res.failed_trials += 1
        elif reference is None or _sufficient_increase(metric, value, G, out, trial - m, reference):
            return trial, out, (a_xi, a_tau)
        a_xi, a_tau = a_xi * armijo, a_tau * armijo
    return None


def _sufficient_increase(metric, value: float, G: ControlPoint, out, s: ControlPoint, reference: float) -> bool:
    """Armijo's test of the step s from m (J(m) = value, gradient G) to the trial ``out = (J, g, G)``:
    ``J(m) + increase >= reference + 1e-4 <G, s>``, the increase from `increase`."""
    slope = metric.inner(G, s)
    return value + increase(value, out[0], slope, metric.inner(out[2], s)) >= reference + 1e-4 * slope


#: Relative change of J below which the line searches judge a step by J's gradient (`increase`): the
#: epsilon of the approximate Wolfe conditions of Hager and Zhang (SIAM J. Optim. 16, 2005), their default.
VALUE_RESOLUTION = 1e-6


def increase(value: float, trial_value: float, slope: float, trial_slope: float) -> float:
    """``J(m + s) - J(m)`` as the line searches judge it: the difference of the values ``trial_value - value``,
    or, where that is at most ``VALUE_RESOLUTION |J(m)|``, the trapezoid rule along the segment,
    ``(slope + trial_slope) / 2`` with ``slope = dJ(m).s`` and ``trial_slope = dJ(m + s).s``.

    Why: near a maximizer a step's increase is ``~ eps^2 / (2 c)`` (eps the projected gradient, c the
    curvature along the step), which for a stopping test ``eps <= 1e-6 ||G0||`` falls below the noise of J's
    evaluation. The pressure J reads is a Lagrange multiplier, a derivative quantity whose round-off is
    hundreds of ulps (the bar of `hyperoc.control.problems.vibrating_bar`: J varies by 8e-16, 200 ulps, over
    relative perturbations 1e-15 of xi), so a test on the values alone ends by chance
    (L-BFGS-B's "no reduction", Newton-CG's "no admissible step") where the gradient still decides: the
    trapezoid rule's error is ``O(|s|^3)`` and that of J's exact gradient far below the value's
    (Hager and Zhang's approximate Armijo condition)."""
    change = trial_value - value
    if abs(change) > VALUE_RESOLUTION * abs(value):
        return change
    return 0.5 * (slope + trial_slope)


def tau_scaling(J: ReducedFunctional, tau_scale: float | str, tau_range, xi_bounds) -> float:
    """The factor c of L-BFGS-B's variable ``c tau`` (the xi variables being scaled to the L2 geometry).

    ``"range"``: with finite bounds ``lo < xi < hi``, the admissible tau interval (length ``L_tau``)
    gets the length of the xi box's diagonal in L2(0,2; L2(omega)): ``c = (hi - lo) sqrt(|Q|) /
    L_tau``, ``|Q| = 2 |omega|`` per control component (s in (0, 2); the sum of the control mass
    matrix is |omega| per component); both blocks are normalized to their ranges, as
    bound-constrained codes commonly normalize variables. Why: tau and xi have unrelated units, while
    scipy's line search and L-BFGS's initial Hessian ``gamma I`` treat all variables alike (the
    ventricle example converges to gtol = 1e-4 in 50-57 iterations for c from 10 to 67, and not in
    120 with c = 1 or 0.1: ``python bench/bench_tau_scale.py``). c = 1 without finite bounds or with tau fixed.
    A number: that factor (> 0).
    """
    if check_tau_scale(tau_scale) == "range":
        lo, hi = xi_bounds
        width = tau_range[1] - tau_range[0]
        if lo is None or hi is None or width <= 0:
            return 1.0
        return float((hi - lo) * np.sqrt(J.s_weights.sum() * J.model.control.mass.sum()) / width)
    return float(tau_scale)


def check_tau_scale(tau_scale):
    """``tau_scale`` itself if it is ``"range"`` or a finite positive number, else `InputError`."""
    if tau_scale == "range":
        return tau_scale
    if (isinstance(tau_scale, bool) or not isinstance(tau_scale, (int, float)) or not np.isfinite(tau_scale)
            or tau_scale <= 0):
        raise InputError(f"tau_scale must be 'range' or a positive number, got {tau_scale!r}")
    return tau_scale


def lbfgsb(J: ReducedFunctional, m0: ControlPoint, *, xi_bounds=(None, None), gtol: float = 1e-6,
           max_iter: int = 200, tau_margin: float | None = None, memory: int = 10, fix_tau: bool = False,
           cache_dir=None, callback=None, tau_scale: float | str = "range") -> OptimizationResult:
    """L-BFGS-B (scipy) on ``-J`` with bounds ``xi_bounds`` on every control value and tau in
    ``[tau_margin, T - eps - tau_margin]``.

    Variables are the coordinates of `ControlSpace.to_coordinates` (``z = U xi D^(1/2)``, U the Cholesky
    factor of the time part of the metric, D the lumped L2(omega) weights, positive also for P2), so
    that the Euclidean geometry scipy uses is the function-space one with the spatial mass lumped
    (mesh-independent iterations): H^1 in time when the objective penalizes ``d xi/dt`` and xi has no
    bounds, else L2 in time (bounds on xi are bounds on z only when the time factor is diagonal).
    tau is scaled by ``tau_scale`` (`tau_scaling`: by default, with bounds on xi, both blocks
    normalized to their admissible ranges). A trial point where the state solver fails gets the
    value ``-J_best + |J_best| + 1`` (worse than any point seen) and the last gradient, so the line
    search backtracks. scipy's line search sees ``J(iterate) + increase``, the increase from the iterate
    to the trial as `increase` judges it (by the gradient where J's change is at its resolution). Stops
    when the projected gradient norm is ``<= gtol`` times its initial value.
    ``callback(k, m, J(m), measure)`` after iteration k, with that norm (as in ``history["grad_norm"]``).
    """
    start = time.perf_counter()
    tau_range = _tau_range(J, tau_margin, fix_tau, m0.tau)
    tau_scale = tau_scaling(J, tau_scale, tau_range, xi_bounds)
    evaluate = EvaluationCache(J, cache_dir)
    coords = _coordinates(J, xi_bounds)
    shape = m0.xi.shape
    res = OptimizationResult(m0, np.nan, 0, False, "")
    # last: (m, J, gradient, J as judged) of the last evaluation; anchor: the same of scipy's current iterate
    state = {"target": None, "last": None, "anchor": None, "best": -np.inf, "grad": None}

    def to_point(z):  # projected: unscaling a value on a bound can leave it one ulp outside
        return _project(J, ControlPoint(coords.from_coordinates(z[:-1].reshape(shape)), float(z[-1]) / tau_scale),
                        tau_range, xi_bounds)

    def fun(z):
        m = to_point(z)
        out = _safe_eval(evaluate, m)
        if out is None:
            res.failed_trials += 1
            return -state["best"] + abs(state["best"]) + 1.0, state["grad"]
        value, g = out
        dual = J.dual(g)  # dJ/dxi as a dual vector
        grad_z = -np.concatenate([coords.coordinate_gradient(dual.xi).ravel(), [dual.tau / tau_scale]])
        judged = value
        if state["anchor"] is not None:  # scipy's line search compares this value with its iterate's
            m_a, value_a, g_a, judged_a = state["anchor"]
            s = m - m_a
            judged = judged_a + increase(value_a, value, J.inner(g_a, s), J.inner(g, s))
        state["last"] = (m, value, g, judged)
        state["best"], state["grad"] = max(state["best"], value), grad_z
        return -judged, grad_z

    def cb(z):
        state["anchor"] = state["last"]
        m, value, g, _ = state["last"]
        gnorm = stationarity(J, m, g, tau_range, xi_bounds)
        res.iterations += 1
        _record(res, value, m, 0.0, gnorm)
        if callback is not None:
            callback(res.iterations, m, value, gnorm)
        if gnorm <= state["target"]:
            raise StopIteration

    lo, hi = xi_bounds
    scale = coords.to_coordinates(np.ones(shape)).ravel()  # diagonal whenever there are bounds
    bounds = [(None if lo is None else lo * s, None if hi is None else hi * s) for s in scale]
    bounds.append((tau_range[0] * tau_scale, tau_range[1] * tau_scale))
    m_init = _project(J, m0, tau_range, xi_bounds)
    z0 = np.concatenate([coords.to_coordinates(m_init.xi).ravel(), [m_init.tau * tau_scale]])
    if _safe_eval(evaluate, m_init) is None:
        raise SolverError(0, 0.0, "initial point", "the state solver fails at the initial control")
    fun(z0)
    state["anchor"] = state["last"]
    _, v_init, g_init, _ = state["last"]
    g0 = stationarity(J, m_init, g_init, tau_range, xi_bounds)
    state["target"] = gtol * g0
    _record(res, v_init, m_init, 0.0, g0)
    # ftol = 0: the projected gradient is the stopping test; scipy's relative-reduction test would end
    # the run where J's changes reach round-off, before it.
    out = sopt.minimize(fun, z0, jac=True, method="L-BFGS-B", bounds=bounds, callback=cb,
                        options={"maxiter": max_iter, "maxcor": memory, "gtol": 0.0, "ftol": 0.0})
    point = to_point(out.x)
    value, g = evaluate(point)
    gnorm = stationarity(J, point, g, tau_range, xi_bounds)
    res.point, res.objective = point, value
    res.converged = gnorm <= state["target"]
    res.message = "projected ||G|| <= gtol ||G0||" if res.converged else str(out.message)
    res.wall_time = time.perf_counter() - start
    res.evaluations = _evaluations(J, evaluate.hits)
    return res


def _coordinates(J: ReducedFunctional, xi_bounds) -> ControlSpace:
    """L-BFGS-B's coordinates: J's control space, or its L2-in-time version when xi has bounds."""
    if tuple(xi_bounds) == (None, None) or not J.space.regular_in_time:
        return J.space
    return J.space.l2_in_time()


def newton_cg(J: ReducedFunctional, m0: ControlPoint, *, xi_bounds=(None, None), gtol: float = 1e-6,
              gtol_abs: float = 0.0, max_iter: int = 100, max_cg: int = 20, tau_margin: float | None = None,
              fix_tau: bool = False,
              armijo: float = 0.5, max_backtracks: int = 30, cache_dir=None, callback=None) -> OptimizationResult:
    """Projected truncated Newton-CG (the projected Newton method of Bertsekas, SIAM J. Control Optim.
    20, 1982, with CG stopped at nonconcavity as in Steihaug's method): second-order steps from
    Hessian-vector products.

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
    29 iterations and 123 gradient evaluations instead of 46 and 285.
    The step ``P(m + alpha d)`` is searched by Armijo backtracking from alpha = 1, as in `barzilai_borwein`;
    where that fails (a poor curvature model: no ascent in ``max_backtracks`` halvings), the same search along G.

    Why: the bounded paper problem is not concave on its free values (J grows along some directions,
    so the maximizer sits on the bounds there) and ill-conditioned, where first-order steps make slow
    progress. When CG meets a direction p along which J is not concave (``<p, -H p> <= 0``) the
    direction is the CG iterate plus p, and a full step along it accepted by the search is doubled while
    J keeps increasing and the projection still moves the trial point (not a step of the fallback along G).

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
    start = time.perf_counter()
    tau_range = _tau_range(J, tau_margin, fix_tau, m0.tau)
    metric = _metric(J, xi_bounds)
    cache = EvaluationCache(J, cache_dir)
    evaluate = _in_metric(cache, metric)
    counts = {"hessian_products": 0, "nonconcave_iterations": 0, "gradient_steps": 0}
    res = OptimizationResult(m0, np.nan, 0, False, "")
    m, value, G, gnorm = _first_iterate(J, metric, evaluate, m0, tau_range, xi_bounds, res)
    target, preconditioner = max(gtol * gnorm, gtol_abs), CurvaturePairs(metric)
    g0 = gnorm
    for k in range(1, max_iter + 1):
        if gnorm <= target:
            break
        free = _free_values(J, m, G, tau_range, xi_bounds)
        d, nonconcave = _newton_direction(J, metric, m, G, free, min(0.5, np.sqrt(gnorm / g0)), max_cg, counts,
                                          preconditioner)
        search = dict(reference=value, res=res)
        step = _ascent_step(J, metric, evaluate, m, value, G, (1.0, 1.0), tau_range, xi_bounds, armijo,
                            max_backtracks, direction=d, **search)
        counts["nonconcave_iterations"] += nonconcave
        if step is None:  # the gradient is an ascent direction whatever the curvature model says
            counts["gradient_steps"] += 1
            step = _ascent_step(J, metric, evaluate, m, value, G, (1.0, 1.0), tau_range, xi_bounds, armijo,
                                max_backtracks, **search)
        elif nonconcave and step[2][0] == 1.0:  # only along d: nonconcavity says nothing about G
            step = _extend(J, evaluate, m, d, step, tau_range, xi_bounds)
        if step is None:
            res.message = "no admissible step (state solver fails or no ascent along the Newton direction nor G)"
            break
        m, value, G, _, gnorm = _take(J, metric, res, k, step, tau_range, xi_bounds, callback)
    res.converged = gnorm <= target
    res.message = ("projected ||G|| <= max(gtol ||G0||, gtol_abs)" if res.converged
                   else res.message or f"maximum number of iterations ({max_iter}) reached")
    res.point, res.objective = m, value
    res.wall_time = time.perf_counter() - start
    res.evaluations = _evaluations(J, cache.hits, **counts)
    return res


def _free_values(J, m: ControlPoint, G: ControlPoint, tau_range, xi_bounds, width: float = 0.01) -> ControlPoint:
    """1.0 where a value is free, 0.0 where it is binding: within ``eps`` of a bound that G pushes
    against, ``eps = min(w, width (hi - lo))`` per block (xi, tau), w the largest projected step
    ``|P(m + G) - m|`` of the block (Bertsekas's rule; without the cap, a first step as wide as the
    box would make every pushed value binding); tau is binding when it is fixed (empty range)."""
    w = _project(J, m + G, tau_range, xi_bounds) - m
    lo, hi = (b if b is not None else sign * np.inf for b, sign in zip(xi_bounds, (-1, 1)))

    def free(x, g, lo, hi, step):
        eps = min(step, width * (hi - lo))
        return np.where(((x <= lo + eps) & (g < 0)) | ((x >= hi - eps) & (g > 0)), 0.0, 1.0)

    tau_free = 0.0 if tau_range[0] == tau_range[1] else float(free(m.tau, G.tau, *tau_range, abs(w.tau)))
    return ControlPoint(free(m.xi, G.xi, lo, hi, np.abs(w.xi).max(initial=0.0)), tau_free)


def _masked(v: ControlPoint, mask: ControlPoint) -> ControlPoint:
    return ControlPoint(v.xi * mask.xi, v.tau * mask.tau)


def _newton_direction(J, metric, m, G, free, forcing, max_cg, counts,
                      preconditioner: "CurvaturePairs") -> tuple[ControlPoint, bool]:
    """``(d, nonconcave)``: d solves ``-H d = G`` on the free values by conjugate gradients in
    ``metric``, preconditioned by ``preconditioner`` (relative residual ``forcing``, at most ``max_cg``
    products), and is G on the binding ones; ``nonconcave`` when CG met a direction p with
    ``<p, -H p> <= 0`` (d is then the CG iterate plus p, an ascent direction since
    ``<G, p> = <r, z> > 0`` in preconditioned CG). The products' pairs ``(p, -H p)`` of positive
    curvature join the preconditioner's pairs for the next direction."""
    r = _masked(G, free)
    z = _masked(preconditioner(r), free)
    x, p, rz = r * 0.0, z, metric.inner(r, z)
    stop, nonconcave, pairs = forcing * metric.norm(r), False, []
    for _ in range(max_cg if rz > 0 else 0):
        Hp = _hessian_product(J, metric, m, G, p, counts)
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


class CurvaturePairs:
    """The limited-memory BFGS approximation of ``(-H)^-1`` from the last ``memory`` pairs
    ``(s, y = -H s)`` of the earlier CG solves (Morales and Nocedal, SIAM J. Optim. 10, 2000: automatic
    preconditioning): CG on the next Newton system, whose Hessian differs little, then needs fewer
    products for the directions the pairs already hold (the soft ones along the ridge among them).
    Without pairs it is the identity; it is symmetric positive definite since every pair has
    ``<s, y> > 0``. Applied by the two-loop recursion in ``metric``, with the initial scaling
    ``<s, y> / <y, y>`` of the newest pair."""

    def __init__(self, metric, memory: int = 20):
        self.metric, self.memory, self.pairs = metric, memory, []

    def add(self, pairs: list) -> None:
        """Append ``pairs`` ``[(s, y, <s, y>)]``, keeping the last ``memory``."""
        self.pairs = (self.pairs + pairs)[-self.memory:]

    def __call__(self, r: ControlPoint) -> ControlPoint:
        inner = self.metric.inner
        q, alphas = r, []
        for s, y, sy in reversed(self.pairs):
            a = inner(s, q) / sy
            q, alphas = q - y * a, [a, *alphas]
        if self.pairs:
            s, y, sy = self.pairs[-1]
            q = q * (sy / inner(y, y))
        for (s, y, sy), a in zip(self.pairs, alphas):
            q = q + s * (a - inner(y, q) / sy)
        return q


def _hessian_product(J, metric, m: ControlPoint, G: ControlPoint, v: ControlPoint, counts) -> ControlPoint | None:
    """``-H v`` (H the Hessian of J in ``metric``) by a forward difference of the gradient; None where
    the state solver fails at the difference point."""
    size = max(np.abs(v.xi).max(initial=0.0), abs(v.tau))
    h = np.sqrt(np.finfo(float).eps) * (1.0 + max(np.abs(m.xi).max(initial=0.0), abs(m.tau))) / size
    out = _safe_eval(J.value_and_gradient, m + v * h)
    counts["hessian_products"] += 1
    if out is None:
        return None
    return (metric.gradient(out[1]) - G) * (-1.0 / h)


def _extend(J, evaluate, m, d, step, tau_range, xi_bounds, max_doublings: int = 20):
    """Double a full step along a direction of nonconcavity while J increases and the projected point moves."""
    trial, out, alpha = step
    for _ in range(max_doublings):
        wider = _project(J, m + d * (2.0 * alpha[0]), tau_range, xi_bounds)
        if np.array_equal(wider.xi, trial.xi) and wider.tau == trial.tau:
            break
        wider_out = _safe_eval(evaluate, wider)
        if wider_out is None or wider_out[0] <= out[0]:
            break
        trial, out, alpha = wider, wider_out, (2.0 * alpha[0], 2.0 * alpha[1])
    return trial, out, alpha

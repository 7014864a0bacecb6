"""Optimizers for ``max_{xi, tau} J(xi, tau)``: the paper's Algorithm 1, and L-BFGS-B with bounds.

Both work on `ControlPoint` m = (xi~, tau) with the inner product of L2(0, 2; L2(omega)) x R, keep
tau inside ``[tau_margin, T - eps - tau_margin]``, and treat a trial point where the state solver
fails as a rejected step (halved), never as a fatal error.

Checkpoint and resume: `EvaluationCache` stores every evaluation ``(m, J, gradient)`` atomically
in a folder. Both optimizers are deterministic, so a resumed run starts again from the first
iterate and replays the cached evaluations (no PDE solve) up to where it stopped: it ends exactly
where an uninterrupted run ends.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.optimize as sopt

from .errors import HyperocError, InputError, SolverError
from .io import read_npz, write_npz
from .reduced import ControlPoint, ReducedFunctional

__all__ = ["OptimizationResult", "EvaluationCache", "barzilai_borwein", "lbfgsb"]


@dataclass
class OptimizationResult:
    """Final point, objective, convergence flag and per-iteration histories."""

    point: ControlPoint
    objective: float
    iterations: int
    converged: bool
    message: str
    history: dict = field(default_factory=lambda: {"objective": [], "grad_norm": [], "tau": [], "step": []})
    wall_time: float = 0.0
    evaluations: dict = field(default_factory=dict)
    failed_trials: int = 0

    def summary(self) -> dict:
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
        }


class EvaluationCache:
    """``(J, Riesz gradient)`` of every evaluated point, on disk (one atomic NPZ per point) or in memory."""

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

    def __call__(self, m: ControlPoint) -> tuple[float, ControlPoint]:
        k = self.key(m)
        if k in self.memory:
            self.hits += 1
            return self.memory[k]
        path = self.dir / f"{k}.npz" if self.dir is not None else None
        if path is not None and path.exists():
            data = read_npz(path)
            out = (float(data["J"]), ControlPoint(data["gxi"], float(data["gtau"])))
            self.hits += 1
        else:
            J, g = self.J.value_and_gradient(m)
            out = (J, g)
            if path is not None:
                write_npz(path, J=np.float64(J), gxi=g.xi, gtau=np.float64(g.tau))
        self.memory[k] = out
        return out


def _project_tau(J: ReducedFunctional, m: ControlPoint, margin: float) -> ControlPoint:
    lo, hi = margin, J.transform.T - J.transform.eps - margin
    return ControlPoint(m.xi, float(np.clip(m.tau, lo, hi)))


def _default_margin(J: ReducedFunctional) -> float:
    return 2.0 * float(J.transform.T) / J.N


def _record(res: OptimizationResult, J: ReducedFunctional, value: float, g: ControlPoint, m: ControlPoint, step: float):
    res.history["objective"].append(float(value))
    res.history["grad_norm"].append(J.norm(g))
    res.history["tau"].append(float(m.tau))
    res.history["step"].append(float(step))


def _safe_eval(evaluate, m):
    """Evaluation, or None when the state solver fails at m (the step is then rejected)."""
    try:
        return evaluate(m)
    except SolverError:
        return None


def barzilai_borwein(J: ReducedFunctional, m0: ControlPoint, *, gtol: float = 1e-6, gtol_abs: float = 0.0,
                     max_iter: int = 200, tau_margin: float | None = None, armijo: float = 0.5,
                     max_backtracks: int = 30, checkpoint=None, callback=None) -> OptimizationResult:
    """The paper's Algorithm 1 (maximization): one Armijo step along G0, then Barzilai-Borwein steps.

    Stops when ``||G|| <= max(gtol ||G0||, gtol_abs)`` or after ``max_iter`` iterations. The BB step
    is ``alpha = <s, s> / <s, -y>`` (s = m_k - m_{k-1}, y = G_k - G_{k-1}); when it is not positive
    (J locally not concave along s) the iteration takes an Armijo step from ``|s| / |y|``.
    A trial point where the state solver fails is rejected and its step halved.
    """
    start = time.perf_counter()
    margin = _default_margin(J) if tau_margin is None else tau_margin
    evaluate = EvaluationCache(J, checkpoint)
    res = OptimizationResult(m0, np.nan, 0, False, "")
    m = _project_tau(J, m0, margin)
    first = _safe_eval(evaluate, m)
    if first is None:
        raise SolverError(0, 0.0, "initial point", "the state solver fails at the initial control")
    value, g = first
    _record(res, J, value, g, m, 0.0)
    g0norm = J.norm(g)
    target = max(gtol * g0norm, gtol_abs)
    m_prev = g_prev = None
    alpha = 1.0
    for k in range(1, max_iter + 1):
        if J.norm(g) <= target:
            res.converged, res.message = True, f"||G|| <= {target:.3g}"
            break
        curv = 0.0
        if m_prev is not None:
            s, y = m - m_prev, g - g_prev
            curv = -J.inner(s, y)
            # BB1 step; where J is not concave along s, the scale-free |s|/|y| with a monotone search.
            alpha = J.inner(s, s) / curv if curv > 0 else J.norm(s) / max(J.norm(y), 1e-300)
        step = _ascent_step(J, evaluate, m, value, g, alpha, margin, armijo, max_backtracks,
                            monotone=(m_prev is None or curv <= 0), res=res)
        if step is None:
            res.message = "no admissible step (state solver fails or no ascent along G)"
            break
        m_prev, g_prev = m, g
        m, value, g, alpha = step
        res.iterations = k
        _record(res, J, value, g, m, alpha)
        if callback is not None:
            callback(k, m, value, g)
    else:
        res.message = f"maximum number of iterations ({max_iter}) reached"
    res.point, res.objective = m, value
    res.converged = res.converged or J.norm(g) <= target
    res.wall_time = time.perf_counter() - start
    res.evaluations = {"state_solves": J.counts["state"], "adjoint_solves": J.counts["adjoint"], "cache_hits": evaluate.hits}
    return res


def _ascent_step(J, evaluate, m, value, g, alpha, margin, armijo, max_backtracks, monotone, res):
    """Trial ``m + alpha G`` (tau projected); backtrack on solver failure, and on lack of ascent
    when ``monotone`` (Armijo with sufficient increase 1e-4 alpha ||G||^2)."""
    gg = J.inner(g, g)
    for _ in range(max_backtracks):
        trial = _project_tau(J, m + g * alpha, margin)
        out = _safe_eval(evaluate, trial)
        if out is None:
            res.failed_trials += 1
        elif not monotone or out[0] >= value + 1e-4 * alpha * gg:
            return trial, out[0], out[1], alpha
        alpha *= armijo
    return None


def lbfgsb(J: ReducedFunctional, m0: ControlPoint, *, xi_bounds=(None, None), gtol: float = 1e-6,
           max_iter: int = 200, tau_margin: float | None = None, memory: int = 10, checkpoint=None,
           callback=None) -> OptimizationResult:
    """L-BFGS-B (scipy) on ``-J`` with bounds ``xi_bounds`` on every control value and tau in
    ``[tau_margin, T - eps - tau_margin]``.

    Variables are scaled by the square roots of the lumped L2(0,2; L2(omega)) weights, so that the
    Euclidean geometry scipy uses approximates the function-space one (mesh-independent
    iterations). A point where the state solver fails returns ``-J = +inf`` equivalents (a large
    value), which makes the line search backtrack. Stops at ``||G|| <= gtol ||G0||``.
    """
    start = time.perf_counter()
    margin = _default_margin(J) if tau_margin is None else tau_margin
    evaluate = EvaluationCache(J, checkpoint)
    lumped = np.asarray(J.model.control.mass.sum(axis=1)).ravel()
    scale = np.sqrt(J.s_weights[:, None] * lumped[None, :])  # z = scale * xi
    shape = m0.xi.shape
    res = OptimizationResult(m0, np.nan, 0, False, "")
    state = {"g0": None, "last": None}

    def to_point(z):
        return ControlPoint(z[:-1].reshape(shape) / scale, float(z[-1]))

    def fun(z):
        m = to_point(z)
        out = _safe_eval(evaluate, m)
        if out is None:
            res.failed_trials += 1
            return 1e30, np.zeros_like(z)
        value, g = out
        dual = _dual(J, g)  # dJ/dxi as a dual vector
        grad_z = np.concatenate([(dual.xi / scale).ravel(), [dual.tau]])
        state["last"] = (m, value, g)
        if state["g0"] is None:
            state["g0"] = J.norm(g)
        return -value, -grad_z

    def cb(z):
        m, value, g = state["last"]
        res.iterations += 1
        _record(res, J, value, g, m, 0.0)
        if callback is not None:
            callback(res.iterations, m, value, g)
        if J.norm(g) <= gtol * state["g0"]:
            raise StopIteration

    lo, hi = xi_bounds
    bounds = [(None if lo is None else lo * s, None if hi is None else hi * s) for s in scale.ravel()]
    bounds.append((margin, J.transform.T - J.transform.eps - margin))
    z0 = np.concatenate([(m0.xi * scale).ravel(), [np.clip(m0.tau, margin, J.transform.T - J.transform.eps - margin)]])
    first = fun(z0)
    m_init, v_init, g_init = state["last"]
    _record(res, J, v_init, g_init, m_init, 0.0)
    if first[0] >= 1e30:
        raise SolverError(0, 0.0, "initial point", "the state solver fails at the initial control")
    out = sopt.minimize(fun, z0, jac=True, method="L-BFGS-B", bounds=bounds, callback=cb,
                        options={"maxiter": max_iter, "maxcor": memory, "gtol": 0.0, "ftol": 1e-15})
    m, value, g = state["last"]
    final = evaluate(to_point(out.x))
    res.point, res.objective = to_point(out.x), final[0]
    res.converged = J.norm(final[1]) <= gtol * state["g0"] or res.iterations == 0 and J.norm(final[1]) == 0
    res.message = "||G|| <= gtol ||G0||" if res.converged else str(out.message)
    res.wall_time = time.perf_counter() - start
    res.evaluations = {"state_solves": J.counts["state"], "adjoint_solves": J.counts["adjoint"], "cache_hits": evaluate.hits}
    return res


def _dual(J: ReducedFunctional, g: ControlPoint) -> ControlPoint:
    """Inverse of the Riesz map: the derivative dJ as a dual vector."""
    Mx = (J.model.control.mass @ g.xi.T).T
    return ControlPoint(J.s_weights[:, None] * Mx, g.tau)

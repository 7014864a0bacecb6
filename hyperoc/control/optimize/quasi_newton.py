"""L-BFGS-B (scipy) for ``max_{xi, tau} J(xi, tau)`` with bounds, in coordinates where the Euclidean geometry
is the control space's."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize as sopt

from ...errors import SolverError
from ..reduced import ControlPoint, ReducedFunctional
from .box import BoxProblem, as_box
from .result import OptimizationResult, Termination
from .run import Run
from .search import increase

__all__ = ["lbfgsb"]


def lbfgsb(problem: ReducedFunctional | BoxProblem, m0: ControlPoint, *, xi_bounds=(None, None), gtol: float = 1e-6,
           max_iter: int = 200, memory: int = 10, tau_scale: float | str = "range", cache_dir=None,
           callback=None) -> OptimizationResult:
    """L-BFGS-B (scipy) on ``-J`` with bounds ``xi_bounds`` on every control value and tau in
    ``[tau_margin, T - eps - tau_margin]``; ``problem``: a reduced functional J with those bounds, or a
    `BoxProblem`, as in `barzilai_borwein`. ``memory``: the correction pairs L-BFGS keeps.

    Variables are the coordinates of `ControlSpace.to_coordinates` (``z = U xi D^(1/2)``, U the Cholesky
    factor of the time part of the metric, D the lumped L2(omega) weights, positive also for P2), so
    that the Euclidean geometry scipy uses is the function-space one with the spatial mass lumped
    (mesh-independent iterations): H^1 in time when the objective penalizes ``d xi/dt`` and xi has no
    bounds, else L2 in time (bounds on xi are bounds on z only when the time factor is diagonal).
    tau is scaled by ``tau_scale`` (`BoxProblem.tau_scale`: by default, with bounds on xi, both blocks
    normalized to their admissible ranges). A trial point where the state solver fails gets the
    value ``-J_best + |J_best| + 1`` (worse than any point seen) and the last gradient, so the line
    search backtracks. scipy's line search sees ``J(iterate) + increase``, the increase from the iterate
    to the trial as `increase` judges it (by the gradient where J's change is at its resolution). Stops
    when the projected gradient norm is ``<= gtol`` times its initial value.
    ``callback(k, m, J(m), measure)`` after iteration k, with that norm (as in ``history["grad_norm"]``).
    """
    box = as_box(problem, m0.tau, xi_bounds)
    J = box.J
    variables = _Variables(box, box.tau_scale(tau_scale), m0.xi.shape)
    run = Run(box, cache_dir, callback)
    # last: (m, evaluation, J as judged) of the last evaluation; anchor: the same of scipy's current iterate
    state = {"last": None, "anchor": None, "best": -np.inf, "grad": None, "target": None}

    def fun(z):
        m = variables.point(z)
        out = run.try_evaluate(m)
        if out is None:
            run.failed_trials += 1
            return -state["best"] + abs(state["best"]) + 1.0, state["grad"]
        grad_z = variables.gradient_of_minus_J(J.dual(out.g))
        judged = out.value
        if state["anchor"] is not None:  # scipy's line search compares this value with its iterate's
            m_a, out_a, judged_a = state["anchor"]
            s = m - m_a
            judged = judged_a + increase(out_a.value, out.value, J.inner(out_a.g, s), J.inner(out.g, s))
        state["last"] = (m, out, judged)
        state["best"], state["grad"] = max(state["best"], out.value), grad_z
        return -judged, grad_z

    def cb(z):
        state["anchor"] = state["last"]
        m, out, _ = state["last"]
        measure = box.stationarity(m, out.g)
        run.advance(run.iterations + 1, m, out.value, measure)
        if measure <= state["target"]:
            raise StopIteration

    m_init = box.project(m0)
    if run.try_evaluate(m_init) is None:
        raise SolverError(0, 0.0, "initial point", "the state solver fails at the initial control")
    z0 = variables.of(m_init)
    fun(z0)
    state["anchor"] = state["last"]
    first = state["last"][1]
    measure = box.stationarity(m_init, first.g)
    state["target"] = gtol * measure
    run.record(m_init, first.value, measure)
    # ftol = 0: the projected gradient is the stopping test; scipy's relative-reduction test would end
    # the run where J's changes reach round-off, before it.
    out = sopt.minimize(fun, z0, jac=True, method="L-BFGS-B", bounds=variables.bounds(), callback=cb,
                        options={"maxiter": max_iter, "maxcor": memory, "gtol": 0.0, "ftol": 0.0})
    point = variables.point(out.x)
    final = run.evaluate(point)
    if box.stationarity(point, final.g) <= state["target"]:
        return run.finish(point, final.value, Termination.CONVERGED, state["target"])
    return run.finish(point, final.value, _termination(out), state["target"], str(out.message))


def _termination(out: sopt.OptimizeResult) -> Termination:
    """Why scipy's L-BFGS-B stopped before the projected gradient met the test: its iteration or evaluation
    limit (status 1), a failed line search, or a test of its own."""
    if out.status == 1:
        return Termination.MAX_ITERATIONS
    return Termination.LINE_SEARCH_FAILED if "ABNORMAL" in str(out.message) else Termination.SOLVER_STOPPED


@dataclass(frozen=True)
class _Variables:
    """L-BFGS-B's variables ``z = (coordinates of xi, c tau)`` of the box's points (`BoxProblem.coordinates`;
    c: the tau scale), for controls of ``shape``."""

    box: BoxProblem
    tau_scale: float
    shape: tuple

    def of(self, m: ControlPoint) -> np.ndarray:
        """z of the point m."""
        return np.concatenate([self.box.coordinates.to_coordinates(m.xi).ravel(), [m.tau * self.tau_scale]])

    def point(self, z: np.ndarray) -> ControlPoint:
        """The point of z, projected: unscaling a value on a bound can leave it one ulp outside."""
        xi = self.box.coordinates.from_coordinates(z[:-1].reshape(self.shape))
        return self.box.project(ControlPoint(xi, float(z[-1]) / self.tau_scale))

    def gradient_of_minus_J(self, dual: ControlPoint) -> np.ndarray:
        """``d(-J)/dz`` from J's derivative as a dual vector (the chain rule of the coordinates)."""
        return -np.concatenate([self.box.coordinates.coordinate_gradient(dual.xi).ravel(), [dual.tau / self.tau_scale]])

    def bounds(self) -> list[tuple]:
        """scipy's bounds on z: those of xi scaled by the coordinates (diagonal whenever xi has bounds), and
        the tau range scaled by c."""
        lo, hi = self.box.xi_bounds
        scale = self.box.coordinates.to_coordinates(np.ones(self.shape)).ravel()
        bounds = [(None if lo is None else lo * s, None if hi is None else hi * s) for s in scale]
        return bounds + [(self.box.tau_range[0] * self.tau_scale, self.box.tau_range[1] * self.tau_scale)]

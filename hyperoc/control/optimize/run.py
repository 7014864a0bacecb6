"""What the three optimizers share around their iterations: the set-up (the bounded problem, the
evaluation cache, the clock) and the wrap-up (the frozen `OptimizationResult`)."""

from __future__ import annotations

import time
from typing import NamedTuple

from ...errors import SolverError
from ..reduced import ControlPoint
from .box import BoxProblem
from .cache import EvaluationCache
from .result import OptimizationResult, Termination


class Evaluation(NamedTuple):
    """J at a point, J's gradient g (the Riesz representative in J's control space) and G, the gradient in
    the box's metric."""

    value: float
    g: ControlPoint
    G: ControlPoint


class Run:
    """One optimization of ``box`` in progress: its evaluations (through the cache in ``cache_dir``), its
    histories, the failed trials, and ``callback(k, m, J(m), measure)`` after each iteration k."""

    def __init__(self, box: BoxProblem, cache_dir=None, callback=None):
        self.started = time.perf_counter()
        self.box, self.callback = box, callback
        self.cache = EvaluationCache(box.J, cache_dir)
        self.history = {"objective": [], "grad_norm": [], "tau": [], "step": []}
        self.iterations = 0
        self.failed_trials = 0

    def evaluate(self, m: ControlPoint) -> Evaluation:
        """`Evaluation` at m through the cache; `SolverError` where the state solver fails."""
        value, g = self.cache(m)
        return Evaluation(value, g, self.box.metric.gradient(g))

    def try_evaluate(self, m: ControlPoint) -> Evaluation | None:
        """`evaluate`, or None where the state solver fails at m (the caller rejects that point)."""
        try:
            return self.evaluate(m)
        except SolverError:
            return None

    def start(self, m0: ControlPoint) -> tuple[ControlPoint, Evaluation, float]:
        """``(m, evaluation, measure)`` at the projected start, recorded as iteration 0; `SolverError` if the
        state solver fails there."""
        m = self.box.project(m0)
        first = self.try_evaluate(m)
        if first is None:
            raise SolverError(0, 0.0, "initial point", "the state solver fails at the initial control")
        measure = self.box.projected_norm(m, first.G)
        self.record(m, first.value, measure)
        return m, first, measure

    def rescale(self, m: ControlPoint, evaluation: Evaluation, box: BoxProblem) -> tuple[Evaluation, float]:
        """Go on in ``box`` (the same problem in another metric) from the start m: ``(evaluation, measure)``
        at m in its metric, the recorded start's measure replaced."""
        self.box = box
        evaluation = Evaluation(evaluation.value, evaluation.g, box.metric.gradient(evaluation.g))
        measure = box.projected_norm(m, evaluation.G)
        self.history["grad_norm"][-1] = float(measure)
        return evaluation, measure

    def record(self, m: ControlPoint, value: float, measure: float, step: float = 0.0) -> None:
        """Append an iterate to the histories (``measure``: the stopping test's, ``step``: the step length)."""
        for name, x in (("objective", value), ("grad_norm", measure), ("tau", m.tau), ("step", step)):
            self.history[name].append(float(x))

    def advance(self, k: int, m: ControlPoint, value: float, measure: float, step: float = 0.0) -> None:
        """Iteration k ended at m: record it and call back."""
        self.iterations = k
        self.record(m, value, measure, step)
        if self.callback is not None:
            self.callback(k, m, value, measure)

    def take(self, k: int, step: tuple) -> tuple[ControlPoint, Evaluation, tuple, float]:
        """Move to the accepted ``step = (m, evaluation, alpha)`` of a line search as iteration k (`advance`);
        returns ``(m, evaluation, alpha, measure)``."""
        m, out, alpha = step
        measure = self.box.projected_norm(m, out.G)
        self.advance(k, m, out.value, measure, alpha[0])
        return m, out, alpha, measure

    def finish(self, m: ControlPoint, value: float, termination: Termination, tolerance: float, detail: str = "",
               **counts) -> OptimizationResult:
        """The result at m (J(m) = value); ``counts``: the method's own entries of ``evaluations``."""
        J = self.box.J
        evaluations = {"state_solves": J.counts["state"], "adjoint_solves": J.counts["adjoint"],
                       "cache_hits": self.cache.hits, **counts}
        return OptimizationResult(m, value, self.iterations, termination, tolerance, detail,
                                  history={k: tuple(v) for k, v in self.history.items()},
                                  wall_time=time.perf_counter() - self.started, evaluations=evaluations,
                                  failed_trials=self.failed_trials)

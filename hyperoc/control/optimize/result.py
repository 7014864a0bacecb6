"""What the optimizers return: the final point, why they stopped (`Termination`) and their histories."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from ..reduced import ControlPoint

__all__ = ["Termination", "OptimizationResult"]


class Termination(enum.Enum):
    """Why an optimizer stopped; only `CONVERGED` means the stopping test was met."""

    #: the projected gradient norm ``||P(m + G) - m||`` is at most the run's tolerance
    CONVERGED = "converged"
    #: the iteration limit was reached before the test was met
    MAX_ITERATIONS = "max_iterations"
    #: no trial step is admissible: the state solver fails on every trial or none increases J enough
    LINE_SEARCH_FAILED = "line_search_failed"
    #: L-BFGS-B ended by a test of its own (scipy's words in `OptimizationResult.detail`) before the run's test
    SOLVER_STOPPED = "solver_stopped"


@dataclass(frozen=True)
class OptimizationResult:
    """The final point m = (xi, tau), J(m), the iterations taken and why the run stopped.

    ``tolerance``: the stopping test's bound on the projected gradient norm; ``detail``: the words of the
    backend (scipy) where it stopped on its own, else empty. ``history``: per iteration (index 0 the
    projected start) ``"objective"`` (J), ``"grad_norm"`` (the stopping test's measure), ``"tau"`` and
    ``"step"`` (the accepted step length, 0 where the method has none). ``evaluations``: J's state and
    adjoint solves, the cache's hits and the method's own counts. ``best``: ``{"point", "objective",
    "iteration"}`` of an earlier iterate with a higher J than the final one (a non-monotone method can end
    below its best value), else None.
    """

    point: ControlPoint
    objective: float
    iterations: int
    termination: Termination
    tolerance: float = 0.0
    detail: str = ""
    history: dict = field(default_factory=lambda: {"objective": (), "grad_norm": (), "tau": (), "step": ()})
    wall_time: float = 0.0
    evaluations: dict = field(default_factory=dict)
    failed_trials: int = 0
    best: dict | None = None

    @property
    def converged(self) -> bool:
        """Whether the stopping test was met."""
        return self.termination is Termination.CONVERGED

    @property
    def message(self) -> str:
        """Why the run stopped, in words (with the backend's own where it stopped on its own)."""
        text = {Termination.CONVERGED: f"projected ||G|| <= {self.tolerance:.3g}",
                Termination.MAX_ITERATIONS: f"maximum number of iterations ({self.iterations}) reached",
                Termination.LINE_SEARCH_FAILED: "no admissible step (state solver fails or no ascent along the "
                                                "search direction)",
                Termination.SOLVER_STOPPED: "stopped by L-BFGS-B's own test"}[self.termination]
        return f"{text} ({self.detail})" if self.detail else text

    def summary(self) -> dict:
        """The result as JSON-ready numbers, lists and strings (``summary.json``'s ``optimization``)."""
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

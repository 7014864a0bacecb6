"""Optimizers for ``max_{xi, tau} J(xi, tau)``: the paper's Algorithm 1 (and its spectral projected
gradient variant), L-BFGS-B, and projected Newton-CG, all with bounds.

All work on `ControlPoint` m = (xi~, tau) with the inner product of the control space
(`hyperoc.control.control_space.ControlSpace`: L2 or H^1 in time, times L2(omega), plus tau^2), keep
tau inside ``[tau_margin, T - eps - tau_margin]``, and treat a trial point where the state solver
fails as a rejected step (halved), never as a fatal error.

One module a concept: `result` (the frozen `OptimizationResult` and its `Termination`), `cache` (the
`EvaluationCache`, with which a resumed run replays its evaluations and ends where an uninterrupted run
ends), `box` (the `BoxProblem`: bounds, projection, metric, stationarity, tau scaling), `run` (the set-up
and wrap-up the optimizers share), `search` (the projected Armijo line search), and one module a method:
`bb` (`barzilai_borwein`, its `BBOptions`), `quasi_newton` (`lbfgsb`), `newton` (`newton_cg`, its
`NewtonCGOptions`; preconditioned by the `CurvaturePairs` of `curvature`). Each takes the problem (a reduced
functional, or a `BoxProblem`), the start, its stopping test and budget, and its method's options."""

from .bb import BBOptions, BBStepRule, barzilai_borwein
from .box import BoxProblem, stationarity, tau_scaling
from .cache import EvaluationCache
from .curvature import CurvaturePairs
from .newton import NewtonCGOptions, newton_cg
from .quasi_newton import lbfgsb
from .result import OptimizationResult, Termination
from .search import VALUE_RESOLUTION, increase

__all__ = ["OptimizationResult", "Termination", "EvaluationCache", "BoxProblem", "BBStepRule", "CurvaturePairs",
           "barzilai_borwein", "BBOptions", "lbfgsb", "newton_cg", "NewtonCGOptions", "stationarity", "tau_scaling",
           "increase", "VALUE_RESOLUTION"]

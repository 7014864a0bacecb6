"""The paper's Algorithm 1: projected Barzilai-Borwein steps for ``max_{xi, tau} J(xi, tau)``, and its
spectral projected gradient variant."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ..reduced import ControlPoint, ReducedFunctional
from .box import BoxProblem, as_box
from .result import OptimizationResult, Termination
from .run import Run
from .search import Backtracking

__all__ = ["barzilai_borwein", "BBOptions", "BBStepRule"]


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


@dataclass(frozen=True)
class BBOptions:
    """The steps of `barzilai_borwein`: ``steps`` (``"joint"`` or ``"blockwise"``), the step length ``bb_step``
    (`BBStepRule`), the window ``nonmonotone`` of the nonmonotone test (0: the paper's Algorithm 1), and the
    Armijo search's sufficient increase ``armijo`` and halvings ``max_backtracks``; `barzilai_borwein` says
    what each does. Checked when made (`hyperoc.errors.InputError`)."""

    steps: str = "joint"
    bb_step: str = "bb1"
    nonmonotone: int = 0
    armijo: float = 0.5
    max_backtracks: int = 30

    def __post_init__(self):
        if self.steps not in ("joint", "blockwise"):
            raise InputError(f"steps must be 'joint' or 'blockwise', got {self.steps!r}")
        BBStepRule(self.bb_step)
        n = self.nonmonotone
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise InputError(f"nonmonotone must be an integer >= 0 (0: the paper's Algorithm 1), got {n!r}")


def barzilai_borwein(problem: ReducedFunctional | BoxProblem, m0: ControlPoint, *, xi_bounds=(None, None),
                     gtol: float = 1e-6, gtol_abs: float = 0.0, max_iter: int = 200, options: BBOptions = BBOptions(),
                     cache_dir=None, callback=None) -> OptimizationResult:
    """The paper's Algorithm 1 (maximization): one Armijo step along G0, then Barzilai-Borwein steps.

    ``problem``: a reduced functional J, whose box has the bounds ``xi_bounds`` and tau in its default
    range (`BoxProblem.around`), or a `BoxProblem` (e.g. with tau fixed, ``fix_tau``: the control is
    optimized at tau = ``m0.tau``). ``options``: the steps and their search (`BBOptions`).

    With ``xi_bounds`` the iterates are projected onto the box (projected BB, the paper's Remark
    ``rk-box`` as a pointwise bound); ``||G||`` is then the projected gradient norm
    ``||P(m + G) - m||``, and G, the steps and the BB inner products are those of the lumped-mass
    metric (`hyperoc.control.control_space.LumpedMetric`: the nodal clip is the projection there, so
    the iteration's fixed points are the KKT points). Stops when it is ``<= max(gtol ||G0||, gtol_abs)``
    or after ``max_iter`` iterations. The BB step
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
    rules = (BBStepRule(options.bb_step), BBStepRule(options.bb_step))
    nonmonotone = options.nonmonotone
    run = Run(as_box(problem, m0.tau, xi_bounds), cache_dir, callback)
    search = Backtracking(run, options.armijo, options.max_backtracks)
    m, current, measure = run.start(m0)
    target = max(gtol * measure, gtol_abs)
    m_prev = G_prev = None
    alpha, termination = (1.0, 1.0), Termination.MAX_ITERATIONS
    for k in range(1, max_iter + 1):
        if measure <= target:
            break
        concave = False
        if m_prev is not None:
            alpha, concave = _bb_steps(run.box.metric, m - m_prev, current.G - G_prev, options.steps == "blockwise",
                                       alpha, rules)
        window = run.history["objective"][-nonmonotone:] if nonmonotone else [current.value]
        reference = min(window) if nonmonotone or not concave else None
        step = search.step(m, current, alpha, reference)
        if step is None:
            termination = Termination.LINE_SEARCH_FAILED
            break
        m_prev, G_prev = m, current.G
        m, current, alpha, measure = run.take(k, step)
    if measure <= target:
        termination = Termination.CONVERGED
    return run.finish(m, current.value, termination, target)


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

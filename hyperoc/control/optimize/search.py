"""The line search of the projected ascent methods (`barzilai_borwein`, `newton_cg`): Armijo backtracking of
a projected step, and how every line search judges a step's increase of J (`increase`)."""

from __future__ import annotations

from dataclasses import dataclass

from ..reduced import ControlPoint
from .run import Evaluation, Run

__all__ = ["Backtracking", "increase", "VALUE_RESOLUTION"]


@dataclass(frozen=True)
class Backtracking:
    """Armijo backtracking of the projected step of ``run``'s box: each rejected trial multiplies the steps
    by ``factor``, at most ``max_trials`` trials. A trial where the state solver fails is rejected (and
    counted in ``run.failed_trials``), never fatal."""

    run: Run
    factor: float = 0.5
    max_trials: int = 30

    def step(self, m: ControlPoint, current: Evaluation, alpha: tuple[float, float], reference: float | None,
             direction: ControlPoint | None = None) -> tuple[ControlPoint, Evaluation, tuple] | None:
        """``(trial, evaluation, alpha)`` at the first accepted trial ``P(m + (alpha_xi d_xi, alpha_tau d_tau))``,
        d = ``direction`` (default G, the gradient in the box's metric, of ``current``, the evaluation at
        m), else None. Unless ``reference`` is None a trial must also pass Armijo's test
        ``J(m) + increase >= reference + 1e-4 <G, s>`` (s = trial - m, the increase as `increase` judges it;
        ``reference = J(m)`` is the monotone test)."""
        a_xi, a_tau = alpha
        d = current.G if direction is None else direction
        for _ in range(self.max_trials):
            trial = self.run.box.project(m + ControlPoint(a_xi * d.xi, a_tau * d.tau))
            out = self.run.try_evaluate(trial)
            if out is None:
                self.run.failed_trials += 1
            elif reference is None or self._sufficient(current, out, trial - m, reference):
                return trial, out, (a_xi, a_tau)
            a_xi, a_tau = a_xi * self.factor, a_tau * self.factor
        return None

    def _sufficient(self, current: Evaluation, trial: Evaluation, s: ControlPoint, reference: float) -> bool:
        """Armijo's test of the step s from the point of ``current`` to that of ``trial``."""
        inner = self.run.box.metric.inner
        slope = inner(current.G, s)
        gain = increase(current.value, trial.value, slope, inner(trial.G, s))
        return current.value + gain >= reference + 1e-4 * slope


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

"""The limited-memory BFGS inverse of curvature pairs: the preconditioner of Newton-CG's inner solves."""

from __future__ import annotations

from ..reduced import ControlPoint

__all__ = ["CurvaturePairs"]


class CurvaturePairs:
    """The limited-memory BFGS approximation of ``(-H)^-1`` from the last ``memory`` pairs
    ``(s, y = -H s)`` of the earlier CG solves (Morales and Nocedal, SIAM J. Optim. 10, 2000: automatic
    preconditioning): CG on the next Newton system, whose Hessian differs little, then needs fewer
    products for the directions the pairs already hold (the soft ones along the ridge among them).
    Without pairs it is the identity; it is symmetric positive definite since every pair has
    ``<s, y> > 0``. Applied by the two-loop recursion in ``metric``, with the initial operator ``initial``
    (``r -> H0 r``, self-adjoint positive definite in ``metric``) or, without one, the initial scaling
    ``<s, y> / <y, y>`` of the newest pair."""

    def __init__(self, metric, memory: int = 20, initial=None):
        self.metric, self.memory, self.pairs, self.initial = metric, memory, [], initial

    def add(self, pairs: list) -> None:
        """Append ``pairs`` ``[(s, y, <s, y>)]``, keeping the last ``memory``."""
        self.pairs = (self.pairs + pairs)[-self.memory:]

    def __call__(self, r: ControlPoint) -> ControlPoint:
        inner = self.metric.inner
        q, alphas = r, []
        for s, y, sy in reversed(self.pairs):
            a = inner(s, q) / sy
            q, alphas = q - y * a, [a, *alphas]
        if self.initial is not None:
            q = self.initial(q)
        elif self.pairs:
            s, y, sy = self.pairs[-1]
            q = q * (sy / inner(y, y))
        for (s, y, sy), a in zip(self.pairs, alphas):
            q = q + s * (a - inner(y, q) / sy)
        return q

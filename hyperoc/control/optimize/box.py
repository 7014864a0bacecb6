"""The bounded problem every optimizer solves: ``max J(xi, tau)`` over a box, with its projection,
its metric and its stationarity measure."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ...errors import InputError
from ..control_space import ControlSpace, TauWeighted
from ..reduced import ControlPoint, ReducedFunctional
from ..tau_scale import is_tau_scale

__all__ = ["BoxProblem", "as_box", "stationarity", "tau_scaling"]


@dataclass(frozen=True)
class BoxProblem:
    """``max J(m)`` over ``m = (xi, tau)`` with ``lo <= xi <= hi`` at every control value
    (``xi_bounds = (lo, hi)``, None: no bound on that side) and tau in ``tau_range = (tau_lo, tau_hi)``
    (seconds; ``tau_lo == tau_hi``: tau fixed).

    The optimizers step in `metric`, decided here once: with a bound on xi the lumped metric of J's
    control space (`hyperoc.control.control_space.LumpedMetric`: the nodal clip is the projection there,
    so the fixed points of projected steps are the KKT points), else the space's own; its tau-part is
    ``tau_weight a.tau b.tau`` (`hyperoc.control.control_space.TauWeighted`; 1: the space's own).
    """

    J: ReducedFunctional
    tau_range: tuple[float, float]
    xi_bounds: tuple = (None, None)
    tau_weight: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "xi_bounds", tuple(self.xi_bounds))

    @classmethod
    def around(cls, J: ReducedFunctional, tau0: float, *, xi_bounds=(None, None), tau_margin: float | None = None,
               fix_tau: bool = False) -> BoxProblem:
        """The box of ``xi_bounds`` with tau in ``[margin, T - eps - margin]`` (default margin: two mean
        steps), or tau fixed at ``tau0``."""
        return cls(J, _tau_range(J, tau_margin, fix_tau, tau0), xi_bounds)

    @property
    def bounded(self) -> bool:
        """Whether xi has a bound."""
        return self.xi_bounds != (None, None)

    @cached_property
    def metric(self):
        """`ControlSpace.metric` of J's control space (the lumped one when xi has a bound), its tau-part
        weighted by `tau_weight`."""
        metric = self.J.space.metric(bounded=self.bounded)
        return metric if self.tau_weight == 1.0 else TauWeighted(metric, self.tau_weight)

    @property
    def cost_inverse(self):
        """``r -> S^-1 r`` in `metric` (`hyperoc.control.control_space.LumpedMetric.space_inverse`) where the metric
        is the lumped one of an H^1-in-time space (bounded xi, beta > 0), whose own metric is the cost's Hessian;
        None where the metric is that space itself or the space is L2 in time (lumped and consistent mass being
        spectrally equivalent there)."""
        return self.metric.space_inverse if self.bounded and self.J.space.regular_in_time else None

    @cached_property
    def coordinates(self) -> ControlSpace:
        """L-BFGS-B's coordinates: J's control space, or its L2-in-time version when xi has a bound (a
        bound on xi is a bound on the coordinates only when the time factor is diagonal)."""
        if not self.bounded or not self.J.space.regular_in_time:
            return self.J.space
        return self.J.space.l2_in_time()

    def project(self, m: ControlPoint) -> ControlPoint:
        """``P(m)``: tau clipped to `tau_range`, xi to `xi_bounds` (nodal clip)."""
        lo, hi = self.xi_bounds
        xi = m.xi if not self.bounded else np.clip(m.xi, -np.inf if lo is None else lo, np.inf if hi is None else hi)
        return ControlPoint(xi, float(np.clip(m.tau, *self.tau_range)))

    def projected_step(self, m: ControlPoint, G: ControlPoint) -> ControlPoint:
        """``P(m + G) - m``: the projected gradient step, zero exactly at the KKT points."""
        return self.project(m + G) - m

    def projected_norm(self, m: ControlPoint, G: ControlPoint) -> float:
        """``|| P(m + G) - m ||`` in `metric`, G the gradient in `metric`."""
        return self.metric.norm(self.projected_step(m, G))

    def stationarity(self, m: ControlPoint, g: ControlPoint) -> float:
        """`projected_norm` from J's gradient g (the Riesz representative in J's control space)."""
        return self.projected_norm(m, self.metric.gradient(g))

    def tau_scale(self, spec: float | str) -> float:
        """The factor c of the scaled variable ``c tau``: L-BFGS-B's variable (the xi variables being scaled to
        the L2 geometry), and Newton-CG's metric, which weighs tau by c^2 (`tau_weight`).

        ``"range"``: with finite bounds ``lo < xi < hi``, the admissible tau interval (length ``L_tau``)
        gets the length of the xi box's diagonal in L2(0,2; L2(omega)): ``c = (hi - lo) sqrt(|Q|) /
        L_tau``, ``|Q| = 2 |omega|`` per control component (s in (0, 2); the sum of the control mass
        matrix is |omega| per component); both blocks are normalized to their ranges, as
        bound-constrained codes commonly normalize variables. Why: tau and xi have unrelated units, while
        scipy's line search and L-BFGS's initial Hessian ``gamma I`` treat all variables alike (the
        ventricle example converges to gtol = 1e-4 in 50-57 iterations for c from 10 to 67, and not in
        120 with c = 1 or 0.1: ``python bench/bench_tau_scale.py``). c = 1 without finite bounds or with
        tau fixed. A number: that factor (> 0). ``"curvature"`` is measured by `newton_cg`, not here: an
        `InputError`, as anything else is.
        """
        if not is_tau_scale(spec) or spec == "curvature":
            raise InputError(f"tau_scale must be 'range' or a positive number here, got {spec!r}"
                             + (" ('curvature' is newton's)" if spec == "curvature" else ""))
        if spec != "range":
            return float(spec)
        lo, hi = self.xi_bounds
        width = self.tau_range[1] - self.tau_range[0]
        if lo is None or hi is None or width <= 0:
            return 1.0
        return float((hi - lo) * np.sqrt(self.J.s_weights.sum() * self.J.model.control.mass.sum()) / width)


def as_box(problem: ReducedFunctional | BoxProblem, tau0: float, xi_bounds=(None, None)) -> BoxProblem:
    """The optimizers' ``problem`` as a `BoxProblem`: a box as given, or for a reduced functional J the box
    `BoxProblem.around` J with ``xi_bounds`` and tau in its default range (``tau0``: the start's tau)."""
    if not isinstance(problem, BoxProblem):
        return BoxProblem.around(problem, tau0, xi_bounds=xi_bounds)
    if tuple(xi_bounds) != (None, None):
        raise InputError("xi_bounds belong to the BoxProblem when one is given")
    return problem


def _tau_range(J: ReducedFunctional, tau_margin: float | None, fix_tau: bool, tau0: float) -> tuple:
    """Admissible tau: ``[margin, T - eps - margin]`` (default margin: two mean steps), or ``tau0`` alone."""
    if fix_tau:
        return (float(tau0), float(tau0))
    margin = 2.0 * float(J.transform.T) / J.N if tau_margin is None else tau_margin
    return (margin, J.transform.T - J.transform.eps - margin)


def stationarity(J: ReducedFunctional, m: ControlPoint, g: ControlPoint, tau_range, xi_bounds=(None, None)) -> float:
    """``|| P(m + G) - m ||`` in the optimizers' metric (G the gradient there, from J's gradient g): the
    projected gradient norm, zero exactly at the KKT points; ``||G||`` when no bound is active
    (`BoxProblem.stationarity`)."""
    return BoxProblem(J, tau_range, xi_bounds).stationarity(m, g)


def tau_scaling(J: ReducedFunctional, tau_scale: float | str, tau_range, xi_bounds) -> float:
    """`BoxProblem.tau_scale` of the box ``(tau_range, xi_bounds)``."""
    return BoxProblem(J, tau_range, xi_bounds).tau_scale(tau_scale)

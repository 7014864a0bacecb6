"""The control space: its inner product, Riesz map, the optimizers' metric and coordinates.

A control point is ``m = (xi~, tau)``, xi~ (N+1, n_ctrl) the nodal values of the control on the
control nodes at the levels of the fixed s-grid (s in [0, 2]), tau a scalar. The inner product is

    <a, b> = int_0^2 (a.xi, b.xi)_{L2(omega)} ds + l_s^2 int_0^2 (d_s a.xi, d_s b.xi)_{L2(omega)} ds + a.tau b.tau

discretized as ``sum_k w_k a_k . M b_k + l_s^2 sum_n (a_{n+1} - a_n) . M (b_{n+1} - b_n) / ds_n``
(w the trapezoid weights of the s-grid, M the L2(omega) Gram matrix of the control nodes). In
matrix form ``<a, b> = a.xi : (A_t b.xi M) + a.tau b.tau``, ``A_t = W + l_s^2 K`` with W the
diagonal time weights and K the tridiagonal 1D stiffness in s (natural end conditions).

``l_s = 0`` is L2(0, 2; L2(omega)), the geometry of the paper's cost ``alpha/2 ||xi||^2``.
``l_s > 0`` is H^1(0, 2; L2(omega)), the geometry of the regularized cost
``alpha/2 ||xi||^2 + beta/2 ||d xi/dt||^2``: with ``dt = mu_dot ds`` and ``mu_dot = T/2`` at
``tau = T/2``, that cost is ``alpha T/4 (||xi||^2_s + l_s^2 ||d_s xi||^2_s)`` with
``l_s = (2/T) sqrt(beta / alpha)``; `control_space` scales the xi-part by ``c = alpha T/2``, so the
metric is the cost's Hessian there, and the number of iterations does not grow with the number of
time levels.

With pointwise bounds on xi the optimizers work in the lumped L2 metric instead (`LumpedMetric`,
``ControlSpace.metric(bounded=True)``), where the nodal clip is the projection onto the bounds.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.linalg as sla
import scipy.sparse.linalg as spla

from ..dynamics.timegrid import trapezoid_weights

__all__ = ["ControlSpace", "LumpedMetric", "TauWeighted", "control_space", "s_time_scale"]


def s_time_scale(alpha: float, beta: float, T: float) -> float:
    """``l_s = (2 / T) sqrt(beta / alpha)`` (dimensionless, the s-interval has length 2): the length in s
    over which the two parts of ``alpha/2 ||xi||^2 + beta/2 ||xi_t||^2`` balance at ``tau = T/2``.
    0 when beta = 0; with alpha = 0 the H^1 part is weighted as if ``sqrt(beta/alpha) = T/2`` (l_s = 1)."""
    if beta <= 0:
        return 0.0
    return 1.0 if alpha <= 0 else (2.0 / T) * float(np.sqrt(beta / alpha))


class ControlSpace:
    """Inner product, Riesz map and optimizer coordinates of the controls ``(xi~, tau)``.

    Parameters
    ----------
    ds : (N,) steps of the fixed s-grid.
    mass : (n_ctrl, n_ctrl) sparse L2(omega) Gram matrix of the control nodes.
    lumped_mass : (n_ctrl,) positive lumped weights of the same nodes.
    time_scale : ``l_s >= 0`` (`s_time_scale`); 0 gives L2 in time, > 0 gives H^1 in time.
    weight : c > 0, the factor of the xi-part, ``<a, b> = c a.xi : (A_t b.xi M) + a.tau b.tau``.
    """

    def __init__(self, ds, mass, lumped_mass, time_scale: float = 0.0, weight: float = 1.0):
        self.ds = np.asarray(ds, dtype=np.float64)
        self.mass, self.lumped_mass = mass, np.asarray(lumped_mass, dtype=np.float64)
        self.time_scale, self.weight = float(time_scale), float(weight)
        self.weights = trapezoid_weights(self.ds)  # (N+1,)
        self._w = self.weight * self.weights  # the time weights of the metric

    @property
    def regular_in_time(self) -> bool:
        """Whether the metric is H^1 in time (``time_scale > 0``)."""
        return self.time_scale > 0

    # --- the time operator A_t = W + l_s^2 K (tridiagonal, SPD) ----------------------------------
    @cached_property
    def time_bands(self) -> np.ndarray:
        """``A_t = c (W + l_s^2 K)`` in upper banded storage (2, N+1): row 0 the superdiagonal, row 1 the diagonal."""
        k = self.weight * self.time_scale**2 / self.ds  # (N,) stiffness of each s-interval
        diag = self._w.copy()
        diag[:-1] += k
        diag[1:] += k
        upper = np.concatenate([[0.0], -k])
        return np.vstack([upper, diag])

    @cached_property
    def time_cholesky(self) -> np.ndarray:
        """Upper banded Cholesky factor U of ``A_t = U^T U`` (2, N+1)."""
        return sla.cholesky_banded(self.time_bands, lower=False)

    def apply_time(self, x: np.ndarray) -> np.ndarray:
        """``A_t x`` for x (N+1, ...)."""
        if not self.regular_in_time:
            return self._w.reshape((-1,) + (1,) * (x.ndim - 1)) * x
        upper, diag = self.time_bands
        out = diag.reshape((-1,) + (1,) * (x.ndim - 1)) * x
        off = upper[1:].reshape((-1,) + (1,) * (x.ndim - 1))
        out[:-1] += off * x[1:]
        out[1:] += off * x[:-1]
        return out

    def solve_time(self, b: np.ndarray) -> np.ndarray:
        """``A_t^{-1} b`` for b (N+1, ...) (a banded Cholesky solve)."""
        if not self.regular_in_time:
            return b / self._w.reshape((-1,) + (1,) * (b.ndim - 1))
        return sla.cho_solve_banded((self.time_cholesky, False), b)

    # --- inner product and Riesz map -------------------------------------------------------------
    @cached_property
    def _mass_lu(self):
        return spla.splu(self.mass.tocsc())

    def dual(self, g):
        """The dual vector d of g: ``d.xi . v.xi + d.tau v.tau = <g, v>`` for every v; ``d.xi = A_t g.xi M``."""
        Mx = (self.mass @ g.xi.T).T
        return type(g)(self.apply_time(Mx), g.tau)

    def riesz(self, d):
        """The Riesz representative g of a dual vector d (inverse of `dual`): ``g.xi = A_t^{-1} d.xi M^{-1}``."""
        xi = self._mass_lu.solve(np.ascontiguousarray(d.xi.T)).T
        return type(d)(self.solve_time(xi), d.tau)

    def inner(self, a, b) -> float:
        return float(np.sum(a.xi * self.dual(b).xi) + a.tau * b.tau)

    def norm(self, a) -> float:
        return float(np.sqrt(max(self.inner(a, a), 0.0)))

    # --- the metric the optimizers work in -------------------------------------------------------
    def metric(self, bounded: bool) -> "ControlSpace | LumpedMetric":
        """This space itself, or with pointwise bounds on xi (``bounded``) its `LumpedMetric`; either
        has ``inner``, ``norm`` and ``gradient``."""
        return LumpedMetric(self) if bounded else self

    @staticmethod
    def gradient(g):
        """The gradient in this metric from the reduced functional's gradient g, which is already the
        Riesz representative in it: g."""
        return g

    # --- coordinates in which the Euclidean geometry is the (lumped) control metric --------------
    @cached_property
    def lumped_weights(self) -> np.ndarray:
        """``w_k D_i`` (N+1, n_ctrl): the L2-in-time part of the metric with the spatial mass lumped."""
        return self._w[:, None] * self.lumped_mass[None, :]

    @cached_property
    def _diagonal_scale(self) -> np.ndarray:
        """``sqrt(w_k D_i)`` (N+1, n_ctrl): the coordinate scale when the metric is L2 in time."""
        return np.sqrt(self.lumped_weights)

    def l2_in_time(self) -> "ControlSpace":
        """The same space with the plain L2(0, 2; L2(omega)) metric in time (unit weight)."""
        return ControlSpace(self.ds, self.mass, self.lumped_mass)

    def to_coordinates(self, xi: np.ndarray) -> np.ndarray:
        """``z = U xi D^(1/2)`` (U the Cholesky factor of A_t; ``sqrt(w) xi sqrt(D)`` in L2): Euclidean
        inner products of z are those of the metric with the spatial mass lumped."""
        if not self.regular_in_time:
            return xi * self._diagonal_scale
        upper, diag = self.time_cholesky
        out = diag[:, None] * xi
        out[:-1] += upper[1:, None] * xi[1:]
        return out * np.sqrt(self.lumped_mass)

    def from_coordinates(self, z: np.ndarray) -> np.ndarray:
        """Inverse of `to_coordinates`."""
        if not self.regular_in_time:
            return z / self._diagonal_scale
        return sla.solve_banded((0, 1), self.time_cholesky, z / np.sqrt(self.lumped_mass))

    def coordinate_gradient(self, dual_xi: np.ndarray) -> np.ndarray:
        """dJ/dz from the dual vector dJ/dxi: ``U^{-T} dJ/dxi D^(-1/2)``."""
        if not self.regular_in_time:
            return dual_xi / self._diagonal_scale
        lower = np.vstack([self.time_cholesky[1], np.concatenate([self.time_cholesky[0, 1:], [0.0]])])
        return sla.solve_banded((1, 0), lower, dual_xi / np.sqrt(self.lumped_mass))


class LumpedMetric:
    """The L2-in-time inner product of a `ControlSpace` with the spatial mass lumped: ``<a, b>_L =
    c sum_k w_k a.xi_k . (D b.xi_k) + a.tau b.tau``, w the trapezoid weights in s, D the lumped mass of
    the control nodes (`ControlSpace.lumped_weights` of `ControlSpace.l2_in_time`), c the space's weight
    (the scale of the cost's Hessian with beta > 0, `control_space`; 1 otherwise), so that the xi-block of
    J's Hessian has the same scale in both metrics.

    Why: with pointwise bounds on xi, the nodal clip is the projection onto the box in this
    metric, and it is not in the consistent-mass one of the control space (M^-1 couples
    neighbouring nodes). So ``m = P(m + G_L)``, with ``G_L = D^-1 dJ/dm`` the gradient in this
    metric, holds exactly at the KKT points of the discrete problem (dJ/dxi_i = 0 where xi_i is
    free, of the sign pushing on the bound where it is active), while ``m = P(m + G)`` with the
    consistent-mass gradient G does not: projected gradient steps along G have other fixed points,
    and ``||P(m + G) - m||`` does not vanish at a KKT point with active bounds. The two metrics are
    spectrally equivalent, so without bounds either gives mesh-independent iterations.
    """

    def __init__(self, space: ControlSpace):
        self.space = space
        self.weights = space.weight * space.l2_in_time().lumped_weights  # (N+1, n_ctrl)

    def inner(self, a, b) -> float:
        return float(np.sum(a.xi * self.weights * b.xi) + a.tau * b.tau)

    def norm(self, a) -> float:
        return float(np.sqrt(max(self.inner(a, a), 0.0)))

    def gradient(self, g):
        """``G_L`` from the gradient g in the control space's metric (its Riesz representative there)."""
        d = self.space.dual(g)
        return type(g)(d.xi / self.weights, d.tau)

    def space_inverse(self, r):
        """``S^-1 r``, S the control space's inner product in this metric (``<a, S b>_L = <a, b>``, ``S b = W^-1
        A_t b.xi M`` on xi, the identity on tau): with beta > 0 the inverse of the cost's Hessian, Newton-CG's
        initial preconditioner (`hyperoc.control.optimize.curvature.CurvaturePairs`), under which CG on the
        lumped metric takes the steps of CG on the space's own."""
        g = self.space.riesz(type(r)(r.xi * self.weights, 0.0))
        return type(r)(g.xi, r.tau)


class TauWeighted:
    """A metric (`ControlSpace` or `LumpedMetric`) with its tau-part weighted: ``<a, b>_w = <a, b> + (w - 1)
    a.tau b.tau``, the gradient's tau-part divided by w.

    Why: J's Hessian in tau (units of J / s^2) and in xi have unrelated scales; where the metric's xi-block
    is the cost's Hessian (`control_space` with beta > 0), ``w = |d^2 J / d tau^2|`` gives both blocks unit
    scale, so that Newton-CG's residual, its stopping test and the projected gradient weigh tau and xi
    alike instead of one of them alone (w = c^2 of L-BFGS-B's variable ``c tau``).
    """

    def __init__(self, metric, weight: float):
        if not (np.isfinite(weight) and weight > 0):
            raise ValueError(f"tau weight must be finite and positive, got {weight!r}")
        self.base, self.weight = metric, float(weight)

    def inner(self, a, b) -> float:
        return self.base.inner(a, b) + (self.weight - 1.0) * a.tau * b.tau

    def norm(self, a) -> float:
        return float(np.sqrt(max(self.inner(a, a), 0.0)))

    def gradient(self, g):
        """The base metric's gradient with its tau-part divided by the weight."""
        G = self.base.gradient(g)
        return type(G)(G.xi, G.tau / self.weight)

    def space_inverse(self, r):
        """The base metric's `space_inverse` (its tau-part the identity in either metric)."""
        return self.base.space_inverse(r)


def control_space(transform, control, alpha: float, beta: float) -> ControlSpace:
    """The control space of a problem with the cost ``alpha/2 ||xi||^2 + beta/2 ||xi_t||^2``.

    beta = 0: L2(0, 2; L2(omega)), the metric of the paper's Algorithm 1. beta > 0: H^1 in time,
    scaled to the Hessian of that cost at ``tau = T/2`` (``c = alpha T/2``, l_s from `s_time_scale`;
    ``c = beta`` when alpha = 0). Why the scale: in that metric the xi-block of J's Hessian is the
    identity plus the observation's part, while tau keeps the weight 1, so that a gradient step
    moves xi and tau by comparable amounts of J and Barzilai-Borwein steps are not held back by the
    ratio of the two curvatures.
    """
    if beta <= 0:
        return ControlSpace(transform.ds(), control.mass, control.lumped_mass)
    weight = alpha * transform.T / 2 if alpha > 0 else beta
    return ControlSpace(transform.ds(), control.mass, control.lumped_mass, s_time_scale(alpha, beta, transform.T),
                        weight)

"""Pointwise measures of a deformation that the monitors and reports read: the smallest det F, the
largest displacement gradient, cell-mean dilatations and the loss of strong ellipticity.

Each takes the deformation gradient F (nc, nq, d, d) at the quadrature points
(`hyperoc.mechanics.kernels.deformation_gradient`) and is traceable by JAX.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from .kernels import VOIGT, pointwise, voigt_derivatives
from .materials import det

__all__ = ["acoustic_tensors", "cell_mean", "directions", "max_grad", "min_acoustic_eigenvalue", "min_det_F",
           "min_symmetric_eigenvalue"]


def min_det_F(F):
    """min det F over the quadrature points (scalar, dimensionless; <= 0 means the map folds)."""
    return jnp.min(det(F))


def max_grad(F):
    """max |grad u| = |F - I| (Frobenius) over the quadrature points (scalar, dimensionless)."""
    return jnp.max(jnp.sqrt(jnp.sum((F - jnp.eye(F.shape[-1])) ** 2, axis=(-2, -1))))


def cell_mean(values, w, cell_volume):
    """``|e|^-1 int_e values dx`` per cell (nc,), for values at the quadrature points (nc, nq), w (nc, nq)
    the weights times |det J|, cell_volume (nc,) their sums ``|e|``."""
    return jnp.sum(w * values, axis=1) / cell_volume


def directions(dim: int) -> np.ndarray:
    """Unit directions (m, dim) sampling the half sphere (1D: 1; 2D: 12 angles; 3D: 31 Fibonacci points)."""
    if dim == 1:
        return np.ones((1, 1))
    if dim == 2:
        a = np.pi * np.arange(12) / 12
        return np.stack([np.cos(a), np.sin(a)], axis=1)
    k = np.arange(31) + 0.5
    z = k / 31
    phi = np.pi * (1 + 5**0.5) * k
    r = np.sqrt(1 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def acoustic_tensors(material, F, frame, dirs):
    """The acoustic tensors ``Q(n)_ik = dP_iJ/dF_kL n_J n_L`` at one point, (m, d, d), for the unit directions
    dirs (m, d): with ``C = d2W/dE2`` and ``S = dW/dE`` (`hyperoc.mechanics.kernels.voigt_derivatives`, the law's
    derivatives in the independent strains), ``dP_iJ/dF_kL = F_iI C_IJKL F_kK + delta_ik S_JL``, so

        Q(n) = F M(n) F^T + (n . S n) I,    M(n)_IK = C_IJKL n_J n_L;

    the 4th-order ``dP/dF`` of the law (its Hessian in F) without forming it."""
    d = F.shape[-1]
    I, J, sym, half = VOIGT[d]
    e = (0.5 * (F.T @ F - jnp.eye(d)))[I, J]
    H, s = voigt_derivatives(material, d, e, frame)
    # C_IJKL as a (d^2, d^2) matrix, rows (I, K) and columns (J, L): M(n) and F M F^T are then two matrix products
    # over all directions at once, with the directions' n_J n_L (d^2, m) and F_iI F_kK (d^2, d^2)
    C = (H * jnp.outer(half, half))[sym[:, None, :, None], sym[None, :, None, :]].reshape(d * d, d * d)
    nn = (dirs[:, :, None] * dirs[:, None, :]).reshape(-1, d * d).T
    FF = (F[:, None, :, None] * F[None, :, None, :]).reshape(d * d, d * d)
    Q = (FF @ (C @ nn)).T.reshape(-1, d, d)
    return Q + (((s * half)[sym].reshape(-1) @ nn))[:, None, None] * jnp.eye(d)


def min_acoustic_eigenvalue(material, F, frames):
    """Smallest eigenvalue of the acoustic tensor ``Q(n)_ik = dP_iJ/dF_kL n_J n_L`` (`acoustic_tensors`) over
    the points and the sampled unit directions n (`directions`) (scalar, stress units), for the strain energy
    of ``material`` (a `hyperoc.mechanics.materials.Material`), F (nc, nq, d, d), frames (nc, nq, kf, d) or
    None.

    Negative values mean loss of strong ellipticity: the continuum problem is no longer
    well posed and discrete solutions localize (e.g. Saint Venant-Kirchhoff in strong
    compression; in 1D exactly ``dP/dF < 0``, i.e. ``u_x < -1 + 1/sqrt(3)``).
    """
    dirs = jnp.asarray(directions(F.shape[-1]))
    Q = pointwise(lambda G, frame: acoustic_tensors(material, G, frame, dirs), F, frames)  # (nc, nq, m, d, d)
    return jnp.min(min_symmetric_eigenvalue(Q))


def min_symmetric_eigenvalue(Q):
    """Smallest eigenvalue of each symmetric d x d matrix of Q (..., d, d), d <= 3, in closed form: elementwise
    arithmetic, where a batched ``eigvalsh`` calls LAPACK once per matrix (millions of acoustic tensors on a P2
    ventricle).

    1D: ``Q_00``; 2D: ``(a + c)/2 - sqrt(((a - c)/2)^2 + b^2)``; 3D: the trigonometric solution of the
    characteristic cubic, ``m + 2 s cos(acos(det(B)/2)/3 + 2 pi/3)`` with ``m = tr Q / 3``,
    ``s^2 = |Q - m I|_F^2 / 6`` and ``B = (Q - m I)/s`` (``m`` where ``s = 0``). Near a double eigenvalue the
    arc cosine's argument is near -1 or 1, where it loses half the digits: the error is about
    ``sqrt(eps) s``, harmless for a sign test."""
    d = Q.shape[-1]
    if d == 1:
        return Q[..., 0, 0]
    if d == 2:
        a, b, c = Q[..., 0, 0], Q[..., 0, 1], Q[..., 1, 1]
        return 0.5 * (a + c) - jnp.sqrt(0.25 * (a - c) ** 2 + b**2)
    # on Q / max|Q_ij|, so that the squares and the determinant neither overflow nor underflow
    scale = jnp.max(jnp.abs(Q), axis=(-2, -1))
    scale = jnp.where(scale > 0, scale, 1.0)
    Q = Q / scale[..., None, None]
    m = jnp.trace(Q, axis1=-2, axis2=-1) / 3
    B = Q - m[..., None, None] * jnp.eye(3)
    s = jnp.sqrt(jnp.sum(B * B, axis=(-2, -1)) / 6)
    half_det = det(B / jnp.where(s > 0, s, 1.0)[..., None, None]) / 2
    angle = jnp.arccos(jnp.clip(half_det, -1.0, 1.0)) / 3
    return scale * (m + 2 * s * jnp.cos(angle + 2 * jnp.pi / 3))

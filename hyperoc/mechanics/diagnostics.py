"""Pointwise measures of a deformation that the monitors and reports read: the smallest det F, the
largest displacement gradient, cell-mean dilatations and the loss of strong ellipticity.

Each takes the deformation gradient F (nc, nq, d, d) at the quadrature points
(`hyperoc.mechanics.kernels.deformation_gradient`) and is traceable by JAX.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from .kernels import pointwise
from .materials import det

__all__ = ["cell_mean", "directions", "max_grad", "min_acoustic_eigenvalue", "min_det_F"]


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


def min_acoustic_eigenvalue(energy_of_F, F, frames):
    """Smallest eigenvalue of the acoustic tensor ``Q(n)_ik = dP_iJ/dF_kL n_J n_L`` over the points
    and the sampled unit directions n (`directions`) (scalar, stress units), for the strain energy
    ``energy_of_F(F, frame)``, F (nc, nq, d, d), frames (nc, nq, kf, d) or None.

    Negative values mean loss of strong ellipticity: the continuum problem is no longer
    well posed and discrete solutions localize (e.g. Saint Venant-Kirchhoff in strong
    compression; in 1D exactly ``dP/dF < 0``, i.e. ``u_x < -1 + 1/sqrt(3)``).
    """
    A = pointwise(jax.hessian(energy_of_F), F, frames)  # (nc, nq, d, d, d, d)
    dirs = jnp.asarray(directions(F.shape[-1]))
    Q = jnp.einsum("cqijkl,nj,nl->cqnik", A, dirs, dirs)  # acoustic tensors
    return jnp.min(jnp.linalg.eigvalsh(Q))

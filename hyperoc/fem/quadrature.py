"""Quadrature rules on the reference simplex ``{xi_i >= 0, sum xi_i <= 1}``.

Low degrees use the classical symmetric rules (centroid; 3-point and 4-point rules of degree 2);
higher degrees use collapsed Gauss-Jacobi products (Stroud conical rules), exact for polynomials
of the requested total degree on intervals, triangles and tetrahedra.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import roots_jacobi

__all__ = ["simplex_rule"]


def simplex_rule(dim: int, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (nq, dim) and weights (nq,) exact for polynomials of total degree ``degree``.

    The weights sum to the reference volume ``1 / dim!``.
    """
    if degree <= 1:
        return np.full((1, dim), 1.0 / (dim + 1)), np.array([1.0 / math.factorial(dim)])
    if degree == 2 and dim == 2:
        pts = np.array([[1 / 6, 1 / 6], [2 / 3, 1 / 6], [1 / 6, 2 / 3]])
        return pts, np.full(3, 1 / 6)
    if degree == 2 and dim == 3:
        a, b = (5 - math.sqrt(5)) / 20, (5 + 3 * math.sqrt(5)) / 20
        pts = np.array([[a, a, a], [b, a, a], [a, b, a], [a, a, b]])
        return pts, np.full(4, 1 / 24)
    return _collapsed_gauss_jacobi(dim, degree)


def _gauss_jacobi01(n: int, alpha: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Jacobi nodes and weights on [0, 1] for the weight (1 - v)^alpha."""
    x, w = roots_jacobi(n, alpha, 0)
    return (1 + x) / 2, w / 2 ** (alpha + 1)


def _collapsed_gauss_jacobi(dim: int, degree: int) -> tuple[np.ndarray, np.ndarray]:
    # Duffy map: xi_d = v_d, xi_{d-1} = v_{d-1} (1 - v_d), ...; the Jacobian (1 - v_k)^(k-1)
    # is absorbed in Gauss-Jacobi weights, so n points per direction integrate degree 2n - 1.
    n = (degree + 2) // 2
    rules = [_gauss_jacobi01(n, k) for k in range(dim)]
    grids = np.meshgrid(*[r[0] for r in rules], indexing="ij")
    weights = np.ones_like(grids[0])
    for k, grid in enumerate(np.meshgrid(*[r[1] for r in rules], indexing="ij")):
        weights = weights * grid
    v = [g.ravel() for g in grids]
    pts = np.empty((v[0].size, dim))
    scale = np.ones_like(v[0])
    for k in reversed(range(dim)):
        pts[:, k] = v[k] * scale
        scale = scale * (1 - v[k])
    return pts, weights.ravel()

"""Quadrature rules on the reference simplex ``{xi_i >= 0, sum xi_i <= 1}``.

Up to degree 5 on triangles and tetrahedra the rules are symmetric ones with positive weights and interior
points (centroid; the 3- and 4-point rules of degree 2; on triangles Strang and Fix's 6-point rule of degree 4
and Radon's 7-point rule of degree 5; on tetrahedra the 14-point rule of degree 5, for degrees 4 and 5, where
the collapsed product needs 27 points: the P2 cells' rule, so half the work per residual and tangent);
other degrees use collapsed Gauss-Jacobi products (Stroud conical rules), exact for polynomials of the
requested total degree on intervals, triangles and tetrahedra. The orbits' coordinates and weights of the
degree-4 triangle rule and the 14-point rule solve the moment equations to round-off
(`tests/test_quadrature.py` checks every rule's exactness).
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
        return _orbit(dim), np.array([1.0 / math.factorial(dim)])
    if (dim, degree) in _SYMMETRIC:
        parts = [(_orbit(dim, a, kind), weight) for a, kind, weight in _SYMMETRIC[dim, degree]]
        return np.concatenate([p for p, _ in parts]), np.concatenate([np.full(len(p), w) for p, w in parts])
    return _collapsed_gauss_jacobi(dim, degree)


def _orbit(dim: int, a: float | None = None, kind: str = "vertex") -> np.ndarray:
    """The points of one symmetry orbit in barycentric coordinates, as reference coordinates (k, dim): the
    centroid (``a`` None); ``"vertex"``: (a, ..., a, 1 - dim a) and its permutations (dim + 1 points);
    ``"edge"`` (tetrahedra): (a, a, 1/2 - a, 1/2 - a) and its permutations (6 points)."""
    if a is None:
        return np.full((1, dim), 1.0 / (dim + 1))
    if kind == "vertex":
        bary = np.full((dim + 1, dim + 1), a) + np.eye(dim + 1) * (1 - (dim + 1) * a)
    else:
        pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
        bary = np.full((6, 4), 0.5 - a)
        for row, (i, j) in enumerate(pairs):
            bary[row, [i, j]] = a
    return bary[:, 1:]


_R15 = math.sqrt(15)
#: ``(dim, degree) -> orbits (a, kind, weight)`` (`_orbit`; weights sum to 1 / dim!), where a symmetric rule
#: needs fewer points than the collapsed product (degree 2: the 3- and 4-point rules)
_SYMMETRIC = {
    (2, 2): [(1 / 6, "vertex", 1 / 6)],
    (3, 2): [((5 - math.sqrt(5)) / 20, "vertex", 1 / 24)],
    (2, 4): [(0.44594849091596483, "vertex", 0.11169079483900557),
             (0.09157621350977095, "vertex", 0.05497587182766108)],
    (2, 5): [(None, "vertex", 9 / 80), ((6 + _R15) / 21, "vertex", (155 + _R15) / 2400),
             ((6 - _R15) / 21, "vertex", (155 - _R15) / 2400)],
    (3, 4): [(0.09273525031089115, "vertex", 0.012248840519393624),
             (0.3108859192633003, "vertex", 0.01878132095300252),
             (0.4544962958743499, "edge", 0.007091003462847014)],
}
_SYMMETRIC[3, 5] = _SYMMETRIC[3, 4]


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

"""Values of finite element fields at given points (probes), e.g. the displacement of the points a benchmark reports.

`probe_matrix` finds the cell holding each point and its reference coordinates there (the affine inverse on
straight-sided cells, refined by Newton's method on the isoparametric map of curved P2 cells), and returns the
sparse matrix ``P`` (m, num_nodes) of the nodal shape values, so that the field at the points is
``P @ u.reshape(num_nodes, components)`` for every time level alike.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import InputError
from .spaces import VectorSpace, _inverse_map, reference_shape

__all__ = ["probe_matrix", "locate"]

#: A point this far outside every cell, in barycentric coordinates, lies outside the mesh.
_OUTSIDE = 1e-8


def locate(mesh, points) -> tuple[np.ndarray, np.ndarray]:
    """The straight cell holding each point (m,) and the point's reference coordinates in it (m, dim): the cell
    whose smallest barycentric coordinate of the point is largest; `InputError` if that is below -1e-8 (the
    point lies outside the mesh)."""
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if points.shape[1] != mesh.dim:
        raise InputError(f"probe: points must have {mesh.dim} coordinates, got shape {points.shape}")
    inverse = np.linalg.inv(mesh.cell_jacobians())  # (nc, dim, dim)
    x0 = mesh.points[mesh.cells[:, 0]]
    cells, xi = np.empty(len(points), np.int64), np.empty_like(points)
    for k, p in enumerate(points):
        local = np.einsum("cij,cj->ci", inverse, p - x0)
        smallest = np.minimum(local.min(axis=1), 1.0 - local.sum(axis=1))
        cells[k] = np.argmax(smallest)
        if smallest[cells[k]] < -_OUTSIDE:
            raise InputError(f"probe: the point {p.tolist()} lies outside the mesh")
        xi[k] = local[cells[k]]
    return cells, xi


def probe_matrix(space: VectorSpace, points) -> sp.csr_matrix:
    """Sparse ``P`` (m, space.num_nodes) with ``(P @ U)[k] = u(points[k])`` for nodal values U (num_nodes, k).

    ``points`` (m, dim) in the reference configuration. On a curved (isoparametric) P2 space the reference
    coordinates solve ``x(xi) = point`` in the located cell; a point between a curved wall and its straight
    facet is located in the nearest straight cell and extrapolated there by the cell's polynomials."""
    cells, xi = locate(space.mesh, points)
    if space.isoparametric:
        cell_x = space.nodes[space.cell_nodes[cells]]  # (m, nloc, dim)
        X = np.atleast_2d(np.asarray(points, dtype=np.float64))
        xi = _inverse_map(cell_x, X[:, None, :], xi[:, None, :])[:, 0]
    N, _ = reference_shape(space.dim, space.degree, xi)  # (m, nloc)
    rows = np.repeat(np.arange(len(cells)), N.shape[1])
    return sp.csr_matrix((N.ravel(), (rows, space.cell_nodes[cells].ravel())), shape=(len(cells), space.num_nodes))

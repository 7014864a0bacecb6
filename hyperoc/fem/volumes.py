"""Volumes of deformed configurations: the cavity enclosed by a boundary of the mesh."""

from __future__ import annotations

import numpy as np

from .quadrature import simplex_rule
from .spaces import VectorSpace, reference_shape

__all__ = ["cavity_volume"]


def cavity_volume(space: VectorSpace, u: np.ndarray, boundary: str = "endocardium", rim: str = "gamma_d") -> np.ndarray:
    """Volume (length^3) enclosed by the deformed surface ``boundary`` (e.g. a ventricle's endocardium),
    closed by the plane of its rim on ``rim`` (the clamped base), at each level: (nt,).

    ``V = sum_f s_f (1/3) int_f (x - O) . a dxi`` over the deformed facets, ``x = sum_a N_a (X_a + u_a)``
    the facet trace of the space (P1: flat triangles, the cones ``(a - O) . ((b - O) x (c - O)) / 6``;
    P2: curved, on isoparametric meshes from the curved reference facets), ``a = dx/dxi1 x dx/dxi2``,
    integrated exactly (degree ``3 k - 2``). ``O`` is the mean of the rim vertices (the closing plane
    contributes nothing when the rim stays in its plane) or of all the surface's vertices when there
    is no rim. The orientations ``s_f = +-1`` make every reference term positive: exact when the
    reference cavity is star-shaped about ``O`` (an ellipsoidal cavity about a point of its base).
    ``u`` (nt, num_nodes, 3) are the nodal displacements of ``space``.
    """
    mesh = space.mesh
    facets = mesh.boundary(boundary)
    nodes = space.facet_nodes(facets)  # (nf, m)
    rim_vertices = np.intersect1d(np.unique(facets), mesh.boundary_vertices(rim)) if rim in mesh.boundaries else []
    origin = mesh.points[rim_vertices if len(rim_vertices) else np.unique(facets)].mean(axis=0)
    xi, w = simplex_rule(2, 3 * space.degree - 2)
    N, dN = reference_shape(2, space.degree, xi)

    def facet_volumes(x):  # (..., num_nodes, 3) -> (..., nf)
        xf = x[..., nodes, :] - origin  # (..., nf, m, 3)
        T = np.einsum("...fai,qaj->...fqij", xf, dN)
        a = np.cross(T[..., 0], T[..., 1])
        return np.einsum("q,qa,...fai,...fqi->...f", w, N, xf, a) / 3.0

    sign = np.sign(facet_volumes(space.nodes))
    return np.einsum("tf,f->t", facet_volumes(space.nodes + np.asarray(u)), sign)

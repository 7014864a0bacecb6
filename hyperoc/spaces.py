"""Lagrange P1/P2 spaces on simplices and their quadrature data.

Nodes are the mesh vertices followed (P2) by edge midpoints. A vector field with ``dim``
components is stored node-major: dof ``a * dim + i`` is component ``i`` at node ``a``.

`CellQuadrature` holds what every kernel needs: reference shape values, physical gradients
``dN/dX`` and the weights ``w_q |det J_c|`` for one quadrature rule.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .errors import InputError
from .mesh import Mesh
from .quadrature import simplex_rule

__all__ = ["VectorSpace", "CellQuadrature", "reference_shape"]


def _local_edges(dim: int) -> list[tuple[int, int]]:
    return list(itertools.combinations(range(dim + 1), 2))


def _barycentric(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric coordinates (nq, dim+1) and their constant reference gradients (dim+1, dim)."""
    dim = xi.shape[1]
    lam = np.concatenate([1.0 - xi.sum(axis=1, keepdims=True), xi], axis=1)
    dlam = np.concatenate([-np.ones((1, dim)), np.eye(dim)], axis=0)
    return lam, dlam


def reference_shape(dim: int, degree: int, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shape functions N (nq, nloc) and reference gradients dN/dxi (nq, nloc, dim).

    P1: ``N_i = lambda_i``. P2: vertices ``lambda_i (2 lambda_i - 1)``, edges ``4 lambda_i lambda_j``
    in the order of ``itertools.combinations(range(dim + 1), 2)``.
    """
    lam, dlam = _barycentric(np.atleast_2d(xi))
    if degree == 1:
        return lam, np.broadcast_to(dlam, (lam.shape[0],) + dlam.shape).copy()
    if degree != 2:
        raise InputError(f"Lagrange degree must be 1 or 2, got {degree}")
    vals = [lam[:, i] * (2 * lam[:, i] - 1) for i in range(dim + 1)]
    grads = [(4 * lam[:, i] - 1)[:, None] * dlam[i] for i in range(dim + 1)]
    for i, j in _local_edges(dim):
        vals.append(4 * lam[:, i] * lam[:, j])
        grads.append(4 * (lam[:, j][:, None] * dlam[i] + lam[:, i][:, None] * dlam[j]))
    return np.stack(vals, axis=1), np.stack(grads, axis=1)


@dataclass(frozen=True, eq=False)
class CellQuadrature:
    """Quadrature data on every cell for one rule.

    Attributes
    ----------
    N : (nq, nloc) shape values at the reference points.
    dN : (nc, nq, nloc, dim) physical gradients dN/dX.
    wdx : (nc, nq) weights times |det J|, so that ``sum(wdx * f) = int_Omega f``.
    x : (nc, nq, dim) physical coordinates of the quadrature points.
    """

    N: np.ndarray
    dN: np.ndarray
    wdx: np.ndarray
    x: np.ndarray


class VectorSpace:
    """Continuous vector-valued Lagrange space of degree 1 or 2 on an affine simplicial mesh.

    Parameters
    ----------
    mesh : Mesh
    degree : 1 or 2
    components : number of field components (default: the mesh dimension; 1 for scalar fields)
    """

    def __init__(self, mesh: Mesh, degree: int = 1, components: int | None = None):
        if degree not in (1, 2):
            raise InputError(f"Lagrange degree must be 1 or 2, got {degree}")
        self.mesh, self.degree = mesh, degree
        self.dim = mesh.dim
        self.components = self.dim if components is None else int(components)
        self.nodes, self.cell_nodes, self._edge_index = self._build_nodes()

    def _build_nodes(self):
        mesh = self.mesh
        if self.degree == 1:
            return mesh.points, mesh.cells, {}
        pairs = np.concatenate([np.sort(mesh.cells[:, [i, j]], axis=1) for i, j in _local_edges(self.dim)])
        edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
        nv = mesh.points.shape[0]
        mid = 0.5 * (mesh.points[edges[:, 0]] + mesh.points[edges[:, 1]])
        edge_nodes = nv + inverse.reshape(len(_local_edges(self.dim)), -1).T
        index = {(int(a), int(b)): nv + k for k, (a, b) in enumerate(edges)}
        return np.concatenate([mesh.points, mid]), np.concatenate([mesh.cells, edge_nodes], axis=1), index

    # --- sizes and dof maps -------------------------------------------------------------------
    @property
    def num_nodes(self) -> int:
        return self.nodes.shape[0]

    @property
    def num_dofs(self) -> int:
        return self.num_nodes * self.components

    @property
    def nloc(self) -> int:
        return self.cell_nodes.shape[1]

    @cached_property
    def cell_dofs(self) -> np.ndarray:
        """(nc, nloc * components) global dofs of each cell, node-major."""
        c = self.components
        return (self.cell_nodes[:, :, None] * c + np.arange(c)).reshape(len(self.cell_nodes), -1)

    def node_dofs(self, nodes: np.ndarray) -> np.ndarray:
        """All component dofs of the given nodes, flattened."""
        return (np.asarray(nodes)[:, None] * self.components + np.arange(self.components)).ravel()

    def facet_nodes(self, facets: np.ndarray) -> np.ndarray:
        """(nf, nloc_facet) nodes on each facet: its vertices then (P2) its edge midpoints."""
        facets = np.asarray(facets, dtype=np.int64)
        if self.degree == 1 or facets.shape[1] == 1:
            return facets
        mids = [[self._edge_index[tuple(sorted((int(f[i]), int(f[j]))))] for i, j in _local_edges(facets.shape[1] - 1)] for f in facets]
        return np.concatenate([facets, np.array(mids, dtype=np.int64).reshape(len(facets), -1)], axis=1)

    def boundary_nodes(self, name: str) -> np.ndarray:
        return np.unique(self.facet_nodes(self.mesh.boundary(name)))

    def cell_mask_nodes(self, mask: np.ndarray) -> np.ndarray:
        """Nodes of the cells selected by a boolean mask."""
        return np.unique(self.cell_nodes[np.asarray(mask, bool)])

    # --- quadrature ---------------------------------------------------------------------------
    def quadrature(self, degree: int) -> CellQuadrature:
        """Shape values, physical gradients and weights for a rule exact to ``degree``."""
        xi, w = simplex_rule(self.dim, degree)
        N, dN_ref = reference_shape(self.dim, self.degree, xi)
        J = self.mesh.cell_jacobians()
        Jinv = np.linalg.inv(J)
        dN = np.einsum("qaj,cjk->cqak", dN_ref, Jinv)
        detJ = np.abs(np.linalg.det(J))
        x0 = self.mesh.points[self.mesh.cells[:, 0]]
        x = x0[:, None, :] + np.einsum("cij,qj->cqi", J, xi)
        return CellQuadrature(N=N, dN=dN, wdx=detJ[:, None] * w[None, :], x=x)

    @cached_property
    def default_degree(self) -> int:
        """Rule degree exact for the mass matrix and for cubic stress times gradient (P2)."""
        return 2 * self.degree

    # --- fields -------------------------------------------------------------------------------
    def interpolate(self, fn) -> np.ndarray:
        """Nodal interpolant of ``fn(x: (n, dim)) -> (n, components)`` as a flat dof vector."""
        vals = np.asarray(fn(self.nodes), dtype=np.float64).reshape(self.num_nodes, self.components)
        return vals.ravel()

    def evaluate(self, u: np.ndarray, quad: CellQuadrature) -> tuple[np.ndarray, np.ndarray]:
        """Values (nc, nq, comp) and gradients (nc, nq, comp, dim) of a dof vector at quadrature points."""
        ue = np.asarray(u).reshape(self.num_nodes, self.components)[self.cell_nodes]
        return np.einsum("qa,cai->cqi", quad.N, ue), np.einsum("cqaj,cai->cqij", quad.dN, ue)

    def errors(self, u: np.ndarray, exact, exact_grad, degree: int | None = None) -> tuple[float, float]:
        """L2 and H1-seminorm errors ``(||u - u_ex||, ||grad(u - u_ex)||)``.

        ``exact(x)`` returns (..., comp) and ``exact_grad(x)`` returns (..., comp, dim) for x (..., dim).
        """
        quad = self.quadrature(degree or 2 * self.degree + 2)
        val, grad = self.evaluate(u, quad)
        ev = np.asarray(exact(quad.x)).reshape(val.shape)
        eg = np.asarray(exact_grad(quad.x)).reshape(grad.shape)
        l2 = np.sqrt(np.sum(quad.wdx * np.sum((val - ev) ** 2, axis=-1)))
        h1 = np.sqrt(np.sum(quad.wdx * np.sum((grad - eg) ** 2, axis=(-2, -1))))
        return float(l2), float(h1)

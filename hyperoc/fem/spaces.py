"""Lagrange P1/P2 spaces on simplices and their quadrature data.

Nodes are the mesh vertices followed (P2) by one node per edge: its midpoint, or on a curved
mesh (`hyperoc.fem.mesh.Mesh.curved_edges`) the position the mesh gives it. A vector field with ``dim``
components is stored node-major: dof ``a * dim + i`` is component ``i`` at node ``a``.

`CellQuadrature` holds what every kernel needs: reference shape values, physical gradients
``dN/dX`` and the weights ``w_q |det J|`` for one quadrature rule. Straight-sided cells have the
constant Jacobian of their affine map; a P2 space on a curved mesh is isoparametric: each cell is
the image of the reference simplex under ``x(xi) = sum_a N_a(xi) X_a`` (P2 shape functions N_a,
nodes X_a), with the Jacobian ``J_q = sum_a X_a (x) dN_a/dxi (xi_q)`` at every quadrature point.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..errors import InputError
from .mesh import Mesh
from .quadrature import simplex_rule

__all__ = ["VectorSpace", "CellQuadrature", "reference_shape", "prolong"]


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


def _edge_rows(edges: np.ndarray, wanted: np.ndarray, num_points: int) -> np.ndarray:
    """Rows of the sorted unique edges (ne, 2) that equal the sorted pairs ``wanted`` (m, 2), (m,);
    `InputError` if a wanted pair is not an edge of the mesh cells."""
    key = lambda e: e[:, 0] * num_points + e[:, 1]
    rows = np.searchsorted(key(edges), key(wanted))
    if wanted.size and (rows.max() >= len(edges) or np.any(key(edges[rows]) != key(wanted))):
        raise InputError("some vertex pairs (e.g. curved edges of the mesh) are not edges of the mesh cells")
    return rows


@dataclass(frozen=True, eq=False)
class CellQuadrature:
    """Quadrature data on every cell for one rule.

    Attributes
    ----------
    N : (nq, nloc) shape values at the reference points.
    dN : (nc, nq, nloc, dim) physical gradients dN/dX.
    wdx : (nc, nq) weights times |det J|, so that ``sum(wdx * f) = int_Omega f``.
    x : (nc, nq, dim) physical coordinates of the quadrature points.
    xi : (nq, dim) the reference points (other bases on the same points, e.g. a P1 pressure).
    """

    N: np.ndarray
    dN: np.ndarray
    wdx: np.ndarray
    x: np.ndarray
    xi: np.ndarray


class VectorSpace:
    """Continuous vector-valued Lagrange space of degree 1 or 2 on a simplicial mesh: affine cells,
    or for degree 2 on a curved mesh isoparametric P2 cells (``isoparametric``).

    Parameters
    ----------
    mesh : Mesh
    degree : 1 or 2
    components : number of field components (default: the mesh dimension; 1 for scalar fields)

    Attributes: ``nodes`` (num_nodes, dim) node coordinates (P2 edge nodes at the mesh's curved
    positions where it has them); ``cell_nodes`` (nc, nloc); ``edges`` (ne, 2) the sorted vertex
    pairs of the P2 edge nodes, node ``nv + k`` on edge k (nv vertices; empty for P1).
    """

    def __init__(self, mesh: Mesh, degree: int = 1, components: int | None = None):
        if degree not in (1, 2):
            raise InputError(f"Lagrange degree must be 1 or 2, got {degree}")
        self.mesh, self.degree = mesh, degree
        self.dim = mesh.dim
        self.components = self.dim if components is None else int(components)
        self.nodes, self.cell_nodes, self.edges = self._build_nodes()

    @property
    def isoparametric(self) -> bool:
        """True for a P2 space on a curved mesh: cells mapped by their P2 nodes, not affinely."""
        return self.degree == 2 and self.mesh.is_curved

    def _build_nodes(self):
        mesh = self.mesh
        if self.degree == 1:
            return mesh.points, mesh.cells, np.zeros((0, 2), np.int64)
        pairs = np.concatenate([np.sort(mesh.cells[:, [i, j]], axis=1) for i, j in _local_edges(self.dim)])
        edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
        nv = mesh.points.shape[0]
        mid = 0.5 * (mesh.points[edges[:, 0]] + mesh.points[edges[:, 1]])
        mid[_edge_rows(edges, mesh.curved_edges, nv)] = mesh.curved_points
        edge_nodes = nv + inverse.reshape(len(_local_edges(self.dim)), -1).T
        return np.concatenate([mesh.points, mid]), np.concatenate([mesh.cells, edge_nodes], axis=1), edges

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

    def edge_nodes(self, pairs) -> np.ndarray:
        """P2 nodes of the edges given as vertex pairs (..., 2) (either order), shape (...);
        `InputError` if a pair is not an edge of the mesh."""
        pairs = np.sort(np.asarray(pairs, dtype=np.int64), axis=-1)
        nv = self.mesh.points.shape[0]
        return nv + _edge_rows(self.edges, pairs.reshape(-1, 2), nv).reshape(pairs.shape[:-1])

    def facet_nodes(self, facets: np.ndarray) -> np.ndarray:
        """(nf, nloc_facet) nodes on each facet: its vertices then (P2) its edge nodes, in the order of
        ``itertools.combinations`` of the facet's vertices."""
        facets = np.asarray(facets, dtype=np.int64)
        if self.degree == 1 or facets.shape[1] == 1:
            return facets
        pairs = np.stack([facets[:, [i, j]] for i, j in _local_edges(facets.shape[1] - 1)], axis=1)
        return np.concatenate([facets, self.edge_nodes(pairs).reshape(len(facets), -1)], axis=1)

    def boundary_nodes(self, name: str) -> np.ndarray:
        return np.unique(self.facet_nodes(self.mesh.boundary(name)))

    def cell_mask_nodes(self, mask: np.ndarray) -> np.ndarray:
        """Nodes of the cells selected by a boolean mask."""
        return np.unique(self.cell_nodes[np.asarray(mask, bool)])

    # --- quadrature ---------------------------------------------------------------------------
    def quadrature(self, degree: int) -> CellQuadrature:
        """Shape values, physical gradients and weights for a rule exact to ``degree`` (on affine
        cells; isoparametric cells have rational integrands, integrated approximately)."""
        xi, w = simplex_rule(self.dim, degree)
        N, dN_ref = reference_shape(self.dim, self.degree, xi)
        if self.isoparametric:
            return self._isoparametric_quadrature(xi, w, N, dN_ref)
        J = self.mesh.cell_jacobians()
        Jinv = np.linalg.inv(J)
        dN = np.einsum("qaj,cjk->cqak", dN_ref, Jinv)
        detJ = np.abs(np.linalg.det(J))
        x0 = self.mesh.points[self.mesh.cells[:, 0]]
        x = x0[:, None, :] + np.einsum("cij,qj->cqi", J, xi)
        return CellQuadrature(N=N, dN=dN, wdx=detJ[:, None] * w[None, :], x=x, xi=xi)

    def _isoparametric_quadrature(self, xi, w, N, dN_ref) -> CellQuadrature:
        """P2 geometry: ``x_q = sum_a N_a(xi_q) X_a``, ``J_q = sum_a X_a (x) dN_a/dxi (xi_q)`` (nc, nq,
        dim, dim), ``dN/dX = dN/dxi J_q^-1``, ``wdx = w_q det J_q``; `InputError` if some ``det J_q <= 0``
        (a curved cell folded over itself: refine the mesh near the curved boundary)."""
        X = self.nodes[self.cell_nodes]  # (nc, nloc, dim)
        J = np.einsum("cai,qaj->cqij", X, dN_ref)
        detJ = np.linalg.det(J)
        if np.any(detJ <= 0):
            bad = int(np.sum(np.any(detJ <= 0, axis=1)))
            raise InputError(f"curved P2 mesh: {bad} cell(s) with det J <= 0 at a quadrature point (cells folded "
                             "by the curved edge nodes; refine near the curved boundary or use Mesh.faceted())")
        dN = np.einsum("qaj,cqjk->cqak", dN_ref, np.linalg.inv(J))
        x = np.einsum("qa,cai->cqi", N, X)
        return CellQuadrature(N=N, dN=dN, wdx=detJ * w[None, :], x=x, xi=xi)

    def facet_quadrature(self, facets: np.ndarray, degree: int):
        """Quadrature on boundary facets (nf, dim) (vertex indices) for a rule exact to ``degree``
        on straight facets: points x (nf, nq, dim), reference weights w (nq,), facet shape values
        N (nq, m) (P1/P2 trace, nodes ordered as `facet_nodes`), and area elements dS (nf, nq)
        (``int_facet g dS = sum_q w_q dS_q g(x_q)``). Isoparametric spaces use the facet's P2 map:
        ``x = sum_a N_a X_a``, ``dS = sqrt(det(T^T T))`` with the tangents ``T = sum_a X_a (x) dN_a/dxi``;
        in 1D the facets are points (w = N = dS = 1)."""
        facets = np.asarray(facets, dtype=np.int64)
        fd = self.dim - 1
        if fd == 0:
            return self.mesh.points[facets], np.ones(1), np.ones((1, 1)), np.ones((len(facets), 1))
        xi, w = simplex_rule(fd, degree)
        N, dN_ref = reference_shape(fd, self.degree, xi)
        if self.isoparametric:
            X = self.nodes[self.facet_nodes(facets)]  # (nf, m, dim)
            T = np.einsum("fai,qaj->fqij", X, dN_ref)
            x = np.einsum("qa,fai->fqi", N, X)
        else:
            xv = self.mesh.points[facets]
            T = np.broadcast_to(np.swapaxes(xv[:, 1:] - xv[:, :1], 1, 2)[:, None], (len(facets), len(w), self.dim, fd))
            x = xv[:, :1, :] + np.einsum("fij,qj->fqi", T[:, 0], xi)
        return x, w, N, np.sqrt(np.linalg.det(np.einsum("fqji,fqjk->fqik", T, T)))

    def laplace_blocks(self) -> np.ndarray:
        """Scalar stiffness matrices ``int grad N_a . grad N_b dX`` (nc, nloc, nloc), rule of degree
        ``2 (degree - 1)`` (exact on affine cells)."""
        q = self.quadrature(2 * self.degree - 2)
        return np.einsum("cq,cqaj,cqbj->cab", q.wdx, q.dN, q.dN)

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


def prolong(coarse: VectorSpace, fine: VectorSpace, u: np.ndarray) -> np.ndarray:
    """Nodal interpolant on ``fine`` (its num_dofs,) of the field ``u`` of ``coarse`` (num_dofs,), when
    ``fine.mesh`` is a uniform refinement of ``coarse.mesh`` (`hyperoc.fem.mesh.refine`, or a generator's
    ``refinements``): the value at each fine node X is the coarse field at the material point X.

    Every fine cell lies in one coarse cell, its parent: its vertices are nodes of the parent's P2
    geometry (vertices and edge points), the points of barycentric coordinates ``e_i`` and
    ``(e_i + e_j) / 2``. A fine node's reference point in the parent is found from there: on
    straight-sided cells it is the mean of its edge's vertices; on a curved mesh (isoparametric
    parents) Newton's method on ``x_parent(xi) = X`` corrects it, since the fine mesh is straighter
    inside than its curved parents and puts its boundary edge nodes on the exact surface, O(h^3)
    outside the parent (where the coarse field is extrapolated). Without that correction a starting
    guess can invert thin boundary cells. Coarse functions are reproduced exactly by nested spaces
    (P1 -> P1, P1 -> P2, P2 -> P2 on straight-sided cells).

    Raises `InputError` if a fine vertex is not such a node or a fine cell has no parent.
    """
    if coarse.components != fine.components or coarse.dim != fine.dim:
        raise InputError("prolong: the spaces differ in dimension or number of components")
    dim = coarse.dim
    geometry = coarse if coarse.degree == 2 else VectorSpace(coarse.mesh, 2, components=1)
    parent, local = _parents(geometry, fine.mesh)
    eye = np.eye(dim + 1)
    node_bary = np.concatenate([eye, [(eye[i] + eye[j]) / 2 for i, j in _local_edges(dim)]])
    bary = node_bary[local]  # (ncf, dim + 1, dim + 1): the fine cells' vertices in their parents
    if fine.degree == 2:
        bary = np.concatenate(
            [bary, np.stack([(bary[:, i] + bary[:, j]) / 2 for i, j in _local_edges(dim)], axis=1)], axis=1)
    xi = bary[..., 1:]  # (ncf, nloc_fine, dim)
    if geometry.isoparametric:
        xi = _inverse_map(geometry.nodes[geometry.cell_nodes[parent]], fine.nodes[fine.cell_nodes], xi)
    N, _ = reference_shape(dim, coarse.degree, xi.reshape(-1, dim))
    N = N.reshape(xi.shape[0], xi.shape[1], -1)  # (ncf, nloc_fine, nloc_coarse)
    uc = np.asarray(u, dtype=np.float64).reshape(coarse.num_nodes, coarse.components)[coarse.cell_nodes[parent]]
    out = np.empty((fine.num_nodes, fine.components))
    out[fine.cell_nodes] = np.einsum("cab,cbi->cai", N, uc)  # a node shared by cells: the same value
    return out.ravel()


def _inverse_map(cell_x: np.ndarray, X: np.ndarray, xi: np.ndarray, max_iter: int = 20) -> np.ndarray:
    """Reference points ``xi`` (nc, m, dim) with ``sum_a N_a(xi) cell_x[:, a] = X`` (nc, m, dim) in the
    isoparametric P2 cells of nodes ``cell_x`` (nc, nloc, dim), by Newton's method from ``xi``, until
    the step is round-off (a reference cell has unit size)."""
    nc, m, dim = xi.shape
    for _ in range(max_iter):
        N, dN = reference_shape(dim, 2, xi.reshape(-1, dim))
        N, dN = N.reshape(nc, m, -1), dN.reshape(nc, m, -1, dim)
        r = np.einsum("cpa,cai->cpi", N, cell_x) - X
        jac = np.einsum("cai,cpaj->cpij", cell_x, dN)
        step = np.linalg.solve(jac, r[..., None])[..., 0]
        xi = xi - step
        if np.abs(step).max() < 1e-13:
            return xi
    raise InputError("prolong: the inverse isoparametric map of a fine node did not converge "
                     "(a fine node far outside its parent)")


def _parents(geometry: VectorSpace, fine: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """For each cell of ``fine``: its parent cell in ``geometry.mesh`` (ncf,) and the local P2 node
    index in the parent of each of its vertices (ncf, dim + 1)."""
    scale = np.ptp(geometry.nodes, axis=0).max()
    dist, node = cKDTree(geometry.nodes).query(fine.points)
    if np.any(dist > 1e-9 * scale):
        raise InputError("prolong: the fine mesh is not a refinement of the coarse one "
                         "(a vertex is not a coarse P2 node)")
    nodes = node[fine.cells]  # (ncf, dim + 1) coarse node of each fine vertex
    nc, nloc = geometry.cell_nodes.shape
    incidence = sp.csr_matrix((np.ones(nc * nloc), geometry.cell_nodes.ravel(), np.arange(nc + 1) * nloc),
                              shape=(nc, geometry.num_nodes))
    vertices = sp.csr_matrix((np.ones(nodes.size), nodes.ravel(), np.arange(0, nodes.size + 1, fine.dim + 1)),
                             shape=(len(nodes), geometry.num_nodes))
    shared = (vertices @ incidence.T).tocoo()  # (ncf, nc): how many of the fine vertices each coarse cell holds
    full = shared.data == fine.dim + 1
    parent = np.full(len(nodes), -1)
    parent[shared.row[full]] = shared.col[full]
    if np.any(parent < 0) or np.count_nonzero(full) != len(nodes):
        raise InputError("prolong: some fine cell lies in no single coarse cell (not a uniform refinement)")
    local = np.argmax(geometry.cell_nodes[parent][:, None, :] == nodes[:, :, None], axis=2)
    return parent, local

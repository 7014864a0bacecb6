"""Control operators ``xi -> <f(xi), phi>``, linear in xi and supported on a region omega.

- `BodyForce`: ``<f(xi), phi> = int_omega xi . phi`` with a vector control xi (what the paper's
  1D experiment uses);
- `ActiveStress`: ``<f(xi), phi> = int_omega xi (fhat (x) fhat) : grad phi`` with a scalar xi and a
  unit fibre field fhat (paper ``sec-app-control``, with the paper's sign).

The control is discretized with the state's Lagrange space restricted to the closure of omega:
its dofs are the nodal values on the nodes of the cells of omega. `ControlData.load` is the
(reduced state dofs x control dofs) matrix B with load ``B xi``, and `ControlData.mass` the
L2(omega) Gram matrix of the control dofs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp

from .errors import InputError
from .mesh import Mesh
from .spaces import VectorSpace

__all__ = ["Region", "BodyForce", "ActiveStress", "ControlData", "circumferential_fibres"]


@dataclass(frozen=True)
class Region:
    """A set of cells: a mesh tag, an axis-aligned box, an annular sector, or the whole domain.

    A cell belongs to the region when its centroid does (tags select cells directly).

    Parameters
    ----------
    kind : "all" | "tag" | "box" | "sector"
    tag : subdomain name (kind "tag").
    lower, upper : box corners, length dim (kind "box").
    r_range, theta_range : radii and polar angles in radians in the (x, y) plane (kind "sector").
    """

    kind: str = "all"
    tag: str | None = None
    lower: tuple | None = None
    upper: tuple | None = None
    r_range: tuple | None = None
    theta_range: tuple | None = None

    def cell_mask(self, mesh: Mesh) -> np.ndarray:
        c = mesh.cell_centroids()
        if self.kind == "all":
            mask = np.ones(mesh.num_cells, bool)
        elif self.kind == "tag":
            if self.tag not in mesh.subdomains:
                raise InputError(f"control region: the mesh has no subdomain {self.tag!r} (available: {sorted(mesh.subdomains)})")
            mask = mesh.subdomains[self.tag]
        elif self.kind == "box":
            lo, hi = np.asarray(self.lower, float), np.asarray(self.upper, float)
            if lo.shape != (mesh.dim,) or hi.shape != (mesh.dim,):
                raise InputError(f"control region: box corners need {mesh.dim} coordinates")
            mask = np.all((c >= lo - 1e-12) & (c <= hi + 1e-12), axis=1)
        elif self.kind == "sector":
            if mesh.dim < 2:
                raise InputError("control region: a sector needs a 2D or 3D mesh")
            r = np.hypot(c[:, 0], c[:, 1])
            th = np.arctan2(c[:, 1], c[:, 0])
            (r0, r1), (a0, a1) = self.r_range or (0, np.inf), self.theta_range or (-np.pi, np.pi)
            mask = (r >= r0) & (r <= r1) & (th >= a0) & (th <= a1)
        else:
            raise InputError(f"control region: unknown kind {self.kind!r} (all, tag, box, sector)")
        if not mask.any():
            raise InputError(f"control region {self.describe()} contains no cell of the mesh (is it outside the domain?)")
        return mask

    def describe(self) -> str:
        if self.kind == "box":
            return f"box {list(self.lower)}..{list(self.upper)}"
        if self.kind == "tag":
            return f"tag {self.tag!r}"
        if self.kind == "sector":
            return f"sector r in {self.r_range}, theta in {self.theta_range}"
        return "all"


@dataclass(frozen=True, eq=False)
class ControlData:
    """Discrete control operator.

    Attributes
    ----------
    load : (n_state, n_ctrl) csr, maps control dofs to the load vector on the reduced state dofs.
    mass : (n_ctrl, n_ctrl) csr, L2(omega) Gram matrix: ``||xi||^2 = xi^T mass xi``.
    nodes : (n_nodes,) indices of the space nodes carrying control values.
    components : values per node (dim for a body force, 1 for active stress).
    cell_mask : (nc,) the cells of omega.
    """

    load: sp.csr_matrix
    mass: sp.csr_matrix
    nodes: np.ndarray
    components: int
    cell_mask: np.ndarray

    @property
    def size(self) -> int:
        return self.nodes.size * self.components

    def coordinates(self, space: VectorSpace) -> np.ndarray:
        """Coordinates (n_nodes, dim) of the control nodes."""
        return space.nodes[self.nodes]

    def nodal(self, xi: np.ndarray) -> np.ndarray:
        """Control vector(s) (..., n_ctrl) as nodal values (..., n_nodes, components)."""
        return np.asarray(xi).reshape(*np.shape(xi)[:-1], self.nodes.size, self.components)


def _cell_blocks_to_matrix(rows_e, cols_e, blocks, shape) -> sp.csr_matrix:
    k, m = rows_e.shape[1], cols_e.shape[1]
    r = np.repeat(rows_e, m, axis=1).ravel()
    c = np.tile(cols_e, (1, k)).ravel()
    v = blocks.reshape(-1)
    keep = (r >= 0) & (c >= 0)
    return sp.coo_matrix((v[keep], (r[keep], c[keep])), shape=shape).tocsr()


def _control_numbering(space: VectorSpace, mask: np.ndarray, components: int):
    nodes = space.cell_mask_nodes(mask)
    local = np.full(space.num_nodes, -1, dtype=np.int64)
    local[nodes] = np.arange(nodes.size)
    cn = local[space.cell_nodes[mask]]  # (nc_omega, nloc)
    cdofs = (cn[:, :, None] * components + np.arange(components)).reshape(len(cn), -1)
    return nodes, cdofs


def _scalar_mass_blocks(space: VectorSpace, mask: np.ndarray) -> np.ndarray:
    q = space.quadrature(2 * space.degree)
    return np.einsum("cq,qa,qb->cab", q.wdx[mask], q.N, q.N)


@dataclass(frozen=True)
class BodyForce:
    """Distributed body force ``<f(xi), phi> = int_omega xi . phi`` (vector control, density units)."""

    region: Region = field(default_factory=Region)

    def build(self, space: VectorSpace, to_reduced: np.ndarray) -> ControlData:
        mask = self.region.cell_mask(space.mesh)
        d = space.components
        nodes, cdofs = _control_numbering(space, mask, d)
        Ms = _scalar_mass_blocks(space, mask)
        blocks = np.einsum("cab,ij->caibj", Ms, np.eye(d)).reshape(len(Ms), d * space.nloc, d * space.nloc)
        sdofs = to_reduced[space.cell_dofs[mask]]
        n_state = int(to_reduced.max()) + 1
        load = _cell_blocks_to_matrix(sdofs, cdofs, blocks, (n_state, nodes.size * d))
        mass = _cell_blocks_to_matrix(cdofs, cdofs, blocks, (nodes.size * d,) * 2)
        return ControlData(load, mass, nodes, d, mask)


def circumferential_fibres(x: np.ndarray) -> np.ndarray:
    """Unit vectors ``(-y, x, 0) / r`` around the z axis, for x of shape (..., dim >= 2)."""
    t = np.zeros_like(x)
    t[..., 0], t[..., 1] = -x[..., 1], x[..., 0]
    return t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-300)


@dataclass(frozen=True)
class ActiveStress:
    """Active stress along fibres ``<f(xi), phi> = int_omega xi (fhat (x) fhat) : grad phi`` (scalar xi).

    ``fibres`` maps quadrature points (..., dim) to unit vectors (..., dim); default: the x axis in
    1D, circumferential in 2D/3D. The sign is the paper's (``sec-app-control``).
    """

    region: Region = field(default_factory=Region)
    fibres: Callable | None = None

    def fibre_field(self, x: np.ndarray) -> np.ndarray:
        if self.fibres is not None:
            f = np.asarray(self.fibres(x), dtype=np.float64)
        elif x.shape[-1] == 1:
            f = np.ones_like(x)
        else:
            f = circumferential_fibres(x)
        return f / np.maximum(np.linalg.norm(f, axis=-1, keepdims=True), 1e-300)

    def build(self, space: VectorSpace, to_reduced: np.ndarray) -> ControlData:
        mask = self.region.cell_mask(space.mesh)
        nodes, cdofs = _control_numbering(space, mask, 1)
        q = space.quadrature(2 * space.degree)
        f = self.fibre_field(q.x[mask])  # (nc, nq, d)
        # B[(a, i), b] = sum_q w N_b f_i f_J dN_a/dX_J
        fdN = np.einsum("cqj,cqaj->cqa", f, q.dN[mask])
        blocks = np.einsum("cq,cqa,cqi,qb->caib", q.wdx[mask], fdN, f, q.N)
        blocks = blocks.reshape(len(blocks), space.nloc * space.components, space.nloc)
        sdofs = to_reduced[space.cell_dofs[mask]]
        n_state = int(to_reduced.max()) + 1
        load = _cell_blocks_to_matrix(sdofs, cdofs, blocks, (n_state, nodes.size))
        mass = _cell_blocks_to_matrix(cdofs, cdofs, _scalar_mass_blocks(space, mask), (nodes.size,) * 2)
        return ControlData(load, mass, nodes, 1, mask)

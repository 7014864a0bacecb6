"""Control operators ``xi -> <f(xi), phi>``, linear in xi and supported on a region omega.

- `BodyForce`: ``<f(xi), phi> = int_omega xi . phi`` with a vector control xi (what the paper's
  1D experiment uses);
- `ActiveStress`: ``<f(xi), phi> = int_omega xi (fhat (x) fhat) : grad phi`` with a scalar xi and a
  unit fibre field fhat (the paper's appendix on control operators, with the paper's sign).

The control is discretized with the state's Lagrange space restricted to the closure of omega:
its dofs are the nodal values on the nodes of the cells of omega. `ControlData.load` is the
(reduced state dofs x control dofs) matrix B with load ``B xi``, and `ControlData.mass` the
L2(omega) Gram matrix of the control dofs.

Either operator takes an optional time profile ``g`` (a `hyperoc.dynamics.laws.TimeLaw`): time-dependent
runs then apply the load ``B (g(t) xi(t))``, so the control scales a prescribed history. With ``g`` the
prescribed activation T_a(t) (Pa) of a cardiac run and an active-stress control, xi is dimensionless and the
fibre tension is ``T_a(t) (1 - xi)``: a modulation of the tissue's contractility that acts only while
the tissue is active, and "a contraction cannot push" is the bound ``xi <= 1``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp

from ..errors import InputError
from ..fem.mesh import Mesh
from ..fem.spaces import VectorSpace
from .fibres import transmural_coordinate

__all__ = ["Region", "BodyForce", "ActiveStress", "ControlData", "circumferential_fibres"]


@dataclass(frozen=True)
class Region:
    """A set of cells: the whole domain, a mesh tag, an axis-aligned box, an annular sector, an
    apical cap or a transmural band.

    A cell belongs to the region when its centroid does (tags select cells directly).

    Parameters
    ----------
    kind : "all" | "tag" | "box" | "sector" | "cap" | "band"
    tag : subdomain name (kind "tag").
    lower, upper : box corners, length dim (kind "box").
    r_range, theta_range : radii and polar angles in radians in the (x, y) plane (kind "sector").
    z_max : height (length units) below which the cells form an apical cap ``z <= z_max`` (kind
        "cap", 3D, long axis z with the apex at the bottom); must lie below the top of the mesh (the
        base of a ventricle).
    transmural : ``(a, b)`` with ``0 <= a < b <= 1``: the cells whose transmural coordinate ``d``
        (`hyperoc.mechanics.fibres.transmural_coordinate`, 0 on ``inner``, 1 on ``outer``) at the centroid lies in
        ``[a, b]`` (kind "band"; e.g. ``(0, 1/3)`` the subendocardial third).
    inner, outer : boundary names of the two walls (kind "band").
    """

    kind: str = "all"
    tag: str | None = None
    lower: tuple | None = None
    upper: tuple | None = None
    r_range: tuple | None = None
    theta_range: tuple | None = None
    z_max: float | None = None
    transmural: tuple | None = None
    inner: str = "endocardium"
    outer: str = "epicardium"

    def cell_mask(self, mesh: Mesh) -> np.ndarray:
        """Boolean (nc,) mask of the cells of the region; `InputError` if it is malformed or empty."""
        c = mesh.cell_centroids()
        if self.kind == "all":
            mask = np.ones(mesh.num_cells, bool)
        elif self.kind == "tag":
            if self.tag not in mesh.subdomains:
                raise InputError(f"control region: the mesh has no subdomain {self.tag!r} "
                                 f"(available: {sorted(mesh.subdomains)})")
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
        elif self.kind == "cap":
            mask = c[:, 2] <= self._cap_level(mesh)
        elif self.kind == "band":
            a, b = self._band()
            d = transmural_coordinate(mesh, self.inner, self.outer)[mesh.cells].mean(axis=1)
            mask = (d >= a) & (d <= b)
        else:
            raise InputError(f"control region: unknown kind {self.kind!r} (all, tag, box, sector, cap, band)")
        if not mask.any():
            raise InputError(f"control region {self.describe()} contains no cell of the mesh "
                             "(is it outside the domain?)")
        return mask

    def _cap_level(self, mesh: Mesh) -> float:
        if mesh.dim != 3:
            raise InputError(f"control region: a cap needs a 3D mesh (long axis z), got dimension {mesh.dim}")
        if self.z_max is None or not np.isfinite(self.z_max):
            raise InputError(f"control region: a cap needs a finite z_max, got {self.z_max}")
        top = float(mesh.points[:, 2].max())
        if self.z_max >= top:
            raise InputError(f"control region: cap z_max = {self.z_max:g} is at or above the base (top of the mesh "
                             f"z = {top:g}); use kind = 'all' for the whole wall")
        return float(self.z_max)

    def _band(self) -> tuple[float, float]:
        band = self.transmural
        if band is None or len(band) != 2 or not (0.0 <= band[0] < band[1] <= 1.0):
            raise InputError(f"control region: a band needs transmural = [a, b] with 0 <= a < b <= 1, got {band}")
        return float(band[0]), float(band[1])

    def describe(self) -> str:
        if self.kind == "box":
            return f"box {list(self.lower)}..{list(self.upper)}"
        if self.kind == "tag":
            return f"tag {self.tag!r}"
        if self.kind == "sector":
            return f"sector r in {self.r_range}, theta in {self.theta_range}"
        if self.kind == "cap":
            return f"cap z <= {self.z_max:g}"
        if self.kind == "band":
            return f"band transmural in {list(self.transmural)}"
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
    cell_nodes : (nc_omega, nloc) indices into ``nodes`` of the nodes of each cell of omega.
    fibres : (nc_omega, dim) unit fibre at each cell centroid of omega (active stress), or None.
    profile : the time profile g, a scalar function of t (traced JAX scalar in, scalar out), or None (g = 1).
    """

    load: sp.csr_matrix
    mass: sp.csr_matrix
    nodes: np.ndarray
    components: int
    cell_mask: np.ndarray
    cell_nodes: np.ndarray
    fibres: np.ndarray | None = None
    profile: Callable | None = None

    def scale(self, t) -> np.ndarray:
        """``g(t)`` at the times ``t`` (k,) on the host, (k,); ones without a profile."""
        t = np.asarray(t, dtype=np.float64)
        return np.ones_like(t) if self.profile is None else self.profile.values(t)

    @property
    def size(self) -> int:
        return self.nodes.size * self.components

    @property
    def lumped_mass(self) -> np.ndarray:
        """Positive diagonal (n_ctrl,) spectrally equivalent to ``mass``: its diagonal scaled to the
        same total, ``m_i = M_ii sum(M) / tr(M)`` (Hinton-Rock-Zienkiewicz lumping). For P1 it equals
        the row sums (``M_ii`` is a fixed fraction of each row in every simplex); for P2 the row
        sums vanish at vertices (straight cells) or turn negative (curved ones), these do not."""
        diag = self.mass.diagonal()
        return diag * (self.mass.sum() / diag.sum())

    def coordinates(self, space: VectorSpace) -> np.ndarray:
        """Coordinates (n_nodes, dim) of the control nodes."""
        return space.nodes[self.nodes]

    def nodal(self, xi: np.ndarray) -> np.ndarray:
        """Control vector(s) (..., n_ctrl) as nodal values (..., n_nodes, components)."""
        return np.asarray(xi).reshape(*np.shape(xi)[:-1], self.nodes.size, self.components)

    def cell_values(self, xi: np.ndarray) -> np.ndarray:
        """Control vector(s) (..., n_ctrl) as the mean of each omega cell's nodal values,
        (..., nc_omega, components) (P1: the value at the centroid)."""
        return self.nodal(xi)[..., self.cell_nodes, :].mean(axis=-2)


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
    return nodes, cn, cdofs


def _scalar_mass_blocks(space: VectorSpace, mask: np.ndarray) -> np.ndarray:
    q = space.quadrature(2 * space.degree)
    return np.einsum("cq,qa,qb->cab", q.wdx[mask], q.N, q.N)


@dataclass(frozen=True)
class BodyForce:
    """Distributed body force ``<f(xi), phi> = int_omega xi . phi`` (vector control, density units), scaled in
    time by ``profile(t)`` when given (module docstring)."""

    region: Region = field(default_factory=Region)
    profile: Callable | None = None

    def build(self, space: VectorSpace, to_reduced: np.ndarray) -> ControlData:
        mask = self.region.cell_mask(space.mesh)
        d = space.components
        nodes, cell_nodes, cdofs = _control_numbering(space, mask, d)
        Ms = _scalar_mass_blocks(space, mask)
        blocks = np.einsum("cab,ij->caibj", Ms, np.eye(d)).reshape(len(Ms), d * space.nloc, d * space.nloc)
        sdofs = to_reduced[space.cell_dofs[mask]]
        n_state = int(to_reduced.max()) + 1
        load = _cell_blocks_to_matrix(sdofs, cdofs, blocks, (n_state, nodes.size * d))
        mass = _cell_blocks_to_matrix(cdofs, cdofs, blocks, (nodes.size * d,) * 2)
        return ControlData(load, mass, nodes, d, mask, cell_nodes, profile=self.profile)


def circumferential_fibres(x: np.ndarray) -> np.ndarray:
    """Unit vectors ``(-y, x, 0) / r`` around the z axis, for x of shape (..., dim >= 2)."""
    t = np.zeros_like(x)
    t[..., 0], t[..., 1] = -x[..., 1], x[..., 0]
    return t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-300)


@dataclass(frozen=True)
class ActiveStress:
    """Active stress along fibres ``<f(xi), phi> = int_omega xi (fhat (x) fhat) : grad phi`` (scalar xi).

    ``xi`` is a stress (the material's units, kPa for the cardiac laws). The sign is the paper's
    (its appendix on control operators): the load acts like a stress ``-xi fhat (x) fhat`` added to the first
    Piola-Kirchhoff stress, so ``xi > 0`` pushes along the fibres and a contraction (fibre tension
    ``T_a > 0``) is ``xi = -T_a``.

    ``fibres(x, cells)`` maps points x (n, nq, dim) of the mesh cells ``cells`` (n,) to unit vectors
    (n, nq, dim), e.g. `hyperoc.mechanics.fibres.FibreFrames.fibre` (row 0 of the material frame); default:
    the x axis in 1D, circumferential in 2D/3D.

    ``profile`` (a `hyperoc.dynamics.laws.TimeLaw`, or None) scales the control in time: the stress added is
    ``-profile(t) xi fhat (x) fhat`` (module docstring; with the prescribed activation as the profile, xi is
    dimensionless and the fibre tension is ``T_a(t) (1 - xi)``).
    """

    region: Region = field(default_factory=Region)
    fibres: Callable | None = None
    profile: Callable | None = None

    def fibre_field(self, x: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """Unit fibres (n, nq, dim) at points x (n, nq, dim) of the cells ``cells`` (n,)."""
        if self.fibres is not None:
            f = np.asarray(self.fibres(x, cells), dtype=np.float64)
            if f.shape != x.shape:
                raise InputError(f"active stress: fibres must return vectors of shape {x.shape}, got {f.shape}")
        elif x.shape[-1] == 1:
            f = np.ones_like(x)
        else:
            f = circumferential_fibres(x)
        return f / np.maximum(np.linalg.norm(f, axis=-1, keepdims=True), 1e-300)

    def build(self, space: VectorSpace, to_reduced: np.ndarray) -> ControlData:
        mask = self.region.cell_mask(space.mesh)
        cells = np.flatnonzero(mask)
        nodes, cell_nodes, cdofs = _control_numbering(space, mask, 1)
        q = space.quadrature(2 * space.degree)
        f = self.fibre_field(q.x[mask], cells)  # (nc_omega, nq, d)
        f_centroid = self.fibre_field(space.mesh.cell_centroids()[mask][:, None, :], cells)[:, 0]
        # B[(a, i), b] = sum_q w N_b f_i f_J dN_a/dX_J
        fdN = np.einsum("cqj,cqaj->cqa", f, q.dN[mask])
        blocks = np.einsum("cq,cqa,cqi,qb->caib", q.wdx[mask], fdN, f, q.N)
        blocks = blocks.reshape(len(blocks), space.nloc * space.components, space.nloc)
        sdofs = to_reduced[space.cell_dofs[mask]]
        n_state = int(to_reduced.max()) + 1
        load = _cell_blocks_to_matrix(sdofs, cdofs, blocks, (n_state, nodes.size))
        mass = _cell_blocks_to_matrix(cdofs, cdofs, _scalar_mass_blocks(space, mask), (nodes.size,) * 2)
        return ControlData(load, mass, nodes, 1, mask, cell_nodes, f_centroid, self.profile)

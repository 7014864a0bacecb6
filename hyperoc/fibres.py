"""Rule-based myocardial fibre fields (after Bayer et al. 2012, single transmural coordinate).

1. `transmural_coordinate`: the P1 solution ``d`` of the Laplace problem ``-div grad d = 0`` with
   ``d = 0`` on the inner wall (endocardium), ``d = 1`` on the outer wall (epicardium) and
   ``grad d . nu = 0`` elsewhere (e.g. the base).
2. `rule_based_fibres`: at each cell the transmural direction ``n_t = grad d / |grad d|``, the
   circumferential direction ``c = a x n_t / |a x n_t|`` (``a`` = long axis, apex to base), the
   longitudinal direction ``l = n_t x c``, the helix angle ``alpha(d) = alpha_endo + (alpha_epi -
   alpha_endo) d`` and the orthonormal, right-handed frame

       f = cos(alpha) c + sin(alpha) l      (fibre)
       s = n_t                              (sheet: transmural)
       n = f x s                            (sheet normal)

   ``alpha`` is measured from ``c`` towards ``l``: with ``a = +z`` pointing from apex to base,
   ``alpha > 0`` means fibres that rise towards the base when going counterclockwise seen from the
   base. Land et al. (2015) problem 3 uses ``alpha_endo = 90``, ``alpha_epi = -90`` degrees.

The frame field is what `hyperoc.model.StateModel` takes as ``frames`` and passes, row by row
(``f, s, n``), to fibre-dependent materials (`hyperoc.materials.Guccione`, `HolzapfelOgden`).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import meshio
import numpy as np
import scipy.sparse.linalg as spla

from .assembly import SparsePattern, reduced_numbering
from .errors import InputError
from .io import atomic_write_bytes
from .mesh import Mesh
from .spaces import VectorSpace

__all__ = ["transmural_coordinate", "rule_based_fibres", "write_fibres"]


def _p1_stiffness_blocks(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """P1 element stiffness matrices ``K_ab = int grad N_a . grad N_b`` (nc, dim+1, dim+1) and the
    constant shape gradients dN/dX (nc, dim+1, dim)."""
    q = VectorSpace(mesh, 1, components=1).quadrature(0)
    return np.einsum("cq,cqaj,cqbj->cab", q.wdx, q.dN, q.dN), q.dN[:, 0]


def transmural_coordinate(mesh: Mesh, inner: str = "endocardium", outer: str = "epicardium") -> np.ndarray:
    """Nodal values (nv,) of the P1 solution of ``Laplace d = 0``, ``d = 0`` on ``inner``, 1 on ``outer``.

    Dimensionless, in [0, 1] (exactly where the P1 stiffness is an M-matrix, up to round-off on
    Gmsh meshes in practice). Boundaries other than ``inner`` and ``outer`` are natural (zero flux).
    """
    lo, hi = mesh.boundary_vertices(inner), mesh.boundary_vertices(outer)
    if np.intersect1d(lo, hi).size:
        raise InputError(f"transmural_coordinate: boundaries {inner!r} and {outer!r} share vertices")
    nv = mesh.points.shape[0]
    d = np.zeros(nv)
    d[hi] = 1.0
    free, to_reduced = reduced_numbering(nv, np.concatenate([lo, hi]))
    if free.size == 0:
        return d
    Ke, _ = _p1_stiffness_blocks(mesh)
    cell_dofs = to_reduced[mesh.cells]
    # Lift the Dirichlet values: rhs = -K_fD d_D, element by element, into the free rows.
    lift = -np.einsum("cab,cb->ca", Ke, d[mesh.cells])
    rhs = np.bincount(cell_dofs[cell_dofs >= 0], weights=lift[cell_dofs >= 0], minlength=free.size)
    K = SparsePattern(cell_dofs, free.size).matrix(Ke)
    d[free] = spla.spsolve(K.tocsc(), rhs)
    return d


def _transmural_directions(mesh: Mesh, d: np.ndarray, dN: np.ndarray) -> np.ndarray:
    """Unit transmural direction per cell (nc, dim): ``grad d`` recovered at the vertices (the
    volume-weighted mean over the cells sharing the vertex) and averaged over the cell's vertices.

    The recovery is smoother than the raw cell gradient and defined where that vanishes (a cell
    whose vertices all lie on one wall, e.g. a thin wall meshed with one layer of cells).
    """
    grad = np.einsum("caj,ca->cj", dN, d[mesh.cells])
    vol = mesh.cell_volumes()
    nodal = np.zeros_like(mesh.points)
    weight = np.zeros(mesh.points.shape[0])
    np.add.at(nodal, mesh.cells, (vol[:, None] * grad)[:, None, :])
    np.add.at(weight, mesh.cells, vol[:, None])
    g = (nodal / weight[:, None])[mesh.cells].mean(axis=1)
    norm = np.linalg.norm(g, axis=1)
    if np.any(norm <= 1e-12 * norm.max()):
        raise InputError("rule_based_fibres: the transmural gradient vanishes on some cells (mesh too coarse?)")
    return g / norm[:, None]


def _circumferential(n_t: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Unit ``c = a x n_t / |a x n_t|`` (nc, 3); where ``n_t`` is parallel to ``a`` (the apex of a
    ventricle, the poles of a shell: the rule is singular there) ``e x n_t`` with ``e`` the
    coordinate axis least aligned with ``n_t``."""
    c = np.cross(axis, n_t)
    norm = np.linalg.norm(c, axis=1)
    singular = norm < 1e-8
    if np.any(singular):
        e = np.eye(3)[np.argmin(np.abs(n_t[singular]), axis=1)]
        c[singular] = np.cross(e, n_t[singular])
        norm[singular] = np.linalg.norm(c[singular], axis=1)
    return c / norm[:, None]


def rule_based_fibres(mesh: Mesh, *, helix_endo: float = 60.0, helix_epi: float = -60.0, long_axis=(0.0, 0.0, 1.0),
                      inner: str = "endocardium", outer: str = "epicardium"):
    """Fibre, sheet and sheet-normal directions with a transmurally varying helix angle (degrees).

    Returns a callable ``frames(x)`` for points x of shape (nc, ..., 3) whose leading axis runs over
    the cells of ``mesh`` (the quadrature points of `StateModel`, or cell centroids as (nc, 1, 3)).
    It returns (nc, ..., 3, 3) frames with rows ``(f, s, n)``: ``n_t``, ``c``, ``l`` are constant per
    cell, and the helix angle uses ``d`` interpolated (P1) at each point. The callable also carries
    ``frames.transmural`` (nodal d) for output.
    """
    if mesh.dim != 3:
        raise InputError(f"rule_based_fibres needs a 3D mesh, got dimension {mesh.dim}")
    axis = np.asarray(long_axis, dtype=np.float64).reshape(3)
    if not np.linalg.norm(axis) > 0:
        raise InputError(f"rule_based_fibres: long_axis must be a nonzero vector, got {long_axis}")
    d = transmural_coordinate(mesh, inner, outer)
    _, dN = _p1_stiffness_blocks(mesh)
    n_t = _transmural_directions(mesh, d, dN)
    c = _circumferential(n_t, axis / np.linalg.norm(axis))
    l = np.cross(n_t, c)
    x0, d_cell = mesh.points[mesh.cells[:, 0]], d[mesh.cells]
    a_endo, a_epi = np.deg2rad(helix_endo), np.deg2rad(helix_epi)

    def frames(x):
        x = np.asarray(x, dtype=np.float64)
        if x.ndim < 2 or x.shape[0] != len(d_cell) or x.shape[-1] != 3:
            raise InputError(f"fibre frames: expected points (num_cells = {len(d_cell)}, ..., 3), got {x.shape}")
        expand = (slice(None),) + (None,) * (x.ndim - 2)
        # P1 interpolation: d(x) = d_0 + grad d . (x - x_0) within each (affine) cell.
        grad = np.einsum("caj,ca->cj", dN, d_cell)
        dx = d_cell[:, 0][expand] + np.einsum("c...j,cj->c...", x - x0[expand], grad)
        alpha = (a_endo + (a_epi - a_endo) * dx)[..., None]
        f = np.cos(alpha) * c[expand] + np.sin(alpha) * l[expand]
        s = np.broadcast_to(n_t[expand], f.shape)
        return np.stack([f, s, np.cross(f, s)], axis=-2)

    frames.transmural = d
    return frames


def write_fibres(path, mesh: Mesh, frames) -> Path:
    """Write a VTU file (atomically) with cell vectors ``fibre``, ``sheet``, ``normal`` evaluated at
    the cell centroids, and the point field ``transmural`` when ``frames`` carries it (ParaView:
    Glyph filter on the cell data)."""
    if mesh.dim != 3:
        raise InputError(f"write_fibres needs a 3D mesh, got dimension {mesh.dim}")
    path = Path(path)
    F = np.asarray(frames(mesh.cell_centroids()[:, None, :]))[:, 0]
    cell_data = {name: [F[:, k]] for k, name in enumerate(("fibre", "sheet", "normal"))}
    point_data = {"transmural": frames.transmural} if hasattr(frames, "transmural") else {}
    out = meshio.Mesh(mesh.points, [("tetra", mesh.cells)], point_data=point_data, cell_data=cell_data)
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        staged = Path(tmp) / path.name
        meshio.write(staged, out, file_format="vtu")
        return atomic_write_bytes(path, staged.read_bytes())

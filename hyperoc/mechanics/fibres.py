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

Fields given as data (`FieldFrames`: `read_fibres` from an XDMF, VTU or NPZ file, `field_frames` from arrays):
the fibre ``f`` and sheet ``s`` per vertex or per cell, checked (finite, unit within a tolerance, ``f . s = 0``
within it, one vector per vertex or cell of the mesh), then

    f = f_h / |f_h|,   s = (s_h - (s_h . f) f) / |...|,   n = f x s

at each point, ``f_h``, ``s_h`` the cell's value or the P1 interpolant of the vertex values.

The frame field is what `hyperoc.mechanics.model.StateModel` takes as ``frames`` and passes, row by row
(``f, s, n``), to fibre-dependent materials (`hyperoc.mechanics.materials.Guccione`, `HolzapfelOgden`).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import meshio
import numpy as np

from ..errors import InputError
from ..fem.assembly import solve_dirichlet
from ..fem.mesh import Mesh
from ..fem.spaces import VectorSpace
from ..io import atomic_write_bytes

__all__ = ["FibreFrames", "ProlateFibres", "FieldFrames", "transmural_coordinate", "rule_based_fibres",
           "prolate_fibres", "field_frames", "read_fibres", "write_fibres"]

#: Names under which files store the fibre and the sheet field (the first one found is used).
FIBRE_NAMES = ("fibre", "fiber", "f0", "f")
SHEET_NAMES = ("sheet", "s0", "s")


def _p1_stiffness_blocks(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """P1 element stiffness matrices ``K_ab = int grad N_a . grad N_b`` (nc, dim+1, dim+1) and the
    constant shape gradients dN/dX (nc, dim+1, dim)."""
    space = VectorSpace(mesh, 1, components=1)
    return space.laplace_blocks(), space.quadrature(0).dN[:, 0]


def transmural_coordinate(mesh: Mesh, inner: str = "endocardium", outer: str = "epicardium") -> np.ndarray:
    """Nodal values (nv,) of the P1 solution of ``Laplace d = 0``, ``d = 0`` on ``inner``, 1 on ``outer``.

    Dimensionless, in [0, 1] (exactly where the P1 stiffness is an M-matrix, up to round-off on
    Gmsh meshes in practice). Boundaries other than ``inner`` and ``outer`` are natural (zero flux).
    """
    lo, hi = mesh.boundary_vertices(inner), mesh.boundary_vertices(outer)
    if np.intersect1d(lo, hi).size:
        raise InputError(f"transmural_coordinate: boundaries {inner!r} and {outer!r} share vertices")
    fixed = np.concatenate([lo, hi])
    values = np.concatenate([np.zeros(lo.size), np.ones(hi.size)])
    Ke, _ = _p1_stiffness_blocks(mesh)
    return solve_dirichlet(Ke, mesh.cells, mesh.points.shape[0], fixed, values)


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


@dataclass(frozen=True, eq=False)
class FibreFrames:
    """Rule-based (f, s, n) frames on a 3D mesh, evaluated at any points of any subset of its cells.

    Per cell the transmural ``n_t``, circumferential ``c`` and longitudinal ``l`` directions are
    constant; the helix angle ``alpha(d) = alpha_endo + (alpha_epi - alpha_endo) d`` uses the P1
    transmural coordinate ``d`` interpolated at each point, and

        f = cos(alpha) c + sin(alpha) l,   s = n_t,   n = f x s.

    Attributes
    ----------
    transmural : (nv,) nodal transmural coordinate d (dimensionless, 0 on ``inner``, 1 on ``outer``).
    sheet, circumferential, longitudinal : (nc, 3) unit vectors ``n_t``, ``c``, ``l`` per cell.
    grad_d : (nc, 3) ``grad d`` per cell (1/length); ``x0`` (nc, 3) first vertex, ``d0`` (nc,) d there.
    centroids : (nc, 3) cell centroids (where `cell_frames` evaluates).
    helix : (alpha_endo, alpha_epi) in radians.
    """

    transmural: np.ndarray
    sheet: np.ndarray
    circumferential: np.ndarray
    longitudinal: np.ndarray
    grad_d: np.ndarray
    x0: np.ndarray
    d0: np.ndarray
    centroids: np.ndarray
    helix: tuple

    @property
    def num_cells(self) -> int:
        return len(self.sheet)

    def _cells(self, x: np.ndarray, cells) -> np.ndarray:
        cells = np.arange(self.num_cells) if cells is None else np.asarray(cells, dtype=np.int64).reshape(-1)
        if x.ndim < 2 or x.shape[0] != cells.size or x.shape[-1] != 3:
            raise InputError(f"fibre frames: expected points (number of cells = {cells.size}, ..., 3), got {x.shape}")
        if cells.size and (cells.min() < 0 or cells.max() >= self.num_cells):
            raise InputError(f"fibre frames: cell indices must lie in [0, {self.num_cells}), "
                             f"got {cells.min()}..{cells.max()}")
        return cells

    def __call__(self, x, cells=None) -> np.ndarray:
        """Frames (n, ..., 3, 3) with rows ``(f, s, n)`` at points x (n, ..., 3) of the cells ``cells``
        (n,) (default: every cell, n = num_cells), e.g. the quadrature points of `StateModel`.

        ``d(x)`` is the P1 interpolant of the straight-sided cell, extended affinely: at the quadrature
        points of isoparametric (curved) P2 cells, which lie off the straight cell by O(h^2) near a
        curved wall, d may leave [0, 1] by O(h^2 |grad d|) (the helix angle is extrapolated as much)."""
        x = np.asarray(x, dtype=np.float64)
        cells = self._cells(x, cells)
        expand = (slice(None),) + (None,) * (x.ndim - 2)
        # P1 interpolation: d(x) = d_0 + grad d . (x - x_0) within each (affine) cell.
        d = self.d0[cells][expand] + np.einsum("c...j,cj->c...", x - self.x0[cells][expand], self.grad_d[cells])
        a_endo, a_epi = self.helix
        alpha = (a_endo + (a_epi - a_endo) * d)[..., None]
        f = np.cos(alpha) * self.circumferential[cells][expand] + np.sin(alpha) * self.longitudinal[cells][expand]
        s = np.broadcast_to(self.sheet[cells][expand], f.shape)
        return np.stack([f, s, np.cross(f, s)], axis=-2)

    def fibre(self, x, cells=None) -> np.ndarray:
        """Unit fibre directions (n, ..., 3) at points x (n, ..., 3) of ``cells``: row 0 of the frame
        (the ``fibres`` argument of `hyperoc.mechanics.controls.ActiveStress`)."""
        return self(x, cells)[..., 0, :]

    def cell_frames(self) -> np.ndarray:
        """Frames (nc, 3, 3) at the cell centroids (output, glyphs)."""
        return self(self.centroids[:, None, :])[:, 0]


def rule_based_fibres(mesh: Mesh, *, helix_endo: float = 60.0, helix_epi: float = -60.0, long_axis=(0.0, 0.0, 1.0),
                      inner: str = "endocardium", outer: str = "epicardium") -> FibreFrames:
    """Fibre, sheet and sheet-normal directions with a transmurally varying helix angle (degrees).

    Returns `FibreFrames`: ``frames(x)`` for points x (nc, ..., 3) whose leading axis runs over the
    cells of ``mesh`` (the quadrature points of `StateModel`, or cell centroids as (nc, 1, 3)), or
    ``frames(x, cells)`` for points of the cells ``cells`` only; (n, ..., 3, 3) frames with rows
    ``(f, s, n)``. ``frames.transmural`` (nodal d) is kept for output and transmural regions.
    """
    if mesh.dim != 3:
        raise InputError(f"rule_based_fibres needs a 3D mesh, got dimension {mesh.dim}")
    axis = np.asarray(long_axis, dtype=np.float64).reshape(3)
    if not np.linalg.norm(axis) > 0:
        raise InputError(f"rule_based_fibres: long_axis must be a nonzero vector, got {long_axis}")
    if not (np.isfinite(helix_endo) and np.isfinite(helix_epi)):
        raise InputError(f"rule_based_fibres: helix angles must be finite, got {helix_endo}, {helix_epi}")
    d = transmural_coordinate(mesh, inner, outer)
    _, dN = _p1_stiffness_blocks(mesh)
    n_t = _transmural_directions(mesh, d, dN)
    c = _circumferential(n_t, axis / np.linalg.norm(axis))
    d_cell = d[mesh.cells]
    return FibreFrames(transmural=d, sheet=n_t, circumferential=c, longitudinal=np.cross(n_t, c),
                       grad_d=np.einsum("caj,ca->cj", dN, d_cell), x0=mesh.points[mesh.cells[:, 0]], d0=d_cell[:, 0],
                       centroids=mesh.cell_centroids(),
                       helix=(float(np.deg2rad(helix_endo)), float(np.deg2rad(helix_epi))))


@dataclass(frozen=True)
class ProlateFibres:
    """Analytic fibres of the truncated prolate wall (Land et al. 2015, problem 3).

    The wall is the family of ellipsoids ``x = rs(t) sin u cos v, y = rs(t) sin u sin v,
    z = rl(t) cos u`` with ``rs(t) = rs_endo + (rs_epi - rs_endo) t``, ``rl`` likewise, ``t`` in [0, 1]
    (endocardium to epicardium), ``u`` in ``[-pi, -arccos(base_z / rl)]`` (so sin u <= 0) and ``v`` in
    ``[-pi, pi]``. With the unit tangents ``e_u = x_u / |x_u|`` (along the meridian, apex to base) and
    ``e_v = x_v / |x_v|`` (circumferential, counterclockwise seen from the base) and the helix angle
    ``alpha(t) = alpha_endo + (alpha_epi - alpha_endo) t``:

        f = sin(alpha) e_u + cos(alpha) e_v,   s = nu (outward normal of the ellipsoid t),   n = f x s.

    ``e_u``, ``e_v``, ``nu`` are orthonormal, so the frame is. On the long axis (the apex), where
    ``e_v`` is undefined, ``e_v = e_y`` and ``e_u = e_x`` stand in. Points off the wall get the ``t`` of
    the ellipsoid through them (bisection for ``t`` in ``[-1/2, 3/2]``; points beyond get the end value).

    Attributes: ``endo``, ``epi`` the ``(rs, rl)`` semi-axes (mm); ``helix`` (alpha_endo, alpha_epi) radians.
    """

    endo: tuple
    epi: tuple
    helix: tuple

    def transmural(self, x) -> np.ndarray:
        """``t`` (...,) of the ellipsoid of the family through each point x (..., 3)."""
        x = np.asarray(x, dtype=np.float64)
        rho2, z2 = x[..., 0] ** 2 + x[..., 1] ** 2, x[..., 2] ** 2
        lo, hi = np.full(rho2.shape, -0.5), np.full(rho2.shape, 1.5)
        for _ in range(64):  # bisection: (rho / rs(t))^2 + (z / rl(t))^2 decreases in t; 2^-64 of the bracket
            mid = 0.5 * (lo + hi)
            rs, rl = self._axes(mid)
            outside = rho2 / rs**2 + z2 / rl**2 > 1.0
            lo, hi = np.where(outside, mid, lo), np.where(outside, hi, mid)
        return 0.5 * (lo + hi)

    def _axes(self, t):
        (rs0, rl0), (rs1, rl1) = self.endo, self.epi
        return rs0 + (rs1 - rs0) * t, rl0 + (rl1 - rl0) * t

    def __call__(self, x) -> np.ndarray:
        """Frames (..., 3, 3) with rows ``(f, s, n)`` at points x (..., 3) (any leading shape, e.g.
        `StateModel`'s quadrature points (nc, nq, 3))."""
        x = np.asarray(x, dtype=np.float64)
        t = self.transmural(x)
        rs, rl = self._axes(t)
        rho = np.hypot(x[..., 0], x[..., 1])
        on_axis = rho < 1e-12 * rl
        safe = np.where(on_axis, 1.0, rho)
        cos_v, sin_v = np.where(on_axis, 1.0, -x[..., 0] / safe), np.where(on_axis, 0.0, -x[..., 1] / safe)
        cos_u, sin_u = x[..., 2] / rl, -rho / rs  # sin u <= 0 on the benchmark's branch of u
        e_u = np.stack([rs * cos_u * cos_v, rs * cos_u * sin_v, -rl * sin_u], axis=-1)
        e_v = np.stack([sin_v, -cos_v, np.zeros_like(rho)], axis=-1)  # x_v / |x_v| = sign(sin u) (-sin v, cos v, 0)
        e_u = np.where(on_axis[..., None], [1.0, 0.0, 0.0], e_u / np.linalg.norm(e_u, axis=-1, keepdims=True))
        e_v = np.where(on_axis[..., None], [0.0, 1.0, 0.0], e_v)
        nu = np.stack([x[..., 0] / rs**2, x[..., 1] / rs**2, x[..., 2] / rl**2], axis=-1)
        nu /= np.linalg.norm(nu, axis=-1, keepdims=True)
        a_endo, a_epi = self.helix
        alpha = (a_endo + (a_epi - a_endo) * t)[..., None]
        f = np.sin(alpha) * e_u + np.cos(alpha) * e_v
        return np.stack([f, nu, np.cross(f, nu)], axis=-2)


def prolate_fibres(*, endo=(7.0, 17.0), epi=(10.0, 20.0), helix_endo: float = 90.0,
                   helix_epi: float = -90.0) -> ProlateFibres:
    """`ProlateFibres` for the wall between the ellipsoids of semi-axes ``endo`` and ``epi`` (mm,
    ``(short, long)``, as `hyperoc.fem.geometry.ventricle`), helix angles in degrees (defaults: Land et al.
    2015 problem 3)."""
    endo, epi = tuple(map(float, endo)), tuple(map(float, epi))
    if len(endo) != 2 or len(epi) != 2 or not (0 < endo[0] < epi[0] and 0 < endo[1] < epi[1]):
        raise InputError(f"prolate_fibres: need 0 < endo < epi semi-axes (short, long), got {endo}, {epi}")
    if any(r1 - r0 > r0 for r0, r1 in zip(endo, epi)):  # keeps rs(t), rl(t) > 0 on the bisection bracket
        raise InputError(f"prolate_fibres: the wall may be at most as thick as the cavity's semi-axes, "
                         f"got {endo}, {epi}")
    if not (np.isfinite(helix_endo) and np.isfinite(helix_epi)):
        raise InputError(f"prolate_fibres: helix angles must be finite, got {helix_endo}, {helix_epi}")
    return ProlateFibres(endo, epi, (float(np.deg2rad(helix_endo)), float(np.deg2rad(helix_epi))))


def write_fibres(path, mesh: Mesh, frames) -> Path:
    """Write a VTU file (atomically) with cell vectors ``fibre``, ``sheet``, ``normal`` evaluated at
    the cell centroids and the point field ``transmural`` (ParaView: Glyph filter on the cell data).

    ``frames``: `FibreFrames` of ``mesh`` (``transmural`` = its Laplace coordinate), `ProlateFibres`
    (``transmural`` = the prolate t at the vertices) or `FieldFrames` (its ``transmural``, zero if it has none)."""
    if mesh.dim != 3:
        raise InputError(f"write_fibres needs a 3D mesh, got dimension {mesh.dim}")
    path = Path(path)
    F = frames(mesh.cell_centroids()[:, None, :])[:, 0]
    transmural = frames.transmural(mesh.points) if callable(frames.transmural) else frames.transmural
    cell_data = {name: [F[:, k]] for k, name in enumerate(("fibre", "sheet", "normal"))}
    point_data = {"transmural": transmural}
    out = meshio.Mesh(mesh.points, [("tetra", mesh.cells)], point_data=point_data, cell_data=cell_data)
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        staged = Path(tmp) / path.name
        meshio.write(staged, out, file_format="vtu")
        return atomic_write_bytes(path, staged.read_bytes())


@dataclass(frozen=True, eq=False)
class FieldFrames:
    """(f, s, n) frames from fibre and sheet vectors given per vertex or per cell of a 3D mesh (module docstring).

    Attributes
    ----------
    fibres, sheets : (n, 3) the given vectors, n = number of vertices (``location = "node"``) or cells ("cell").
    location : ``"node"`` or ``"cell"``.
    cells : (nc, 4) the mesh's cells; ``x0`` (nc, 3) their first vertex; ``inverse`` (nc, 3, 3) the inverse
        of the straight cell's Jacobian (barycentric coordinates of a point, for vertex fields).
    centroids : (nc, 3) cell centroids (where `cell_frames` evaluates).
    transmural : (nv,) a transmural coordinate for output (zeros when the source has none).
    """

    fibres: np.ndarray
    sheets: np.ndarray
    location: str
    cells: np.ndarray
    x0: np.ndarray
    inverse: np.ndarray
    centroids: np.ndarray
    transmural: np.ndarray

    @property
    def num_cells(self) -> int:
        return len(self.cells)

    def __call__(self, x, cells=None) -> np.ndarray:
        """Frames (n, ..., 3, 3) with rows ``(f, s, n)`` at points x (n, ..., 3) of the cells ``cells`` (n,)
        (default: every cell), e.g. the quadrature points of `StateModel`."""
        x = np.asarray(x, dtype=np.float64)
        cells = np.arange(self.num_cells) if cells is None else np.asarray(cells, dtype=np.int64).reshape(-1)
        if x.ndim < 2 or x.shape[0] != cells.size or x.shape[-1] != 3:
            raise InputError(f"fibre frames: expected points (number of cells = {cells.size}, ..., 3), got {x.shape}")
        expand = (slice(None),) + (None,) * (x.ndim - 2)
        if self.location == "cell":
            f = np.broadcast_to(self.fibres[cells][expand], x.shape)
            s = np.broadcast_to(self.sheets[cells][expand], x.shape)
        else:
            lam = np.einsum("cij,c...j->c...i", self.inverse[cells], x - self.x0[cells][expand])
            lam = np.concatenate([1.0 - lam.sum(-1, keepdims=True), lam], axis=-1)  # barycentric (n, ..., 4)
            f = np.einsum("c...a,cai->c...i", lam, self.fibres[self.cells[cells]])
            s = np.einsum("c...a,cai->c...i", lam, self.sheets[self.cells[cells]])
        f = f / np.linalg.norm(f, axis=-1, keepdims=True)
        s = s - np.sum(s * f, axis=-1, keepdims=True) * f
        s = s / np.linalg.norm(s, axis=-1, keepdims=True)
        return np.stack([f, s, np.cross(f, s)], axis=-2)

    def fibre(self, x, cells=None) -> np.ndarray:
        """Unit fibre directions (n, ..., 3) at points x (n, ..., 3) of ``cells`` (row 0 of the frame)."""
        return self(x, cells)[..., 0, :]

    def cell_frames(self) -> np.ndarray:
        """Frames (nc, 3, 3) at the cell centroids (output, glyphs)."""
        return self(self.centroids[:, None, :])[:, 0]


def field_frames(mesh: Mesh, fibres, sheets, *, location: str = "auto", tolerance: float = 1e-3,
                 source: str = "fibres", transmural=None) -> FieldFrames:
    """`FieldFrames` of the vectors ``fibres``, ``sheets`` (n, 3) on the 3D ``mesh``, after the checks of the module
    docstring, each failure one `InputError` line starting with ``source``.

    ``location``: ``"node"`` (n = vertices), ``"cell"`` (n = cells) or ``"auto"`` (from n; a mesh with as many
    vertices as cells needs it stated). ``tolerance``: the largest ``| |f| - 1 |``, ``| |s| - 1 |`` and ``|f . s|``
    accepted (dimensionless; the vectors are normalised and orthogonalised afterwards)."""
    if mesh.dim != 3:
        raise InputError(f"{source}: fibre fields need a 3D mesh, got dimension {mesh.dim}")
    nv, nc = len(mesh.points), mesh.num_cells
    f, s = (np.asarray(v, dtype=np.float64) for v in (fibres, sheets))
    location = _field_location(f, s, nv, nc, location, source)
    for name, v in (("fibre", f), ("sheet", s)):
        bad = int(np.sum(~np.isfinite(v).all(axis=1)))
        if bad:
            raise InputError(f"{source}: {bad} {name} vector(s) are not finite")
        error = np.abs(np.linalg.norm(v, axis=1) - 1.0)
        if error.max() > tolerance:
            raise InputError(f"{source}: {int(np.sum(error > tolerance))} {name} vector(s) are not unit "
                             f"(largest | |v| - 1 | = {error.max():.3g} > tolerance {tolerance:g})")
    dot = np.abs(np.sum(f * s, axis=1))
    if dot.max() > tolerance:
        raise InputError(f"{source}: fibre and sheet are not orthogonal at {int(np.sum(dot > tolerance))} "
                         f"{location}(s) (largest |f . s| = {dot.max():.3g} > tolerance {tolerance:g})")
    J = mesh.cell_jacobians()
    return FieldFrames(fibres=f, sheets=s, location=location, cells=mesh.cells, x0=mesh.points[mesh.cells[:, 0]],
                       inverse=np.linalg.inv(J), centroids=mesh.cell_centroids(),
                       transmural=np.zeros(nv) if transmural is None else np.asarray(transmural, dtype=np.float64))


def _field_location(f: np.ndarray, s: np.ndarray, nv: int, nc: int, location: str, source: str) -> str:
    """``"node"`` or ``"cell"``: the stated location checked against the number of vectors, or inferred from it."""
    if location not in ("auto", "node", "cell"):
        raise InputError(f"{source}: location must be 'auto', 'node' or 'cell', got {location!r}")
    if f.ndim != 2 or f.shape[1] != 3 or s.shape != f.shape:
        raise InputError(f"{source}: fibre and sheet must both have shape (n, 3), got {f.shape} and {s.shape}")
    counts = {"node": nv, "cell": nc}
    if location == "auto":
        matches = [where for where, n in counts.items() if n == len(f)]
        if len(matches) == 2:
            raise InputError(f"{source}: the mesh has as many vertices as cells ({nv}): state location = "
                             "'node' or 'cell'")
        location = matches[0] if matches else location
    if location == "auto" or counts[location] != len(f):
        raise InputError(f"{source}: {len(f)} fibre vectors, but the mesh has {nv} vertices and {nc} cells")
    return location


def read_fibres(path, mesh: Mesh, *, location: str = "auto", tolerance: float = 1e-3) -> FieldFrames:
    """`FieldFrames` of the fibre and sheet fields of a file, checked as in `field_frames`.

    - ``.npz``: arrays named ``fibre`` (or ``fiber``, ``f0``, ``f``) and ``sheet`` (or ``s0``, ``s``), (n, 3),
      in the mesh's vertex or cell order.
    - ``.vtu``, ``.xdmf`` (meshio's or DOLFIN(x)'s layout, `hyperoc.fem.files.read_raw`) and other meshio files:
      point data (per vertex) or cell data (per cell) of those names. The file's points (cell centroids) are
      matched to the mesh's vertices (centroids) by position, to 1e-8 of the mesh's size, so the file may
      number them differently or hold more points (the edge nodes of a P2 field).
    """
    path = Path(path)
    source = f"fibres file {path}"
    if not path.is_file():
        raise InputError(f"{source}: not found")
    if path.suffix.lower() == ".npz":
        from ..io import read_npz

        try:
            arrays = read_npz(path)
        except Exception as exc:  # a damaged or foreign file: zipfile, pickle and numpy errors
            raise InputError(f"{source}: cannot read it ({type(exc).__name__})") from exc
        f, s = (_named_array(arrays, names, source) for names in (FIBRE_NAMES, SHEET_NAMES))
    else:
        f, s, location = _mesh_file_fields(path, mesh, location, source)
    return field_frames(mesh, f, s, location=location, tolerance=tolerance, source=source)


def _named_array(arrays: dict, names: tuple, source: str) -> np.ndarray:
    key = next((name for name in names if name in arrays), None)
    if key is None:
        found = ", ".join(sorted(arrays)) or "none"
        raise InputError(f"{source}: no array named {' or '.join(names)} (found: {found})")
    return np.asarray(arrays[key], dtype=np.float64).reshape(len(arrays[key]), -1)


def _mesh_file_fields(path: Path, mesh: Mesh, location: str, source: str) -> tuple:
    """Fibre and sheet (n, 3) of a mesh file, reordered to the mesh's vertices or cells, and their location."""
    from scipy.spatial import cKDTree

    from ..fem.files import read_raw

    raw = read_raw(path)
    tets = [b for b, block in enumerate(raw.cells) if block.type in ("tetra", "tetra10")]
    cell_data = {name: np.concatenate([np.asarray(blocks[b]).reshape(len(raw.cells[b].data), -1) for b in tets])
                 for name, blocks in raw.cell_data.items() if tets}
    by_node = location in ("auto", "node") and any(n in raw.point_data for n in FIBRE_NAMES)
    arrays = raw.point_data if by_node else cell_data
    f, s = (_named_array(arrays, names, source) for names in (FIBRE_NAMES, SHEET_NAMES))
    if by_node:
        file_x, mesh_x = raw.points[:, :3], mesh.points
    else:
        file_x = np.concatenate([raw.points[np.asarray(raw.cells[b].data)[:, :4]].mean(axis=1) for b in tets])
        mesh_x = mesh.cell_centroids()
    distance, rows = cKDTree(file_x).query(mesh_x)
    size = np.ptp(mesh.points, axis=0).max()
    if distance.max() > 1e-8 * size:
        what = "vertices" if by_node else "cell centroids"
        raise InputError(f"{source}: its points do not match the mesh's {what} "
                         f"(largest distance {distance.max():.3g}, mesh size {size:.3g})")
    return f[rows], s[rows], "node" if by_node else "cell"

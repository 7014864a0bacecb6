"""Curved geometries and mesh files.

Generators (boundaries tagged after meshing by the nearest analytic surface):

- `annulus`: 2D ring, structured polar grid or Gmsh;
- `thick_shell`: 3D spherical shell (Gmsh OCC);
- `ventricle`: idealized left ventricle of the Land et al. (2015) cardiac mechanics benchmark
  (truncated prolate ellipsoidal shell, Gmsh OCC).

Their vertices lie on the exact surfaces, also after ``refinements`` uniform (red) refinements
(`hyperoc.fem.mesh.refine`), which split every cell into 2^d and put the new boundary vertices on the
exact surfaces: nested-looking sequences of shape-regular meshes for convergence studies, where
Gmsh meshes of decreasing size are unrelated to each other. With ``curved=True`` (default) the mesh also carries, for
every edge of a facet on a curved surface, the point of that surface near the edge midpoint
(`hyperoc.fem.mesh.Mesh.curved_edges`): P2 spaces then map those cells isoparametrically and see the
boundary to O(h^3) (areas and volumes to O(h^4)) instead of the O(h^2) of the flat facets; P1
spaces see the straight-sided cells either way. ``curved=False`` keeps the straight-sided mesh.
The midpoint ``m`` is moved along the surface normal direction at ``m`` to the surface (one root
of a quadratic for these quadrics); an edge that also lies in a flat boundary (the ventricle's
rim, on the base plane) moves within that plane, so flat boundaries stay flat.

Building blocks of such generators, public for other domains (`hyperoc.cardiac.benchmark_geometry`):
`gmsh_model` and `gmsh_generate` (a Gmsh model and its simplices), `Quadric` (an analytic wall),
`tagged` (boundaries named after the nearest surface, P2 edges curved onto the walls) and `refined`.

File I/O (`from_file`, `to_file`) lives in `hyperoc.fem.files` and is re-exported here.

Gmsh is imported on first use and finalized at the end of every call, so no Gmsh state outlives
a call; Gmsh being a process-wide singleton, do not run the Gmsh-based generators concurrently in
threads of one process, nor while the caller has Gmsh initialized itself.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable

import numpy as np

from ..errors import InputError
from .assembly import solve_dirichlet
from .files import _drop_unused_points, from_file, to_file
from .mesh import Mesh, refine
from .spaces import VectorSpace

__all__ = ["annulus", "thick_shell", "ventricle", "from_file", "to_file"]

_GMSH_SIMPLEX = {1: 1, 2: 2, 3: 4}  # Gmsh element type of the linear simplex of each dimension

# A signed-distance-like function of points (n, dim) -> (n,), zero on one analytic surface.
_Distance = Callable[[np.ndarray], np.ndarray]


# --------------------------------------------------------------------------------------------
# Generators
# --------------------------------------------------------------------------------------------


def annulus(
    r_inner: float = 0.5,
    r_outer: float = 1.0,
    h: float = 0.1,
    *,
    structured: bool = False,
    n_radial: int | None = None,
    n_theta: int | None = None,
    curved: bool = True,
    refinements: int = 0,
) -> Mesh:
    """Triangulated annulus ``r_inner < |x| < r_outer`` centred at the origin.

    Parameters
    ----------
    r_inner, r_outer : float
        Radii of the inner (cavity) and outer circles, in model length units.
    h : float
        Target edge length (same units). With ``structured=True`` it only sets the defaults
        ``n_radial = ceil((r_outer - r_inner) / h)`` and ``n_theta = ceil(2 pi r_outer / h)``.
    structured : bool
        If True, a polar grid (``n_radial`` rings of ``n_theta`` quadrilaterals, each split into
        two triangles) built without Gmsh; all boundary vertices lie on the circles, so the area
        error is ``O(n_theta^-2)``, convenient for convergence studies. Otherwise Gmsh meshes
        the disk minus the disk with size ``h``.
    n_radial, n_theta : int, optional
        Number of cells across the ring and around it (structured grid only).
    curved : bool
        Carry the P2 node positions of the boundary edges on the circles (module docstring).
    refinements : int
        Uniform refinements of the generated mesh (module docstring), each halving h.

    Returns
    -------
    Mesh
        2D mesh. Boundaries: ``"gamma_d"`` and ``"outer"`` = facets on the outer circle,
        ``"gamma_n"`` and ``"inner"`` = facets on the inner circle.
    """
    _require(0 < r_inner < r_outer, "annulus: need 0 < r_inner < r_outer")
    _require(h > 0, "annulus: need h > 0")
    if structured:
        n_radial = math.ceil((r_outer - r_inner) / h) if n_radial is None else n_radial
        n_theta = max(3, math.ceil(2 * math.pi * r_outer / h)) if n_theta is None else n_theta
        mesh = _polar_grid(r_inner, r_outer, n_radial, n_theta)
    else:
        _require(n_radial is None and n_theta is None, "annulus: n_radial/n_theta need structured=True")
        mesh = _gmsh_annulus(r_inner, r_outer, h)
    return _curved_shell(mesh, r_inner, r_outer, curved, refinements)


def thick_shell(r_inner: float = 0.5, r_outer: float = 1.0, h: float = 0.2, *, curved: bool = True,
                refinements: int = 0) -> Mesh:
    """Tetrahedral mesh of the spherical shell ``r_inner < |x| < r_outer`` (Gmsh OCC).

    Parameters
    ----------
    r_inner, r_outer : float
        Radii of the cavity and outer spheres, in model length units.
    h : float
        Target edge length (same units).
    curved : bool
        Carry the P2 node positions of the boundary edges on the spheres (module docstring).
    refinements : int
        Uniform refinements of the generated mesh (module docstring), each halving h.

    Returns
    -------
    Mesh
        3D mesh. Boundaries: ``"gamma_d"`` and ``"outer"`` = triangles on the outer sphere,
        ``"gamma_n"`` and ``"inner"`` = triangles on the inner sphere.
    """
    _require(0 < r_inner < r_outer, "thick_shell: need 0 < r_inner < r_outer")
    _require(h > 0, "thick_shell: need h > 0")
    with gmsh_model("thick_shell") as gmsh:
        occ = gmsh.model.occ
        occ.cut([(3, occ.addSphere(0, 0, 0, r_outer))], [(3, occ.addSphere(0, 0, 0, r_inner))])
        occ.synchronize()
        mesh = gmsh_generate(gmsh, 3, h)
    return _curved_shell(mesh, r_inner, r_outer, curved, refinements)


def ventricle(
    h: float = 2.0,
    *,
    endo: tuple[float, float] = (7.0, 17.0),
    epi: tuple[float, float] = (10.0, 20.0),
    base_z: float = 5.0,
    curved: bool = True,
    refinements: int = 0,
) -> Mesh:
    """Idealized left ventricle of the Land et al. (2015) benchmark: a truncated prolate shell.

    The wall lies between the ellipsoids ``(x^2 + y^2) / rs^2 + z^2 / rl^2 = 1`` with
    ``(rs, rl) = endo`` (cavity) and ``epi`` (outside), below the base plane ``z = base_z``.
    The long axis is ``z``, the apex at ``z = -rl``. Built with Gmsh OCC (unit spheres dilated
    into ellipsoids, the part above the base cut off by a box, the cavity subtracted).

    Parameters
    ----------
    h : float
        Target edge length, mm.
    endo, epi : (float, float)
        Short and long semi-axes ``(rs, rl)`` of the endocardial and epicardial ellipsoids, mm.
    base_z : float
        Height of the base plane, mm; must cut the cavity (``|base_z| < endo[1]``).
    curved : bool
        Carry the P2 node positions of the edges on the two ellipsoids (module docstring); the
        rim edges move along the base plane, onto the circles where it cuts the ellipsoids.
    refinements : int
        Uniform refinements of the Gmsh mesh (module docstring), each halving h: a nested
        sequence for convergence studies (``ventricle(4, refinements=k)``, k = 0, 1, 2).

    Returns
    -------
    Mesh
        3D tetrahedral mesh, mm. Boundaries: ``"endocardium"`` (= ``"gamma_n"``, the cavity
        wall), ``"epicardium"``, ``"base"`` (= ``"gamma_d"``; use `Mesh.with_boundary` for another
        Dirichlet boundary). The cavity is closed apart from the base plane.
    """
    (rs_endo, rl_endo), (rs_epi, rl_epi) = endo, epi
    _require(h > 0, "ventricle: need h > 0")
    _require(0 < rs_endo < rs_epi and 0 < rl_endo < rl_epi, "ventricle: endo semi-axes must be below epi ones")
    _require(abs(base_z) < rl_endo, "ventricle: the base plane must cut the cavity (|base_z| < endo long axis)")
    with gmsh_model("ventricle") as gmsh:
        occ = gmsh.model.occ
        width = 4 * rs_epi
        above_base = occ.addBox(-width / 2, -width / 2, base_z, width, width, 2 * rl_epi)
        wall = [(3, _occ_ellipsoid(occ, rs_epi, rl_epi))]
        occ.cut(wall, [(3, _occ_ellipsoid(occ, rs_endo, rl_endo)), (3, above_base)])
        occ.synchronize()
        mesh = gmsh_generate(gmsh, 3, h)
    walls = {"endocardium": Quadric((rs_endo, rs_endo, rl_endo)), "epicardium": Quadric((rs_epi, rs_epi, rl_epi))}
    tag = lambda mesh, curved: tagged(mesh, walls, {"base": lambda x: x[:, 2] - base_z}, dirichlet="base",
                                       neumann="endocardium", curved=curved, planes={"base": (0.0, 0.0, 1.0)})
    return refined(mesh, tag, curved, refinements)


def _polar_grid(r_inner: float, r_outer: float, n_radial: int, n_theta: int) -> Mesh:
    """Structured annulus: vertex ``(i, j)`` at radius ``r_i``, angle ``2 pi j / n_theta``."""
    _require(n_radial >= 1 and n_theta >= 3, "annulus: need n_radial >= 1 and n_theta >= 3")
    r = np.linspace(r_inner, r_outer, n_radial + 1)
    theta = 2 * np.pi * np.arange(n_theta) / n_theta
    points = np.stack([np.outer(r, np.cos(theta)).ravel(), np.outer(r, np.sin(theta)).ravel()], axis=1)
    idx = np.arange(points.shape[0]).reshape(n_radial + 1, n_theta)
    nxt = np.roll(idx, -1, axis=1)  # angular neighbour, periodic
    v00, v10, v01, v11 = idx[:-1].ravel(), idx[1:].ravel(), nxt[:-1].ravel(), nxt[1:].ravel()
    cells = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return Mesh(points, cells)


def _gmsh_annulus(r_inner: float, r_outer: float, h: float) -> Mesh:
    with gmsh_model("annulus") as gmsh:
        occ = gmsh.model.occ
        occ.cut([(2, occ.addDisk(0, 0, 0, r_outer, r_outer))], [(2, occ.addDisk(0, 0, 0, r_inner, r_inner))])
        occ.synchronize()
        return gmsh_generate(gmsh, 2, h)


class Quadric:
    """The surface ``f(x) = sum_i x_i^2 / s_i^2 - 1 = 0`` centred at the origin, semi-axes ``s`` (dim,):
    a circle, a sphere or an ellipsoid of revolution."""

    def __init__(self, semi_axes):
        self.a = 1.0 / np.asarray(semi_axes, dtype=np.float64) ** 2  # diagonal of A, f = x^T A x - 1

    def distance(self, x: np.ndarray) -> np.ndarray:
        """First-order signed distance ``f / |grad f|`` of points x (n, dim), (n,)."""
        return (x**2 @ self.a - 1.0) / np.linalg.norm(2 * self.a * x, axis=1)

    def project(self, x: np.ndarray, keep_normal: np.ndarray) -> np.ndarray:
        """Points (n, dim) on the surface: ``x - t d`` with ``d = g - (g . n) n``, ``g = grad f(x)``,
        ``n = keep_normal`` (n, dim) (unit normal of a plane to stay in, or 0), and t the root of
        smallest |t| of the quadratic ``f(x - t d) = f(x) - 2 t d^T A x + t^2 d^T A d = 0``."""
        g = 2 * self.a * x
        d = g - np.einsum("ni,ni->n", g, keep_normal)[:, None] * keep_normal
        c0, c1, c2 = x**2 @ self.a - 1.0, -2 * (d * x) @ self.a, d**2 @ self.a
        q = -0.5 * (c1 + np.sign(c1) * np.sqrt(c1**2 - 4 * c2 * c0))
        return x - (c0 / q)[:, None] * d


def _curved_shell(mesh: Mesh, r_inner: float, r_outer: float, curved: bool, refinements: int) -> Mesh:
    """`tagged` for the concentric circles/spheres ``|x| = r_outer`` (``"outer"``, ``gamma_d``) and
    ``|x| = r_inner`` (``"inner"``, ``gamma_n``, the cavity) of an annulus or a shell, `refined`."""
    spheres = {name: Quadric(np.full(mesh.dim, r)) for name, r in (("outer", r_outer), ("inner", r_inner))}
    tag = lambda mesh, curved: tagged(mesh, spheres, {}, dirichlet="outer", neumann="inner", curved=curved)
    return refined(mesh, tag, curved, refinements)


def refined(mesh: Mesh, tag: Callable, curved: bool, refinements: int) -> Mesh:
    """``tag(mesh, curved)`` (boundary names and curved edges) after ``refinements`` uniform refinements
    (`hyperoc.fem.mesh.refine`), each of the curved mesh: the new vertices of the boundary edges land on
    the exact surfaces, so the refined meshes approximate the true domain, not the first mesh's."""
    _require(isinstance(refinements, int) and refinements >= 0,
             f"need refinements >= 0 (an integer), got {refinements!r}")
    for _ in range(refinements):
        mesh = refine(tag(mesh, True))
    return tag(mesh, curved)


def tagged(mesh: Mesh, walls: dict, flat: dict, *, dirichlet: str, neumann: str, curved: bool,
           planes: dict | None = None) -> Mesh:
    """Boundary facets named after the nearest of the curved ``walls`` (name -> `Quadric`) and the
    ``flat`` surfaces (name -> distance function), `_tag_boundary`; with ``curved``, the P2 edge
    nodes curved onto the walls (`_curve_edges`, ``planes`` the unit normals of flat boundaries),
    after removing the cells whose vertices all lie on the cavity wall ``neumann``: such a cell lies
    in the convex hull of points of a convex surface bounding the cavity, i.e. in the exact cavity,
    and curving its wall facets outwards folds it (Gmsh leaves a few: one at the apex of ventricle(2.0))."""
    distances = {**flat, **{name: q.distance for name, q in walls.items()}}
    mesh = _tag_boundary(mesh, distances, dirichlet=dirichlet, neumann=neumann)
    if not curved:
        return mesh
    on_cavity = np.zeros(len(mesh.points), bool)
    on_cavity[mesh.boundary_vertices(neumann)] = True
    inside = on_cavity[mesh.cells].all(axis=1)
    if inside.any():
        points, cells, _ = _drop_unused_points(mesh.points, mesh.cells[~inside], {})
        return tagged(Mesh(points, cells), walls, flat, dirichlet=dirichlet, neumann=neumann, curved=curved,
                       planes=planes)
    return _curve_edges(mesh, walls, planes)


def _facet_edges(facets: np.ndarray) -> np.ndarray:
    """Distinct edges (ne, 2), sorted pairs, of the facets (nf, k)."""
    pairs = [facets[:, [i, j]] for i in range(facets.shape[1]) for j in range(i + 1, facets.shape[1])]
    return np.unique(np.sort(np.concatenate(pairs), axis=1), axis=0)


def _curve_edges(mesh: Mesh, surfaces: dict, planes: dict | None = None) -> Mesh:
    """``mesh`` with curved P2 edge nodes. The node of every edge of the facets of ``surfaces``
    (boundary name -> `Quadric`) moves from the edge midpoint onto that surface (`Quadric.project`;
    an edge that is also an edge of a flat boundary in ``planes``, name -> unit normal (dim,), moves
    within it; a normal given as a function of the midpoints (n, dim) -> (n, dim), e.g. of a cone, moves
    the edge node within the tangent plane at its midpoint); the other boundary edge nodes and the vertices
    stay; the interior edge nodes move by the discrete harmonic extension of those shifts
    (``int grad s . grad phi = 0`` per component, P2 on the straight mesh). Spreading the boundary
    curvature into the first layers of cells keeps the cells along a concave wall from being squeezed
    (ventricle(4.0): min det J_q / det J_affine 0.68, 0.41 with the interior edge nodes left at their
    midpoints)."""
    nv = len(mesh.points)
    key = lambda e: e[:, 0] * nv + e[:, 1]
    space = VectorSpace(mesh, 2, components=1)
    shift = np.zeros((space.num_nodes, mesh.dim))  # of every P2 node from its straight position
    fixed = [np.arange(nv), space.edge_nodes(_facet_edges(mesh.boundary_facets()))]
    for name, surface in surfaces.items():
        e = _facet_edges(mesh.boundary(name))
        keep = np.zeros((len(e), mesh.dim))
        mid = 0.5 * (mesh.points[e[:, 0]] + mesh.points[e[:, 1]])
        for plane, normal in (planes or {}).items():
            on_plane = np.isin(key(e), key(_facet_edges(mesh.boundary(plane))))
            keep[on_plane] = normal(mid[on_plane]) if callable(normal) else normal
        shift[space.edge_nodes(e)] = surface.project(mid, keep) - mid
    fixed = np.unique(np.concatenate(fixed))
    shift = solve_dirichlet(space.laplace_blocks(), space.cell_nodes, space.num_nodes, fixed, shift[fixed])
    return mesh.with_curved_edges(space.edges, space.nodes[nv:] + shift[nv:])


def _occ_ellipsoid(occ, rs: float, rl: float) -> int:
    """OCC volume tag of the ellipsoid with semi-axes ``(rs, rs, rl)`` centred at the origin."""
    tag = occ.addSphere(0, 0, 0, 1.0)
    occ.dilate([(3, tag)], 0, 0, 0, rs, rs, rl)
    return tag


def _tag_boundary(mesh: Mesh, surfaces: dict[str, _Distance], *, dirichlet: str, neumann: str) -> Mesh:
    """Name every boundary facet after the surface nearest to its vertices.

    A facet goes to the surface whose ``|distance|``, summed over the facet's vertices, is
    smallest; ``gamma_d`` and ``gamma_n`` alias the surfaces named ``dirichlet`` and ``neumann``.
    """
    facets = mesh.boundary_facets()
    names = list(surfaces)
    score = np.stack([np.abs(surfaces[name](mesh.points))[facets].sum(axis=1) for name in names])
    nearest = score.argmin(axis=0)
    bnd = {name: facets[nearest == k] for k, name in enumerate(names)}
    bnd["gamma_d"], bnd["gamma_n"] = bnd[dirichlet], bnd[neumann]
    return Mesh(mesh.points, mesh.cells, bnd)


# --------------------------------------------------------------------------------------------
# Gmsh
# --------------------------------------------------------------------------------------------


@contextlib.contextmanager
def gmsh_model(name: str):
    """A fresh, silent Gmsh instance holding one model; the ``gmsh`` module is yielded."""
    import gmsh

    # interruptible=False: no SIGINT handler, so this also works outside the main thread.
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        yield gmsh
    finally:
        gmsh.finalize()


def gmsh_generate(gmsh, dim: int, h: float) -> Mesh:
    """Mesh the current (synchronized) Gmsh model with size ``h``; keep its ``dim``-simplices."""
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.model.mesh.generate(dim)
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    _, cell_nodes = gmsh.model.mesh.getElementsByType(_GMSH_SIMPLEX[dim])
    index = np.zeros(int(node_tags.max()) + 1, dtype=np.int64)
    index[node_tags.astype(np.int64)] = np.arange(len(node_tags))
    cells = index[np.asarray(cell_nodes, dtype=np.int64)].reshape(-1, dim + 1)
    points, cells, _ = _drop_unused_points(coords.reshape(-1, 3)[:, :dim], cells, {})
    return Mesh(points, cells)


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise InputError(message)

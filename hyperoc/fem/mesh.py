"""Simplicial meshes with named boundaries and subdomains.

A `Mesh` is geometry only: points, cells (straight-sided simplices), named sets of boundary facets
and of cells, and optionally the exact positions of some edge midpoints (``curved_edges``,
``curved_points``: e.g. midpoints of edges on a curved boundary moved onto the true surface), which
the quadratic spaces of `hyperoc.fem.spaces` use as isoparametric P2 geometry. The names the solver
looks for by default are

- ``"gamma_d"``: the Dirichlet boundary Gamma_D (``u = 0``), e.g. the outer wall;
- ``"gamma_n"``: the free boundary Gamma_N (e.g. a cavity wall), where a traction ``g`` acts;
- ``"omega"``: the control region (a cell subset), optional: controls may use a predicate instead.

Structured generators for intervals, rectangles and boxes live here; Gmsh-based geometries
(annulus, thick shell, idealized ventricle) and file readers live in `hyperoc.fem.geometry`.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

__all__ = ["Mesh", "ALIASES", "find_group", "interval", "rectangle", "box", "refine"]

#: Canonical boundary names and the names (compared without case) that files use for them.
ALIASES = {
    "endocardium": ("endocardium", "endo"),
    "epicardium": ("epicardium", "epi"),
    "base": ("base", "top"),
}



@dataclass(frozen=True, eq=False)
class Mesh:
    """Simplicial mesh, straight-sided unless ``curved_edges`` is given.

    Attributes
    ----------
    points : (nv, dim) float64
        Vertex coordinates (reference configuration), in length units of the model.
    cells : (nc, dim + 1) int64
        Vertex indices of each simplex, positively oriented (``det J > 0``).
    boundaries : dict[str, (nf, dim) int64]
        Named sets of boundary facets (vertex indices); points in 1D, edges in 2D, triangles in 3D.
    subdomains : dict[str, (nc,) bool]
        Named cell subsets (e.g. the control region ``"omega"``).
    curved_edges : (ne, 2) int64
        Edges (vertex pairs, stored sorted) whose midpoint node does not lie halfway between the
        vertices; empty for a straight-sided mesh.
    curved_points : (ne, dim) float64
        Position of the P2 node of each curved edge (e.g. the straight midpoint moved onto the
        exact boundary surface). Degree-2 spaces put their edge node there and map every cell
        isoparametrically (``x(xi) = sum_a N_a(xi) X_a`` over the 6 / 10 P2 nodes); degree-1
        spaces and the vertex-based methods below (`cell_volumes`, `volume`, `cell_jacobians`)
        see the straight-sided cells.
    """

    points: np.ndarray
    cells: np.ndarray
    boundaries: dict = field(default_factory=dict)
    subdomains: dict = field(default_factory=dict)
    curved_edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    curved_points: np.ndarray | None = None

    def __post_init__(self):
        pts = np.ascontiguousarray(self.points, dtype=np.float64)
        if pts.ndim == 1:
            pts = pts[:, None]
        cells = np.ascontiguousarray(self.cells, dtype=np.int64)
        dim = pts.shape[1]
        if dim not in (1, 2, 3) or cells.ndim != 2 or cells.shape[1] != dim + 1:
            raise InputError(f"mesh: expected simplices of dimension {dim}, got cells of shape {cells.shape}")
        if cells.size and (cells.min() < 0 or cells.max() >= len(pts)):
            raise InputError("mesh: cell vertex index out of range")
        cells = _orient_positively(pts, cells)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "cells", cells)
        bnd = {k: np.asarray(v, dtype=np.int64).reshape(-1, dim) for k, v in self.boundaries.items()}
        sub = {k: np.asarray(v, dtype=bool).reshape(-1) for k, v in self.subdomains.items()}
        for name, mask in sub.items():
            if mask.shape != (len(cells),):
                raise InputError(f"mesh: subdomain {name!r} has {mask.size} flags for {len(cells)} cells")
        object.__setattr__(self, "boundaries", bnd)
        object.__setattr__(self, "subdomains", sub)
        edges, positions = _curved_edge_data(self.curved_edges, self.curved_points, len(pts), dim)
        object.__setattr__(self, "curved_edges", edges)
        object.__setattr__(self, "curved_points", positions)

    @property
    def dim(self) -> int:
        return self.points.shape[1]

    @property
    def num_cells(self) -> int:
        return self.cells.shape[0]

    @property
    def is_curved(self) -> bool:
        """True when some edge carries a P2 node off its straight midpoint (``curved_edges``)."""
        return len(self.curved_edges) > 0

    def cell_jacobians(self) -> np.ndarray:
        """Affine maps of the straight-sided cells ``J[c] = [x_1 - x_0, ..., x_d - x_0]`` as (nc, dim, dim) arrays
        (columns = edges)."""
        x = self.points[self.cells]
        return np.swapaxes(x[:, 1:, :] - x[:, :1, :], 1, 2)

    def cell_volumes(self) -> np.ndarray:
        """Measures (length, area or volume) of the straight-sided cells, shape (nc,) (for a curved
        mesh, the isoparametric measures are ``VectorSpace(mesh, 2).quadrature(k).wdx.sum(1)``)."""
        return np.abs(np.linalg.det(self.cell_jacobians())) / _factorial(self.dim)

    def volume(self) -> float:
        return float(self.cell_volumes().sum())

    def cell_centroids(self) -> np.ndarray:
        return self.points[self.cells].mean(axis=1)

    def boundary_facets(self) -> np.ndarray:
        """All facets that belong to exactly one cell, (nf, dim)."""
        faces = np.concatenate([np.delete(self.cells, k, axis=1) for k in range(self.dim + 1)])
        key = np.sort(faces, axis=1)
        uniq, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        return uniq[counts == 1]

    def boundary(self, name: str) -> np.ndarray:
        """The facets of the boundary ``name`` (or of the one boundary that an alias of it names, `find_group`)."""
        return self.boundaries[find_group(self.boundaries, name)]

    def boundary_vertices(self, name: str) -> np.ndarray:
        return np.unique(self.boundary(name))

    def with_subdomain(self, name: str, mask) -> "Mesh":
        """A copy with one more named cell subset."""
        return dataclasses.replace(self, subdomains={**self.subdomains, name: np.asarray(mask, bool)})

    def with_boundary(self, name: str, facets) -> "Mesh":
        """A copy with one more named facet set."""
        return dataclasses.replace(self, boundaries={**self.boundaries, name: np.asarray(facets)})

    def with_curved_edges(self, edges, positions) -> "Mesh":
        """A copy whose P2 edge nodes of ``edges`` (ne, 2) sit at ``positions`` (ne, dim), replacing
        any curved edges this mesh had."""
        return dataclasses.replace(self, curved_edges=np.asarray(edges), curved_points=np.asarray(positions))

    def faceted(self) -> "Mesh":
        """The straight-sided copy (no curved edges): P2 edge nodes at the straight midpoints."""
        return dataclasses.replace(self, curved_edges=np.zeros((0, 2), np.int64), curved_points=None)

    def h(self) -> float:
        """Largest edge length."""
        x = self.points[self.cells]
        pairs = itertools.combinations(range(self.dim + 1), 2)
        return float(max(np.linalg.norm(x[:, i] - x[:, j], axis=1).max() for i, j in pairs))


def find_group(named: dict, wanted, kind: str = "boundary", source: str = "mesh") -> str:
    """The key of ``named`` that ``wanted`` designates: itself (a name, or a number as its string), else
    the one key among the aliases of ``wanted``'s canonical name (`ALIASES`, any case).

    Raises `InputError` (one line naming the tags found) when there is none."""
    wanted = str(wanted)
    if wanted in named:
        return wanted
    group = next((names for names in ALIASES.values() if wanted.lower() in names), ())
    hits = [key for key in named if key.lower() in group]
    if len(hits) == 1:
        return hits[0]
    found = ", ".join(sorted(named)) or "none"
    raise InputError(f"{source}: no {kind} tag {wanted!r} (tags found: {found})")


def _curved_edge_data(edges, positions, num_points: int, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``(edges (ne, 2) int64, sorted per row, positions (ne, dim) float64)``."""
    edges = np.sort(np.asarray(edges, dtype=np.int64).reshape(-1, 2), axis=1)
    positions = np.zeros((0, dim)) if positions is None else positions
    positions = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1, dim)
    if len(positions) != len(edges):
        raise InputError(f"mesh: {len(edges)} curved edges but {len(positions)} positions")
    if edges.size and (edges.min() < 0 or edges.max() >= num_points or np.any(edges[:, 0] == edges[:, 1])):
        raise InputError("mesh: a curved edge has a vertex index out of range or twice the same vertex")
    if not np.all(np.isfinite(positions)):
        raise InputError("mesh: curved edge positions must be finite")
    return edges, positions


#: Red refinement: the children of a simplex as rows of local node indices, vertices ``0 .. d`` then
#: the edge nodes ``d + 1 + k`` of the local edges ``k`` in ``itertools.combinations(range(d + 1), 2)``
#: order. In 3D the four corner tetrahedra; the inner octahedron is split separately (`_octahedron`).
_CORNERS = {
    1: [[0, 2], [2, 1]],
    2: [[0, 3, 4], [3, 1, 5], [4, 5, 2], [3, 5, 4]],
    3: [[0, 4, 5, 6], [4, 1, 7, 8], [5, 7, 2, 9], [6, 8, 9, 3]],
}
#: The octahedron's three diagonals (pairs of opposite edge nodes: m01-m23, m02-m13, m03-m12), each
#: followed by the other four edge nodes in cyclic order around it.
_DIAGONALS = [((4, 9), (5, 6, 8, 7)), ((5, 8), (4, 6, 9, 7)), ((6, 7), (4, 5, 9, 8))]


def refine(mesh: Mesh) -> Mesh:
    """Uniform red refinement: every simplex splits into ``2^d`` (a segment into 2, a triangle into
    4, a tetrahedron into 8, its inner octahedron cut along its shortest diagonal, which keeps the
    shape quality bounded over repeated refinements); named boundaries split with their facets and
    subdomains pass to the children.

    The new vertex of an edge is its P2 node: the straight midpoint, or the mesh's curved point for
    a curved edge (``curved_edges``), so repeated refinement of a curved mesh puts every new
    boundary vertex on the exact surface. The result is straight-sided; curving its boundary edges
    again is the geometry's job (`hyperoc.fem.geometry` generators take ``refinements``).

    Raises `InputError` if a child would be inverted (a curved node too far off its midpoint).
    """
    dim, nv = mesh.dim, len(mesh.points)
    local = list(itertools.combinations(range(dim + 1), 2))
    edges, inverse = np.unique(np.sort(mesh.cells[:, local], axis=2).reshape(-1, 2), axis=0, return_inverse=True)
    straight = np.concatenate([mesh.points, 0.5 * (mesh.points[edges[:, 0]] + mesh.points[edges[:, 1]])])
    points = straight.copy()
    if mesh.is_curved:
        points[nv + _edge_index(edges, mesh.curved_edges, nv)] = mesh.curved_points
    nodes = np.concatenate([mesh.cells, nv + inverse.reshape(mesh.num_cells, len(local))], axis=1)
    children = nodes[:, _CORNERS[dim]]  # (nc, k, dim + 1)
    if dim == 3:
        children = np.concatenate([children, _octahedron(nodes, points)], axis=1)
    nchild = children.shape[1]
    children = _orient_positively(straight, children.reshape(-1, dim + 1))
    x = points[children]
    if np.any(np.linalg.det(np.swapaxes(x[:, 1:] - x[:, :1], 1, 2)) <= 0):
        raise InputError("refine: a curved edge node lies so far off its midpoint that a child cell folds")
    boundaries = {name: _refine_facets(facets, edges, nv) for name, facets in mesh.boundaries.items()}
    subdomains = {name: np.repeat(mask, nchild) for name, mask in mesh.subdomains.items()}
    return Mesh(points, children, boundaries, subdomains)


def _edge_index(edges: np.ndarray, wanted: np.ndarray, nv: int) -> np.ndarray:
    """Rows of the sorted unique ``edges`` (ne, 2) holding the vertex pairs ``wanted`` (..., 2)."""
    key = lambda e: e[..., 0] * nv + e[..., 1]
    return np.searchsorted(key(edges), key(np.sort(wanted, axis=-1)))


def _octahedron(nodes: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The four tetrahedra (nc, 4, 4) of each cell's inner octahedron around its shortest diagonal
    (local node indices as in `_CORNERS`)."""
    length = np.stack([np.linalg.norm(points[nodes[:, a]] - points[nodes[:, b]], axis=1)
                       for (a, b), _ in _DIAGONALS], 1)
    templates = np.array([[[a, b, ring[i], ring[(i + 1) % 4]] for i in range(4)] for (a, b), ring in _DIAGONALS])
    local = templates[np.argmin(length, axis=1)]  # (nc, 4, 4)
    return np.take_along_axis(nodes[:, None, :], local, axis=2)


def _refine_facets(facets: np.ndarray, edges: np.ndarray, nv: int) -> np.ndarray:
    """The ``2^(d-1)`` children of every boundary facet (nf, d) of a mesh refined by `refine`."""
    d = facets.shape[1]
    if d == 1:
        return facets
    local = list(itertools.combinations(range(d), 2))
    nodes = np.concatenate([facets, nv + _edge_index(edges, facets[:, local], nv)], axis=1)
    return nodes[:, _CORNERS[d - 1]].reshape(-1, d)


def _factorial(d: int) -> int:
    return {1: 1, 2: 2, 3: 6}[d]


def _orient_positively(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Swap two vertices of every negatively oriented simplex; reject degenerate ones."""
    if not cells.size:
        return cells
    x = points[cells]
    det = np.linalg.det(np.swapaxes(x[:, 1:, :] - x[:, :1, :], 1, 2))
    scale = np.max(np.abs(x - x[:, :1, :])) ** points.shape[1]
    if np.any(np.abs(det) <= 1e-14 * scale):
        raise InputError(f"mesh: {int(np.sum(np.abs(det) <= 1e-14 * scale))} degenerate (zero-volume) cell(s)")
    cells = cells.copy()
    neg = det < 0
    cells[neg, 0], cells[neg, 1] = cells[neg, 1].copy(), cells[neg, 0].copy()
    return cells


def _facets_where(mesh_points: np.ndarray, facets: np.ndarray, predicate) -> np.ndarray:
    """Facets all of whose vertices satisfy ``predicate(x) -> bool array``."""
    ok = predicate(mesh_points)
    return facets[np.all(ok[facets], axis=1)]


def interval(n: int = 100, length: float = 1.0) -> Mesh:
    """The paper's 1D body ``(0, L)`` with ``n`` cells: Gamma_D = {0}, Gamma_N = {L}."""
    if n < 1 or length <= 0:
        raise InputError("interval: need n >= 1 and length > 0")
    x = np.linspace(0.0, length, n + 1)
    cells = np.stack([np.arange(n), np.arange(1, n + 1)], axis=1)
    return Mesh(x[:, None], cells, {"gamma_d": [[0]], "gamma_n": [[n]]})


def rectangle(nx: int = 8, ny: int | None = None, size=(1.0, 1.0), dirichlet: str = "left") -> Mesh:
    """Structured triangulation of ``[0, a] x [0, b]`` (each square split along its diagonal).

    Boundaries: ``left, right, bottom, top``; ``gamma_d`` is the side named by ``dirichlet``
    and ``gamma_n`` is the rest of the boundary.
    """
    ny = nx if ny is None else ny
    a, b = size
    xs, ys = np.linspace(0, a, nx + 1), np.linspace(0, b, ny + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel()], axis=1)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    v00, v10, v01, v11 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
    cells = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    sides = {
        "left": lambda x: np.isclose(x[:, 0], 0.0),
        "right": lambda x: np.isclose(x[:, 0], a),
        "bottom": lambda x: np.isclose(x[:, 1], 0.0),
        "top": lambda x: np.isclose(x[:, 1], b),
    }
    return _with_sides(Mesh(pts, cells), sides, dirichlet)


def box(nx: int = 4, ny: int | None = None, nz: int | None = None, size=(1.0, 1.0, 1.0),
        dirichlet: str = "left") -> Mesh:
    """Structured tetrahedral mesh of a box, six tetrahedra per hexahedron (Kuhn split, conforming).

    Boundaries: ``left/right`` (x), ``bottom/top`` (y), ``front/back`` (z); ``gamma_d`` is the side
    named by ``dirichlet`` and ``gamma_n`` the rest.
    """
    ny = nx if ny is None else ny
    nz = nx if nz is None else nz
    a, b, c = size
    grid = np.meshgrid(np.linspace(0, a, nx + 1), np.linspace(0, b, ny + 1), np.linspace(0, c, nz + 1), indexing="ij")
    pts = np.stack([g.ravel() for g in grid], axis=1)
    idx = np.arange(pts.shape[0]).reshape(nx + 1, ny + 1, nz + 1)
    corner = {}
    for i, j, k in itertools.product((0, 1), repeat=3):
        corner[(i, j, k)] = idx[i : nx + i, j : ny + j, k : nz + k].ravel()
    tets = []
    # Kuhn subdivision: one tetrahedron per permutation of the axes, along the main diagonal.
    for perm in itertools.permutations(range(3)):
        path = [(0, 0, 0)]
        for axis in perm:
            nxt = list(path[-1])
            nxt[axis] = 1
            path.append(tuple(nxt))
        tets.append(np.stack([corner[p] for p in path], axis=1))
    sides = {
        "left": lambda x: np.isclose(x[:, 0], 0.0),
        "right": lambda x: np.isclose(x[:, 0], a),
        "bottom": lambda x: np.isclose(x[:, 1], 0.0),
        "top": lambda x: np.isclose(x[:, 1], b),
        "front": lambda x: np.isclose(x[:, 2], 0.0),
        "back": lambda x: np.isclose(x[:, 2], c),
    }
    return _with_sides(Mesh(pts, np.concatenate(tets)), sides, dirichlet)


def _with_sides(mesh: Mesh, sides: dict, dirichlet: str) -> Mesh:
    if dirichlet not in sides:
        raise InputError(f"unknown side {dirichlet!r}; choose one of {sorted(sides)}")
    facets = mesh.boundary_facets()
    bnd = {name: _facets_where(mesh.points, facets, pred) for name, pred in sides.items()}
    on_d = np.all(sides[dirichlet](mesh.points)[facets], axis=1)
    bnd["gamma_d"] = facets[on_d]
    bnd["gamma_n"] = facets[~on_d]
    return Mesh(mesh.points, mesh.cells, bnd, mesh.subdomains)

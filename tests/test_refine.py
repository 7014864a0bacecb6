"""Uniform (red) refinement, `hyperoc.fem.mesh.refine`, and the ``refinements`` of the geometry generators.

- Straight meshes: refinement keeps the old vertices, adds the edge midpoints, splits every cell into
  2^d children of total volume equal to the parent's (round-off), every named boundary into 2^(d-1)
  facets of the same total measure, and passes subdomains to the children. Every edge of the refined
  mesh is half a parent edge, or (3D) a diagonal of an inner octahedron, the shortest of the three.
- Shape regularity: a corner child is the parent scaled by 1/2 about a vertex, so the worst cell
  quality ``|K| / (longest edge)^d`` cannot improve; the shortest-diagonal split of the octahedron
  keeps it from degrading with the number of refinements (finitely many similarity classes for the
  structured box, whose Kuhn cells are reproduced exactly). Asserted: equal to round-off for the box,
  and no smaller than half the initial minimum after two refinements of an unstructured Gmsh mesh
  (measured: equal to round-off there too).
- Curved meshes: the new boundary vertices are the curved P2 edge nodes, on the exact surface to
  round-off; the P2 volume of the nested curved sequence converges at O(h^4) and the faceted one
  at O(h^2), with pre-asymptotic terms O(h^2) relative (tests/test_isoparametric.py), so the
  observed orders lie within 0.2 of 4 and 2 (measured 3.99-4.00 and 2.11-2.03).
"""

import itertools
import math

import numpy as np
import pytest

from hyperoc.errors import InputError
from hyperoc.fem import geometry
from hyperoc.fem.mesh import box, interval, rectangle, refine
from hyperoc.fem.spaces import VectorSpace, prolong


def facet_measures(points, facets):
    """Length / area of every facet (nf, d) of a 2D / 3D mesh."""
    x = points[facets]
    if facets.shape[1] == 2:
        return np.linalg.norm(x[:, 1] - x[:, 0], axis=1)
    return np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1) / 2


def edges(mesh):
    pairs = itertools.combinations(range(mesh.dim + 1), 2)
    return np.unique(np.sort(np.concatenate([mesh.cells[:, list(p)] for p in pairs]), axis=1), axis=0)


def quality(mesh):
    """``|K| / (longest edge)^d`` per cell (scale invariant, up to a constant the inverse aspect ratio)."""
    x = mesh.points[mesh.cells]
    longest = np.max([np.linalg.norm(x[:, i] - x[:, j], axis=1)
                      for i, j in itertools.combinations(range(mesh.dim + 1), 2)], axis=0)
    return mesh.cell_volumes() / longest**mesh.dim


def p2_volume(mesh):
    return float(VectorSpace(mesh, 2).quadrature(4).wdx.sum())


STRAIGHT = {"interval": lambda: interval(5), "rectangle": lambda: rectangle(3, 2, size=(2.0, 1.0)),
            "box": lambda: box(2, 3, 2, size=(1.0, 2.0, 0.5))}


@pytest.mark.parametrize("name", STRAIGHT)
def test_refine_splits_cells_and_keeps_volume_and_old_vertices(name):
    mesh = STRAIGHT[name]()
    fine = refine(mesh)
    d, nv = mesh.dim, len(mesh.points)
    assert fine.num_cells == 2**d * mesh.num_cells
    np.testing.assert_array_equal(fine.points[:nv], mesh.points)
    parent_edges = edges(mesh)
    assert len(fine.points) == nv + len(parent_edges)
    midpoints = 0.5 * (mesh.points[parent_edges[:, 0]] + mesh.points[parent_edges[:, 1]])
    np.testing.assert_allclose(np.sort(fine.points[nv:], axis=0), np.sort(midpoints, axis=0), rtol=0, atol=1e-15)
    assert fine.volume() == pytest.approx(mesh.volume(), rel=1e-13)
    assert np.all(fine.cell_volumes() > 0)


@pytest.mark.parametrize("name", ["rectangle", "box"])
def test_refine_splits_named_boundaries_and_subdomains(name):
    mesh = STRAIGHT[name]()
    mesh = mesh.with_subdomain("left_half", mesh.cell_centroids()[:, 0] < 0.5 * mesh.points[:, 0].max())
    fine = refine(mesh)
    for tag, facets in mesh.boundaries.items():
        assert len(fine.boundaries[tag]) == 2 ** (mesh.dim - 1) * len(facets)
        np.testing.assert_allclose(facet_measures(fine.points, fine.boundaries[tag]).sum(),
                                   facet_measures(mesh.points, facets).sum(), rtol=1e-13)
    sub, fine_sub = mesh.subdomains["left_half"], fine.subdomains["left_half"]
    assert fine_sub.sum() == 2**mesh.dim * sub.sum()
    assert fine.cell_volumes()[fine_sub].sum() == pytest.approx(mesh.cell_volumes()[sub].sum(), rel=1e-13)


def test_refine_keeps_the_boundary_of_the_domain():
    mesh = box(2)
    fine = refine(mesh)
    tagged = np.concatenate(list(fine.boundaries.values()))
    as_set = lambda f: {tuple(sorted(r)) for r in np.asarray(f).tolist()}
    assert as_set(tagged) == as_set(fine.boundary_facets())


def test_refined_edges_are_halves_or_shortest_octahedron_diagonals():
    mesh = geometry.ventricle(9.0, curved=False)
    fine = refine(mesh)
    h_parent = mesh.h()
    lengths = np.linalg.norm(np.subtract(*fine.points[edges(fine)].transpose(1, 0, 2)), axis=1)
    # Halves of parent edges are <= h / 2. The octahedron's diagonals are the tetrahedron's
    # bimedians, whose squares sum to a quarter of the sum of its six squared edges (<= 6 h^2 / 4):
    # the shortest is <= h / sqrt(2).
    assert lengths.max() <= h_parent / math.sqrt(2) * (1 + 1e-12)
    assert fine.h() < mesh.h()


def test_box_refinement_reproduces_its_cell_shapes():
    mesh = box(2)
    q = [quality(mesh).min()]
    for _ in range(2):
        mesh = refine(mesh)
        q.append(quality(mesh).min())
    np.testing.assert_allclose(q, q[0], rtol=1e-12)


def test_unstructured_refinement_keeps_shape_regularity():
    mesh = geometry.thick_shell(0.5, 1.0, 0.4, curved=False)
    q0 = quality(mesh).min()
    for _ in range(2):
        mesh = refine(mesh)
    assert quality(mesh).min() >= 0.5 * q0


def test_refine_rejects_a_curved_node_that_folds_a_child():
    mesh = rectangle(1, 1)
    # The diagonal's curved node pushed beyond a corner inverts the children on one side.
    diag = [e for e in edges(mesh) if np.linalg.norm(np.subtract(*mesh.points[e])) > 1.1][0]
    bent = mesh.with_curved_edges([diag], [[3.0, 3.0]])
    with pytest.raises(InputError, match="folds"):
        refine(bent)


# ---- curved geometries -----------------------------------------------------------------------


def test_refined_ventricle_puts_new_boundary_vertices_on_the_ellipsoids():
    coarse = geometry.ventricle(9.0)
    mesh = geometry.ventricle(9.0, refinements=1)
    nv = len(coarse.points)
    assert mesh.num_cells == 8 * coarse.num_cells
    for name, (rs, rl) in (("endocardium", (7.0, 17.0)), ("epicardium", (10.0, 20.0))):
        x = mesh.points[mesh.boundary_vertices(name)]
        residual = np.abs((x[:, 0] ** 2 + x[:, 1] ** 2) / rs**2 + x[:, 2] ** 2 / rl**2 - 1.0)
        new = mesh.boundary_vertices(name) >= nv
        assert new.sum() > 0
        assert residual[new].max() < 1e-12  # curved edge nodes: the exact surface to round-off
        assert residual.max() < 1e-6  # Gmsh's vertices
    base = mesh.points[mesh.boundary_vertices("base")]
    np.testing.assert_allclose(base[:, 2], 5.0, rtol=0, atol=1e-12)
    assert mesh.is_curved  # the refined mesh is curved again (its own edge nodes on the surfaces)


@pytest.mark.parametrize("curved, order", [(True, 4.0), (False, 2.0)])
def test_nested_annulus_area_converges_at_the_geometric_order(curved, order):
    exact = math.pi * (1.0 - 0.25)
    errors = np.array([abs(p2_volume(geometry.annulus(0.5, 1.0, 0.4, refinements=k, curved=curved)) - exact)
                       for k in range(3)])
    rates = np.log2(errors[:-1] / errors[1:])
    assert np.all(np.abs(rates - order) < 0.2), rates


@pytest.mark.parametrize("bad", [-1, 1.5, "2"])
def test_geometry_rejects_bad_refinements(bad):
    with pytest.raises(InputError, match="refinements"):
        geometry.annulus(0.5, 1.0, 0.4, refinements=bad)


# ---- transfer between nested levels (`hyperoc.fem.spaces.prolong`) ---------------------------------


def _polynomial(degree: int, components: int):
    """A field of total degree ``degree`` with ``components`` components, nonzero in every monomial."""
    def fn(x):
        s = x.sum(axis=1)
        base = 0.3 + x @ np.arange(1.0, x.shape[1] + 1) + (degree == 2) * (s**2 - 0.7 * x[:, 0] * x[:, -1])
        return np.stack([(c + 1.0) * base - c * x[:, 0] for c in range(components)], axis=1)
    return fn


@pytest.mark.parametrize("name", ["interval", "rectangle", "box", "annulus-straight"])
@pytest.mark.parametrize("coarse_degree, fine_degree", [(1, 1), (1, 2), (2, 2)])
def test_prolong_reproduces_coarse_fields_in_nested_spaces(name, coarse_degree, fine_degree):
    """P1 -> P1, P1 -> P2, P2 -> P2 on straight-sided cells: the fine space contains the coarse
    one, so a coarse polynomial comes back as the fine interpolant, to round-off."""
    meshes = {"interval": lambda: interval(3), "rectangle": lambda: rectangle(3, 2),
              "box": lambda: box(2, 1, 2), "annulus-straight": lambda: geometry.annulus(0.5, 1.0, 0.4, curved=False)}
    mesh = meshes[name]()
    coarse, fine = VectorSpace(mesh, coarse_degree), VectorSpace(refine(mesh), fine_degree)
    fn = _polynomial(coarse_degree, coarse.components)
    out = prolong(coarse, fine, coarse.interpolate(fn))
    exact = fine.interpolate(fn)
    assert np.max(np.abs(out - exact)) <= 1e-13 * np.max(np.abs(exact))


@pytest.mark.parametrize("make", [lambda k: geometry.annulus(0.5, 1.0, 0.3, refinements=k),
                                  lambda k: geometry.ventricle(9.0, refinements=k)], ids=["annulus", "ventricle"])
def test_prolong_on_curved_meshes_evaluates_at_the_material_points(make):
    """Isoparametric P2 parents: the coordinate field X is in the coarse space, and the value at a
    fine node is the coarse field at that node's material point (inverse map by Newton), so X comes
    back as the fine nodes, to round-off, although the fine boundary edge nodes lie on the exact
    surface, off the parents' curved images, and the fine cells are straight inside."""
    coarse, fine = VectorSpace(make(0), 2), VectorSpace(make(1), 2)
    X = prolong(coarse, fine, coarse.nodes.ravel()).reshape(fine.nodes.shape)
    size = np.ptp(fine.nodes, axis=0).max()
    assert np.max(np.abs(X - fine.nodes)) <= 1e-13 * size
    straight = VectorSpace(make(1).faceted(), 2).nodes
    assert np.max(np.abs(straight - fine.nodes)) > 1e-3 * size  # the fine mesh is curved too


def test_prolong_rejects_meshes_that_are_not_nested():
    with pytest.raises(InputError, match="refinement"):
        prolong(VectorSpace(rectangle(3), 1), VectorSpace(rectangle(5), 1), np.zeros(2 * 16))
    with pytest.raises(InputError, match="components"):
        prolong(VectorSpace(rectangle(2), 1), VectorSpace(refine(rectangle(2)), 1, components=1), np.zeros(18))

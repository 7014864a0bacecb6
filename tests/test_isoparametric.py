"""Isoparametric (curved) P2 cells on the curved geometries of hyperoc.fem.geometry.

- Volumes. A P2 map through nodes on a smooth boundary approximates it to O(h^3) pointwise, and the
  area or volume between the two to O(h^4) (the leading O(h^3) error of quadratic interpolation is
  orthogonal to constants on each edge / facet, Simpson's rule); straight facets miss it by O(h^2).
  Measured: the area of a structured annulus (nested polar grids, h halved), the volume of a Gmsh
  spherical shell and the cavity volume of the Gmsh ventricle (unstructured, not nested; h is the
  mean facet size ``sqrt(mean facet area)`` of the curved surface). Asserted: observed order within
  0.2 of 4 (curved) and of 2 (faceted) on the nested grids, where the pre-asymptotic terms are
  O(h^2) relative (4.0 and 2.0 observed); within 0.5 on the unstructured meshes, whose irregular
  refinement moves the fitted order by that much (faceted 1.95-2.4 observed, curved 3.5-4.4 pairwise,
  3.8-3.9 from the first to the last mesh, which is what is asserted).
- Affine meshes: `VectorSpace.quadrature` and the facet quadrature are the affine formulas, bit for
  bit; the isoparametric code on curved nodes placed at the straight midpoints reproduces them to
  round-off, and P1 spaces ignore curved nodes.
- Follower pressure on a closed curved surface (the whole boundary of a curved shell): f = -p grad V
  to round-off, V equals the model's int det F dX (both are exact polynomial integrals on the
  isoparametric cells, divergence theorem), the load stiffness is symmetric and passes its Taylor
  test (remainder O(eps^2): rate within 0.1 of 2), as tests/test_follower.py does on straight facets.
- Linear limit: a thick-walled cylinder (plane strain, outer wall clamped) under a pressure on the
  inner wall, linearized at rest (tangent K(0), follower force f(0)), against Lame's solution: the
  curved P2 displacement of the inner wall is more accurate on every mesh and converges at least
  half an order faster than on straight facets (measured orders 2.8 and 1.9: the faceted geometry
  error O(h^2) dominates there).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.fem import geometry
from hyperoc.fem.mesh import box
from hyperoc.fem.spaces import VectorSpace
from hyperoc.mechanics.cavity import CavityVolume
from hyperoc.mechanics.follower import FollowerPressure
from hyperoc.mechanics.materials import NeoHookean
from hyperoc.mechanics.model import StateModel
from test_follower import assembled_stiffness, assert_conservative, random_u, taylor_remainders


def observed_order(h, errors):
    """Order p of ``e = c h^p`` fitted between the first and last of (h, e) pairs."""
    return math.log(errors[0] / errors[-1]) / math.log(h[0] / h[-1])


def mean_facet_size(mesh, name):
    x = mesh.points[mesh.boundary(name)]
    return float(np.sqrt(np.mean(np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1) / 2)))


def p2_volume(mesh):
    return float(VectorSpace(mesh, 2).quadrature(4).wdx.sum())


def cap_volume(rs, rl, z_top):
    """Volume of the ellipsoid ``(x^2 + y^2) / rs^2 + z^2 / rl^2 <= 1`` below the plane z = z_top."""
    return math.pi * rs**2 * ((z_top + rl) - (z_top**3 + rl**3) / (3 * rl**2))


# ---- volumes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("curved, order", [(True, 4.0), (False, 2.0)])
def test_structured_annulus_area_converges_at_the_geometric_order(curved, order):
    n_theta = np.array([8, 16, 32])
    exact = math.pi * (1.0 - 0.25)
    errors = [abs(p2_volume(geometry.annulus(0.5, 1.0, structured=True, n_radial=2, n_theta=n, curved=curved)) - exact)
              for n in n_theta]
    rates = np.log2(np.array(errors[:-1]) / errors[1:])
    assert np.all(np.abs(rates - order) < 0.2), rates


@pytest.mark.parametrize("curved, order", [(True, 4.0), (False, 2.0)])
def test_shell_volume_converges_at_the_geometric_order(curved, order):
    meshes = [geometry.thick_shell(0.5, 1.0, h, curved=curved) for h in (0.4, 0.28, 0.2)]
    exact = 4 / 3 * math.pi * (1.0 - 0.125)
    errors = [abs(p2_volume(m) - exact) for m in meshes]
    p = observed_order([mean_facet_size(m, "inner") for m in meshes], errors)
    assert abs(p - order) < 0.5, (p, errors)


@pytest.mark.parametrize("curved, order", [(True, 4.0), (False, 2.0)])
def test_ventricle_cavity_volume_converges_at_the_geometric_order(curved, order):
    meshes = [geometry.ventricle(h, curved=curved) for h in (4.0, 3.0, 2.0)]
    exact = cap_volume(7.0, 17.0, 5.0)
    errors = []
    for mesh in meshes:
        model = StateModel(mesh, NeoHookean(1.0, 1.0), degree=2, dirichlet=None, pin_rigid=False)
        errors.append(abs(float(CavityVolume(model).volume(np.zeros(model.n))) - exact))
    p = observed_order([mean_facet_size(m, "endocardium") for m in meshes], errors)
    assert abs(p - order) < 0.5, (p, errors)


def test_curved_ventricle_keeps_the_base_flat_and_puts_edge_nodes_on_the_walls():
    mesh = geometry.ventricle(4.0)
    space = VectorSpace(mesh, 2)
    base = space.boundary_nodes("base")
    np.testing.assert_allclose(space.nodes[base, 2], 5.0, rtol=0, atol=1e-12)
    for name, (rs, rl) in (("endocardium", (7.0, 17.0)), ("epicardium", (10.0, 20.0))):
        x = space.nodes[space.boundary_nodes(name)]
        residual = (x[:, 0] ** 2 + x[:, 1] ** 2) / rs**2 + x[:, 2] ** 2 / rl**2 - 1.0
        assert np.max(np.abs(residual)) < 1e-6  # Gmsh's vertices; the edge nodes are exact to round-off
    assert p2_volume(mesh) == pytest.approx(cap_volume(10.0, 20.0, 5.0) - cap_volume(7.0, 17.0, 5.0), rel=1e-3)


# ---- affine meshes ---------------------------------------------------------------------------


def affine_quadrature(mesh, degree, rule):
    """The affine formulas: dN = dN_ref J^-1, wdx = |det J| w, x = x_0 + J xi."""
    from hyperoc.fem.quadrature import simplex_rule
    from hyperoc.fem.spaces import reference_shape

    xi, w = simplex_rule(mesh.dim, rule)
    N, dN_ref = reference_shape(mesh.dim, degree, xi)
    J = mesh.cell_jacobians()
    dN = np.einsum("qaj,cjk->cqak", dN_ref, np.linalg.inv(J))
    x = mesh.points[mesh.cells[:, 0]][:, None, :] + np.einsum("cij,qj->cqi", J, xi)
    return N, dN, np.abs(np.linalg.det(J))[:, None] * w[None, :], x


@pytest.mark.parametrize("mesh_fn", [lambda: box(2, 1, 1), lambda: geometry.annulus(0.5, 1.0, 0.3, curved=False)])
@pytest.mark.parametrize("degree", [1, 2])
def test_affine_meshes_keep_the_affine_quadrature(mesh_fn, degree):
    mesh = mesh_fn()
    assert not mesh.is_curved
    q = VectorSpace(mesh, degree).quadrature(4)
    for got, want in zip((q.N, q.dN, q.wdx, q.x), affine_quadrature(mesh, degree, 4)):
        np.testing.assert_array_equal(got, want)


def test_isoparametric_map_of_straight_midpoints_is_the_affine_map():
    mesh = geometry.thick_shell(0.5, 1.0, 0.4)
    straight = mesh.faceted()
    space = VectorSpace(straight, 2)
    midpoints = space.nodes[len(mesh.points):]
    iso = VectorSpace(straight.with_curved_edges(space.edges, midpoints), 2)
    assert iso.isoparametric and not space.isoparametric
    a, b = space.quadrature(4), iso.quadrature(4)
    scale = np.abs(a.dN).max()
    assert np.max(np.abs(a.dN - b.dN)) <= 1e-12 * scale
    np.testing.assert_allclose(b.wdx, a.wdx, rtol=1e-12)
    np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-14)
    fa, fb = space.facet_quadrature(mesh.boundary("inner"), 4), iso.facet_quadrature(mesh.boundary("inner"), 4)
    for x, y in zip(fa, fb):
        np.testing.assert_allclose(y, x, rtol=1e-12, atol=1e-14)


def test_p1_spaces_ignore_curved_edges():
    mesh = geometry.annulus(0.5, 1.0, structured=True, n_radial=2, n_theta=12)
    assert mesh.is_curved
    a, b = VectorSpace(mesh, 1).quadrature(2), VectorSpace(mesh.faceted(), 1).quadrature(2)
    np.testing.assert_array_equal(a.wdx, b.wdx)
    np.testing.assert_array_equal(a.dN, b.dN)


# ---- follower pressure on a curved closed surface --------------------------------------------


@pytest.fixture(scope="module")
def curved_shell_model():
    mesh = geometry.thick_shell(0.5, 1.0, 0.5)
    mesh = mesh.with_boundary("all", mesh.boundary_facets())
    model = StateModel(mesh, NeoHookean(1.0, 1.0), degree=2, dirichlet="outer")
    assert model.space.isoparametric
    return model


def test_curved_closed_surface_force_is_minus_p_grad_enclosed_volume(curved_shell_model):
    model = curved_shell_model
    fol = FollowerPressure(model, "all", 0.7)
    u = random_u(model, amp=0.02)
    assert_conservative(model, fol, u)
    forces = np.asarray(fol.facet_forces(u))
    assert np.max(np.abs(forces.reshape(-1, 3).sum(axis=0))) <= 1e-14 * np.abs(forces).sum()  # no net force


def test_curved_load_stiffness_matches_finite_differences(curved_shell_model):
    model = curved_shell_model
    fol = FollowerPressure(model, "inner", 0.3)
    u, v = random_u(model, amp=0.02), random_u(model, amp=1.0, seed=1)
    rem = taylor_remainders(fol, assembled_stiffness(model, fol, u), u, v, np.array([1e-2, 5e-3, 2.5e-3]))
    assert np.all(np.abs(np.log2(np.array(rem[:-1]) / rem[1:]) - 2) < 0.1), rem


# ---- linear limit: Lame's thick-walled cylinder ----------------------------------------------


def lame_inner_displacement(a, b, p, mu, lam):
    """Radial displacement of the inner wall r = a of a plane-strain cylinder a < r < b, clamped at
    r = b, pressure p on r = a: ``u = A r + B / r``, ``u(b) = 0``, ``sigma_rr(a) = -p``."""
    B = p / (2 * (lam + mu) / b**2 + 2 * mu / a**2)
    return B * (1 / a - a / b**2)


def linearized_inner_displacement(mesh, mu, lam, p):
    """Radial displacement (n,) at the inner-wall nodes of the linearized problem ``K(0) u = f(0)``
    (tangent at rest, follower pressure at rest), P2; dense (a few hundred dofs)."""
    model = StateModel(mesh, NeoHookean(mu, lam), degree=2)
    zero = jnp.zeros(model.n)
    K = np.asarray(jax.jit(jax.jacfwd(model.internal_force))(zero))
    u = np.linalg.solve(K, np.asarray(jax.jit(FollowerPressure(model, "inner", p).force)(zero)))
    nodes = model.space.boundary_nodes("inner")
    x = model.space.nodes[nodes]
    return np.einsum("ni,ni->n", model.expand(u)[nodes], x / np.linalg.norm(x, axis=1, keepdims=True))


@pytest.mark.slow
def test_inflated_cylinder_converges_faster_on_curved_cells():
    """Linear elasticity (the neo-Hookean law linearized at rest: Lame moduli mu, lam) against
    Lame's solution; the error of u_r on the inner wall, max over its nodes, relative."""
    a, b, mu, lam, p = 0.5, 1.0, 1.0, 2.0, 1.0
    exact = lame_inner_displacement(a, b, p, mu, lam)
    errors = {True: [], False: []}
    for n_theta in (12, 24):
        for curved in (True, False):
            mesh = geometry.annulus(a, b, structured=True, n_radial=n_theta // 6, n_theta=n_theta, curved=curved)
            errors[curved].append(np.max(np.abs(linearized_inner_displacement(mesh, mu, lam, p) - exact)) / exact)
    curved, faceted = np.array(errors[True]), np.array(errors[False])
    print(f"\nrelative max error of u_r(a): curved {curved}, faceted {faceted}")
    assert np.all(curved < faceted)
    assert np.log2(curved[0] / curved[1]) > np.log2(faceted[0] / faceted[1]) + 0.5

"""Active fibre tension (hyperoc.mechanics.active), the analytic benchmark fibres
(hyperoc.mechanics.fibres.prolate_fibres) and Land et al. (2015) problem 3 (hyperoc.cardiac.land.contraction_problem).

- Fibres: for points built from prolate coordinates (t, u, v) the field recovers t (bisection, to a few
  ulps amplified by 1 / |d/dt (rho^2 / rs^2 + z^2 / rl^2)| <= 10 in this wall) and equals
  ``sin(alpha) e_u + cos(alpha) e_v`` with the tangents computed from (u, v) directly; the frame is
  orthonormal and right-handed; alpha = +90 / 0 / -90 degrees at t = 0 / 1/2 / 1.
- Patch test: Saint Venant-Kirchhoff with fibres along x and T f0 (x) f0 added to S, symmetry planes
  x = 0, y = 0, z = 0 and free faces elsewhere: the exact solution is homogeneous, ``2 mu E + lambda
  tr(E) I = -T e_x (x) e_x``, i.e. ``E_yy = E_zz = lambda T / (2 mu (2 mu + 3 lambda))``, ``E_xx =
  E_yy - T / (2 mu)``, stretches sqrt(1 + 2 E). P1 and P2 contain it, so the static solve returns it up
  to Newton's stopping test (last increment <= rtol |u|; the error after it is smaller still).
- Tangent: the energy ``T int E_ff`` is quadratic in u, so the force is affine and the assembled
  stiffness equals the force's Jacobian to round-off (also in the displacement block of Taylor-Hood).
- Problem 3 setup: the published moduli and loads; on the endocardium the fibres are longitudinal
  (circumferential component ``cos(alpha(t)) = sin(pi t)``, t ~ 0 at the mesh's endocardial nodes).
- Problem 3 on the coarsest ventricle (Taylor-Hood, incompressible): the total volume is kept (the
  constant is a P1 pressure test function) and activation shortens the fibres on average: at the
  same pressure, ``A(T) = int E_ff`` at equilibrium decreases along a stable path in T since
  ``dA/dT = -grad A^T H^-1 grad A < 0`` (H the positive definite Hessian of the energy; the endocardial
  pressure with the clamped rim is conservative), so A(with tension) < A(pressure alone).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.cardiac.land import CONTRACTION, VentricleMesh, contraction_problem, ventricle_apex
from hyperoc.dynamics.statics import StaticOptions, solve_static
from hyperoc.dynamics.stepper import Scheme
from hyperoc.errors import InputError
from hyperoc.fem.mesh import box
from hyperoc.mechanics.active import FibreTension, axis_taper
from hyperoc.mechanics.fibres import prolate_fibres
from hyperoc.mechanics.materials import NeoHookean, SaintVenantKirchhoff
from hyperoc.mechanics.mixed import TaylorHoodModel
from hyperoc.mechanics.model import StateModel

EPS = np.finfo(float).eps


def prolate_wall(t, u, v):
    """Points x and unit tangents e_u, e_v (n, 3) of the benchmark wall at prolate coordinates (t, u, v),
    straight from the parameterization."""
    rs, rl = 7.0 + 3.0 * t, 17.0 + 3.0 * t
    x = np.stack([rs * np.sin(u) * np.cos(v), rs * np.sin(u) * np.sin(v), rl * np.cos(u)], axis=-1)
    e_u = unit(np.stack([rs * np.cos(u) * np.cos(v), rs * np.cos(u) * np.sin(v), -rl * np.sin(u)], axis=-1))
    e_v = unit(np.stack([-rs * np.sin(u) * np.sin(v), rs * np.sin(u) * np.cos(v), np.zeros_like(u)], axis=-1))
    return x, e_u, e_v


def prolate_coordinates(n=500, seed=0):
    """Random (t, u, v) in the benchmark wall, u away from the axis."""
    rng = np.random.default_rng(seed)
    return (rng.uniform(0.0, 1.0, n), rng.uniform(-np.pi + 0.05, -np.arccos(5.0 / 17.0), n),
            rng.uniform(-np.pi, np.pi, n))


def unit(a):
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def test_prolate_fibres_follow_the_benchmark_rule():
    t, u, v = prolate_coordinates()
    x, e_u, e_v = prolate_wall(t, u, v)
    fibres = prolate_fibres()
    np.testing.assert_allclose(fibres.transmural(x), t, rtol=0, atol=40 * 10 * EPS)
    frames = fibres(x)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", frames, frames), np.broadcast_to(np.eye(3), frames.shape),
                               rtol=0, atol=10 * EPS)
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, rtol=0, atol=10 * EPS)
    alpha = np.deg2rad(90.0 - 180.0 * t)[:, None]
    np.testing.assert_allclose(frames[:, 0], np.sin(alpha) * e_u + np.cos(alpha) * e_v, rtol=0, atol=1e3 * EPS)
    _, u, v = prolate_coordinates(3, seed=1)
    for t_wall, expected in ((0.0, 1), (0.5, 0), (1.0, -1)):  # f = e_u, e_v, -e_u
        x, e_u, e_v = prolate_wall(np.full(3, t_wall), u, v)
        target = e_v if expected == 0 else expected * e_u
        np.testing.assert_allclose(fibres(x)[:, 0], target, rtol=0, atol=1e3 * EPS)


def test_prolate_fibres_reject_bad_axes():
    with pytest.raises(InputError, match="endo < epi"):
        prolate_fibres(endo=(10.0, 20.0), epi=(7.0, 17.0))
    with pytest.raises(InputError, match="finite"):
        prolate_fibres(helix_endo=math.nan)


def along_x(x):
    return np.broadcast_to(np.eye(3), x.shape[:-1] + (3, 3))


def turning(x):
    """Fibres in the (x, y) plane turning with x + 2 y: a field that varies inside every cell."""
    a = x[..., 0] + 2.0 * x[..., 1]
    f = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)
    s = np.broadcast_to([0.0, 0.0, 1.0], f.shape)
    return np.stack([f, s, np.cross(f, s)], axis=-2)


@pytest.mark.parametrize("degree", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_homogeneous_contraction_is_exact(degree):
    mu, lam, T = 1.0, 1.0, 0.3
    model = StateModel(box(2, 2, 2, size=(1.0, 0.8, 0.6)), SaintVenantKirchhoff(mu=mu, lam=lam), degree=degree,
                       frames=along_x, dirichlet=None,
                       dirichlet_components={"left": (0,), "bottom": (1,), "front": (2,)})
    sol = solve_static(model, follower=FibreTension(model, T), constraint="none",
                       options=StaticOptions(steps=2, line_search=False))
    E_t = lam * T / (2 * mu * (2 * mu + 3 * lam))
    stretch = np.sqrt(1.0 + 2.0 * np.array([E_t - T / (2 * mu), E_t, E_t]))
    exact = model.space.nodes * (stretch - 1.0)
    assert stretch[0] < 1.0 < stretch[1]  # the fibres shorten, the cross-section widens
    np.testing.assert_allclose(model.expand(sol.u), exact, rtol=0, atol=Scheme().rtol * np.abs(exact).max())


def dense_stiffness(model, tension):
    blocks = tension.add_stiffness(jnp.zeros(model.pattern.element_shape), None, 0.7)
    return model.pattern.matrix(np.asarray(blocks)).toarray()


@pytest.mark.parametrize("mixed", [False, True])
@pytest.mark.parametrize("profile", [None, axis_taper(0.5, axis=(1.0, 0.0, 0.0))], ids=["uniform", "tapered"])
def test_stiffness_is_the_jacobian_of_the_affine_force(mixed, profile):
    mesh = box(2, 1, 1, size=(1.0, 0.7, 0.5))
    model = TaylorHoodModel(mesh, NeoHookean(1.0, 1.0), bulk_modulus=math.inf, frames=turning) if mixed else \
        StateModel(mesh, NeoHookean(1.0, 1.0), degree=2, frames=turning)
    tension = FibreTension(model, 2.5, profile)
    K = dense_stiffness(model, tension)
    rng = np.random.default_rng(0)
    u, v = jnp.asarray(0.1 * rng.standard_normal(model.n)), jnp.asarray(rng.standard_normal(model.n))
    jac = np.asarray(jax.jacfwd(lambda w: -tension.force(w, 0.7))(u))
    scale = np.abs(K).max()
    np.testing.assert_allclose(K, jac, rtol=0, atol=1e-13 * scale)
    step = np.asarray(tension.force(u + v, 0.7) - tension.force(u, 0.7))
    np.testing.assert_allclose(step, -K @ np.asarray(v), rtol=0, atol=1e-13 * scale * np.abs(np.asarray(v)).max())
    if mixed:  # no stiffness on the pressures
        assert not np.any(K[model.n_u:]) and not np.any(K[:, model.n_u:])


def test_axis_taper_is_the_squared_distance_ratio_capped_at_one():
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    normal = np.array([2.0, -1.0, 0.0]) / math.sqrt(5.0)  # orthogonal to the axis
    rho = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0])
    x = 7.0 * axis + rho[:, None] * normal  # distance rho from the axis, anywhere along it
    w = axis_taper(2.0, axis=3.0 * axis)(x)
    np.testing.assert_allclose(w, np.minimum(1.0, rho**2 / 4.0), rtol=0, atol=100 * EPS)
    assert w[0] == 0.0 and w[-2] == w[-1] == 1.0
    with pytest.raises(InputError, match="radius"):
        axis_taper(0.0)


def test_profile_weights_the_energy():
    """A constant profile c scales the energy, force and stiffness by c; a profile that vanishes on the
    cells of x < 1/2 (the box has two columns of cubes along x) removes their contribution."""
    model = StateModel(box(2, 1, 1, size=(1.0, 0.7, 0.5)), NeoHookean(1.0, 1.0), degree=2, frames=turning)
    u = jnp.asarray(0.1 * np.random.default_rng(1).standard_normal(model.n))
    plain = FibreTension(model, 2.5)
    scaled = FibreTension(model, 2.5, lambda x: np.full(x.shape[:-1], 0.3))
    E = np.asarray(plain.fibre_strain(u))
    terms = 2.5 * model.quad.wdx * E  # the energy's summands
    # sums of N terms (the energy: all points; an element matrix entry: its nq points) round within N eps sum |terms|
    sum_tol = lambda n, size: n * EPS * size
    np.testing.assert_allclose(scaled.energy(u), 0.3 * plain.energy(u), rtol=0,
                               atol=sum_tol(terms.size, np.abs(terms).sum()))
    K = np.asarray(plain.element_stiffness())
    np.testing.assert_allclose(scaled.element_stiffness(), 0.3 * K, rtol=0,
                               atol=sum_tol(terms.shape[1], np.abs(K).max()))
    right = FibreTension(model, 2.5, lambda x: (x[..., 0] > 0.5).astype(float))
    in_right = np.asarray(model.quad.x[..., 0] > 0.5)  # whole cells: the cells do not straddle x = 1/2
    assert np.all(in_right.all(axis=1) | ~in_right.any(axis=1))
    np.testing.assert_allclose(right.energy(u), np.sum(np.where(in_right, terms, 0.0)), rtol=0,
                               atol=sum_tol(terms.size, np.abs(terms).sum()))
    with pytest.raises(InputError, match="profile"):
        FibreTension(model, 2.5, lambda x: np.full(x.shape[:-1], np.nan))


def test_taper_is_a_problem_3_variant_only():
    with pytest.raises(InputError, match="problem 3"):
        ventricle_apex(VentricleMesh(6.0), problem=2, taper=4.0)


def test_fibre_tension_needs_fibres_and_a_finite_value():
    model = StateModel(box(1, 1, 1), NeoHookean(1.0, 1.0), degree=1)
    with pytest.raises(InputError, match="frames"):
        FibreTension(model, 1.0)
    with pytest.raises(InputError, match="finite"):
        FibreTension(StateModel(box(1, 1, 1), NeoHookean(1.0, 1.0), degree=1, frames=along_x), math.inf)


@pytest.fixture(scope="module")
def problem3():
    return contraction_problem(6.0, bulk_modulus=math.inf, volumetric="taylor-hood", isochoric=True)


def test_contraction_problem_is_land_problem_3(problem3):
    model, (pressure, tension) = problem3
    mat = model.material
    published = tuple(CONTRACTION[k] for k in ("C", "bf", "bt", "bfs"))
    assert (mat.C, mat.bf, mat.bt, mat.bfs) == (2.0, 8.0, 2.0, 4.0) == published
    assert (pressure.boundary, pressure.pressure, tension.tension) == ("endocardium", 15.0, 60.0)
    nodes = model.space.nodes[np.unique(model.space.facet_nodes(model.mesh.boundary("endocardium")))]
    nodes = nodes[np.hypot(nodes[:, 0], nodes[:, 1]) > 1.0]  # off the axis, where e_v is defined
    fibres = prolate_fibres()
    t, f = fibres.transmural(nodes), fibres(nodes)[:, 0]
    assert np.abs(t).max() <= 1e-6  # Gmsh's vertices are on the ellipsoid to its geometric tolerance
    circumferential = unit(np.stack([-nodes[:, 1], nodes[:, 0], np.zeros(len(nodes))], axis=-1))
    # f . e_v = cos(alpha(t)) = sin(pi t): 0 on the exact endocardium
    np.testing.assert_allclose(np.einsum("ni,ni->n", f, circumferential), np.sin(np.pi * t), rtol=0, atol=1e-12)


@pytest.mark.slow
def test_activation_shortens_the_fibres_and_keeps_the_volume(problem3):
    model, (pressure, tension) = problem3
    opts = dict(constraint="none", options=StaticOptions(steps=10, cutbacks=8, line_search=False))
    active = solve_static(model, follower=(pressure, tension), **opts)
    passive = solve_static(model, follower=pressure, **opts)
    volume = float(np.sum(model.quad.wdx))
    for sol in (active, passive):  # int (J - 1) q = 0 for the P1 pressure q = 1, up to Newton's test
        assert abs(sol.volume / volume - 1.0) <= 10 * Scheme().rtol
    mean_fibre_strain = lambda sol: float(tension.energy(jnp.asarray(sol.u))) / (tension.tension * volume)
    assert mean_fibre_strain(active) < mean_fibre_strain(passive)

"""Follower pressure (hyperoc.mechanics.follower) and its use in the quasi-static solver.

- Tangent: the assembled load stiffness K_p = -df/du (per-facet jacfwd scattered into the cell
  blocks) against finite differences: the Taylor remainder |f(u + eps v) - f(u) + eps K_p v| is
  O(eps^2), so halving eps divides it by 4 (asserted: observed rate within 0.1 of 2). In 2D the
  force is affine in u (the area vector is the turned tangent), so the remainder is round-off.
- Conservative identity on a closed surface: f = -p grad V with V = (1/d) int x . n da, to round-off
  (both sides are exact polynomial integrals); V itself equals the model's int det F dX (divergence
  theorem, exact for the discrete surface); the load stiffness is then symmetric.
- No net force from a uniform pressure on a closed surface, at rest and deformed; the force on one
  face at rest is p |face| along the inward normal (orientation).
- solve_static: the unconstrained solve is an equilibrium of R(u) = f(u); with the volume target
  set to the unconstrained solution's volume, the constrained solve finds the same u and p = 0;
  Newton failure raises SolverError naming the load step.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.dynamics.constraint import NoConstraint
from hyperoc.dynamics.statics import StaticOptions, solve_static
from hyperoc.errors import InputError, SolverError
from hyperoc.fem.mesh import box, rectangle
from hyperoc.mechanics.follower import FollowerPressure
from hyperoc.mechanics.materials import NeoHookean
from hyperoc.mechanics.model import StateModel


def closed_model(mesh, degree):
    """Model whose tag ``all`` is the whole (closed) boundary; Dirichlet on the left side."""
    mesh = mesh.with_boundary("all", mesh.boundary_facets())
    return StateModel(mesh, NeoHookean(1.0, 1.0), degree=degree, dirichlet="left")


def random_u(model, amp=0.05, seed=0):
    return jnp.asarray(amp * np.random.default_rng(seed).standard_normal(model.n))


def assembled_stiffness(model, fol, u):
    blocks = jax.jit(lambda u: fol.add_stiffness(jnp.zeros(model.pattern.element_shape), u))(u)
    return model.pattern.matrix(np.asarray(blocks)).toarray()


MESHES = [(lambda: box(2, 1, 1, size=(1.0, 0.7, 0.5)), 1), (lambda: box(2, 1, 1, size=(1.0, 0.7, 0.5)), 2),
          (lambda: rectangle(3, 2, size=(1.0, 0.6)), 2)]


@pytest.mark.parametrize("mesh_fn,degree", MESHES)
def test_load_stiffness_matches_finite_differences(mesh_fn, degree):
    mesh = mesh_fn()
    face = "front" if mesh.dim == 3 else "bottom"  # open surface: K_p not symmetric in general
    model = StateModel(mesh, NeoHookean(1.0, 1.0), degree=degree, dirichlet="left")
    fol = FollowerPressure(model, face, 0.3)
    u, v = random_u(model), random_u(model, amp=1.0, seed=1)
    K = assembled_stiffness(model, fol, u)
    eps = np.array([1e-2, 5e-3, 2.5e-3])
    rem = taylor_remainders(fol, K, u, v, eps)
    print(f"\nTaylor remainders {rem}")
    if mesh.dim == 2:  # the 2D area vector (dx/dxi turned) is linear in x: f is affine, remainder = round-off
        assert max(rem) <= 1e-13 * eps[-1] * np.max(np.abs(K @ np.asarray(v)))
    else:
        assert np.all(np.abs(np.log2(np.array(rem[:-1]) / rem[1:]) - 2) < 0.1)


@pytest.mark.parametrize("mesh_fn,degree", MESHES)
def test_closed_surface_force_is_minus_p_grad_enclosed_volume(mesh_fn, degree):
    model = closed_model(mesh_fn(), degree)
    assert_conservative(model, FollowerPressure(model, "all", 0.7), random_u(model))


def taylor_remainders(fol, K, u, v, eps) -> list:
    """``max |f(u + e v) - f(u) + e K v|`` for each e in eps (K = -df/du assembled, dense)."""
    f = jax.jit(fol.force)
    return [np.max(np.abs(np.asarray(f(u + e * v) - f(u)) + e * K @ np.asarray(v))) for e in eps]


def assert_conservative(model, fol, u):
    """On a closed surface at u: f = -p grad V (V = enclosed volume) and V = int det F dX to round-off
    (both exact polynomial integrals), and the load stiffness K_p = p Hess V is symmetric."""
    p = fol.pressure
    f = np.asarray(jax.jit(fol.force)(u))
    grad_V = np.asarray(jax.jit(jax.grad(fol.enclosed_volume))(u))
    assert np.max(np.abs(f + p * grad_V)) <= 1e-13 * np.max(np.abs(f))
    assert float(jax.jit(fol.enclosed_volume)(u)) == pytest.approx(float(model.jitted["volume"](u)), rel=1e-13)
    K = assembled_stiffness(model, fol, u)
    assert np.max(np.abs(K - K.T)) <= 1e-13 * np.max(np.abs(K))


@pytest.mark.parametrize("mesh_fn,degree", MESHES)
def test_uniform_pressure_on_closed_surface_has_no_net_force(mesh_fn, degree):
    model = closed_model(mesh_fn(), degree)
    p, dim = 0.7, model.dim
    fol = FollowerPressure(model, "all", p)
    area = np.abs(np.asarray(fol.facet_forces(jnp.zeros(model.n)))).sum() / p  # >= the surface measure
    for u in (jnp.zeros(model.n), random_u(model)):
        net = np.asarray(fol.facet_forces(u)).reshape(-1, dim).sum(axis=0)
        assert np.max(np.abs(net)) <= 1e-14 * p * area


def test_pressure_pushes_along_the_inward_normal():
    model = StateModel(box(2, 1, 1, size=(1.0, 0.7, 0.5)), NeoHookean(1.0, 1.0), degree=2)
    fol = FollowerPressure(model, "front", 0.3)  # the face z = 0, area 0.7
    net = np.asarray(fol.facet_forces(jnp.zeros(model.n))).reshape(-1, 3).sum(axis=0)
    np.testing.assert_allclose(net, [0.0, 0.0, 0.3 * 0.7], atol=1e-15)


def test_interior_facets_are_rejected():
    mesh = box(2, 1, 1)
    cells = mesh.cells
    interior = np.sort(cells[:, :3], axis=1)  # some faces of cells, most of them interior
    with pytest.raises(InputError, match="interior|not faces"):
        FollowerPressure(StateModel(mesh.with_boundary("bad", interior), NeoHookean(1.0, 1.0)), "bad", 1.0)


@pytest.fixture(scope="module")
def inflated_plate():
    """2D neo-Hookean plate clamped on the left, pressure 0.05 on its deformed bottom (max |grad u| ~ 0.1)."""
    model = StateModel(rectangle(4, 2, size=(1.0, 0.5)), NeoHookean(1.0, 1.0), degree=2)
    return model, FollowerPressure(model, "bottom", 0.05)


def test_unconstrained_static_solve_is_an_equilibrium(inflated_plate):
    model, fol = inflated_plate
    sol = solve_static(model, follower=fol, constraint="none", options=StaticOptions(steps=2, line_search=False))
    r = np.asarray(model.internal_force(jnp.asarray(sol.u)) - fol.force(jnp.asarray(sol.u)))
    f = np.asarray(fol.force(jnp.asarray(sol.u)))
    assert sol.p == 0.0 and np.max(np.abs(sol.u)) > 1e-2
    assert np.max(np.abs(r)) <= 1e-10 * np.max(np.abs(f))


def test_constraint_at_the_unconstrained_volume_is_inactive(inflated_plate):
    """If the volume target is the volume of the unconstrained equilibrium, that equilibrium with p = 0
    solves the constrained problem too: both paths must agree (Newton tolerance 1e-11, condition O(10))."""
    model, fol = inflated_plate
    free = solve_static(model, follower=fol, constraint="none", options=StaticOptions(steps=2, line_search=False))
    tied = solve_static(model, follower=fol, volume=free.volume, options=StaticOptions(steps=2))
    assert np.max(np.abs(tied.u - free.u)) <= 1e-9 * np.max(np.abs(free.u))
    assert abs(tied.p) <= 1e-9 * fol.pressure


def test_newton_failure_names_the_load_step(inflated_plate):
    model, fol = inflated_plate
    # Start from the mirror image y -> -y (u = (0, -2y), det F = -1 everywhere): ln J is undefined there.
    mirrored = model.interpolate(lambda x: np.stack([0.0 * x[:, 0], -2.0 * x[:, 1]], axis=1))
    with pytest.raises(SolverError) as err:
        solve_static(model, follower=fol, constraint="none", u0=mirrored,
                     options=StaticOptions(steps=2, line_search=False))
    assert err.value.step == 0 and err.value.cause in ("newton", "nonfinite", "detF")
    assert "load step 1 (load factor" in str(err.value) and "2 nominal steps" in str(err.value)


def test_volume_target_needs_the_constraint(inflated_plate):
    model, fol = inflated_plate
    with pytest.raises(InputError):
        solve_static(model, follower=fol, constraint="none", volume=0.5)


def test_no_constraint_is_spelled_none_or_by_its_object(inflated_plate):
    """``constraint="none"`` and a `NoConstraint` are the same unconstrained solve (no multiplier); another
    name is refused."""
    model, fol = inflated_plate
    options = StaticOptions(steps=2, line_search=False)
    by_name = solve_static(model, follower=fol, constraint="none", options=options)
    by_object = solve_static(model, follower=fol, constraint=NoConstraint(model), options=options)
    np.testing.assert_array_equal(by_object.u, by_name.u)
    assert by_object.p == by_name.p == 0.0
    with pytest.raises(InputError, match="constraint"):
        solve_static(model, follower=fol, constraint="volume")

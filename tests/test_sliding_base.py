"""Component-wise Dirichlet conditions (`StateModel(dirichlet_components=...)`): a sliding base.

A unit box, incompressible through the volume constraint, neo-Hookean (mu = 1), stands on its
bottom face z = 0 and carries a dead load (nominal traction) -t e_z on its top z = 1. With a
sliding bottom (u_z = 0 only) the exact solution is homogeneous, ``F = diag(l, l, lz)`` with
``l^2 lz = 1``: the lateral faces are traction free, ``mu (l - 1/l) + p / l = 0`` (J = 1, cof F =
F^-T), so ``p = -mu (l^2 - 1)``, and the top gives ``mu (lz - 1/lz) + p / lz = -t``, i.e.
``mu (lz - lz^-2) = -t``. P1 elements represent this linear field exactly, so the discrete solution
equals it up to the Newton tolerance (1e-11 relative): we check it to 1e-9. A clamped bottom (the
default) cannot expand there, so its solution is not homogeneous.

The sliding plane leaves three rigid motions (translations in x, y and the rotation about z); the
model fixes three single dofs on the base (an isostatic support, no reactions under this balanced
load), which keeps the homogeneous solution, up to the translation that the pins fix.
"""

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

import hyperoc as ho
from hyperoc.dynamics.statics import StaticOptions, solve_static
from hyperoc.errors import InputError
from hyperoc.fem.mesh import box

MU, T = 1.0, 0.1


def compressed_box(**kw):
    model = ho.StateModel(box(2, dirichlet="front"), ho.NeoHookean(MU, 1.0), **kw)
    return model, solve_static(model, load=model.load_vector(traction=(0.0, 0.0, -T), neumann="back"),
                               options=StaticOptions(steps=2))


@pytest.mark.slow
def test_sliding_base_expands_laterally_as_the_exact_homogeneous_solution():
    model, sol = compressed_box(dirichlet=None, dirichlet_components={"front": (2,)})
    assert len(model.pinned_dofs) == 3 and model.rigid_modes.shape == (model.n, 0)
    lz = scipy.optimize.brentq(lambda l: MU * (l - l**-2) + T, 0.5, 1.0)
    l = lz**-0.5
    grad = np.asarray(model.deformation_gradient(jnp.asarray(sol.u)))  # (nc, 1, 3, 3)
    expected = np.diag([l, l, lz])
    print(f"\nlz = {lz:.6f}, l = {l:.6f}, p = {sol.p:.6f}; max |F - F_exact| = {np.max(np.abs(grad - expected)):.1e}")
    assert np.max(np.abs(grad - expected)) <= 1e-9
    assert sol.p == pytest.approx(-MU * (l**2 - 1), rel=1e-9)
    U = model.expand(sol.u)
    bottom = model.space.boundary_nodes("front")
    assert np.max(np.abs(U[bottom, 2])) == 0.0  # u_z = 0 exactly on the sliding base
    # the base itself spreads: its width grows by the factor l
    width = np.ptp(model.space.nodes[bottom, 0] + U[bottom, 0])
    assert width == pytest.approx(l, rel=1e-9)


@pytest.mark.slow
def test_clamped_base_does_not_expand():
    model, sol = compressed_box()
    assert len(model.pinned_dofs) == 0
    U = model.expand(sol.u)
    bottom = model.space.boundary_nodes("front")
    assert np.max(np.abs(U[bottom])) == 0.0
    top = model.space.boundary_nodes("back")
    assert np.ptp(model.space.nodes[top, 0] + U[top, 0]) > 1.001  # the top still bulges
    grad = np.asarray(model.deformation_gradient(jnp.asarray(sol.u)))
    assert np.ptp(grad[:, 0, 0, 0]) > 1e-3  # not homogeneous


def test_unpinned_sliding_base_keeps_three_rigid_motions_in_the_kernel():
    """pin_rigid=False: the translations in x, y and the rotation about z remain, and the elastic
    tangent at rest does not resist them (the dynamics resists them only through the mass)."""
    model = ho.StateModel(box(2, dirichlet="front"), ho.NeoHookean(MU, 1.0), dirichlet=None,
                          dirichlet_components={"front": (2,)}, pin_rigid=False)
    R = model.rigid_modes
    assert R.shape == (model.n, 3) and len(model.pinned_dofs) == 0
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12)
    K = model.pattern.matrix(np.asarray(model.tangent_blocks(jnp.zeros(model.n), 1.0, 0.0)))
    assert np.max(np.abs(K @ R)) <= 1e-13 * abs(K).max()
    assert np.max(np.abs(R[model.to_reduced[2::3][model.to_reduced[2::3] >= 0]])) <= 1e-14  # no u_z component


def test_ventricle_sliding_base_is_pinned_on_the_base():
    from hyperoc.fem.geometry import ventricle

    mesh = ventricle(4.0)
    model = ho.StateModel(mesh, ho.Guccione(), dirichlet=None, dirichlet_components={"base": (2,)},
                          frames=lambda x: np.broadcast_to(np.eye(3), x.shape[:-1] + (3, 3)))
    nodes = model.pinned_dofs // 3
    assert len(model.pinned_dofs) == 3 and model.rigid_modes.shape[1] == 0
    assert np.all(np.isin(nodes, mesh.boundary_vertices("base")))
    assert set(model.pinned_dofs % 3) <= {0, 1}  # in-plane components only


@pytest.mark.parametrize("components", [(3,), (), (0, 0), (0.5,)])
def test_bad_components_are_input_errors(components):
    with pytest.raises(InputError, match="dirichlet_components"):
        ho.StateModel(box(1), ho.NeoHookean(), dirichlet=None, dirichlet_components={"front": components})


def test_unknown_boundary_is_an_input_error():
    with pytest.raises(InputError, match=r"no boundary tag 'lid' \(tags found: back, bottom, front, gamma_d, "):
        ho.StateModel(box(1), ho.NeoHookean(), dirichlet_components={"lid": (2,)})


def test_sliding_a_clamped_boundary_is_an_input_error():
    """The ventricle's Gamma_D is its base: sliding it needs dirichlet=None, not a silent full clamp."""
    with pytest.raises(InputError, match="already clamped"):
        ho.StateModel(box(1, dirichlet="front"), ho.NeoHookean(), dirichlet_components={"front": (2,)})


@pytest.mark.slow
def test_prolonged_sliding_solution_is_moved_onto_the_refined_meshs_pins():
    """The pins are picked on each mesh anew (here the coarse P1 box pins u_y at (0, 0.5, 0), its
    refinement at (0, 0, 0) and (1, 0, 0)), and the homogeneous solution is exact on both meshes,
    so the coarse one carried over (`StateModel.prolong`, which re-pins by a rigid motion) *is* the
    fine one, to the Newton tolerance (1e-11 relative, checked to 1e-9), and Newton from it has
    nothing left to do. Merely dropping the coarse values at the new pins would leave the guess off
    by the translation 0.5 (l - 1) everywhere but at the pins."""
    from hyperoc.fem.mesh import refine

    kw = dict(dirichlet=None, dirichlet_components={"front": (2,)})
    coarse, coarse_sol = compressed_box(**kw)
    fine = ho.StateModel(refine(box(2, dirichlet="front")), ho.NeoHookean(MU, 1.0), **kw)
    pins = lambda model: {tuple(x) for x in model.space.nodes[model.pinned_dofs // 3]}
    assert pins(coarse) != pins(fine)
    load = fine.load_vector(traction=(0.0, 0.0, -T), neumann="back")
    cold = solve_static(fine, load=load, options=StaticOptions(steps=2))
    guess = fine.prolong(coarse, coarse_sol.u)
    scale = np.max(np.abs(cold.u))
    print(f"\nmax |prolonged - fine| = {np.max(np.abs(guess - cold.u)):.1e} (max |u| = {scale:.3f})")
    assert np.max(np.abs(guess - cold.u)) <= 1e-9 * scale
    assert np.max(np.abs(fine.expand(guess)[fine.pinned_dofs // 3, fine.pinned_dofs % 3])) == 0.0
    warm = solve_static(fine, load=load, guess=guess)
    assert warm.from_guess and warm.newton_iterations.tolist() == [1]
    assert np.max(np.abs(warm.u - cold.u)) <= 1e-9 * scale

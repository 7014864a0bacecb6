"""The cavity volume (`hyperoc.mechanics.cavity.CavityVolume`): exact for the discrete wall (P1 and P2,
curved cells), converging to the analytic truncated ellipsoid, invariant under the motions that keep the
lid, with its gradient and Hessian those of the volume."""

import numpy as np
import pytest

import hyperoc as ho
from hyperoc.errors import InputError
from hyperoc.fem.geometry import thick_shell, ventricle
from hyperoc.mechanics.cavity import CavityVolume

RS, RL, BASE = 7.0, 17.0, 5.0


def truncated_ellipsoid_volume():
    """pi rs^2 int_{-rl}^{base} (1 - z^2 / rl^2) dz: the Land ventricle's cavity, mm^3."""
    F = lambda z: z - z**3 / (3 * RL**2)
    return np.pi * RS**2 * (F(BASE) - F(-RL))


def model_of(mesh, degree):
    return ho.StateModel(mesh, ho.NeoHookean(1.0, 10.0), degree=degree, dirichlet=None, pin_rigid=False)


@pytest.fixture(scope="module", params=[1, 2])
def lv(request):
    return model_of(ventricle(4.0), request.param)


@pytest.mark.slow
def test_the_cavity_converges_to_the_truncated_ellipsoid_and_p2_curved_is_far_closer():
    exact = truncated_ellipsoid_volume()
    errors = {}
    for degree in (1, 2):
        models = [model_of(ventricle(h), degree) for h in (4.0, 2.0)]
        errors[degree] = [abs(float(CavityVolume(m).volume(np.zeros(m.n))) - exact) / exact for m in models]
    # P1: the chords of the walls, second order in h; P2 on curved cells: the surface to fourth order
    assert errors[1][1] < errors[1][0] / 3
    assert errors[2][0] < errors[1][0] / 10 and errors[2][1] < 1e-3


def test_a_closed_wall_encloses_a_volume_independent_of_the_apex():
    model = model_of(thick_shell(0.5, 1.0, 0.25), 2)
    v = [float(CavityVolume(model, "gamma_n", apex=c).volume(np.zeros(model.n))) for c in
         ([0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [5.0, 1.0, -2.0])]
    np.testing.assert_allclose(v, v[0], rtol=1e-13)
    assert abs(v[0] - 4 / 3 * np.pi * 0.5**3) < 2e-3 * v[0]


def test_the_cavity_is_the_truncated_ellipsoid_to_the_meshs_accuracy(lv):
    """At h = 4 mm: P1 within the volume its flat facets cut off (sagitta h^2 / (8 R) over a wall of
    area about 3 V / R, R >= RS), P2 on curved cells within 0.1 %."""
    exact, h = truncated_ellipsoid_volume(), 4.0
    error = abs(float(CavityVolume(lv).volume(np.zeros(lv.n))) - exact) / exact
    assert error < (h**2 / (8 * RS) * 3 / RS if lv.space.degree == 1 else 1e-3)


def test_motions_that_keep_the_lid_keep_the_volume(lv):
    """A translation in the base plane and a rotation about the long axis move the rim in the plane
    through the apex: the flat lid stays the lid, the volume is unchanged to round-off."""
    cav = CavityVolume(lv)
    V0 = float(cav.volume(np.zeros(lv.n)))
    X = lv.space.nodes
    a = 0.3
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    for motion in (X * 0 + [1.5, -0.7, 0.0], X @ R.T - X):
        assert abs(float(cav.volume(lv.restrict(motion))) - V0) <= 1e-12 * V0


def test_a_moving_apex_keeps_the_volume_under_every_rigid_motion(lv):
    """``apex="rim"`` follows the rim: a translation along the long axis and a tilt leave the volume
    unchanged. A fixed apex, left below the lifted rim, loses the cone between the lid and itself,
    (1/3) A h (A the lid's area, h the lift; A to the P1 rim polygon's accuracy)."""
    moving, fixed = CavityVolume(lv, apex="rim"), CavityVolume(lv)
    V0 = float(moving.volume(np.zeros(lv.n)))
    X = lv.space.nodes
    a = 0.2
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    lift = lv.restrict(X * 0 + [0.0, 0.0, 2.0])
    for motion in (lift, lv.restrict(X @ R.T - X + [0.3, 0.1, -1.0])):
        assert abs(float(moving.volume(motion)) - V0) <= 1e-12 * V0
    lid = np.pi * 49 * (1 - BASE**2 / RL**2)  # the base disc's area, mm^2
    assert abs(float(fixed.volume(lift)) - (V0 - lid * 2.0 / 3)) < 0.1 * lid * 2.0 / 3
    np.testing.assert_allclose(moving.volumes(np.stack([np.zeros(lv.n), lift])), V0, rtol=1e-12)
    with pytest.raises(InputError, match="apex='rim' is not a sum over the ranks' facets"):
        moving.restricted(lv, None, np.arange(3), np.arange(3))


APEXES = [None, "rim"]


@pytest.mark.parametrize("apex", APEXES)
def test_the_gradient_is_the_volumes_derivative(lv, apex):
    """Central differences of V along a random direction: V is a polynomial of degree d in u (the moving apex is
    linear in u, and V linear in it), so their error is h^2 times a third derivative, far below the tolerance at
    these h."""
    cav = CavityVolume(lv, apex=apex)
    u = np.asarray(np.random.default_rng(0).normal(size=lv.n))
    g = np.asarray(cav.gradient(np.zeros(lv.n)))
    for h in (1e-3, 5e-4):
        fd = (float(cav.volume(h * u)) - float(cav.volume(-h * u))) / (2 * h)
        assert abs(fd - g @ u) <= 1e-6 * abs(g @ u)


@pytest.mark.parametrize("apex", APEXES)
def test_the_hessian_is_the_gradients_derivative(lv, apex):
    """The facet blocks plus, with the moving apex, the dense part ``U W U^T`` (`CavityVolume.low_rank`): their
    product with w is the central difference of the gradient, and both parts are symmetric."""
    import jax.numpy as jnp

    cav = CavityVolume(lv, apex=apex)
    rng = np.random.default_rng(1)
    u, w = 0.05 * rng.normal(size=lv.n), rng.normal(size=lv.n)
    blocks = cav.add_hessian(jnp.zeros((lv.mesh.num_cells,) + (lv.cell_dofs.shape[1],) * 2), jnp.asarray(u))
    H = lv.pattern.matrix(np.asarray(blocks))
    Hw = H @ w
    low_rank = cav.low_rank(jnp.asarray(u))
    assert (low_rank is None) == (apex is None)
    if low_rank is not None:
        U, W = (np.asarray(a) for a in low_rank)
        assert U.shape == (lv.n, 6) and np.array_equal(W, W.T)
        Hw = Hw + U @ (W @ (U.T @ w))
    h = 1e-5
    fd = (np.asarray(cav.gradient(u + h * w)) - np.asarray(cav.gradient(u - h * w))) / (2 * h)
    np.testing.assert_allclose(Hw, fd, atol=1e-7 * np.max(np.abs(fd)))
    np.testing.assert_allclose((H - H.T).toarray(), 0, atol=1e-12 * abs(H).max())


def test_an_outer_wall_or_a_bad_apex_is_refused():
    model = model_of(ventricle(4.0), 1)
    with pytest.raises(InputError, match="no positive volume"):
        CavityVolume(model, "epicardium")  # the outer wall: the body is on the cavity's side
    with pytest.raises(InputError, match="apex"):
        CavityVolume(model, apex=[0.0, np.nan, 0.0])

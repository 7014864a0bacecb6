"""The model's state diagnostics (`hyperoc.mechanics.diagnostics` through `StateModel`)."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.fem.mesh import box
from hyperoc.mechanics import diagnostics
from hyperoc.mechanics.materials import Fung, HolzapfelOgden, NeoHookean, Ogden, SaintVenantKirchhoff, tangent_modulus
from hyperoc.mechanics.model import StateModel
from test_cardiac_materials import MATERIALS as CARDIAC_LAWS
from test_cardiac_materials import sample_points


def _turning_frames(x):
    """Fibres in the (x, y) plane turning with x + 2 y, sheets along z: a frame that varies inside every cell."""
    a = x[..., 0] + 2.0 * x[..., 1]
    f = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)
    s = np.broadcast_to([0.0, 0.0, 1.0], f.shape)
    return np.stack([f, s, np.cross(f, s)], axis=-2)


def test_the_acoustic_check_over_cell_chunks_is_the_check_over_all_points_at_once():
    """`StateModel.min_acoustic_eigenvalues` takes the acoustic tensors of `map_cells`' chunks of cells one
    chunk at a time (a whole P2 ventricle's at once take gigabytes); per state, its minimum is the one over
    all points at once: the same numbers, chunked (here 5 cells a chunk: several chunks and a remainder), to
    round-off."""
    model = StateModel(box(2, 2, 1), HolzapfelOgden(bulk_modulus=30.0), degree=2, frames=_turning_frames,
                       dirichlet=None)
    model.tangent_chunk_points = 5 * model._w.shape[1]
    assert len(model.mesh.cells) % 5 and len(model.mesh.cells) > 10
    rng = np.random.default_rng(0)
    states = 0.02 * rng.standard_normal((3, model.n))
    whole = [float(diagnostics.min_acoustic_eigenvalue(model.material, model.deformation_gradient(u),
                                                       model.material_frames)) for u in states]
    # the same closed-form eigenvalues, fused differently: round-off amplified near double eigenvalues
    # (`test_closed_form_smallest_eigenvalue_is_lapacks`), on the scale of the tensors, the bulk modulus
    np.testing.assert_allclose(model.min_acoustic_eigenvalues(states), whole, rtol=0, atol=1e-7 * 30.0)
    assert min(whole) < max(whole)  # the states differ: the check is not of one repeated value


#: every law of the library, the cardiac ones with their fibre frames (`sample_points`)
LAWS = {"svk": SaintVenantKirchhoff(1.0, 2.0), "neo-hookean": NeoHookean(1.0, 2.0), "fung": Fung(beta=1.0, gamma=2.0),
        "ogden": Ogden(coefficients=(0.5, -0.2), exponents=(2.0, -3.0)), **CARDIAC_LAWS}


@partial(jax.jit, static_argnums=0)
def _both_routes(law, F, frames, dirs):
    """The acoustic tensors at the points F (np, d, d) with frames (np, kf, d) or None, by
    `diagnostics.acoustic_tensors` and by contracting the law's Hessian in F (`tangent_modulus`)."""
    closed = jax.vmap(lambda G, a: diagnostics.acoustic_tensors(law, G, a, dirs))(F, frames)
    A = jax.vmap(lambda G, a: tangent_modulus(law, G, a))(F, frames)
    return closed, jnp.einsum("piJkL,nJ,nL->pnik", A, dirs, dirs)


@pytest.mark.parametrize("name, d", [*((name, 3) for name in LAWS), ("svk", 1), ("svk", 2), ("holzapfel-ogden", 2)])
def test_acoustic_tensors_are_the_contracted_hessian_of_the_energy(name, d):
    """`diagnostics.acoustic_tensors` (from the law's derivatives in the independent strains) equals
    ``n_J n_L d2W/dF_iJ dF_kL`` of the law's Hessian in F (`tangent_modulus`, JAX), over the sampled directions,
    at generic and fibre-stretched F (`sample_points`): the same derivative by another route, so equal to
    round-off (1e-12 of the largest entry; the laws' exponentials and the bulk modulus make the entries span
    six decades). Every law in 3D; the strain pairs of 1D and 2D (`kernels.VOIGT`) on SVK and Holzapfel-Ogden."""
    law = LAWS[name]
    points = sample_points(d) if d > 1 else {"stretched": (np.array([[1.1]]), np.eye(1))}
    F = jnp.asarray(np.stack([F for F, _ in points.values()]))
    frames = jnp.asarray(np.stack([a for _, a in points.values()])) if name in CARDIAC_LAWS else None
    closed, expected = _both_routes(law, F, frames, jnp.asarray(diagnostics.directions(d)))
    scale = float(jnp.max(jnp.abs(expected)))
    np.testing.assert_allclose(closed, expected, rtol=0, atol=1e-12 * scale)


def _symmetric(rng, eigenvalues):
    """Symmetric matrices R diag(eigenvalues) R^T with random rotations R, (len(eigenvalues), d, d)."""
    q, _ = np.linalg.qr(rng.standard_normal((len(eigenvalues), eigenvalues.shape[1], eigenvalues.shape[1])))
    return np.einsum("nij,nj,nkj->nik", q, eigenvalues, q)


def test_closed_form_smallest_eigenvalue_is_lapacks():
    """`diagnostics.min_symmetric_eigenvalue` against LAPACK's ``eigvalsh`` on random symmetric 1x1, 2x2 and 3x3
    matrices of both signs, with distinct, double and triple eigenvalues (the triple ones multiples of I, where
    the trigonometric formula divides by nothing). Tolerance: near a double eigenvalue the arc cosine loses half
    the digits, an error of a few sqrt(eps) times the eigenvalues' spread; 1e-7 of the largest eigenvalue."""
    rng = np.random.default_rng(1)
    for d in (1, 2, 3):
        distinct = rng.uniform(-2.0, 5.0, (200, d))
        double = np.repeat(rng.uniform(-2.0, 5.0, (200, 1)), d, axis=1)
        double[:, -1] += rng.choice([0.0, 1e-9, 1.0], 200)
        Q = _symmetric(rng, np.concatenate([distinct, double]))
        exact = np.linalg.eigvalsh(Q)[:, 0]
        closed = np.asarray(diagnostics.min_symmetric_eigenvalue(Q))
        np.testing.assert_allclose(closed, exact, rtol=0, atol=1e-7 * np.max(np.abs(exact)))
    identity = 3.0 * np.eye(3)[None]
    np.testing.assert_array_equal(np.asarray(diagnostics.min_symmetric_eigenvalue(identity)), [3.0])

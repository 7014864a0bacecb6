"""`StateModel.tangent_blocks` equals ``jax.hessian`` of the element energy, to round-off.

The reference is the Hessian, in the cell's dofs, of ``sum_q w_q (a W(F_q) + b det F_q)`` by
JAX on W(E(F)) itself; the model instead forms the Voigt Hessian of W(E), pushes it through the
strain-displacement matrix B and adds the stress and det F terms in closed form. Both are exact,
so they differ only by rounding.

With ``volumetric="cell-mean"`` the bulk term U(J) is taken on the cell mean theta of J, and the
model adds its rank-one part ``a U''(theta) / |e| g g^T`` and ``a U'(theta)`` times the det F
Hessian; the reference differentiates the cell energy ``a |e| U(theta)`` directly.

Tolerance: an entry is a sum of at most nq d^4 = 27 * 81 ~ 2200 products (P2 tetrahedra, 27
points) taken in different orders by the two routes. Float64 rounds each product and partial sum
by <= eps = 2.2e-16 relative, so the difference is bounded by ~ 2200 eps ~ 5e-13 times the sum of
the absolute terms, and is typically ~ sqrt(2200) eps ~ 1e-14 of it; measured <= 6e-15 of
max |K| on these cases (Guccione's volumetric penalty, bulk modulus 500 C, dominates max |K|).
1e-13 max |K| therefore only admits rounding: a wrong or missing term (a sign in the det F
Hessian, a factor 1/2 on the off-diagonal strains) shows up at O(1e-2) or larger.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hyperoc as ho
from hyperoc.fem.mesh import box, interval, rectangle
from hyperoc.mechanics.materials import det

TOL = 1e-13


def reference_blocks(model, u, a, b):
    """``jax.hessian`` of each element's ``sum_q w_q (a W(F) + b det F)`` in its dofs, (nc, k, k);
    with ``volumetric="cell-mean"`` W is the law without its bulk term U, and ``a |e| U(theta)``,
    ``theta = sum_q w_q det F / |e|``, is added."""
    d = model.dim
    ue = jnp.concatenate([u, jnp.zeros(1)])[model._gather].reshape(model._gather.shape[0], -1, d)
    law, bulk = model.material.volumetric_split() if model.volumetric == "cell-mean" else (model.material, None)

    def energy(ue, dN, w, frames):
        F = jnp.eye(d) + jnp.einsum("qaj,ai->qij", dN, ue)
        psi = lambda G, f: a * law.energy_of_F(G, f) + b * det(G)
        W = jax.vmap(lambda G: psi(G, None))(F) if frames is None else jax.vmap(psi)(F, frames)
        if bulk is None:
            return jnp.sum(w * W)
        return jnp.sum(w * W) + a * jnp.sum(w) * bulk(jnp.sum(w * det(F)) / jnp.sum(w))

    k = ue.shape[1] * d
    hess = lambda ue, dN, w, fr: jax.hessian(energy)(ue, dN, w, fr).reshape(k, k)
    return jax.vmap(hess)(ue, model._dN, model._w, model.material_frames)


def _frames(*rows):
    """Constant orthonormal frame ``rows`` at every point x (..., d) -> (..., len(rows), d)."""
    frame = np.array(rows, dtype=np.float64)
    return lambda x: np.broadcast_to(frame, x.shape[:-1] + frame.shape)


FRAME2 = _frames([0.6, 0.8], [-0.8, 0.6])
FRAME3 = _frames([0.6, 0.8, 0.0], [-0.8, 0.6, 0.0], [0.0, 0.0, 1.0])

CASES = [  # (mesh, material, degree, frames, a, b): every law, every dimension, P1 and P2
    (lambda: interval(5), ho.NeoHookean(1.0, 2.0), 2, None, 1.0, 0.7),
    (lambda: rectangle(3), ho.SaintVenantKirchhoff(1.0, 2.0), 1, None, 0.5, -2.0),
    (lambda: rectangle(3), ho.Ogden((0.3, 0.2), (2.0, 3.5)), 2, None, 1.0, 0.7),
    (lambda: rectangle(3), ho.HolzapfelOgden(), 2, FRAME2, 1.0, -2.0),
    (lambda: box(2), ho.NeoHookean(1.0, 5.0), 1, None, 1.0, 0.7),
    (lambda: box(1), ho.Guccione(), 2, FRAME3, 0.5, -2.0),
    (lambda: box(2), ho.HolzapfelOgden(), 1, FRAME3, 1.0, 0.7),
    (lambda: box(1), ho.Fung(), 2, None, 1.0, 0.7),
]


CELL_MEAN_CASES = [  # the laws with a separate bulk term, cell-mean J
    (lambda: interval(5), ho.NeoHookean(1.0, 30.0), 2, None, 1.0, 0.7),
    (lambda: rectangle(3), ho.HolzapfelOgden(), 2, FRAME2, 0.5, -2.0),
    (lambda: box(2), ho.NeoHookean(1.0, 50.0), 1, None, 1.0, 0.7),
    (lambda: box(1), ho.Guccione(), 2, FRAME3, 0.5, -2.0),
    (lambda: box(1), ho.Guccione(isochoric=True), 2, FRAME3, 1.0, 0.7),
]


def _case_id(case):
    iso = "-isochoric" if getattr(case[1], "isochoric", False) else ""
    return f"{type(case[1]).__name__}{iso}-{case[0]().dim}d-P{case[2]}"


SLOW_CASES = {"Guccione-3d-P2", "HolzapfelOgden-3d-P1", "NeoHookean-3d-P1-cell-mean", "Guccione-3d-P2-cell-mean",
              "Guccione-isochoric-3d-P2-cell-mean"}  # the largest element matrices: the slow tier


def _params():
    cases = [(c + ("pointwise",), _case_id(c)) for c in CASES]
    cases += [(c + ("cell-mean",), _case_id(c) + "-cell-mean") for c in CELL_MEAN_CASES]
    return [pytest.param(*c, id=i, marks=[pytest.mark.slow] if i in SLOW_CASES else []) for c, i in cases]


@pytest.mark.parametrize("mesh_fn,material,degree,frames,a,b,volumetric", _params())
def test_tangent_equals_hessian_of_the_element_energy(mesh_fn, material, degree, frames, a, b, volumetric):
    model = ho.StateModel(mesh_fn(), material, degree=degree, frames=frames, volumetric=volumetric)
    # A smooth finite strain (|grad u| ~ 0.3), different in every component.
    u = jnp.asarray(model.interpolate(lambda x: 0.1 * np.sin(2.0 * x + 0.3) * (1 + np.arange(x.shape[1]))))
    K = np.asarray(jax.jit(model.tangent_blocks)(u, a, b))
    ref = np.asarray(jax.jit(lambda u: reference_blocks(model, u, a, b))(u))
    assert K.shape == ref.shape == (model.mesh.num_cells,) + (model.space.nloc * model.dim,) * 2
    err = np.max(np.abs(K - ref)) / np.max(np.abs(ref))
    print(f"\n{type(material).__name__} {model.dim}D P{degree} a = {a}, b = {b}: {err:.1e}")
    assert err <= TOL


@pytest.mark.slow
def test_chunked_tangent_equals_one_batch():
    """Cells in chunks (here 7 points at a time, with a remainder) give the same blocks as all at once."""
    model = ho.StateModel(box(2), ho.Guccione(), degree=1, frames=FRAME3)
    u = jnp.asarray(model.interpolate(lambda x: 0.05 * np.cos(3.0 * x)))
    whole = np.asarray(model.tangent_blocks(u, 1.0, 0.3))
    model.tangent_chunk_points = 7 * model._w.shape[1]
    assert model.mesh.num_cells % 7 != 0
    chunked = np.asarray(model.tangent_blocks(u, 1.0, 0.3))
    assert np.max(np.abs(chunked - whole)) <= TOL * np.max(np.abs(whole))


@pytest.mark.slow
def test_det_hessian_alone():
    """a = 0: only the closed-form Hessian of det F remains (it is not a material property)."""
    model = ho.StateModel(box(1), ho.SaintVenantKirchhoff(1.0, 1.0), degree=1)
    u = jnp.asarray(model.interpolate(lambda x: 0.2 * x[:, ::-1] ** 2))
    K, ref = model.tangent_blocks(u, 0.0, 1.0), reference_blocks(model, u, 0.0, 1.0)
    assert float(jnp.max(jnp.abs(ref))) > 0.01
    assert float(jnp.max(jnp.abs(K - ref))) <= TOL * float(jnp.max(jnp.abs(ref)))

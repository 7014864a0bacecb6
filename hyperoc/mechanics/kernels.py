"""JAX element kernels of the state model: one cell's energy and tangent, and their maps over cells.

A cell's data are its unknowns ue (nloc, d) (node-major; 0 on constrained dofs), the physical
shape gradients dN (nq, nloc, d), the quadrature weights times |det J| w (nq,) and the material
frames (nq, kf, d) or None. Everything nonlinear derives from the cell energy

    Pi_e(ue) = sum_q w_q W(F_q),        F_q = I + sum_a ue_a (x) dN_qa,

(with ``volumetric="cell-mean"`` the law's bulk term U(J) enters on the cell mean of J instead,
``Pi_e = sum_q w_q W_rest(F_q) + |e| U(theta_e)``, ``theta_e = sum_q w_q det F_q / |e|``): the force
is its gradient by JAX, the tangent its Hessian, formed in Voigt notation (`element_tangent`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from ..errors import InputError
from .materials import Material, det

__all__ = ["VOIGT", "VOLUMETRIC", "at_points", "cell_bulk_tangent", "deformation_gradient", "element_F",
           "element_energy", "element_tangent", "gather", "map_cells", "pointwise", "scatter", "split_law",
           "voigt_derivatives"]

#: `StateModel` ``volumetric`` choices.
VOLUMETRIC = ("pointwise", "cell-mean")


def _voigt(d: int):
    """Independent strain pairs ``(I, J)``, ``I <= J`` (diagonal first), the (d, d) map back to
    the pair index, and 1 (diagonal) or 1/2 (off-diagonal) per pair."""
    pairs = [(i, i) for i in range(d)] + [(i, j) for i in range(d) for j in range(d) if i < j][::-1]
    sym = np.zeros((d, d), dtype=np.int64)
    for k, (i, j) in enumerate(pairs):
        sym[i, j] = sym[j, i] = k
    I, J = (np.array(c) for c in zip(*pairs))
    return I, J, sym, np.where(I == J, 1.0, 0.5)


#: ``{d: (I, J, sym, half)}``: the nv = d (d + 1) / 2 independent strains ``e_alpha = E_{I_alpha J_alpha}``,
#: the (d, d) index map ``E = e[sym]``, and 1 (diagonal) or 1/2 (off-diagonal) per alpha.
VOIGT = {d: _voigt(d) for d in (1, 2, 3)}
_EPS2 = np.array([[0.0, 1.0], [-1.0, 0.0]])
_EPS3 = np.zeros((3, 3, 3))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _EPS3[_i, _j, _k], _EPS3[_i, _k, _j] = 1.0, -1.0
# T_r of `element_tangent`: I for the stress term, then the det F Hessian's eps_ik(m).
_CLOSED_FORM_T = {1: np.eye(1)[None], 2: np.stack([np.eye(2), _EPS2]),
                  3: np.concatenate([np.eye(3)[None], np.moveaxis(_EPS3, 2, 0)])}


def split_law(material: Material, volumetric: str):
    """``(law at the points, bulk term U(J) on the cell mean of J or None)`` for `StateModel`
    ``volumetric``."""
    if volumetric not in VOLUMETRIC:
        raise InputError(f"volumetric must be one of {list(VOLUMETRIC)}, got {volumetric!r}")
    if volumetric == "pointwise":
        return material, None
    rest, bulk = material.volumetric_split()
    if bulk is None:
        raise InputError(f"volumetric='cell-mean' needs a law with a separate bulk term (Guccione, "
                         f"Holzapfel-Ogden, neo-Hookean); {type(material).__name__} has none")
    return rest, bulk


def gather(x, index):
    """``x`` (n,) at ``index`` (any shape), where the index n (the dump slot of constrained dofs) reads 0."""
    return jnp.concatenate([x, jnp.zeros(1, x.dtype)])[index]


def scatter(values, index, n: int):
    """The sum of ``values`` into the entries ``index`` (same shape) of a vector (n,); the values at
    index n (constrained dofs) are dropped. The transpose of `gather`."""
    return jnp.zeros(n + 1, values.dtype).at[index].add(values)[:n]


def element_F(ue, dN):
    """F = I + grad u at the points of one cell, (nq, d, d); ue (nloc, d), dN (nq, nloc, d)."""
    return jnp.eye(ue.shape[1]) + jnp.einsum("qaj,ai->qij", dN, ue)


def deformation_gradient(ue, dN):
    """F = I + grad u at every quadrature point, (nc, nq, d, d); ue (nc, nloc, d), dN (nc, nq, nloc, d)."""
    return jnp.eye(ue.shape[2]) + jnp.einsum("cqaj,cai->cqij", dN, ue)


def at_points(fn, F, frames):
    """``fn(F_q, frame_q)`` at the points of one cell, F (nq, d, d), frames (nq, kf, d) or None."""
    return jax.vmap(lambda G: fn(G, None))(F) if frames is None else jax.vmap(fn)(F, frames)


def pointwise(fn, F, frames):
    """``fn(F, frame)`` at every quadrature point, F (nc, nq, d, d), frames (nc, nq, kf, d) or None."""
    return jax.vmap(lambda G, frames: at_points(fn, G, frames))(F, frames)


def map_cells(kernel, xs, batch: int):
    """``kernel`` over the cells, the leading axis of every array in the tuple ``xs``, ``batch``
    cells at a time: one vmap when they all fit, else a chunked map (bounds the kernel's memory)."""
    return jax.vmap(kernel)(xs) if xs[0].shape[0] <= batch else jax.lax.map(kernel, xs, batch_size=batch)


def element_energy(law: Material, bulk, ue, dN, w, frames):
    """``Pi_e = sum_q w_q W(F_q)`` of one cell, plus ``|e| U(theta_e)`` for a cell-mean ``bulk`` U
    (scalar, energy = stress times the mesh's length unit cubed); ue (nloc, d)."""
    F = element_F(ue, dN)
    energy = jnp.sum(w * at_points(law.energy_of_F, F, frames))
    if bulk is None:
        return energy
    vol = jnp.sum(w)
    return energy + vol * bulk(jnp.sum(w * det(F)) / vol)


def voigt_derivatives(law: Material, dim: int, e, frame):
    """``(d2W/de2 (nv, nv), dW/de (nv,))`` at one point, W as a function of the nv = d(d+1)/2
    independent strains ``e_alpha = E_{I_alpha J_alpha}`` (`VOIGT`: E = e[sym])."""
    sym = VOIGT[dim][2]
    g = jax.grad(lambda e: law.energy(e[sym], frame))
    return jax.jacfwd(lambda e: (g(e), g(e)), has_aux=True)(e)


def element_tangent(law: Material, bulk, ue, dN, w, frames, a, b):
    """Hessian of ``sum_q w_q (a W(F_q) + b det F_q)`` in the cell's dofs ue (nloc, d): (k, k),
    k = nloc d, rows and columns node-major (with a cell-mean ``bulk`` U, W is the rest of the law
    and ``a |e| U(theta)`` is added, below).

    With ``dF = e_i (x) grad N_a`` and ``E = (F^T F - I) / 2`` (W depends on F through E only):

    - material part ``sum_q w_q a B_q^T H_q B_q``, H = d2W/de2 in the nv independent strains,
      ``B_q[alpha, (a, i)] = (F_iI dN_aJ + F_iJ dN_aI) / 2`` (``(I, J)`` = pair alpha): the
      change of e under a unit change of dof (a, i);
    - parts known in closed form, each ``(sum_q w_q dN_a^T M_r dN_b) T_r[i, k]``: the geometric
      (stress) term ``M_0 = a S``, ``S = dW/dE``, ``T_0 = I``, and the Hessian of det F,
      ``d2 det F / dF_iJ dF_kL = eps_ik eps_JL`` (2D: ``M_1 = b eps``, ``T_1 = eps``) and
      ``eps_ikm eps_JLN F_mN`` (3D: ``M_m = b eps_JLN F_mN``, ``T_m = eps_ikm``, m = 0, 1, 2);
    - cell-mean bulk term: ``a U''(theta) / |e| g g^T`` with ``g = sum_q w_q (cof F_q) dN_q`` the
      gradient of ``|e| theta``, plus ``a U'(theta)`` added to b in the det F Hessian.

    Shapes: dN (nq, nloc, d) physical shape gradients, w (nq,) weights times |det J|, frames
    (nq, kf, d) or None; a a scalar, b a scalar or one value per point (nq,) (the Taylor-Hood
    pressure, `hyperoc.mechanics.mixed`).
    """
    d, n = ue.shape[1], ue.shape[0]
    I, J, sym, half = VOIGT[d]
    F = element_F(ue, dN)  # (nq, d, d)
    if bulk is not None:
        b, bulk_block = cell_bulk_tangent(bulk, F, dN, w, a, b)
    e = (0.5 * (jnp.einsum("qkI,qkJ->qIJ", F, F) - jnp.eye(d)))[:, I, J]  # (nq, nv)
    if frames is None:
        H, s = jax.vmap(lambda x: voigt_derivatives(law, d, x, None))(e)
    else:
        H, s = jax.vmap(lambda x, frame: voigt_derivatives(law, d, x, frame))(e, frames)
    # B[q, alpha, a, i]; the contraction over (q, alpha) is one matrix product per cell.
    FI, FJ = F[:, :, I].transpose(0, 2, 1)[:, :, None, :], F[:, :, J].transpose(0, 2, 1)[:, :, None, :]
    dNI, dNJ = dN[:, :, I].transpose(0, 2, 1)[..., None], dN[:, :, J].transpose(0, 2, 1)[..., None]
    B = (0.5 * (FI * dNJ + FJ * dNI)).reshape(len(w), len(I), n * d)
    K = jnp.einsum("qak,qal->kl", B, jnp.einsum("qab,qbl->qal", (a * w)[:, None, None] * H, B))
    S = (s * half)[:, sym]  # (nq, d, d): the off-diagonal e_alpha stands for E_IJ and E_JI
    M = [a * S[:, None]]
    b = jnp.broadcast_to(b, w.shape)
    if d == 2:
        M.append(b[:, None, None, None] * _EPS2)
    elif d == 3:
        M.append(jnp.einsum("q,JLN,qmN->qmJL", b, _EPS3, F))
    M = jnp.concatenate(M, axis=1)  # (nq, r, d, d)
    G = jnp.einsum("qaJ,qrJb->rab", dN, jnp.einsum("q,qrJL,qbL->qrJb", w, M, dN))
    K = K.reshape(n, d, n, d) + jnp.einsum("rab,rik->aibk", G, _CLOSED_FORM_T[d])
    K = K.reshape(n * d, n * d)
    return K if bulk is None else K + bulk_block


def cell_bulk_tangent(bulk, F, dN, w, a, b):
    """``(b + a U'(theta), a U''(theta) / |e| g g^T (k, k))`` for one cell: the cell-mean bulk
    term's share of the det F Hessian's coefficient and its rank-one part; F (nq, d, d)."""
    vol = jnp.sum(w)
    theta = jnp.sum(w * det(F)) / vol
    dU = jax.grad(bulk)
    g = jnp.einsum("q,qiJ,qaJ->ai", w, jax.vmap(jax.grad(det))(F), dN).reshape(-1)  # d(|e| theta)/d ue
    return b + a * dU(theta), (a * jax.grad(dU)(theta) / vol) * jnp.outer(g, g)

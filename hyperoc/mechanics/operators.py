"""The linear parts of the state model: element blocks of the mass and damping operators, load
vectors, nodal control values, and the host-side solves that traced code calls.

Element blocks are (nc, k, k), k = nloc * d, rows and columns node-major (``a * d + i``), assembled
on the reduced dofs by `hyperoc.fem.assembly.SparsePattern`; load vectors are on the free dofs.
"""

from __future__ import annotations

import jax
import numpy as np
import scipy.sparse as sp
from jax.experimental import sparse as jsparse

from .._jax import on_device
from ..errors import InputError
from ..fem.spaces import VectorSpace

__all__ = ["apply_inverse", "control_values", "laplace_blocks", "load_vector", "mass_blocks", "to_bcoo",
           "vector_blocks"]


def vector_blocks(scalar_blocks: np.ndarray, d: int) -> np.ndarray:
    """Blocks ``A_ab delta_ij`` (nc, nloc d, nloc d) of a scalar form's blocks A (nc, nloc, nloc)
    acting on each of the d components alike."""
    k = scalar_blocks.shape[1]
    return np.einsum("cab,ij->caibj", scalar_blocks, np.eye(d)).reshape(len(scalar_blocks), k * d, k * d)


def mass_blocks(space: VectorSpace, density: float) -> np.ndarray:
    """Element mass matrices (nc, k, k): ``density int N_a N_b delta_ij dx`` (density times the
    mesh's length unit to the power d)."""
    q = space.quadrature(2 * space.degree)
    return vector_blocks(density * np.einsum("cq,qa,qb->cab", q.wdx, q.N, q.N), space.components)


def laplace_blocks(space: VectorSpace) -> np.ndarray:
    """Element vector-Laplacian matrices (nc, k, k): ``int grad N_a . grad N_b delta_ij dx``, the
    damping operator up to its coefficient (the damping kappa in ``kappa (grad u_t, grad phi)``)."""
    return vector_blocks(space.laplace_blocks(), space.components)


def to_bcoo(mat) -> jsparse.BCOO:
    """A SciPy sparse matrix as a JAX sparse matrix, for traced matvecs, with its duplicate entries
    summed (matrices assembled from element blocks hold one entry per element sharing a pair of
    dofs; a matvec's cost goes with the stored entries)."""
    mat = sp.csr_matrix(mat, copy=True)
    mat.sum_duplicates()
    return jsparse.BCOO.from_scipy_sparse(mat.tocoo())


def combined_matvec(A, B):
    """``(y, a, b) -> a A y + b B y`` for two SciPy sparse matrices, traced, as one matvec over the
    union of their patterns (for the scalars a, b that change from call to call)."""
    U = (abs(sp.csr_matrix(A)) + abs(sp.csr_matrix(B))).tocsr()
    U.sort_indices()
    rows = np.repeat(np.arange(U.shape[0]), np.diff(U.indptr))
    A_data, B_data = (on_device(np.asarray(sp.csr_matrix(X)[rows, U.indices]).ravel()) for X in (A, B))
    index = on_device(np.stack([rows, U.indices], axis=1), dtype=None)
    shape = U.shape
    return lambda y, a, b: jsparse.BCOO((a * A_data + b * B_data, index), shape=shape) @ y


def apply_inverse(solve, v):
    """``A^-1 v`` (n,) inside traced code, for a host solve ``solve(x: ndarray (n,)) = A^-1 x`` of a
    constant matrix A; A^-1 is linear, so its JVP is itself."""

    @jax.custom_jvp
    def inverse(v):
        return jax.pure_callback(lambda x: solve(np.asarray(x)), jax.ShapeDtypeStruct(v.shape, v.dtype), v)

    @inverse.defjvp
    def _(primals, tangents):
        (v,), (dv,) = primals, tangents
        return inverse(v), inverse(dv)

    return inverse(v)


def load_vector(space: VectorSpace, free: np.ndarray, *, body_force=None, traction=None, t: float = 0.0,
                neumann: str | None = None) -> np.ndarray:
    """External load ``int_Omega f . phi dx + int_{Gamma_N} g . phi ds`` on the free dofs ``free``,
    (n,); f a force per volume, g per area of the reference configuration.

    ``body_force`` and ``traction`` are constant vectors (d,) or callables ``(x, t) -> (..., d)``
    with x of shape (..., d); ``neumann`` names the boundary Gamma_N (needed with ``traction``).
    """
    full = np.zeros(space.num_dofs)
    if body_force is not None:
        q = space.quadrature(2 * space.degree + 2)
        f = _field_values(body_force, q.x, t, space.components)
        contrib = np.einsum("cq,qa,cqi->cai", q.wdx, q.N, f)
        np.add.at(full, space.cell_dofs, contrib.reshape(len(contrib), -1))
    if traction is not None:
        facets = space.mesh.boundary(neumann)
        x, w, N, dS = space.facet_quadrature(facets, 2 * space.degree + 2)
        g = _field_values(traction, x, t, space.components)
        contrib = np.einsum("fq,q,qa,fqi->fai", dS, w, N, g)
        fdofs = space.node_dofs(space.facet_nodes(facets).ravel()).reshape(len(facets), -1)
        np.add.at(full, fdofs, contrib.reshape(len(facets), -1))
    return full[free]


def _field_values(fn, x, t, d: int) -> np.ndarray:
    """A constant vector (d,) or a callable ``(x, t)`` at the points x (..., d), as (..., d)."""
    if callable(fn):
        return np.broadcast_to(np.asarray(fn(x, t), dtype=np.float64), x.shape[:-1] + (d,))
    return np.broadcast_to(np.asarray(fn, dtype=np.float64).reshape(d), x.shape[:-1] + (d,))


def control_values(control, space: VectorSpace, fn, t) -> np.ndarray:
    """Nodal values (len(t), n_ctrl) of the built control operator ``control`` (or None: `InputError`)
    for a callable ``xi(x, t)``, x of shape (n_nodes, dim), returning (n_nodes,) or
    (n_nodes, components): a prescribed control as a Python function."""
    if control is None:
        raise InputError("this model has no control operator")
    x = control.coordinates(space)
    rows = [np.broadcast_to(np.asarray(fn(x, float(tk)), dtype=np.float64).reshape(x.shape[0], -1),
                            (x.shape[0], control.components)).ravel() for tk in np.atleast_1d(t)]
    return np.stack(rows)

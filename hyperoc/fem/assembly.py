"""Sparse assembly into a fixed CSR pattern, filled in place.

The pattern is built once from the element dof lists, in a reduced numbering where constrained
(Dirichlet) dofs are dropped. Each later assembly is one ``np.bincount`` of the element matrices
into the CSR data array: no COO conversion, no sorting, no new index arrays.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["SparsePattern", "dump_index", "reduced_numbering", "solve_dirichlet"]


def reduced_numbering(num_dofs: int, constrained: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Free dofs (nfree,) and the map full -> reduced index (num_dofs,), -1 where constrained."""
    keep = np.ones(num_dofs, dtype=bool)
    keep[np.asarray(constrained, dtype=np.int64)] = False
    free = np.flatnonzero(keep)
    to_reduced = np.full(num_dofs, -1, dtype=np.int64)
    to_reduced[free] = np.arange(free.size)
    return free, to_reduced


def dump_index(reduced: np.ndarray, n: int) -> np.ndarray:
    """Reduced dof indices (any shape, -1 = constrained, as `reduced_numbering` gives them) with the
    constrained ones sent to the dump slot n: the index of `hyperoc.mechanics.kernels.gather` (which
    reads 0 there) and of `hyperoc.mechanics.kernels.scatter` (which drops what lands there)."""
    return np.where(reduced < 0, n, reduced)


def relabel_index(index: np.ndarray, n: int, dofs: np.ndarray) -> np.ndarray:
    """A gather ``index`` over n unknowns (dump slot n, `dump_index`) relabelled onto the subset ``dofs``
    (m,) of them, increasing: entry i becomes the position of ``index`` in ``dofs``, and the dump slot,
    or an unknown not in ``dofs``, becomes m."""
    to_subset = np.full(n + 1, dofs.size, dtype=np.int64)
    to_subset[dofs] = np.arange(dofs.size)
    return to_subset[np.asarray(index)]


class SparsePattern:
    """CSR structure of a matrix assembled from element blocks.

    Parameters
    ----------
    element_dofs : (nc, k) int
        Reduced dof indices of each element, -1 for dofs that are dropped (row and column).
    size : int
        Number of reduced dofs.
    """

    #: entries whose CSR position is looked up at once (bounds the int64 temporaries to 128 MB)
    lookup_chunk = 1 << 24

    def __init__(self, element_dofs: np.ndarray, size: int):
        ed = np.asarray(element_dofs, dtype=np.int64)
        nc, k = ed.shape
        # Entry (c, a, b) of the flattened element blocks has the key row * size + col; one int64
        # array of them, no separate row and column arrays and no argsort-based inverse: at 145k
        # Taylor-Hood cells (167M entries, 1.3 GB per int64 array) the older build peaked at 14.5 GB.
        key = (ed[:, :, None] * size + ed[:, None, :]).reshape(-1)
        valid = ((ed[:, :, None] >= 0) & (ed[:, None, :] >= 0)).reshape(-1)
        uniq = np.sort(key[valid])  # sort and mask, not np.unique: NumPy >= 2.3 hashes there, minutes at 1e8 keys
        uniq = uniq[np.concatenate(([True], uniq[1:] != uniq[:-1]))] if uniq.size else uniq
        self.size, self.nnz = size, uniq.size
        self.indices = (uniq % size).astype(np.int32)
        self.indptr = np.searchsorted(uniq // size, np.arange(size + 1)).astype(np.int32)
        # Entry e goes to data[position[e]]; dropped entries to a trailing dump slot that is cut off
        # after the bincount. int32 while the slots fit (half the memory of the largest kept array).
        self.position = np.empty(key.size, dtype=np.int32 if self.nnz < 2**31 - 1 else np.int64)
        for start in range(0, key.size, self.lookup_chunk):
            part = slice(start, start + self.lookup_chunk)
            self.position[part] = np.where(valid[part], np.searchsorted(uniq, key[part]), self.nnz)
        self.element_shape = (nc, k, k)

    def data(self, element_matrices: np.ndarray) -> np.ndarray:
        """CSR data array for element matrices of shape (nc, k, k)."""
        vals = np.asarray(element_matrices, dtype=np.float64).reshape(-1)
        return np.bincount(self.position, weights=vals, minlength=self.nnz + 1)[: self.nnz]

    def matrix(self, element_matrices: np.ndarray | None = None, data: np.ndarray | None = None) -> sp.csr_matrix:
        """The assembled CSR matrix (sharing the pattern arrays)."""
        if data is None:
            data = self.data(element_matrices)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))


def solve_dirichlet(element_matrices: np.ndarray, element_dofs: np.ndarray, num_dofs: int, fixed: np.ndarray,
                    values: np.ndarray) -> np.ndarray:
    """Solution x of ``K x = 0`` on the dofs not in ``fixed``, with ``x[fixed] = values``.

    K is assembled from ``element_matrices`` (nc, k, k) on ``element_dofs`` (nc, k) (full numbering,
    num_dofs dofs), symmetric positive definite on the free dofs (a Laplace stiffness); ``values``
    is (m,) or (m, r) for m fixed dofs (r right-hand sides). Solves ``K_ff x_f = -K_fD x_D``
    (`_solve_spd`: a sparse LU, or AMG-preconditioned CG to relative residual 1e-12 above
    `DIRECT_LIMIT` free dofs); returns x, (num_dofs,) or (num_dofs, r).
    """
    values = np.asarray(values, dtype=np.float64)
    x = np.zeros((num_dofs,) + values.shape[1:])
    x[fixed] = values
    free, to_reduced = reduced_numbering(num_dofs, fixed)
    if free.size == 0:
        return x
    red = to_reduced[element_dofs]
    lift = -np.einsum("cab,cb...->ca...", element_matrices, x[element_dofs])  # -K_fD x_D, element by element
    rhs = np.zeros((free.size,) + values.shape[1:])
    np.add.at(rhs, red[red >= 0], lift[red >= 0])
    K = SparsePattern(red, free.size).matrix(element_matrices)
    x[free] = _solve_spd(K, rhs)
    return x


#: `solve_dirichlet` factors systems up to this size (exact to round-off, fast); larger ones, whose
#: LU fill grows as n^(4/3) in 3D (a ventricle of 145k cells: minutes and GBs), go to CG with
#: smoothed-aggregation AMG (pyamg), which costs about O(n).
DIRECT_LIMIT = 10_000


def _solve_spd(K: sp.csr_matrix, rhs: np.ndarray, rtol: float = 1e-12, max_iter: int = 300) -> np.ndarray:
    """``K x = rhs`` for a symmetric positive definite K (n, n), rhs (n,) or (n, r): sparse LU up to
    `DIRECT_LIMIT` unknowns, else AMG-preconditioned CG per column to ``|rhs - K x| <= rtol |rhs|``
    (a sparse LU if CG has not got there in ``max_iter`` iterations)."""
    if K.shape[0] <= DIRECT_LIMIT:
        return spla.splu(K.tocsc()).solve(rhs)
    import pyamg  # only for large systems

    amg = pyamg.smoothed_aggregation_solver(K.tocsr(), symmetry="hermitian")
    cols = rhs.reshape(K.shape[0], -1)
    x = np.stack([amg.solve(b, tol=rtol / 10, accel="cg", maxiter=max_iter) for b in cols.T], axis=1)
    if np.any(np.linalg.norm(cols - K @ x, axis=0) > rtol * np.linalg.norm(cols, axis=0)):
        return spla.splu(K.tocsc()).solve(rhs)
    return x.reshape(rhs.shape)

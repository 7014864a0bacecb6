"""Sparse assembly into a fixed CSR pattern, filled in place.

The pattern is built once from the element dof lists, in a reduced numbering where constrained
(Dirichlet) dofs are dropped. Each later assembly is one ``np.bincount`` of the element matrices
into the CSR data array: no COO conversion, no sorting, no new index arrays.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["SparsePattern", "reduced_numbering", "solve_dirichlet"]


def reduced_numbering(num_dofs: int, constrained: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Free dofs (nfree,) and the map full -> reduced index (num_dofs,), -1 where constrained."""
    keep = np.ones(num_dofs, dtype=bool)
    keep[np.asarray(constrained, dtype=np.int64)] = False
    free = np.flatnonzero(keep)
    to_reduced = np.full(num_dofs, -1, dtype=np.int64)
    to_reduced[free] = np.arange(free.size)
    return free, to_reduced


class SparsePattern:
    """CSR structure of a matrix assembled from element blocks.

    Parameters
    ----------
    element_dofs : (nc, k) int
        Reduced dof indices of each element, -1 for dofs that are dropped (row and column).
    size : int
        Number of reduced dofs.
    """

    def __init__(self, element_dofs: np.ndarray, size: int):
        ed = np.asarray(element_dofs, dtype=np.int64)
        nc, k = ed.shape
        rows = np.repeat(ed, k, axis=1).ravel()
        cols = np.tile(ed, (1, k)).ravel()
        valid = (rows >= 0) & (cols >= 0)
        key = rows[valid] * size + cols[valid]
        uniq, inverse = np.unique(key, return_inverse=True)
        self.size, self.nnz = size, uniq.size
        self.indices = (uniq % size).astype(np.int32)
        self.indptr = np.searchsorted(uniq // size, np.arange(size + 1)).astype(np.int32)
        # Entry e of the flattened element blocks goes to data[position[e]]; dropped entries to a
        # trailing dump slot that is cut off after the bincount.
        self.position = np.full(rows.size, self.nnz, dtype=np.int64)
        self.position[valid] = inverse
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
    num_dofs dofs); ``values`` is (m,) or (m, r) for m fixed dofs (r right-hand sides, one sparse
    LU). Solves ``K_ff x_f = -K_fD x_D``; returns x, (num_dofs,) or (num_dofs, r).
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
    x[free] = spla.splu(K.tocsc()).solve(rhs)
    return x

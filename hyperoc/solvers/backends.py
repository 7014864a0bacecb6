"""Backends of `hyperoc.solvers.linsolve.SparseSolver`: how K is assembled, factored and solved per method.

A backend turns the element blocks into K (`matrix`) and factors it (`factor`); what is kept, when it is
refreshed and how a factor is refined to the tolerance is the solver's policy (`SparseSolver`), the same
for every backend.

- `SuperLUBackend` (``"lu"``, ``"lu_reuse"``): SuperLU of K in a fill-reducing ordering fixed once
  (METIS nested dissection, `nested_dissection`, or SuperLU's minimum degree taken from the first
  factorization); diagonal pivots first, threshold partial pivoting as the fallback.
- `PardisoBackend` (``"pardiso"``, ``"pardiso_reuse"``, ``"pardiso_single"``, ``"pardiso_single_reuse"``):
  MKL PARDISO's symmetric indefinite ``L D L^T`` of ``(K + K^T) / 2`` (`hyperoc.solvers.pardiso`), in
  double or single precision: a factor of a modified K, which the policy refines against K itself.
- `MinresBackend` (``"minres"``): no factorization; MINRES preconditioned by the absolute diagonal.

Each backend adds to the solver's ``stats`` (the same dict): ``assembly_s``, ``order_s``, ``factor_s``,
``factorizations``, ``fill``, ``off_diagonal_pivots`` and (MINRES) ``iterations``.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["SuperLUBackend", "PardisoBackend", "MinresBackend", "nested_dissection"]


def nested_dissection(pattern) -> np.ndarray:
    """Fill-reducing order ``q`` (n,) of a structurally symmetric pattern, new index -> old index
    (the LU factors ``K[q][:, q]``), by METIS multilevel nested dissection of the graph of ``K``.

    On 3D P2 meshes this gives fewer stored factor entries and faster SuperLU factorizations than
    minimum degree (``python bench/bench_ordering.py``).
    """
    import pymetis

    n = pattern.size
    A = sp.csr_matrix((np.ones(pattern.nnz, dtype=np.int8), pattern.indices, pattern.indptr), shape=(n, n))
    A = (A + A.T).tocsr()  # the element patterns are symmetric; this only guards the graph METIS needs
    A.setdiag(0)
    A.eliminate_zeros()
    q, _ = pymetis.nested_dissection(pymetis.CSRAdjacency(A.indptr, A.indices))
    return np.asarray(q, dtype=np.int64)


class _Backend:
    """What the backends share: the pattern, the solver's ``stats`` and K in the original numbering."""

    #: whether `factor` factors K itself (True) or a modified K that must be refined against K (False)
    exact = True
    #: whether a failed refinement may be retried with `factor` (``fallback=True``)
    can_fall_back = False

    def __init__(self, pattern, stats: dict):
        self.pattern, self.stats = pattern, stats

    def prepare(self) -> None:
        """Work done once before the first matrix (an ordering); nothing by default."""

    def matrix(self, blocks):
        """``(K, q)``: K (CSR) in the original numbering from the element blocks, no permutation."""
        t0 = time.perf_counter()
        K = self.pattern.matrix(np.asarray(blocks, dtype=np.float64).reshape(self.pattern.element_shape))
        self.stats["assembly_s"] += time.perf_counter() - t0
        return K, None

    def keepable(self, q) -> bool:
        """Whether a factor of the K of `matrix` (permutation q) may be kept for later calls."""
        return True

    @property
    def order(self):
        """The permutation q (new -> old index) in which kept factors were built, None for the original."""
        return None

    def _counted(self, lu, t0: float, fill: int, off_diagonal: int):
        self.stats["factor_s"] += time.perf_counter() - t0
        self.stats["factorizations"] += 1
        self.stats["fill"], self.stats["off_diagonal_pivots"] = fill, off_diagonal
        return lu


class SuperLUBackend(_Backend):
    """SuperLU of K in a fixed symmetric ordering (``ordering``: ``"nd"``, METIS nested dissection before the
    first call, or ``"mmd"``, SuperLU's minimum degree on ``K + K^T`` from the first factorization). Once
    the ordering is fixed, the element blocks are summed by one ``np.bincount`` straight into the CSC data
    of the permuted K (no conversion, no re-ordering), factored with the natural ordering. Pivots:
    ``pivot_thresh`` first, ``fallback_thresh`` on a retry (`SparseSolver`)."""

    def __init__(self, pattern, stats: dict, *, ordering: str, pivot_thresh: float, fallback_thresh: float):
        super().__init__(pattern, stats)
        self.ordering, self.pivot_thresh, self.fallback_thresh = ordering, pivot_thresh, fallback_thresh
        self.can_fall_back = fallback_thresh > pivot_thresh  # else a second factorization repeats the first
        self._order = None  # (q, position, indices, indptr) of the permuted CSC, once fixed

    def prepare(self) -> None:
        if self._order is None and self.ordering == "nd":
            t0 = time.perf_counter()
            self._set_order(nested_dissection(self.pattern))
            self.stats["order_s"] += time.perf_counter() - t0

    @property
    def order(self):
        return self._order[0]

    def keepable(self, q) -> bool:
        # The first "mmd" factorization is of K in the original numbering, later ones of the permuted K.
        return q is not None

    def _set_order(self, q):
        """Permuted CSC structure and the map element entry -> CSC data slot, for ``K[q][:, q]``
        (``q``: new index -> old index)."""
        P = self.pattern
        tag = sp.csr_matrix((np.arange(1, P.nnz + 1, dtype=np.float64), P.indices, P.indptr), shape=(P.size, P.size))
        Kq = tag[q][:, q].tocsc()
        Kq.sort_indices()
        src = Kq.data.astype(np.int64) - 1  # permuted-CSC slot k holds CSR entry src[k]
        slot = np.empty(P.nnz + 1, dtype=np.int64)
        slot[src] = np.arange(P.nnz)
        slot[P.nnz] = P.nnz  # dropped entries stay in the dump slot
        self._order = (q, slot[P.position], Kq.indices.astype(np.int32), Kq.indptr.astype(np.int32))

    def matrix(self, blocks):
        """K (CSC) in the fixed ordering, and its permutation q (None before an ordering is fixed)."""
        if self._order is None:
            K, q = super().matrix(blocks)
            return K.tocsc(), q
        t0 = time.perf_counter()
        q, position, indices, indptr = self._order
        data = np.bincount(position, weights=np.asarray(blocks, dtype=np.float64).reshape(-1),
                           minlength=indices.size + 1)[: indices.size]
        K = sp.csc_matrix((data, indices, indptr), shape=(self.pattern.size,) * 2)
        self.stats["assembly_s"] += time.perf_counter() - t0
        return K, q

    def factor(self, K, permuted: bool, fallback: bool = False):
        """SuperLU of K: in its own numbering if ``permuted`` (K already in the fixed ordering), else ordered by
        SuperLU's minimum degree on ``K + K^T``; with ``ordering="mmd"`` the first factorization fixes the
        ordering (a K that is not ``permuted`` is ordered by SuperLU even when an ordering is fixed by then:
        the fallback of the very first call factors the same unpermuted K again)."""
        t0 = time.perf_counter()
        lu = spla.splu(K, permc_spec="NATURAL" if permuted else "MMD_AT_PLUS_A",
                       diag_pivot_thresh=self.fallback_thresh if fallback else self.pivot_thresh,
                       options={"SymmetricMode": True})
        # lu.nnz, not lu.L / lu.U: each builds a copy of the factor (+2.8 GB at 80k dofs)
        lu = self._counted(lu, t0, lu.nnz, int(np.count_nonzero(lu.perm_r != lu.perm_c)))
        if self._order is None:
            self._set_order(np.argsort(lu.perm_c))
        return lu


class PardisoBackend(_Backend):
    """MKL PARDISO's ``L D L^T`` of the symmetric part ``(K + K^T) / 2``, built from the CSR K by one bincount
    into its upper triangle (`hyperoc.solvers.pardiso.PardisoLDL`); ``single``: factored in single precision.
    PARDISO orders with METIS and perturbs the pivots it cannot take: a factor of a modified K."""

    exact = False

    def __init__(self, pattern, stats: dict, *, single: bool):
        super().__init__(pattern, stats)
        self.single = single
        self._upper = None  # (slot, weight, indices, indptr): CSR data -> the upper triangle of (K + K^T) / 2

    def factor(self, K, permuted: bool = False, fallback: bool = False):
        from .pardiso import PardisoLDL

        t0 = time.perf_counter()
        if self._upper is None:
            self._upper = _upper_triangle_map(self.pattern)
        slot, weight, indices, indptr = self._upper
        data = np.bincount(slot, weights=K.data * weight, minlength=indices.size)
        lu = PardisoLDL(sp.csr_matrix((data, indices, indptr), shape=K.shape), single=self.single)
        return self._counted(lu, t0, lu.nnz, lu.perturbed_pivots)


class MinresBackend(_Backend):
    """No factorization: MINRES preconditioned by the absolute diagonal (K is mass dominated in dynamics),
    restarted until the true backward error is ``<= rtol``."""

    def __init__(self, pattern, stats: dict, *, rtol: float):
        super().__init__(pattern, stats)
        self.rtol = rtol

    def solve(self, K, rhs):
        """``K^-1 rhs`` column by column, rhs (n, m); ``LinAlgError`` if MINRES does not reach ``10 rtol``."""
        return np.stack([self._minres(K, rhs[:, j]) for j in range(rhs.shape[1])], axis=1)

    def _minres(self, K, rhs):
        M = sp.diags(1.0 / np.abs(K.diagonal()))  # Jacobi: K is mass dominated in dynamics
        count = [0]
        cb = lambda _: count.__setitem__(0, count[0] + 1)
        Knorm = abs(K).sum(axis=1).max()
        x = None
        for _ in range(4):  # restarts until the true backward error meets rtol (scipy tests an estimate)
            x, info = spla.minres(K, rhs, x0=x, M=M, rtol=self.rtol, maxiter=5000, callback=cb)
            err = np.abs(rhs - K @ x).max() / max(Knorm * np.abs(x).max() + np.abs(rhs).max(), 1e-300)
            if err <= self.rtol:
                break
        self.stats["iterations"] += count[0]
        if info != 0 or not err <= 10 * self.rtol:
            raise np.linalg.LinAlgError(f"MINRES did not converge (info = {info}, backward error {err:.2e})")
        return x


def _upper_triangle_map(pattern) -> tuple:
    """For the structurally symmetric CSR ``pattern``: ``(slot, weight, indices, indptr)`` with the
    upper triangle's CSR structure and, per entry (i, j) of the pattern, the slot of (min, max) in it
    and the weight (1 on the diagonal, 1/2 off it): ``bincount(slot, data * weight)`` is ``(K + K^T) / 2``."""
    n = pattern.size
    rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(pattern.indptr))
    cols = pattern.indices.astype(np.int64)
    lo, hi = np.minimum(rows, cols), np.maximum(rows, cols)
    key, slot = np.unique(lo * n + hi, return_inverse=True)
    indptr = np.searchsorted(key // n, np.arange(n + 1)).astype(np.int32)
    return slot, np.where(rows == cols, 1.0, 0.5), (key % n).astype(np.int32), indptr

"""Symmetric indefinite sparse factorization ``P K P^T = L D L^T`` by Intel MKL PARDISO, through ctypes.

Why: the quasi-static tangents of the benchmarks (Taylor-Hood saddle points with a conservative
follower pressure) are symmetric and indefinite. SuperLU (`scipy.sparse.linalg.splu`) factors them as
``K = L U`` and stores both factors; PARDISO's symmetric indefinite mode (matrix type -2) stores one
triangle, orders with METIS nested dissection, pivots 1x1 and 2x2 (Bunch-Kaufman) inside supernodes,
replaces the pivots it cannot take by ``+-eps |K|`` (perturbation ``1e-8``; the caller's iterative
refinement against the true K removes their effect) and runs threaded BLAS-3 kernels. The library
comes from the ``mkl`` wheel on PyPI (``libmkl_rt``); nothing else is needed.

The interface is the one `scipy.sparse.linalg.splu` returns, as far as `hyperoc.solvers.linsolve` uses it:
``solve(b)`` for ``b`` (n,) or (n, k) and ``nnz`` (entries of the stored factor L).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import glob
import os
import site
import sys

import numpy as np
import scipy.sparse as sp

__all__ = ["PardisoLDL", "available"]

_REAL_SYMMETRIC_INDEFINITE = -2
_ANALYSIS_FACTOR, _SOLVE, _RELEASE = 12, 33, -1
_ERRORS = {-1: "input inconsistent", -2: "not enough memory", -3: "reordering problem",
           -4: "zero pivot, numerical factorization or iterative refinement problem", -5: "unclassified internal error",
           -6: "reordering failed", -7: "diagonal matrix is singular", -8: "32-bit integer overflow",
           -9: "not enough memory for out-of-core", -10: "error opening out-of-core files",
           -11: "read/write error with out-of-core files", -12: "pardiso_64 called from a 32-bit library"}


@functools.cache
def _library() -> ctypes.CDLL:
    """``libmkl_rt`` from ``HYPEROC_MKL_RT`` (a path), the loader's search path, or the ``lib`` folder
    of this interpreter's prefix or user base, where the ``mkl`` wheel puts it."""
    paths = [os.environ.get("HYPEROC_MKL_RT"), ctypes.util.find_library("mkl_rt")]
    for base in (sys.prefix, site.USER_BASE):
        paths += sorted(glob.glob(os.path.join(base, "lib", "libmkl_rt.so*")), key=len)
    for path in filter(None, paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        lib.pardiso.restype = None
        return lib
    raise ImportError("MKL PARDISO needs the mkl package (python -m pip install mkl), or HYPEROC_MKL_RT "
                      "set to the path of libmkl_rt")


def available() -> bool:
    """Whether MKL PARDISO can be loaded (`_library`)."""
    try:
        _library()
    except ImportError:
        return False
    return True


def require(method: str) -> None:
    """`InputError` naming the fix when the solver ``method`` (a PARDISO method) cannot load MKL."""
    if not available():
        from ..errors import InputError

        raise InputError(f"the {method!r} solver needs MKL: python -m pip install mkl")


def _cast_finite(values: np.ndarray, dtype, what: str, *, fortran: bool = False) -> np.ndarray:
    """``values`` in PARDISO's precision, or ``LinAlgError`` when one of them is NaN or Inf there."""
    with np.errstate(over="ignore"):  # a double beyond single precision becomes Inf: refused below
        out = (np.asfortranarray if fortran else np.ascontiguousarray)(values, dtype=dtype)
    if not np.isfinite(out).all():
        raise np.linalg.LinAlgError(f"PARDISO: the {what} has non-finite entries (NaN or Inf"
                                    f"{', or beyond single precision' if dtype == np.float32 else ''})")
    return out


class PardisoLDL:
    """``L D L^T`` of the symmetric matrix whose upper triangle (diagonal included) is ``upper`` (CSR, n x n).
    ``single``: values, factor and solves in single precision (``iparm(28) = 1``; half the factor's
    memory, and a solve only to about ``cond * 6e-8``: refine against the double-precision K).

    After construction: ``nnz`` (entries of L, PARDISO ``iparm(18)``), ``perturbed_pivots``
    (``iparm(14)``), ``inertia`` (positive and negative eigenvalues of K, ``iparm(22)``, ``iparm(23)``),
    ``memory_mb`` (PARDISO's peak, ``max(iparm(15), iparm(16) + iparm(17))`` KB). ``free()`` releases
    the factor (also when the object is collected); calls must come from one thread at a time.

    A matrix or right-hand side with a NaN or Inf entry (in the precision PARDISO gets: a double above
    3.4e38 is Inf in single precision) raises ``LinAlgError`` before PARDISO sees it: its scaling and
    matching on such values can corrupt the heap ("double free or corruption", the process aborts),
    as on a Newton iterate with inverted elements.
    """

    def __init__(self, upper: sp.csr_matrix, *, single: bool = False):
        upper = sp.csr_matrix(upper)
        upper.sort_indices()
        self.n = upper.shape[0]
        self._lib = _library()
        self._dtype = np.float32 if single else np.float64
        self._data = _cast_finite(upper.data, self._dtype, "matrix")
        self._indptr = np.ascontiguousarray(upper.indptr, dtype=np.int32)
        self._indices = np.ascontiguousarray(upper.indices, dtype=np.int32)
        self._pt = np.zeros(64, dtype=np.int64)  # PARDISO's opaque handle; zero before the first call
        self._iparm = np.zeros(64, dtype=np.int32)
        settings = {1: 1,    # not the defaults: the values below
                    2: 2,    # METIS nested dissection
                    10: 8,   # perturb pivots below 1e-8 |K|
                    11: 1,   # symmetric scaling and
                    13: 1,   # weighted matching: recommended for saddle points
                    18: -1,  # report the factor's entries
                    21: 1,   # 1x1 and 2x2 Bunch-Kaufman pivots
                    28: int(single),  # factor (and values, right-hand sides) in single precision
                    35: 1}   # zero-based indices
        for k, v in settings.items():
            self._iparm[k - 1] = v
        # pointers taken once: releasing at interpreter exit must not import anything (ndarray.ctypes does)
        ptr = lambda a: a.ctypes.data_as(ctypes.c_void_p)
        self._args = [ptr(a) for a in (self._pt, self._data, self._indptr, self._indices, self._iparm)]
        self._live = False
        self._call(_ANALYSIS_FACTOR, np.zeros((self.n, 1)))
        self._live = True
        ip = self._iparm
        self.nnz = int(ip[17])
        self.perturbed_pivots = int(ip[13])
        self.inertia = (int(ip[21]), int(ip[22]))
        self.memory_mb = max(int(ip[14]), int(ip[15]) + int(ip[16])) / 1024.0

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``K^-1 b`` for b (n,) or (n, k)."""
        b = np.asarray(b, dtype=np.float64)
        cols = _cast_finite(b.reshape(self.n, -1), self._dtype, "right-hand side", fortran=True)
        return self._call(_SOLVE, cols).astype(np.float64).reshape(b.shape)

    def free(self):
        """Release the factor (idempotent)."""
        if self._live:
            self._live = False
            self._call(_RELEASE, None)

    def __del__(self):
        if getattr(self, "_live", False):
            self.free()

    def _call(self, phase: int, b: np.ndarray | None) -> np.ndarray | None:
        """One PARDISO call; ``b`` (n, k) Fortran-ordered right-hand sides, or None (release)."""
        x = None if b is None else np.zeros_like(b, order="F")
        error = ctypes.c_int32(0)
        i32 = lambda v: ctypes.byref(ctypes.c_int32(v))
        pt, data, indptr, indices, iparm = self._args
        nrhs, b_ptr, x_ptr = (1, None, None) if b is None else (b.shape[1], b.ctypes.data_as(ctypes.c_void_p),
                                                                   x.ctypes.data_as(ctypes.c_void_p))
        self._lib.pardiso(pt, i32(1), i32(1), i32(_REAL_SYMMETRIC_INDEFINITE), i32(phase), i32(self.n),
                          data, indptr, indices, None, i32(nrhs), iparm, i32(0), b_ptr, x_ptr, ctypes.byref(error))
        if error.value:
            raise np.linalg.LinAlgError(f"PARDISO phase {phase}: error {error.value} "
                                        f"({_ERRORS.get(error.value, 'unknown')})")
        return x

"""Linear solvers for the bordered step system, by a Schur complement on the single multiplier.

Each Newton iteration (and each adjoint step) solves

    [ K    col ] [x]   [r_u]
    [ row^T  d ] [q] = [r_c]

with K symmetric (possibly indefinite under compression) given by element blocks and the scalar corner
``d`` (0 unless the constraint's row depends on its multiplier, `hyperoc.dynamics.constraint`). With one
factorization of K: ``K a = r_u``, ``K b = col``, ``q = (row.a - r_c) / (row.b - d)``, ``x = a - b q``.
The adjoint solves the transpose, which is the same call with ``col`` and ``row`` swapped.

A constraint may add to the Jacobian a dense symmetric low-rank term that the element blocks cannot hold
(the volume of a cavity closed by a lid through the moving centroid of its rim: rank ``2 dim``):
``K_full = K + U W U^T``, ``U`` (n, k), ``W`` (k, k) symmetric, given to a solve as ``lowrank=(U, W)``.
The dense solver adds it to its dense K. The sparse solver never puts it into the sparse matrix: it solves
``K^-1 [r_u, col, U]`` with the one factorization of K (``Z = K^-1 U``: k more columns) and corrects
``a`` and ``b`` by the Woodbury identity

    K_full^-1 v = K^-1 v - Z (I_k + W U^T Z)^-1 W U^T K^-1 v,

valid for a singular W (W = 0 gives K^-1 v), before the border is eliminated as above. The transposed
solve needs nothing more: W is symmetric, so ``K_full^T = K^T + U W U^T``.

- `DenseSolver`: LU in JAX (small problems; the whole time loop can be compiled).
- `TridiagonalSolver`: 1D P1 meshes numbered along the line (the paper's case), in JAX.
- `SparseSolver`: assembly into a fixed sparsity pattern and a host solver (SuperLU, MINRES from scipy;
  MKL PARDISO's symmetric indefinite LDL^T, `hyperoc.solvers.pardiso`), called on the host by the time
  steps' and the static solves' Newton (`hyperoc.solvers.host_newton`: ``try_solve``, ``try_kept_solve``) or
  from traced code through ``jax.pure_callback`` (``solve``, ``refresh_solve``, ``kept_solve``); SuperLU runs
  on K permuted once by METIS nested dissection (`nested_dissection`).
  The method's assembly and factorization are its backend (`hyperoc.solvers.backends`).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np

from .._jax import on_device
from ..errors import InputError
from ..fem.assembly import dump_index
from .backends import MinresBackend, PardisoBackend, SuperLUBackend, nested_dissection
from .threads import openblas_threads

__all__ = ["DenseSolver", "TridiagonalSolver", "SparseSolver", "make_solver", "nested_dissection"]


def eliminate_border(ab, row, r_c, dot=None, corner=0.0):
    """The bordered solution ``(x, q)`` from ``a = K^-1 r_u`` and ``b = K^-1 col``, the columns of ab
    (NumPy or JAX arrays): ``q = (row . a - r_c) / (row . b - corner)``, ``x = a - b q``. ``dot(u, v)``:
    the inner product (default ``u @ v``; a distributed solve passes the sum over the ranks of their parts')."""
    a, b = ab[:, 0], ab[:, 1]
    dot = dot or (lambda u, v: u @ v)
    q = (dot(row, a) - r_c) / (dot(row, b) - corner)
    return a - b * q, q


def _schur(solve2, col, row, r_u, r_c, corner):
    return eliminate_border(solve2(jnp.stack([r_u, col], axis=1)), row, r_c, corner=corner)


class _Woodbury:
    """Solves with ``K + U W U^T`` from solves with K (NumPy): for ``x = K^-1 v`` (n,) or (n, m),
    ``(K + U W U^T)^-1 v = x - Z C U^T x`` with ``Z = K^-1 U`` (n, k) and ``C = (I_k + W U^T Z)^-1 W``
    (k, k). W (k, k) symmetric, possibly singular; ``LinAlgError`` if ``I_k + W U^T Z`` is singular
    (so is ``K + U W U^T``)."""

    def __init__(self, U, W, Z):
        self.U, self.Z = U, Z
        self.C = np.linalg.solve(np.eye(len(W)) + W @ (U.T @ Z), W)

    def corrected(self, x):
        """``(K + U W U^T)^-1 v`` from ``x = K^-1 v``, same shape as x."""
        return x - self.Z @ (self.C @ (self.U.T @ x))


class DenseSolver:
    """Dense LU of the assembled K, traced by JAX."""

    traced = True

    def __init__(self, model):
        k = model.cell_dofs.shape[1]
        n = model.n
        ed = dump_index(model.cell_dofs, n)
        self.n = n
        self._rows = jnp.asarray(np.repeat(ed, k, axis=1).ravel())
        self._cols = jnp.asarray(np.tile(ed, (1, k)).ravel())

    def assemble(self, blocks):
        K = jnp.zeros((self.n + 1, self.n + 1), blocks.dtype).at[self._rows, self._cols].add(blocks.reshape(-1))
        return K[: self.n, : self.n]

    def solve(self, blocks, col, row, r_u, r_c, corner=0.0, lowrank=None):
        """The bordered solve ``(x (n,), q)`` with ``K + U W U^T`` for ``lowrank = (U (n, k), W (k, k))``
        (None: K), the term added to the dense K."""
        K = self.assemble(blocks)
        if lowrank is not None:
            U, W = lowrank
            K = K + U @ W @ U.T
        lu = jax.scipy.linalg.lu_factor(K)
        return _schur(lambda B: jax.scipy.linalg.lu_solve(lu, B), col, row, r_u, r_c, corner)


class TridiagonalSolver:
    """Tridiagonal solve for 1D P1 meshes whose reduced dofs are numbered along the line."""

    traced = True

    def __init__(self, model):
        ed = model.cell_dofs
        if model.dim != 1 or model.space.degree != 1 or ed.shape[1] != 2:
            raise InputError("the tridiagonal solver needs a 1D P1 model")
        both = (ed[:, 0] >= 0) & (ed[:, 1] >= 0)
        if not np.all(np.abs(ed[both, 1] - ed[both, 0]) == 1):
            raise InputError("the tridiagonal solver needs dofs numbered along the line")
        self.n = n = model.n
        # Flat positions in blocks (nc, 2, 2) summed into each diagonal entry: gathers, which XLA
        # fuses with the sums, rather than scatters.
        cells = np.arange(len(ed))
        flat = lambda c, a, b: 4 * c + 2 * a + b
        lo = np.argmin(np.where(ed < 0, n, ed), axis=1)  # local index of the lower dof of a full cell
        hi = 1 - lo
        row_lo = ed[cells, lo]
        diag = [(ed[:, a], flat(cells, a, a)) for a in (0, 1)]
        self._diag = _gather_table(n, diag, 4 * len(ed))
        self._upper = _gather_table(n, [(np.where(both, row_lo, -1), flat(cells, lo, hi))], 4 * len(ed))
        self._lower = _gather_table(n, [(np.where(both, row_lo + 1, -1), flat(cells, hi, lo))], 4 * len(ed))

    def solve(self, blocks, col, row, r_u, r_c, corner=0.0, lowrank=None):
        """The bordered solve ``(x (n,), q)``; ``lowrank`` must be None (a 1D P1 line has no cavity)."""
        if lowrank is not None:
            raise InputError("the tridiagonal solver has no low-rank term")
        flat = jnp.concatenate([blocks.reshape(-1), jnp.zeros(1, blocks.dtype)])
        d, du, dl = (flat[t].sum(axis=1) for t in (self._diag, self._upper, self._lower))
        solve2 = lambda B: jax.lax.linalg.tridiagonal_solve(dl, d, du, B)
        return _schur(solve2, col, row, r_u, r_c, corner)


def _gather_table(n, pairs, sentinel):
    """Index table (n, w) of the flat positions summed into each of n entries, padded with
    ``sentinel`` (the index of an appended zero). pairs: [(target (m,), position (m,))], target < 0
    skipped."""
    target = np.concatenate([t for t, _ in pairs])
    pos = np.concatenate([p for _, p in pairs])
    keep = target >= 0
    target, pos = target[keep], pos[keep]
    order = np.argsort(target, kind="stable")
    target, pos = target[order], pos[order]
    counts = np.bincount(target, minlength=n)
    table = np.full((n, max(int(counts.max(initial=0)), 1)), sentinel)
    slot = np.arange(len(target)) - np.repeat(np.cumsum(counts) - counts, counts)
    table[target, slot] = pos
    return on_device(table, dtype=None)


class SparseSolver:
    """Host solver on the sparsity pattern of the model, called on the host or through ``jax.pure_callback``: a backend
    (`backend`, `hyperoc.solvers.backends`: K's assembly and factorization for the method) under one reuse and
    precision policy (this class: the kept factorizations, their refresh, iterative refinement to ``rtol``,
    the chord Newton's kept Jacobian, the worker thread and ``stats``).

    method
        ``"lu"`` (default): SuperLU with diagonal pivots first and threshold partial pivoting as
        the fallback (``pivot_thresh``, below), robust for indefinite K, with a symmetric
        fill-reducing ordering (``ordering``) computed once and reused: the element blocks are
        summed by one ``np.bincount`` straight into the CSC data of the permuted matrix (no
        COO/CSR->CSC conversion, no re-ordering), then factored with the natural ordering.
        ``"lu_reuse"``: the same factorization, kept across calls (Newton iterations, time steps,
        the adjoint sweep) and used as the preconditioner of iterative refinement on the current
        K until the normwise backward error ``|r| / (|K| |x| + |b|)`` is ``<= rtol``; K is
        re-factored when that does not contract fast enough (``reuse_rate``) or within
        ``reuse_max_iter`` iterations. Same accuracy as ``"lu"``, far fewer factorizations.
        ``"pardiso"``, ``"pardiso_reuse"``: the same two strategies with MKL PARDISO's symmetric
        indefinite ``L D L^T`` (`hyperoc.solvers.pardiso.PardisoLDL`) of the symmetric part ``(K + K^T) / 2``
        in place of SuperLU, refined against K itself to the same ``rtol`` (so a K that is not
        symmetric is still solved exactly, or the solve fails, never silently). For symmetric K
        (conservative loads, and follower pressures on a surface whose rim is held: the clamped
        benchmarks' tangents are symmetric to round-off; a sliding base lets the rim move) it stores one
        triangle instead of L and U and runs threaded: bench/bench_pardiso.py. ``"pardiso_single"``,
        ``"pardiso_single_reuse"``: the factorization in single precision (half its memory), refined
        against K in double precision to the same ``rtol``, or the solve fails. The refinement of a
        fresh PARDISO factorization goes on while the backward error falls by 10% or more in 3 steps,
        up to ``refine_max_iter`` steps: its rate is ``|K_s^-1 K_a|``, K's skew part (follower
        loads) against its symmetric part, plus ``cond * 6e-8`` with the single factor, so a fixed
        small cap on the steps would stop short of ``rtol`` on slightly nonsymmetric tangents.
        Needs the ``mkl`` package; ``pivot_thresh``, ``fallback_thresh`` and ``ordering`` do not
        apply (PARDISO orders with METIS and pivots in 1x1 and 2x2 blocks, perturbing the pivots it
        cannot take).
        ``"minres"``: MINRES preconditioned by the absolute diagonal (K is mass dominated in
        dynamics), restarted until the true backward error is ``<= rtol``. (Smoothed-aggregation
        AMG of ``|K|``, set up at every call, is far slower here: ``python bench/bench_2d3d.py``.)
    pivot_thresh, fallback_thresh : SuperLU keeps the diagonal pivot while
        ``|K_jj| >= thresh * max_i |K_ij|`` and swaps a row in otherwise, which breaks the
        nested-dissection structure and adds fill. The first factorization of a call uses
        ``pivot_thresh`` (default 0: the diagonal unless it is exactly zero, i.e. the ordering's
        structure is kept); when iterative refinement with it does not reach ``rtol`` (tiny pivots),
        K is factored again with ``fallback_thresh`` (default 0.1) and ``stats["pivoting_fallbacks"]``
        counts it. On the Taylor-Hood saddle point (zero pressure diagonal, indefinite K_uu under
        load) threshold 0.1 swaps thousands of rows, with more fill and slower factorizations than
        diagonal pivots (``python bench/bench_pivot.py``).
    rtol : backward-error tolerance of the iterative parts (``<= 1e-12``; the gradients are exact
        up to it).
    ordering : ``"nd"`` (default): METIS nested dissection of the pattern (`nested_dissection`),
        before the first factorization; ``"mmd"``: SuperLU's minimum degree on ``K + K^T``
        (``MMD_AT_PLUS_A``), taken from the first factorization, kept for comparison
        (``python bench/bench_ordering.py``).

    ``stats`` accumulates ``calls``, ``factorizations``, ``iterations`` (refinement or Krylov),
    ``kept_solves`` (chord Newton's solves with a kept Jacobian: `kept_solve`) and the host
    seconds ``order_s`` (nested dissection), ``assembly_s`` (blocks -> matrix), ``factor_s``,
    ``solve_s`` and ``host_s`` (whole ``host_solve``); ``fill`` is the number of entries SuperLU
    stores for L and U in the last factorization (``SuperLU.nnz``: supernodal, the zeros inside
    supernodes included; PARDISO: the entries of L) and ``off_diagonal_pivots`` the pivots it took
    off the diagonal (``perm_r != perm_c``; PARDISO: the perturbed pivots); ``failed`` counts
    traced solves that returned NaN (singular K, MINRES failure, a stalled PARDISO refinement;
    ``last_failure`` holds the message).

    Threads: ``jax.pure_callback`` may run each call on a different XLA thread, and scipy's SuperLU
    tracks a factorization's memory per thread: one freed on another thread than the one that built it
    is never released (scipy issue #15921). ``"lu_reuse"`` keeps factorizations across calls, and leaked
    one per refresh (LV Taylor-Hood at 11,569 unknowns: +70 MB per factorization, 4.5 GB after 43). So
    every call runs on the solver's own single worker thread, where each factorization is built and freed,
    with OpenBLAS limited to ``blas_threads`` threads (`hyperoc.solvers.threads.openblas_threads`: its
    spinning threads would take the cores from XLA between the solves; None leaves OpenBLAS as it is set).
    """

    traced = False
    blas_threads: int | None = 1
    methods = ("lu", "lu_reuse", "pardiso", "pardiso_reuse", "pardiso_single", "pardiso_single_reuse", "minres")
    orderings = ("nd", "mmd")

    def __init__(self, model, method: str = "lu", rtol: float = 1e-13, *, pivot_thresh: float = 0.0,
                 fallback_thresh: float = 0.1,
                 reuse_rate: float = 0.25, reuse_max_iter: int = 8, refine_max_iter: int = 50,
                 ordering: str = "nd"):
        if method not in self.methods:
            raise InputError(f"unknown sparse method {method!r} ({', '.join(self.methods)})")
        if ordering not in self.orderings:
            raise InputError(f"unknown ordering {ordering!r} ({', '.join(self.orderings)})")
        if not 0 < rtol <= 1e-12:
            raise InputError(f"the iterative tolerance must lie in (0, 1e-12], got {rtol}")
        if method.startswith("pardiso"):
            from .pardiso import require

            require(method)
        self.pattern, self.n, self.method, self.rtol = model.pattern, model.n, method, rtol
        self.stats = {}
        self.reset_stats()
        self.backend = _backend(method, self.pattern, self.stats, rtol=rtol, ordering=ordering,
                                pivot_thresh=pivot_thresh, fallback_thresh=fallback_thresh)
        self._reuse = method.endswith("_reuse")
        self.reuse_rate, self.reuse_max_iter, self.refine_max_iter = reuse_rate, reuse_max_iter, refine_max_iter
        self._lu = None  # kept factorization ("_reuse" methods)
        self._kept = None  # the chord iteration's factorization (`refresh_solve`)
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hyperoc-superlu")
        self.last_failure = None

    def __del__(self):
        worker = getattr(self, "_worker", None)
        if worker is None:
            return
        try:  # free a kept factorization on the thread that built it, then stop that thread
            worker.submit(self._release)
        except RuntimeError:  # interpreter exit: the executors are already shut down
            pass
        worker.shutdown(wait=False)  # the submitted release still runs; never joins from the worker itself

    def _release(self):
        self._lu = self._kept = None

    def forget_factorization(self) -> None:
        """Drop the kept factorization (on the thread that built it), so that the next chord iteration
        starts with a fresh one: a solve resumed from a saved state then takes the same iterations as
        one that ran through (`hyperoc.dynamics.resumable`)."""
        self._worker.submit(self._release).result()

    def reset_stats(self):
        """Zero the counters and timings of ``stats`` (the same dict, shared with the backend)."""
        self.stats.clear()
        self.stats.update({"calls": 0, "factorizations": 0, "iterations": 0, "kept_solves": 0,
                           "refactor_after_stall": 0, "failed": 0, "order_s": 0.0, "assembly_s": 0.0,
                           "factor_s": 0.0, "solve_s": 0.0, "host_s": 0.0, "fill": 0, "off_diagonal_pivots": 0,
                           "pivoting_fallbacks": 0})

    # --- solves -------------------------------------------------------------------------------
    def host_solve(self, blocks, col, row, r_u, r_c, corner=0.0, lowrank=None, keep: bool = False):
        """The bordered solve ``(x, q)`` as one array (n + 1,), on the solver's worker thread (class
        docstring), with ``K + U W U^T`` for ``lowrank = (U (n, k), W (k, k))`` (None: K); ``keep``: keep this
        Jacobian (with its ``corner`` and low-rank term) for `kept_solve`."""
        return self._on_worker(self._host_solve, blocks, col, row, r_u, r_c, corner, lowrank, keep)

    def _on_worker(self, fn, *args):
        """``fn(*args)`` on the worker thread, with OpenBLAS at ``blas_threads`` (class docstring)."""
        return self._worker.submit(self._limited, fn, *args).result()

    def _limited(self, fn, *args):
        with openblas_threads(self.blas_threads):
            return fn(*args)

    def _host_solve(self, blocks, col, row, r_u, r_c, corner=0.0, lowrank=None, keep: bool = False):
        t_start = time.perf_counter()
        self.stats["calls"] += 1
        self.backend.prepare()
        K, q = self.backend.matrix(blocks)
        # U's k columns join r_u and col in the one solve with K (Z = K^-1 U, for the Woodbury correction)
        rhs = _checked_rhs(np.column_stack([r_u, col] if lowrank is None else [r_u, col, lowrank[0]]))
        if not np.isfinite(K.data).all():
            raise np.linalg.LinAlgError("the tangent or the residual has non-finite entries (NaN or Inf)")
        if keep:
            self._kept = None  # freed before the new factorization is built
        if isinstance(self.backend, MinresBackend):
            t0 = time.perf_counter()
            lu, x = None, self.backend.solve(K, rhs)
            self.stats["solve_s"] += time.perf_counter() - t0
        else:
            lu, x = self._factored_solve(K, rhs if q is None else rhs[q], q, keep)
            x = _unpermuted(x, q)
        low_rank = None if lowrank is None else _Woodbury(rhs[:, 2:], _checked_rhs(lowrank[1]), x[:, 2:])
        ab = x if low_rank is None else low_rank.corrected(x[:, :2])
        if lu is not None:
            self._kept = (lu, ab[:, 1], np.asarray(row, dtype=np.float64), float(corner), low_rank)
        self.stats["host_s"] += time.perf_counter() - t_start
        return _bordered(ab, row, r_c, corner)

    def _factored_solve(self, K, rhs, q, keep: bool):
        """``(lu, K^-1 rhs)`` (rhs and the solution in the ordering q) by the reuse policy: with ``keep``, a
        fresh factor, returned as ``lu`` for chord Newton to keep (None if the backend cannot keep it);
        otherwise ``lu`` is None and the solve uses the kept factor of a "_reuse" method, refined and
        refreshed when it stalls, or a fresh factor (kept by a "_reuse" method)."""
        keepable = self.backend.keepable(q)
        if keep:
            lu, x = self._fresh_solve(K, rhs, q is not None)
            return (lu if keepable else None), x
        if self._reuse and self._lu is not None:
            x = self._solve_refined(K, rhs, self._lu, max_iter=self.reuse_max_iter, rate=self.reuse_rate)
            if x is None:  # the kept factorization is too far from K: refresh it
                self.stats["refactor_after_stall"] += 1
                self._lu = None  # freed before the new factorization is built
                self._lu, x = self._fresh_solve(K, rhs, q is not None)
            return None, x
        lu, x = self._fresh_solve(K, rhs, q is not None)
        self._lu = lu if self._reuse and keepable else None
        return None, x

    def _host_kept_solve(self, r_u, r_c):
        """The bordered solve with the whole Jacobian of the last `refresh_solve`: its factorization of K,
        ``b = K_full^-1 col``, ``row``, the corner and its low-rank term's `_Woodbury` (None: K_full = K);
        one solve with the factor, no refinement (chord Newton)."""
        t_start = time.perf_counter()
        self.stats["calls"] += 1
        lu, b, row, corner, low_rank = self._kept
        q = self.backend.order
        r_u = _checked_rhs(r_u)
        a = _unpermuted(lu.solve(r_u if q is None else r_u[q]), q)
        if low_rank is not None:
            a = low_rank.corrected(a)
        self.stats["kept_solves"] += 1
        self.stats["solve_s"] += time.perf_counter() - t_start
        self.stats["host_s"] += time.perf_counter() - t_start
        return _bordered(np.stack([a, b], axis=1), row, r_c, corner)

    def _fresh_solve(self, K, rhs, permuted: bool):
        """Factor K (``permuted``: in the backend's fixed ordering) and solve with refinement: ``(lu, x)``.
        A factor of K itself (SuperLU): two refinement steps; when the first pivots leave them short of
        ``rtol``, the backend's fallback pivots. A factor of a modified K (PARDISO's perturbed ``L D L^T``
        of ``(K + K^T) / 2``): refinement while it contracts (by 0.9 or better in 3 steps), up to
        ``refine_max_iter`` steps (a fresh factor is the best there is, so a slow contraction is waited
        out, where a kept factor is refreshed instead)."""
        backend = self.backend
        lu = backend.factor(K, permuted)
        if not backend.exact:
            return lu, self._solve_refined(K, rhs, lu, max_iter=self.refine_max_iter, rate=0.9, patience=3,
                                           strict=True)
        x = self._solve_refined(K, rhs, lu, max_iter=2, rate=self.reuse_rate if backend.can_fall_back else None)
        if x is None:
            self.stats["pivoting_fallbacks"] += 1
            lu = None  # freed before the second factorization is built (GBs at 80k dofs)
            lu = backend.factor(K, permuted, fallback=True)
            x = self._solve_refined(K, rhs, lu, max_iter=2)
        return lu, x

    def _solve_refined(self, K, rhs, lu, *, max_iter, rate=None, patience=1, strict=False):
        """Iterative refinement with ``lu`` (of K or of an earlier K) to backward error ``rtol``.

        Returns None when ``rate`` is given (a kept factorization, or diagonal pivots that can fall
        back, `_fresh_solve`) and the refinement does not contract by at least that factor in
        ``patience`` steps (the error of a stationary iteration need not fall at every step) or
        does not converge in ``max_iter``; with ``strict`` (a factorization of a modified K:
        PARDISO's perturbed LDL^T of the symmetric part) that raises ``LinAlgError``.
        """
        t0 = time.perf_counter()
        x = lu.solve(rhs)
        Knorm = abs(K).sum(axis=0).max()
        bnorm = np.abs(rhs).max(axis=0)
        history = []  # backward errors of the earlier iterates
        for it in range(max_iter + 1):
            r = rhs - K @ x
            scale = Knorm * np.abs(x).max(axis=0) + bnorm
            err = np.max(np.abs(r).max(axis=0) / np.where(scale > 0, scale, 1.0))
            if err <= self.rtol:
                self.stats["solve_s"] += time.perf_counter() - t0
                return x
            # A NaN backward error (a singular factor) does not recover by refining.
            if it == max_iter or not np.isfinite(err) or (rate is not None and it >= patience
                                                          and err > rate * history[-patience]):
                break
            history.append(err)
            x = x + lu.solve(r)
            self.stats["iterations"] += 1
        self.stats["solve_s"] += time.perf_counter() - t0
        if strict:
            how = ("gave a non-finite iterate after" if not np.isfinite(err) else
                   "did not converge in" if it == max_iter else "stalled after")
            raise np.linalg.LinAlgError(f"iterative refinement {how} {it} steps at backward error {err:.2e} > "
                                        f"{self.rtol:.0e} (K far from symmetric, or singular)")
        # With a fresh factorization the refinement floor is round-off: keep the refined x (a
        # numerically singular K shows up as a Newton failure, reported with the step).
        return None if rate is not None else x

    def try_solve(self, *args, keep: bool = False):
        """`host_solve` with NaN (on the host, as `hyperoc.solvers.host_newton`'s callers use it) for a singular
        matrix (SuperLU), a tangent or residual with NaN or Inf entries (an iterate with inverted elements), a
        refinement that fails (PARDISO) or a MINRES failure: JAX leaves an exception raised inside
        ``jax.pure_callback`` (`solve`) undefined, while NaN makes Newton fail, so the caller cuts the load step
        back or raises `SolverError` naming the step. ``stats["failed"]`` counts these, and ``last_failure``
        keeps the message."""
        return self._or_nan(lambda: self.host_solve(*args, keep=True) if keep else self.host_solve(*args))

    def _or_nan(self, solve):
        try:
            return solve()
        except (RuntimeError, np.linalg.LinAlgError) as err:
            self.stats["failed"] += 1
            self.last_failure = str(err)
            return np.full(self.n + 1, np.nan)

    def _callback(self, fn, *args):
        out = jax.pure_callback(fn, jax.ShapeDtypeStruct((self.n + 1,), jnp.float64), *args)
        return out[:-1], out[-1]

    def solve(self, blocks, col, row, r_u, r_c, corner=0.0, lowrank=None):
        """The bordered solve ``(x (n,), q)`` with ``K + U W U^T`` for ``lowrank = (U (n, k), W (k, k))``
        (None: K), traced: `host_solve` through ``jax.pure_callback`` (None adds no operand)."""
        return self._callback(self.try_solve, blocks, col, row, r_u, r_c, jnp.asarray(corner, jnp.float64),
                              lowrank)

    @property
    def chord(self) -> bool:
        """Whether `refresh_solve` / `kept_solve` are available (every method with a factorization)."""
        return not isinstance(self.backend, MinresBackend)

    def refresh_solve(self, blocks, col, row, r_u, r_c, corner=0.0, lowrank=None):
        """`solve`, keeping this Jacobian (the factorization of K, ``K_full^-1 col``, ``row``, the corner and,
        with ``lowrank``, ``Z = K^-1 U`` and ``(I_k + W U^T Z)^-1 W``) for `kept_solve` (chord Newton, traced).
        A refresh without ``lowrank`` keeps none."""
        return self._callback(lambda *a: self.try_solve(*a, keep=True), blocks, col, row, r_u, r_c,
                              jnp.asarray(corner, jnp.float64), lowrank)

    def kept_solve(self, r_u, r_c):
        """The bordered solve with the Jacobian of the last `refresh_solve`, its low-rank term included
        (traced); NaN if there is none yet, which asks the chord iteration for a refresh (not counted as a failure)."""
        return self._callback(self.try_kept_solve, r_u, r_c)

    def try_kept_solve(self, r_u, r_c):
        """The host part of `kept_solve`: ``(x, q)`` as one array (n + 1,), NaN without a kept Jacobian or when the
        solve fails."""
        if self._kept is None:
            return np.full(self.n + 1, np.nan)
        return self._or_nan(lambda: self._on_worker(self._host_kept_solve, r_u, r_c))


def _checked_rhs(rhs) -> np.ndarray:
    """The right-hand sides as a float64 array; ``LinAlgError`` if not finite (an iterate outside the
    energy's domain: no factorization can help, and PARDISO corrupts its heap on such values,
    `hyperoc.solvers.pardiso`)."""
    rhs = np.asarray(rhs, dtype=np.float64)
    if not np.isfinite(rhs).all():
        raise np.linalg.LinAlgError("the tangent or the residual has non-finite entries (NaN or Inf)")
    return rhs


def _unpermuted(ab, q):
    """``ab`` solved in the ordering ``q`` (new -> old index) back in the original numbering."""
    if q is None:
        return ab
    out = np.empty_like(ab)
    out[q] = ab
    return out


def _bordered(ab, row, r_c, corner=0.0) -> np.ndarray:
    """`eliminate_border` on the host, as one array ``(x, q)`` (n + 1,)."""
    x, q = eliminate_border(ab, np.asarray(row, dtype=np.float64), float(r_c), corner=float(corner))
    return np.concatenate([x, [q]])


def _backend(method: str, pattern, stats: dict, *, rtol, ordering, pivot_thresh, fallback_thresh):
    """The backend of a method string (`SparseSolver`): SuperLU, PARDISO (double or single) or MINRES."""
    if method == "minres":
        return MinresBackend(pattern, stats, rtol=rtol)
    if method.startswith("pardiso"):
        return PardisoBackend(pattern, stats, single=method.startswith("pardiso_single"))
    return SuperLUBackend(pattern, stats, ordering=ordering, pivot_thresh=pivot_thresh,
                          fallback_thresh=fallback_thresh)


def make_solver(model, kind: str = "auto"):
    """``"auto"``: tridiagonal for 1D P1, sparse LU otherwise. The dense LU is never faster than the
    sparse one, compilation included, and up to several times slower from a few hundred dofs
    (``python bench/bench_auto_solver.py``); it stays available as ``"dense"``."""
    if kind == "auto":
        kind = "tridiagonal" if model.dim == 1 and model.space.degree == 1 else "lu"
    if kind == "tridiagonal":
        return TridiagonalSolver(model)
    if kind == "dense":
        return DenseSolver(model)
    if kind in SparseSolver.methods:
        return SparseSolver(model, kind)
    raise InputError(f"unknown linear solver {kind!r} (auto, tridiagonal, dense, {', '.join(SparseSolver.methods)})")

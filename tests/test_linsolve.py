"""The sparse bordered solver of `hyperoc.solvers.linsolve`: the pressure-bordered Newton system

    [ K    col ] [du]   [r_u]
    [ row   0  ] [dp] = [r_c]

assembled from element blocks and solved on the host (SuperLU / MINRES) from inside jitted code.

- Every method agrees with a dense solve of the bordered system to the solver's backward-error
  tolerance ``rtol`` times the condition number (well conditioned here: K is an SPD mass-like
  matrix, so the bound is a few ulps times ``cond(K) ~ 10``; asserted 1e-10 relative).
- The nested-dissection order is a permutation of the dofs, and the LU of the permuted K solves the
  original system (both orderings, checked against the dense solve).
- A singular K does not raise inside ``jax.pure_callback`` (JAX leaves an exception there undefined;
  it hung the traced Newton loop when the process had one CPU): the solve returns NaN, which makes
  Newton fail with the step named, and the solver counts and keeps the failure.
- On an indefinite saddle point (Taylor-Hood at bulk_modulus = inf: a zero pressure block) the default
  diagonal pivots and refinement reach the solver's normwise backward error ``rtol`` on the
  bordered system, so the solution agrees with a dense solve to the forward-error bound
  ``2 cond_inf(A) rtol`` (relative, inf-norm).
- Tiny diagonal pivots (kept by the default ``pivot_thresh = 0``) leave the refinement short of
  ``rtol``; the solver then factors again with threshold partial pivoting and still meets the bound.
- Host solves run with one OpenBLAS thread (its spinning threads would take XLA's cores), and leave
  OpenBLAS's thread count as it was.
- The tridiagonal solver (1D P1) agrees with the dense LU on any numbering along the line (points in
  descending order, cells shuffled, both ends held): two direct solves of a well-conditioned
  system, so to a few ulps times cond(K) (asserted 1e-12 relative).
- A dense symmetric low-rank term ``K + U W U^T`` (``lowrank=(U, W)``, rank 2 dim: a cavity's lid through
  its rim's centroid) enters the dense solve, every sparse method's (by the Woodbury identity on the
  factorization of K), the transposed one (col and row swapped: the adjoint's) and the chord iteration's
  kept solve, traced or not, also with a singular W; the dense solves of K_full agree with them to
  1e-10 relative (cond_2 of K_full and of ``I + W U^T K^-1 U`` checked below 1e3, so the solver's
  backward error 1e-13 amplifies to 1e-10 at most). Without the term every solve is bitwise as before,
  and the tridiagonal solver refuses one.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.errors import InputError
from hyperoc.fem.mesh import Mesh, box, interval
from hyperoc.mechanics.materials import Guccione, SaintVenantKirchhoff
from hyperoc.mechanics.mixed import TaylorHoodModel
from hyperoc.mechanics.model import StateModel
from hyperoc.solvers.linsolve import DenseSolver, SparseSolver, TridiagonalSolver, nested_dissection
from hyperoc.solvers.pardiso import available as pardiso_available


@pytest.fixture(scope="module")
def model():
    return StateModel(box(2, dirichlet="left"), SaintVenantKirchhoff(1.0, 1.0), damping=0.05)


def spd_blocks(model, seed=0):
    """Element blocks ``B B^T + k I`` (SPD each, so the assembled K is SPD)."""
    nc, k, _ = model.pattern.element_shape
    B = np.random.default_rng(seed).standard_normal((nc, k, k)) / np.sqrt(k)
    return B @ np.swapaxes(B, 1, 2) + k * np.eye(k)


def bordered_rhs(model, seed=1):
    rng = np.random.default_rng(seed)
    return rng.standard_normal(model.n), rng.standard_normal(model.n), rng.standard_normal(model.n), 0.3


def bordered_matrix(model, blocks, col, row, corner=0.0, lowrank=None):
    """``[[K, col], [row, corner]]`` (n + 1, n + 1), with ``K + U W U^T`` for ``lowrank = (U, W)``."""
    K = model.pattern.matrix(blocks).toarray()
    if lowrank is not None:
        U, W = lowrank
        K = K + U @ W @ U.T
    return np.block([[K, col[:, None]], [row[None, :], np.full((1, 1), corner)]])


def dense_bordered_solve(model, blocks, col, row, r_u, r_c, corner=0.0, lowrank=None):
    return np.linalg.solve(bordered_matrix(model, blocks, col, row, corner, lowrank), np.concatenate([r_u, [r_c]]))


def solve_within_forward_error_bound(model, solver, blocks):
    """Solve with ``solver``; assert the normwise backward error is ``<= rtol`` and the error against a
    dense solve ``<= 2 cond_inf(A) rtol`` (relative); return the solver."""
    col, row, r_u, r_c = bordered_rhs(model)
    A = bordered_matrix(model, blocks, col, row)
    b = np.concatenate([r_u, [r_c]])
    expected = np.linalg.solve(A, b)
    x = solver.host_solve(blocks, col, row, r_u, r_c)
    backward = np.abs(A @ x - b).max() / (np.abs(A).sum(axis=1).max() * np.abs(x).max() + np.abs(b).max())
    assert backward <= solver.rtol
    bound = 2 * np.linalg.cond(A, np.inf) * solver.rtol
    assert np.abs(x - expected).max() <= bound * np.abs(expected).max()
    return solver


@pytest.mark.parametrize("ordering", SparseSolver.orderings)
@pytest.mark.parametrize("method", SparseSolver.methods)
def test_sparse_methods_match_a_dense_bordered_solve(model, method, ordering):
    blocks = spd_blocks(model)
    col, row, r_u, r_c = bordered_rhs(model)
    expected = dense_bordered_solve(model, blocks, col, row, r_u, r_c)
    solver = SparseSolver(model, method, ordering=ordering)
    for _ in range(2):  # the second call runs on the kept ordering (and kept factorization for lu_reuse)
        x = solver.host_solve(blocks, col, row, r_u, r_c)
        np.testing.assert_allclose(x, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())
    assert solver.stats["calls"] == 2 and solver.stats["failed"] == 0


@pytest.mark.parametrize("method", ["dense", "lu", "minres"])
def test_a_corner_enters_every_bordered_solve_and_the_kept_one(model, method):
    """With a corner d (a row that depends on the multiplier), the traced solve, the refreshed one and the
    chord iteration's kept solve (its corner kept with the Jacobian) all agree with a dense solve of
    ``[[K, col], [row, d]]`` to 1e-10 relative (K SPD, cond ~ 10; d of the size of ``row . K^-1 col``)."""
    blocks = spd_blocks(model)
    col, row, r_u, r_c = bordered_rhs(model)
    corner = -0.7 * abs(row @ np.linalg.solve(model.pattern.matrix(blocks).toarray(), col))
    expected = dense_bordered_solve(model, blocks, col, row, r_u, r_c, corner)
    without = dense_bordered_solve(model, blocks, col, row, r_u, r_c)
    assert np.abs(expected - without).max() > 1e-3 * np.abs(expected).max()  # the corner matters here
    solver = DenseSolver(model) if method == "dense" else SparseSolver(model, method)
    args = tuple(jnp.asarray(a) for a in (blocks, col, row, r_u)) + (r_c, corner)
    solves = [jax.jit(solver.solve)(*args)]
    if getattr(solver, "chord", False):
        solves += [jax.jit(solver.refresh_solve)(*args), jax.jit(solver.kept_solve)(args[3], r_c)]
    for du, dp in solves:
        x = np.concatenate([np.asarray(du), [float(dp)]])
        np.testing.assert_allclose(x, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())


def test_singular_matrix_gives_nan_from_the_traced_solve(model):
    solver = SparseSolver(model, "lu")
    col, row, r_u, r_c = bordered_rhs(model)
    blocks = np.zeros(model.pattern.element_shape)
    du, dp = jax.jit(solver.solve)(jnp.asarray(blocks), jnp.asarray(col), jnp.asarray(row), jnp.asarray(r_u), r_c)
    assert np.all(np.isnan(np.asarray(du))) and np.isnan(float(dp))
    assert solver.stats["failed"] == 1
    assert "singular" in solver.last_failure.lower()
    # A later regular solve works again.
    x = solver.host_solve(spd_blocks(model), col, row, r_u, r_c)
    assert np.all(np.isfinite(x))


def check_non_finite_tangent_fails_cleanly(model, method):
    """A tangent with NaN or Inf entries (a Newton iterate with inverted elements) gives NaN from the
    traced solve and says why, also when a factorization is kept from an earlier call; the solver
    works again afterwards."""
    solver = SparseSolver(model, method)
    col, row, r_u, r_c = bordered_rhs(model)
    good = spd_blocks(model)
    solve = jax.jit(solver.solve)
    args = (jnp.asarray(col), jnp.asarray(row), jnp.asarray(r_u), r_c)
    assert np.all(np.isfinite(np.asarray(solve(jnp.asarray(good), *args)[0])))
    for failures, bad_value in enumerate((np.nan, np.inf), start=1):
        bad = good.copy()
        bad[:, 0, 0] = bad_value  # in every element: some of these entries are free dofs' (not dropped)
        du, dp = solve(jnp.asarray(bad), *args)
        assert np.all(np.isnan(np.asarray(du))) and np.isnan(float(dp))
        assert solver.stats["failed"] == failures and "non-finite" in solver.last_failure
    assert np.all(np.isfinite(np.asarray(solve(jnp.asarray(good), *args)[0])))


@pytest.mark.parametrize("method", ["lu", "lu_reuse", "minres"])
def test_non_finite_tangent_fails_cleanly(model, method):
    check_non_finite_tangent_fails_cleanly(model, method)


def test_nested_dissection_is_a_permutation_of_the_dofs():
    model = StateModel(box(4, dirichlet="left"), SaintVenantKirchhoff(1.0, 1.0), degree=2)
    q = nested_dissection(model.pattern)
    assert q.shape == (model.n,)
    np.testing.assert_array_equal(np.sort(q), np.arange(model.n))


def test_unknown_ordering_is_an_input_error(model):
    from hyperoc.errors import InputError

    with pytest.raises(InputError, match="ordering"):
        SparseSolver(model, "lu", ordering="amd")


def taylor_hood_saddle_point():
    """A Taylor-Hood model at bulk_modulus = inf and its tangent blocks at a perturbed state (indefinite, with a
    zero pressure block)."""
    model = TaylorHoodModel(box(2, dirichlet="left"), Guccione(bulk_modulus=0.0), bulk_modulus=np.inf,
                            frames=lambda x: np.broadcast_to(np.eye(3), x.shape[:-1] + (3, 3)))
    rng = np.random.default_rng(2)
    x0 = jnp.asarray(model.unknowns(0.02 * rng.standard_normal(model.n_u), rng.standard_normal(model.n_p)))
    return model, np.asarray(model.tangent_blocks(x0, 1.0, 0.0))


@pytest.mark.slow
def test_saddle_point_solve_meets_the_forward_error_bound():
    model, blocks = taylor_hood_saddle_point()
    solver = solve_within_forward_error_bound(model, SparseSolver(model, "lu"), blocks)
    assert solver.stats["fill"] > 0 and solver.stats["pivoting_fallbacks"] == 0


def test_tiny_diagonal_pivots_fall_back_to_partial_pivoting(model):
    nc, k, _ = model.pattern.element_shape
    P = np.random.default_rng(3).standard_normal((nc, k, k))
    blocks = P + np.swapaxes(P, 1, 2)
    blocks[:, np.arange(k), np.arange(k)] = 1e-12  # indefinite, nonsingular, with pivots 1e-12 of the column
    solver = solve_within_forward_error_bound(model, SparseSolver(model, "lu"), blocks)
    assert solver.stats["pivoting_fallbacks"] == 1 and solver.stats["off_diagonal_pivots"] > 0


def test_factorizations_live_and_die_on_the_solver_thread(model, monkeypatch):
    """scipy's SuperLU never releases a factorization freed on another thread than its own (scipy
    #15921), and ``jax.pure_callback`` may call from any thread: every factorization must be built,
    used and freed on the solver's worker, whichever thread calls (here: two other threads, with a
    kept ``lu_reuse`` factorization refreshed in between)."""
    import threading
    import weakref

    import hyperoc.solvers.backends as backends

    built, freed = [], []

    class TracedLU:  # SuperLU has no weak references: wrap it to see where it is freed
        def __init__(self, lu):
            self._lu = lu
            built.append(threading.get_ident())
            weakref.finalize(self, lambda: freed.append(threading.get_ident()))

        def __getattr__(self, name):
            return getattr(self._lu, name)

    real = backends.spla.splu
    monkeypatch.setattr(backends.spla, "splu", lambda *a, **k: TracedLU(real(*a, **k)))
    solver = SparseSolver(model, "lu_reuse", reuse_max_iter=0)  # no refinement: each call refreshes
    col, row, r_u, r_c = bordered_rhs(model)
    for seed in (0, 1, 2):
        caller = threading.Thread(target=solver.host_solve, args=(spd_blocks(model, seed), col, row, r_u, r_c))
        caller.start()
        caller.join()
    worker = solver._worker
    del solver  # __del__ submits the release of the kept factorization to the worker
    worker.shutdown(wait=True)
    assert len(built) == 3 and len(freed) == 3
    assert len(set(built) | set(freed)) == 1 and built[0] != threading.get_ident()


def test_large_dirichlet_laplace_solve_by_amg_cg_meets_its_residual_and_error_bounds():
    """`hyperoc.fem.assembly.solve_dirichlet` above `DIRECT_LIMIT` free dofs (P1 box, 23^3 = 12,167
    interior vertices): AMG-preconditioned CG stops at relative residual 1e-12, so the error to the
    exact discrete solution, here the linear Dirichlet data itself (harmonic and in P1), is at most
    ``cond_2(K_ff) * 1e-12`` relative in the 2-norm (the fallback LU would meet it with room)."""
    import scipy.sparse.linalg as spla

    from hyperoc.fem.assembly import DIRECT_LIMIT, SparsePattern, reduced_numbering, solve_dirichlet
    from hyperoc.fem.spaces import VectorSpace

    mesh = box(24)
    space = VectorSpace(mesh, 1, components=1)
    X = mesh.points
    boundary = np.flatnonzero(np.any((X < 1e-12) | (X > 1 - 1e-12), axis=1))
    exact = 1.0 + X @ np.array([2.0, -3.0, 0.5])
    x = solve_dirichlet(space.laplace_blocks(), mesh.cells, len(X), boundary, exact[boundary])
    free, to_reduced = reduced_numbering(len(X), boundary)
    assert free.size > DIRECT_LIMIT
    K = SparsePattern(to_reduced[mesh.cells], free.size).matrix(space.laplace_blocks()).tocsc()
    extreme = lambda **kw: float(spla.eigsh(K, k=1, return_eigenvectors=False, **kw)[0])
    cond = extreme(which="LA") / extreme(sigma=0.0, which="LM")
    error = np.linalg.norm(x[free] - exact[free]) / np.linalg.norm(exact[free])
    print(f"\nn = {free.size}, cond_2 = {cond:.0f}, relative error {error:.2e}")
    assert error <= cond * 1e-12
    assert np.array_equal(x[boundary], exact[boundary])


def test_first_call_fallback_with_minimum_degree_keeps_the_minimum_degree_ordering(model):
    """``ordering="mmd"`` takes its ordering from the first factorization; when that first call falls
    back to partial pivoting, K is still in the original numbering and must be ordered again, not
    factored in the original numbering (which on this box stores more fill)."""
    import scipy.sparse.linalg as spla

    nc, k, _ = model.pattern.element_shape
    P = np.random.default_rng(3).standard_normal((nc, k, k))
    blocks = P + np.swapaxes(P, 1, 2)
    blocks[:, np.arange(k), np.arange(k)] = 1e-12
    solver = solve_within_forward_error_bound(model, SparseSolver(model, "lu", ordering="mmd"), blocks)
    assert solver.stats["pivoting_fallbacks"] == 1
    K = model.pattern.matrix(blocks).tocsc()
    expected = spla.splu(K, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=solver.backend.fallback_thresh,
                         options={"SymmetricMode": True}).nnz
    natural = spla.splu(K, permc_spec="NATURAL", diag_pivot_thresh=solver.backend.fallback_thresh,
                        options={"SymmetricMode": True}).nnz
    print(f"\nfill of the fallback: {solver.stats['fill']}, minimum degree {expected}, original numbering {natural}")
    assert solver.stats["fill"] == expected < natural


class _NaNFactor:
    """A factorization whose solves are NaN (a singular factor: zero pivots divide)."""

    def solve(self, rhs):
        return np.full_like(rhs, np.nan)


@pytest.mark.parametrize("rate", [None, 0.25])
def test_refinement_stops_at_a_non_finite_iterate(model, rate):
    """Refining cannot recover a NaN iterate: no refinement step is taken; a strict refinement
    (PARDISO's perturbed factor) says so, a kept factorization (``rate``) is given up (None)."""
    solver = SparseSolver(model, "lu")
    K = model.pattern.matrix(spd_blocks(model)).tocsr()
    rhs = np.ones(K.shape[0])
    result = solver._solve_refined(K, rhs, _NaNFactor(), max_iter=50, rate=rate)
    assert (result is None) if rate else np.all(np.isnan(result))
    with pytest.raises(np.linalg.LinAlgError, match="non-finite iterate after 0 steps"):
        solver._solve_refined(K, rhs, _NaNFactor(), max_iter=50, rate=rate, strict=True)
    assert solver.stats["iterations"] == 0


@pytest.mark.parametrize("held", [["gamma_d"], ["gamma_d", "gamma_n"]])
def test_tridiagonal_solve_matches_the_dense_solve_on_any_numbering_along_the_line(held):
    n = 12
    x = np.linspace(1.0, 0.0, n + 1)[:, None]  # points numbered from the right end
    cells = np.random.default_rng(2).permutation(np.stack([np.arange(1, n + 1), np.arange(n)], axis=1))
    boundaries = {"gamma_d": [[n]], "gamma_n": [[0]], "ends": [[0], [n]]}
    mesh = Mesh(x, cells, boundaries)
    model = StateModel(mesh, SaintVenantKirchhoff(1.0, 1.0), dirichlet="ends" if len(held) == 2 else "gamma_d")
    blocks = spd_blocks(model) + 0.1 * np.random.default_rng(3).standard_normal(model.pattern.element_shape)
    col, row, r_u, r_c = bordered_rhs(model)
    expected = DenseSolver(model).solve(jnp.asarray(blocks), col, row, r_u, r_c)
    got = TridiagonalSolver(model).solve(jnp.asarray(blocks), col, row, r_u, r_c)
    scale = np.abs(expected[0]).max()
    np.testing.assert_allclose(got[0], expected[0], rtol=0, atol=1e-12 * scale)
    assert abs(float(got[1] - expected[1])) <= 1e-12 * abs(float(expected[1]))


def _openblas_threads():
    from threadpoolctl import threadpool_info

    return {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["internal_api"] == "openblas"}


def test_host_solves_run_with_one_openblas_thread(model, monkeypatch):
    """During a host solve (on the solver's worker thread) every OpenBLAS library runs one thread, and
    afterwards its thread count is the one it had; ``blas_threads = None`` leaves it as it is set."""
    from hyperoc.solvers import backends

    before = _openblas_threads()
    if not before:
        pytest.skip("no OpenBLAS loaded")
    seen = []
    splu = backends.spla.splu
    monkeypatch.setattr(backends.spla, "splu", lambda *a, **k: seen.append(_openblas_threads()) or splu(*a, **k))
    solver = SparseSolver(model, "lu")
    solve_within_forward_error_bound(model, solver, spd_blocks(model))
    assert seen and all(set(threads.values()) == {1} for threads in seen)
    assert _openblas_threads() == before
    solver.blas_threads = None
    seen.clear()
    solve_within_forward_error_bound(model, solver, spd_blocks(model, seed=2))
    assert seen and all(threads == before for threads in seen)


PARDISO = pytest.param("pardiso", marks=pytest.mark.skipif(not pardiso_available(), reason="MKL is not installed"))


def low_rank_term(model, blocks, rank, seed=1):
    """``(U, W)``: U (n, 2 dim) with columns of unit size and W (2 dim, 2 dim) symmetric of ``rank``, with
    ``|W| ~ |K|_2`` (the term changes the solution by O(1) and makes K_full indefinite); asserts that K_full
    and ``I + W U^T K^-1 U`` (the Woodbury identity's small matrix) have cond_2 below 1e3."""
    k = 2 * model.dim
    rng = np.random.default_rng(seed)
    K = model.pattern.matrix(blocks).toarray()
    U = rng.standard_normal((model.n, k)) / np.sqrt(model.n)
    V = np.linalg.qr(rng.standard_normal((k, k)))[0][:, :rank]
    W = 0.3 * np.linalg.norm(K, 2) * V @ np.diag(rng.standard_normal(rank)) @ V.T
    assert np.linalg.matrix_rank(W) == rank
    assert np.linalg.cond(K + U @ W @ U.T) < 1e3
    assert np.linalg.cond(np.eye(k) + W @ U.T @ np.linalg.solve(K, U)) < 1e3
    return U, W


def bordered_solver(model, method):
    return DenseSolver(model) if method == "dense" else SparseSolver(model, method)


def as_solution(du, dp):
    return np.concatenate([np.asarray(du), [float(dp)]])


def assert_close(x, expected):
    np.testing.assert_allclose(x, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())


@pytest.mark.parametrize("rank", [6, 4])  # 2 dim, and a singular W
@pytest.mark.parametrize("method", ["dense", "lu", "lu_reuse", "minres", PARDISO])
def test_a_low_rank_term_enters_the_bordered_solve_and_its_transpose(model, method, rank):
    """With ``lowrank = (U, W)`` the solve, eager and jitted, is the dense solve of
    ``[[K + U W U^T, col], [row, d]]``, and the one with col and row swapped is the solve with that
    matrix's transpose (the adjoint's: W symmetric, K symmetric here); the term matters (O(1))."""
    blocks = spd_blocks(model)
    col, row, r_u, r_c = bordered_rhs(model)
    corner = -0.3
    lowrank = low_rank_term(model, blocks, rank)
    b = np.concatenate([r_u, [r_c]])
    A = bordered_matrix(model, blocks, col, row, corner, lowrank)
    with_term, without = np.linalg.solve(A, b), dense_bordered_solve(model, blocks, col, row, r_u, r_c, corner)
    assert np.abs(with_term - without).max() > 0.1 * np.abs(with_term).max()
    solver = bordered_solver(model, method)
    traced_lowrank = tuple(jnp.asarray(a) for a in lowrank)
    for c, r, matrix in ((col, row, A), (row, col, A.T)):
        expected = np.linalg.solve(matrix, b)
        args = tuple(jnp.asarray(a) for a in (blocks, c, r, r_u)) + (r_c, corner)
        for solve in (solver.solve, jax.jit(solver.solve)):
            assert_close(as_solution(*solve(*args, lowrank=traced_lowrank)), expected)


@pytest.mark.parametrize("method", ["lu", "lu_reuse", PARDISO])
def test_the_kept_solve_uses_the_low_rank_term_of_its_refresh(model, method):
    """Chord Newton: after ``refresh_solve`` with ``lowrank``, ``kept_solve`` of new right-hand sides solves
    with the whole kept K_full (no new factorization); after a refresh without it, with K alone."""
    blocks = spd_blocks(model)
    col, row, r_u, r_c = bordered_rhs(model)
    r_u2, r_c2 = np.random.default_rng(5).standard_normal(model.n), -0.8
    corner = -0.3
    lowrank = low_rank_term(model, blocks, 2 * model.dim)
    solver = SparseSolver(model, method)
    refresh, kept = jax.jit(solver.refresh_solve), jax.jit(solver.kept_solve)
    args = tuple(jnp.asarray(a) for a in (blocks, col, row, r_u)) + (r_c, corner)
    for term in (lowrank, None):
        expected = dense_bordered_solve(model, blocks, col, row, r_u, r_c, corner, term)
        expected2 = dense_bordered_solve(model, blocks, col, row, r_u2, r_c2, corner, term)
        assert_close(as_solution(*refresh(*args, lowrank=term)), expected)
        factorizations = solver.stats["factorizations"]
        assert_close(as_solution(*kept(jnp.asarray(r_u2), r_c2)), expected2)
        assert solver.stats["factorizations"] == factorizations
    assert solver.stats["kept_solves"] == 2


@pytest.mark.parametrize("method", ["dense", "lu", "lu_reuse", "minres", PARDISO])
def test_without_a_low_rank_term_the_solves_are_bitwise_unchanged(model, method):
    """``lowrank=None`` traces the same program (the same operations on the same shapes, the host callback's
    operands included) and gives bitwise the results of the call without it, on two solvers taking the
    same calls (the second solve of "lu_reuse" refines its kept factorization; chord: refresh, kept)."""
    blocks = spd_blocks(model)
    col, row, r_u, r_c = bordered_rhs(model)
    args = tuple(jnp.asarray(a) for a in (blocks, col, row, r_u)) + (r_c, -0.3)
    plain, with_none = bordered_solver(model, method), bordered_solver(model, method)
    names = ["solve", "solve"] + (["refresh_solve"] if getattr(plain, "chord", False) else [])
    for name in names:
        ops = [[(e.primitive, [v.aval for v in e.invars]) for e in jax.make_jaxpr(fn)(*args).eqns]
               for fn in (getattr(plain, name), lambda *a: getattr(with_none, name)(*a, lowrank=None))]
        assert ops[0] == ops[1]
        got = [as_solution(*jax.jit(getattr(plain, name))(*args)),
               as_solution(*jax.jit(getattr(with_none, name))(*args, lowrank=None))]
        np.testing.assert_array_equal(got[0], got[1])
    if names[-1] == "refresh_solve":
        np.testing.assert_array_equal(as_solution(*plain.kept_solve(args[3], r_c)),
                                      as_solution(*with_none.kept_solve(args[3], r_c)))


def test_the_tridiagonal_solver_refuses_a_low_rank_term():
    """A 1D P1 line has no cavity: a low-rank term is an `InputError` when the solve is traced."""
    model = StateModel(interval(6), SaintVenantKirchhoff(1.0, 1.0))
    blocks = spd_blocks(model)
    col, row, r_u, r_c = bordered_rhs(model)
    lowrank = (np.ones((model.n, 2)), np.eye(2))
    with pytest.raises(InputError, match="low-rank"):
        TridiagonalSolver(model).solve(jnp.asarray(blocks), col, row, r_u, r_c, lowrank=lowrank)

"""MKL PARDISO's symmetric indefinite factorization (hyperoc.solvers.pardiso) and the solver methods on it
(`SparseSolver` ``"pardiso"``, ``"pardiso_reuse"`` and their single-precision factorizations).

- A saddle point ``[[A, B^T], [B, 0]]`` with A (n x n) SPD and B (m x n) of full rank has inertia
  (n positive, m negative) (Sylvester: it is congruent to ``diag(A, -B A^-1 B^T)``); PARDISO reports it,
  and its solve agrees with a dense one to the forward-error bound ``cond_inf rtol`` with its own
  refinement's floor (a few ulps amplified by cond: asserted with 100 eps cond).
- Through `SparseSolver`, on the Taylor-Hood saddle point and on symmetric indefinite blocks with tiny
  diagonal pivots (where SuperLU needs its partial-pivoting fallback), the bordered solve meets the
  normwise backward error ``rtol`` and the forward-error bound ``2 cond_inf(A) rtol``.
- K not symmetric: PARDISO factors ``(K + K^T) / 2``, refined against K itself. A skew part well below
  the symmetric one (relative 1e-3: the refinement contracts by about that per step) is solved to the
  same bounds, and so is one that contracts slowly (0.4 per step: more steps than the old cap of 8);
  a skew part comparable to the symmetric one makes the refinement stall, and the solve fails (NaN from
  the traced solve, the message kept), never returning an inaccurate answer.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp

from hyperoc.solvers.linsolve import SparseSolver
from hyperoc.solvers.pardiso import PardisoLDL, available
from test_linsolve import (
    bordered_rhs,
    check_non_finite_tangent_fails_cleanly,
    model,  # noqa: F401  (the fixture)
    solve_within_forward_error_bound,
    spd_blocks,
    taylor_hood_saddle_point,
)

pytestmark = pytest.mark.skipif(not available(), reason="MKL (pip install mkl) is not installed")
EPS = np.finfo(float).eps


def saddle_point(n=300, m=60, seed=0):
    rng = np.random.default_rng(seed)
    A = sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(n, n))  # SPD: eigenvalues in (0.5, 4.5)
    B = sp.random(m, n, density=0.05, random_state=seed) + sp.eye(m, n)  # full rank
    return sp.bmat([[A, B.T], [B, None]]).tocsr(), rng


def test_inertia_and_solve_of_a_saddle_point():
    K, rng = saddle_point()
    lu = PardisoLDL(sp.triu(K).tocsr())
    assert lu.inertia == (300, 60) and lu.nnz > 0 and lu.memory_mb > 0
    Kd = K.toarray()
    b = rng.standard_normal((K.shape[0], 2))
    bound = 100 * EPS * np.linalg.cond(Kd, np.inf)
    for rhs in (b, b[:, 0]):  # (n, k) and (n,)
        x = lu.solve(rhs)
        expected = np.linalg.solve(Kd, rhs)
        assert x.shape == rhs.shape
        assert np.abs(x - expected).max() <= bound * np.abs(expected).max()
    lu.free()
    lu.free()  # idempotent


@pytest.mark.parametrize("single", [False, True])
def test_non_finite_values_never_reach_pardiso(single):
    """PARDISO corrupted its heap on a matrix with Inf entries (process aborted): such a matrix or
    right-hand side is refused with LinAlgError, in the precision PARDISO would get (a double of
    1e39 is Inf in single precision), and a factor stays usable after a refused right-hand side."""
    K, rng = saddle_point()
    upper = sp.triu(K).tocsr()
    bad_values = (np.nan, np.inf, -np.inf) + ((1e39,) if single else ())
    for bad in bad_values:
        U = upper.copy()
        U.data[5] = bad
        with pytest.raises(np.linalg.LinAlgError, match="matrix has non-finite"):
            PardisoLDL(U, single=single)
    lu = PardisoLDL(upper, single=single)
    b = rng.standard_normal(K.shape[0])
    for bad in bad_values:
        with pytest.raises(np.linalg.LinAlgError, match="right-hand side has non-finite"):
            lu.solve(np.where(np.arange(b.size) == 3, bad, b))
    Kd = K.toarray()
    expected = np.linalg.solve(Kd, b)
    unit = np.finfo(np.float32 if single else np.float64).eps  # the bounds of the two tests above
    assert np.abs(lu.solve(b) - expected).max() <= 100 * unit * np.linalg.cond(Kd, np.inf) * np.abs(expected).max()
    lu.free()


@pytest.mark.parametrize("method", ["pardiso", "pardiso_reuse", "pardiso_single", "pardiso_single_reuse"])
def test_non_finite_tangent_fails_cleanly_with_pardiso(model, method):  # noqa: F811
    check_non_finite_tangent_fails_cleanly(model, method)


@pytest.mark.parametrize("method", ["pardiso", "pardiso_reuse", "pardiso_single", "pardiso_single_reuse"])
def test_taylor_hood_saddle_point(method):
    th_model, blocks = taylor_hood_saddle_point()
    solver = solve_within_forward_error_bound(th_model, SparseSolver(th_model, method), blocks)
    assert solver.stats["fill"] > 0 and solver.stats["failed"] == 0


def test_single_precision_factor_alone_solves_only_to_single_precision():
    """The single-precision factor's solve is off by about ``cond * 6e-8`` (far above the double one's
    ``100 eps cond``) but within ``100 * 6e-8 * cond`` of the exact solution; refinement against the
    double-precision K is what brings it to ``rtol`` (`test_taylor_hood_saddle_point`)."""
    K, rng = saddle_point()
    lu = PardisoLDL(sp.triu(K).tocsr(), single=True)
    assert lu.inertia == (300, 60)
    Kd = K.toarray()
    b = rng.standard_normal(K.shape[0])
    expected, cond = np.linalg.solve(Kd, b), np.linalg.cond(Kd, np.inf)
    x = lu.solve(b)
    error = np.abs(x - expected).max() / np.abs(expected).max()
    assert x.dtype == np.float64
    assert 100 * EPS * cond < error <= 100 * np.finfo(np.float32).eps * cond


def test_tiny_diagonal_pivots(model):  # noqa: F811
    nc, k, _ = model.pattern.element_shape
    P = np.random.default_rng(3).standard_normal((nc, k, k))
    blocks = P + np.swapaxes(P, 1, 2)
    blocks[:, np.arange(k), np.arange(k)] = 1e-12  # as in test_linsolve: SuperLU falls back to pivoting there
    solver = solve_within_forward_error_bound(model, SparseSolver(model, "pardiso"), blocks)
    assert solver.stats["failed"] == 0 and solver.stats["factorizations"] == 1


def skewed_blocks(model, size):  # noqa: F811
    """SPD blocks plus a skew-symmetric part of relative ``size``."""
    S = np.random.default_rng(5).standard_normal(model.pattern.element_shape)
    blocks = spd_blocks(model)
    return blocks + size * np.abs(blocks).max() * (S - np.swapaxes(S, 1, 2))


def test_a_slightly_nonsymmetric_matrix_is_solved_against_itself(model):  # noqa: F811
    solver = solve_within_forward_error_bound(model, SparseSolver(model, "pardiso"), skewed_blocks(model, 1e-3))
    assert solver.stats["iterations"] >= 1  # the symmetric part alone is not K


def test_a_far_from_symmetric_matrix_fails_loudly(model):  # noqa: F811
    solver = SparseSolver(model, "pardiso")
    col, row, r_u, r_c = bordered_rhs(model)
    blocks = jnp.asarray(skewed_blocks(model, 1.0))
    du, dp = jax.jit(solver.solve)(blocks, jnp.asarray(col), jnp.asarray(row), jnp.asarray(r_u), r_c)
    assert np.all(np.isnan(np.asarray(du))) and solver.stats["failed"] == 1
    assert "refinement stalled" in solver.last_failure


def test_a_slowly_contracting_refinement_runs_until_it_converges(model):  # noqa: F811
    """Refinement with the factor of the symmetric part K_s contracts by ``rho = |K_s^-1 K_a|`` per step
    (K_a the skew part). Scaled to rho = 0.4 (computed densely), reaching rtol = 1e-13 takes about
    log(1e-13) / log(0.4) = 33 steps, within
    ``refine_max_iter``; the solve meets the backward and forward error bounds."""
    Ks = model.pattern.matrix(spd_blocks(model)).toarray()
    Ka = model.pattern.matrix(skewed_blocks(model, 1.0) - spd_blocks(model)).toarray()
    rho1 = np.max(np.abs(np.linalg.eigvals(np.linalg.solve(Ks, Ka))))
    solver = solve_within_forward_error_bound(model, SparseSolver(model, "pardiso"),
                                              skewed_blocks(model, 0.4 / rho1))
    print(f"\nrho = 0.4: {solver.stats['iterations']} refinement steps")
    assert 8 < solver.stats["iterations"] < solver.refine_max_iter and solver.stats["failed"] == 0

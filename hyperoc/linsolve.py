"""Linear solvers for the bordered step system, by a Schur complement on the single multiplier.

Each Newton iteration (and each adjoint step) solves

    [ K    col ] [x]   [r_u]
    [ row^T  0 ] [q] = [r_c]

with K symmetric (possibly indefinite under compression) given by element blocks. With one
factorization of K: ``K a = r_u``, ``K b = col``, ``q = (row.a - r_c) / (row.b)``, ``x = a - b q``.
The adjoint solves the transpose, which is the same call with ``col`` and ``row`` swapped.

- `DenseSolver`: LU in JAX (small problems; the whole time loop can be compiled).
- `TridiagonalSolver`: 1D P1 meshes numbered along the line (the paper's case), in JAX.
- `SparseSolver`: assembly into a fixed CSR pattern and scipy/pyamg on the host, called from
  traced code through ``jax.pure_callback``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

from . import _jax  # noqa: F401
from .errors import InputError

__all__ = ["DenseSolver", "TridiagonalSolver", "SparseSolver", "make_solver"]


def _schur(solve2, col, row, r_u, r_c):
    ab = solve2(jnp.stack([r_u, col], axis=1))
    a, b = ab[:, 0], ab[:, 1]
    q = (row @ a - r_c) / (row @ b)
    return a - b * q, q


class DenseSolver:
    """Dense LU of the assembled K, traced by JAX."""

    traced = True

    def __init__(self, model):
        k = model.cell_dofs.shape[1]
        n = model.n
        ed = np.where(model.cell_dofs < 0, n, model.cell_dofs)
        self.n = n
        self._rows = jnp.asarray(np.repeat(ed, k, axis=1).ravel())
        self._cols = jnp.asarray(np.tile(ed, (1, k)).ravel())

    def assemble(self, blocks):
        K = jnp.zeros((self.n + 1, self.n + 1), blocks.dtype).at[self._rows, self._cols].add(blocks.reshape(-1))
        return K[: self.n, : self.n]

    def solve(self, blocks, col, row, r_u, r_c):
        lu = jax.scipy.linalg.lu_factor(self.assemble(blocks))
        return _schur(lambda B: jax.scipy.linalg.lu_solve(lu, B), col, row, r_u, r_c)


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
        self.n = model.n
        lo = np.minimum(ed[:, 0], ed[:, 1])
        swap = ed[:, 0] > ed[:, 1]
        self._diag_idx = jnp.asarray(np.where(ed < 0, self.n, ed))
        self._upper_idx = jnp.asarray(np.where(both, lo, self.n))
        self._swap = jnp.asarray(swap)

    def solve(self, blocks, col, row, r_u, r_c):
        n = self.n
        d = jnp.zeros(n + 1).at[self._diag_idx[:, 0]].add(blocks[:, 0, 0]).at[self._diag_idx[:, 1]].add(blocks[:, 1, 1])[:n]
        up_val = jnp.where(self._swap, blocks[:, 1, 0], blocks[:, 0, 1])
        lo_val = jnp.where(self._swap, blocks[:, 0, 1], blocks[:, 1, 0])
        du = jnp.zeros(n + 1).at[self._upper_idx].add(up_val)[:n]
        dl = jnp.concatenate([jnp.zeros(1), jnp.zeros(n + 1).at[self._upper_idx].add(lo_val)[: n - 1]])
        du = du.at[n - 1].set(0.0)
        solve2 = lambda B: jax.lax.linalg.tridiagonal_solve(dl, d, du, B)
        return _schur(solve2, col, row, r_u, r_c)


class SparseSolver:
    """Host solver on the CSR pattern of the model, reached through ``jax.pure_callback``.

    method : "lu" (SuperLU, robust for indefinite K), or "minres" (MINRES preconditioned by
    smoothed-aggregation AMG of the mass-dominated part, tolerance ``rtol``).
    """

    traced = False

    def __init__(self, model, method: str = "lu", rtol: float = 1e-13):
        if method not in ("lu", "minres"):
            raise InputError(f"unknown sparse method {method!r} (lu, minres)")
        self.pattern, self.n, self.method, self.rtol = model.pattern, model.n, method, rtol
        self.stats = {"factorizations": 0, "iterations": 0}

    def host_solve(self, blocks, col, row, r_u, r_c):
        K = self.pattern.matrix(np.asarray(blocks)).tocsc()
        rhs = np.stack([np.asarray(r_u), np.asarray(col)], axis=1)
        if self.method == "lu":
            ab = spla.splu(K).solve(rhs)
            self.stats["factorizations"] += 1
        else:
            ab = np.stack([self._minres(K, rhs[:, j]) for j in range(2)], axis=1)
        a, b = ab[:, 0], ab[:, 1]
        row = np.asarray(row)
        q = (row @ a - float(r_c)) / (row @ b)
        return np.concatenate([a - b * q, [q]])

    def _minres(self, K, rhs):
        import pyamg

        ml = pyamg.smoothed_aggregation_solver(abs(K).tocsr(), symmetry="symmetric")
        count = [0]
        x, info = spla.minres(K, rhs, M=ml.aspreconditioner(), rtol=self.rtol, maxiter=2000,
                              callback=lambda _: count.__setitem__(0, count[0] + 1))
        self.stats["iterations"] += count[0]
        if info != 0:
            raise np.linalg.LinAlgError(f"MINRES did not converge (info = {info})")
        return x

    def solve(self, blocks, col, row, r_u, r_c):
        out = jax.pure_callback(self.host_solve, jax.ShapeDtypeStruct((self.n + 1,), jnp.float64),
                                blocks, col, row, r_u, r_c)
        return out[:-1], out[-1]


def make_solver(model, kind: str = "auto"):
    """``"auto"``: tridiagonal for 1D P1, dense up to 600 dofs, sparse LU beyond."""
    if kind == "auto":
        if model.dim == 1 and model.space.degree == 1:
            kind = "tridiagonal"
        else:
            kind = "dense" if model.n <= 600 else "lu"
    if kind == "tridiagonal":
        return TridiagonalSolver(model)
    if kind == "dense":
        return DenseSolver(model)
    if kind in ("lu", "minres"):
        return SparseSolver(model, kind)
    raise InputError(f"unknown linear solver {kind!r} (auto, tridiagonal, dense, lu, minres)")

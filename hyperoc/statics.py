"""Quasi-static equilibrium under the volume constraint (no inertia, no damping).

Find ``(u, p)`` with ``R(u) + p G(u) = B xi + f`` and ``vol(u) = V``: the same residual and
Newton as a time step with ``M = 0`` and ``kappa = 0``. Used for space-convergence studies on
manufactured solutions and for static benchmarks; ``V`` defaults to the reference volume.
Loads can be applied in increments (``steps > 1``) for large deformations.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from . import _jax  # noqa: F401
from .dynamics import Scheme
from .errors import SolverError
from .linsolve import make_solver
from .model import StateModel
from .newton import newton

__all__ = ["StaticSolution", "solve_static"]


@dataclass(eq=False)
class StaticSolution:
    """Equilibrium ``u`` (n,) reduced, multiplier ``p``, volume, Newton iterations per load step."""

    model: StateModel
    u: np.ndarray
    p: float
    volume: float
    newton_iterations: np.ndarray

    def displacement(self) -> np.ndarray:
        return self.model.expand(self.u)


def _compiled_solve(model: StateModel, lin, scheme: Scheme):
    """The jitted Newton solve of one load step, cached on the model per (solver kind, scheme)."""
    cache = model.__dict__.setdefault("_static_solves", {})
    key = (type(lin).__name__, getattr(lin, "method", None), scheme)
    if key in cache:
        return cache[key]

    def residual(x, fk, Vk):
        r = model.internal_force(x[:-1]) + x[-1] * model.volume_gradient(x[:-1]) - fk
        return jnp.concatenate([r, (model.volume(x[:-1]) - Vk)[None]])

    def jacobian_parts(x):
        G = model.volume_gradient(x[:-1])
        return model.tangent_blocks(x[:-1], 1.0, x[-1]), G, G

    @jax.jit
    def solve(x0, fk, Vk):
        x, it, status = newton(lambda x: residual(x, fk, Vk), jacobian_parts, lin, x0,
                               rtol=scheme.rtol, atol=scheme.atol, max_iter=scheme.max_iter)
        return x, it, status, model.min_det_F(x[:-1])

    cache[key] = solve
    return solve


def solve_static(model: StateModel, *, load=None, xi=None, volume: float | None = None, steps: int = 1,
                 scheme: Scheme = Scheme(), solver="auto", u0=None) -> StaticSolution:
    """Equilibrium with external load vector ``load`` (n,) and control ``xi``, ramped in ``steps``.

    Raises `SolverError` naming the load step when Newton fails or an element inverts.
    """
    lin = make_solver(model, solver) if isinstance(solver, str) else solver
    B = model.jax_operators[2]
    f = jnp.zeros(model.n) if load is None else jnp.asarray(load)
    if xi is not None:
        f = f + B @ jnp.asarray(xi)
    u = np.zeros(model.n) if u0 is None else np.asarray(u0, dtype=np.float64)
    V = float(model.jitted["volume"](jnp.asarray(u))) if volume is None else float(volume)

    solve = _compiled_solve(model, lin, scheme)
    V_start = float(model.jitted["volume"](jnp.asarray(u)))
    x = jnp.concatenate([jnp.asarray(u), jnp.zeros(1)])
    iters = []
    for k in range(1, steps + 1):
        s = k / steps
        x, it, status, mindet = solve(x, s * f, V_start + s * (V - V_start))
        iters.append(int(it))
        if int(status) != 0 or not float(mindet) > 0:
            cause = {1: "newton", 2: "nonfinite"}.get(int(status), "detF")
            raise SolverError(k - 1, s, cause, f"load step {k}/{steps}, min det F = {float(mindet):.3g}")
    u = np.asarray(x[:-1])
    return StaticSolution(model, u, float(x[-1]), float(model.jitted["volume"](jnp.asarray(u))), np.array(iters))

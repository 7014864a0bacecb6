"""Exact gradient of the discrete objective by a backward adjoint recursion (discretize-then-optimize).

Step n maps the level state ``(y0_n, y1_n)`` to ``x = (y0_{n+1}, p_{n+1/2})`` through the step
residual ``F(x; y0_n, y1_n, xi_n, xi_{n+1}, dt_n) = 0`` and ``y1_{n+1} = v(y0_{n+1}, y0_n, y1_n, dt_n)``.
Going backwards with ``lambda = (dJ/dy0_{n+1}, dJ/dy1_{n+1})`` (totals, future included):

    g_x = (lambda0 + (dv/dy0_{n+1})^T lambda1,  dJ/dp_{n+1/2})
    F_x^T w = g_x                                      (transposed bordered step matrix)
    dJ/d(y0_n, y1_n, xi_n, xi_{n+1}, dt_n) += (dv/d.)^T lambda1 - (dF/d.)^T w

All partial derivatives are vector-Jacobian products of the same JAX residual that Newton solves,
so the gradient is exact for the discrete J up to the Newton and linear-solver tolerances. This is
the discrete counterpart of the paper's ``ende3``-``ende4``; ``dJ/dtau = sum_n dJ/ddt_n ddt_n/dtau``.

Checkpointing (`Adjoint.record`, `Adjoint.backward_checkpointed`): the forward pass keeps the level
state ``(y0, y1)`` only at the checkpoint levels ``0, k, 2k, ...`` (plus the few levels the
objective reads) and the N step multipliers (one scalar each). The backward pass takes the segments
``[c_j, c_{j+1}]`` last to first, recomputes each from its checkpoint with the stepper's own compiled
step (Newton warm-started from the same ``p_{c_j - 1/2}``, hence the same states) and runs `sweep`
over it. Memory: ``ceil(N/k) + k + 1`` level states instead of ``N + 1``; cost: one more forward solve.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from . import _jax  # noqa: F401
from .dynamics import TimeStepper
from .errors import InputError
from .timegrid import TimeGrid

__all__ = ["Adjoint", "Checkpoints"]


@dataclass(eq=False)
class Checkpoints:
    """A forward solve that kept only some level states (made by `Adjoint.record`).

    grid : TimeGrid, N steps; xi : (N+1, n_ctrl) controls; loads : (N+1, n) external loads (a
    broadcast view when constant); V0 : the constrained volume ``int det F`` (length^d);
    bounds : (C+1,) segment bounds ``0 = c_0 < c_1 < ... < c_C = N``, segment j covering the steps
    ``c_j .. c_{j+1} - 1``; states : C pairs ``(y0, y1)`` at the levels ``c_0 .. c_{C-1}``, (n,) each;
    p_steps : (N,) step multipliers (all kept); kept : ``{level: (y0, y1)}`` for the extra levels
    asked for (those the objective reads).
    """

    grid: TimeGrid
    xi: np.ndarray
    loads: np.ndarray
    V0: float
    bounds: np.ndarray
    states: list
    p_steps: np.ndarray
    kept: dict

    @property
    def stored_states(self) -> int:
        """Level states held between the forward and the backward pass, ``C + len(kept)``."""
        return len(self.states) + len(self.kept)


class Adjoint:
    """Backward recursion for a `TimeStepper` (multiplier="step" only)."""

    def __init__(self, stepper: TimeStepper):
        if stepper.scheme.multiplier != "step":
            raise InputError("exact gradients are implemented for multiplier='step' (the default)")
        self.stepper = stepper

    def step(self, carry, inputs):
        """One backward step; carry = (lambda0, lambda1) at level n+1, totals."""
        st = self.stepper
        lam0, lam1 = carry
        y0n, pn, y0, y1, xi0, xi1, f0, f1, dt, V0, gp = inputs
        x = jnp.concatenate([y0n, pn[None]])
        _, vjp_v = jax.vjp(st.velocity, y0n, y0, y1, dt)
        v_y0n, v_y0, v_y1, v_dt = vjp_v(lam1)
        blocks, col, row = st.jacobian_parts(x, y0, dt)
        w_u, w_p = st.solver.solve(blocks, row, col, lam0 + v_y0n, gp)  # transpose: col <-> row
        w = jnp.concatenate([w_u, w_p[None]])
        res = lambda y0, y1, xi0, xi1, dt: st.residual(x, y0, y1, 0.0, xi0, xi1, f0, f1, dt, V0)
        _, vjp_r = jax.vjp(res, y0, y1, xi0, xi1, dt)
        r_y0, r_y1, r_xi0, r_xi1, r_dt = vjp_r(w)
        return (v_y0 - r_y0, v_y1 - r_y1), (-r_xi0, -r_xi1, v_dt - r_dt)

    @staticmethod
    def _inputs(Y0, Y1, P, Xi, F, dt, V0, gP):
        """Per-step inputs of `step` for a level range (see `sweep`)."""
        return (Y0[1:], P, Y0[:-1], Y1[:-1], Xi[:-1], Xi[1:], F[:-1], F[1:], dt, jnp.full(dt.shape[0], V0), gP)

    @staticmethod
    def _control_totals(Xi, gxi0, gxi1):
        """``dJ/dxi`` at the levels from the per-step derivatives in ``xi_n`` and ``xi_{n+1}``."""
        return jnp.zeros_like(Xi).at[:-1].add(gxi0).at[1:].add(gxi1)

    @cached_property
    def _scan(self):
        def run(lam, Y0, Y1, P, Xi, F, dt, V0, gY0, gY1, gP):
            def body(carry, inp):
                (l0, l1), out = self.step(carry, inp[:-2])
                g0, g1 = inp[-2:]
                return (l0 + g0, l1 + g1), out

            xs = self._inputs(Y0, Y1, P, Xi, F, dt, V0, gP) + (gY0, gY1)
            lam, (gxi0, gxi1, gdt) = jax.lax.scan(body, lam, xs, reverse=True)
            return lam, self._control_totals(Xi, gxi0, gxi1), gdt

        return jax.jit(run)

    @cached_property
    def _jit_step(self):
        return jax.jit(self.step)

    def sweep(self, lam, Y0, Y1, P, Xi, F, dt, V0, gY0, gY1, gP):
        """Backward recursion over the L steps of the level range ``a .. b = a + L``.

        lam : totals ``(dJ/dy0_b, dJ/dy1_b)``, (n,) each; Y0, Y1 : (L+1, n) states, Xi : (L+1, n_ctrl)
        controls, F : (L+1, n) external loads at the levels a..b; P, dt, gP : (L,) step multipliers,
        steps, ``dJ/dp`` (partial); gY0, gY1 : (L, n) partials ``dJ/dy0``, ``dJ/dy1`` at the levels a..b-1.
        Returns the totals at level a, ``dJ/dxi`` (L+1, n_ctrl) from the steps of the range (the end
        levels also receive contributions from the neighbouring ranges) and ``dJ/ddt`` (L,).
        """
        if self.stepper.solver.traced:
            args = (Y0, Y1, P, Xi, F, dt)
            lam, gXi, gdt = self._scan(lam, *(jnp.asarray(a) for a in args), V0, jnp.asarray(gY0), jnp.asarray(gY1),
                                       jnp.asarray(gP))
        else:
            lam, (gxi0, gxi1, gdt) = self._python_loop(lam, gY0, gY1, self._inputs(Y0, Y1, P, Xi, F, dt, V0, gP))
            gXi = self._control_totals(Xi, gxi0, gxi1)
        return lam, np.asarray(gXi), np.asarray(gdt)

    def backward(self, Y0, Y1, P, Xi, F, dt, V0, gY0, gY1, gP):
        """Totals ``(dJ/dxi (N+1, n_ctrl), dJ/ddt (N,))`` from the whole stored state and J's partials
        (gY0, gY1 : (N+1, n), gP : (N,)): one `sweep` over all steps."""
        _, gXi, gdt = self.sweep((gY0[-1], gY1[-1]), Y0, Y1, P, Xi, F, dt, V0, gY0[:-1], gY1[:-1], gP)
        return gXi, gdt

    # --- checkpointing ----------------------------------------------------------------------------
    def advance(self, y0, y1, p_prev, t, xi, loads, V0):
        """The stepper's own loop (compiled scan, or jitted step driven from Python) over the levels
        ``t`` (L+1,) from ``(y0, y1)`` with previous multiplier ``p_prev`` (Newton's initial guess; a
        Python float, as `TimeStepper.run` passes it, so that the compiled scans are shared);
        xi (L+1, n_ctrl), loads (L+1, n). Returns the stepper's outputs (Y0, Y1 (L, n), P, iterations,
        status, min det F, max |grad u| (L,)) for the levels after the first."""
        st = self.stepper
        if st.solver.traced:
            return st._scan(jnp.asarray(y0), jnp.asarray(y1), jnp.asarray(p_prev), jnp.asarray(xi), jnp.asarray(loads),
                            jnp.asarray(np.diff(t)), V0)
        return st._python_loop(y0, y1, p_prev, xi, loads, TimeGrid(t), V0, False)

    def record(self, grid: TimeGrid, xi, loads, u0, v0, every: int, keep=()) -> Checkpoints:
        """Forward solve keeping the level states at ``0, every, 2 every, ...`` and at the levels
        ``keep``; raises `SolverError` (step, cause) like `TimeStepper.run` when a step fails."""
        N = grid.num_steps
        bounds = np.append(np.arange(0, N, every), N)
        V0 = float(self.stepper.model.jitted["volume"](jnp.asarray(u0)))
        y0, y1 = jnp.asarray(u0, dtype=jnp.float64), jnp.asarray(v0, dtype=jnp.float64)
        kept = {0: (y0, y1)} if 0 in keep else {}
        states, P, its, status, mindet = [], [], [], [], []
        for a, b in zip(bounds[:-1], bounds[1:]):
            states.append((y0, y1))
            out = self.advance(y0, y1, float(P[-1][-1]) if P else 0.0, grid.t[a:b + 1], xi[a:b + 1],
                               loads[a:b + 1], V0)
            for store, o in zip((P, its, status, mindet), out[2:6]):
                store.append(np.asarray(o))
            if np.any(status[-1] != 0):
                self.stepper._raise_on_failure(np.concatenate(status), grid, np.concatenate(its), np.concatenate(mindet))
            kept.update({k: (jnp.asarray(out[0][k - a - 1]), jnp.asarray(out[1][k - a - 1])) for k in keep if a < k <= b})
            y0, y1 = jnp.asarray(out[0][-1]), jnp.asarray(out[1][-1])
        return Checkpoints(grid, xi, loads, V0, bounds, states, np.concatenate(P), kept)

    def backward_checkpointed(self, ck: Checkpoints, g_kept: dict, gP):
        """Totals ``(dJ/dxi (N+1, n_ctrl), dJ/ddt (N,))`` as `backward`, from checkpoints: J's partials
        ``g_kept = {level: (dJ/dy0, dJ/dy1)}`` (zero at the other levels) and ``gP`` (N,)."""
        n, N = ck.states[0][0].shape[0], ck.grid.num_steps
        zero = jnp.zeros(n)
        lam = g_kept.get(N, (zero, zero))
        gXi, gdt = np.zeros_like(ck.xi), np.zeros(N)
        for j in reversed(range(len(ck.states))):
            a, b = ck.bounds[j], ck.bounds[j + 1]
            y0, y1 = ck.states[j]
            Y0n, Y1n, P = self.advance(y0, y1, float(ck.p_steps[a - 1]) if a else 0.0, ck.grid.t[a:b + 1],
                                       ck.xi[a:b + 1], ck.loads[a:b + 1], ck.V0)[:3]
            gY0, gY1 = np.zeros((b - a, n)), np.zeros((b - a, n))
            for k, (g0, g1) in g_kept.items():
                if a <= k < b:
                    gY0[k - a], gY1[k - a] = g0, g1
            lam, gxi, gdt[a:b] = self.sweep(lam, jnp.concatenate([y0[None], jnp.asarray(Y0n)]),
                                            jnp.concatenate([y1[None], jnp.asarray(Y1n)]), P, ck.xi[a:b + 1],
                                            ck.loads[a:b + 1], ck.grid.dt[a:b], ck.V0, gY0, gY1, gP[a:b])
            gXi[a:b + 1] += gxi
        return gXi, gdt

    def _python_loop(self, lam, gY0, gY1, xs):
        N = xs[0].shape[0]
        carry = lam
        outs = [None] * N
        for n in reversed(range(N)):
            (l0, l1), out = self._jit_step(carry, tuple(jnp.asarray(a[n]) for a in xs))
            carry = (l0 + gY0[n], l1 + gY1[n])
            outs[n] = out
        return carry, tuple(jnp.stack([o[k] for o in outs]) for k in range(3))

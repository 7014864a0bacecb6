"""Exact gradient of the discrete objective by a backward adjoint recursion (discretize-then-optimize).

Step n maps the level state ``(y0_n, y1_n)`` to ``x = (y0_{n+1}, p_{n+1/2})`` through the step
residual ``F(x; y0_n, y1_n, xi_n, xi_{n+1}, dt_n) = 0`` and ``y1_{n+1} = v(y0_{n+1}, y0_n, y1_n, dt_n)``.
Going backwards with ``lambda = (dJ/dy0_{n+1}, dJ/dy1_{n+1})`` (totals, future included):

    g_x = (lambda0 + (dv/dy0_{n+1})^T lambda1,  dJ/dp_{n+1/2})
    F_x^T w = g_x                                      (transposed bordered step matrix)
    dJ/d(y0_n, y1_n, xi_n, xi_{n+1}, dt_n) += (dv/d.)^T lambda1 - (dF/d.)^T w

All partial derivatives are vector-Jacobian products of the same JAX residual that Newton solves,
so the gradient is exact for the discrete J up to the Newton and linear-solver tolerances. This is
the discrete counterpart of the paper's optimality conditions; ``dJ/dtau = sum_n dJ/ddt_n ddt_n/dtau``.

Checkpointing (`Adjoint.record`, `Adjoint.backward_checkpointed`): the forward pass keeps the level
state ``(y0, y1)`` only at the checkpoint levels ``0, k, 2k, ...`` (plus the few levels the
objective reads) and the N step multipliers (one scalar each). The backward pass takes the segments
``[c_j, c_{j+1}]`` last to first, recomputes each from its checkpoint with the stepper's own compiled
step (Newton warm-started from the same ``p_{c_j - 1/2}``, hence the same states) and runs `sweep`
over it. Memory: ``ceil(N/k) + k + 1`` level states instead of ``N + 1``; cost: one more forward solve.

Binomial checkpointing (`Adjoint.record_revolve`, `Adjoint.backward_revolve`): the actions of
`hyperoc.control.revolve.schedule(N, s)`; the forward pass keeps the s snapshots its first sweep stores,
the state at level N-1 and ``y0_N``; the backward pass restores, advances and reverses one step at
a time with the stepper's jitted step and `step` (one compilation each, whatever the lengths; the
Newton warm start of an advance from level a is the recorded ``p_{a-1/2}``, so recomputed states
equal the forward ones bit for bit). Memory: s + 2 level states; cost ``t(N, s) + 1`` step
evaluations instead of N (`hyperoc.control.revolve.minimal_advances`), e.g. 4.5 N for N = 3000, s = 10.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from ..dynamics.stepper import TimeStepper
from ..dynamics.timegrid import TimeGrid
from ..errors import InputError
from .revolve import Advance, Free, Restore, Reverse, Store, schedule

__all__ = ["Adjoint", "Checkpoints", "RevolveRecord"]


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


@dataclass(eq=False)
class RevolveRecord:
    """A forward solve under a binomial schedule (made by `Adjoint.record_revolve`).

    grid, xi, loads, V0, p_steps, kept : as in `Checkpoints`; actions : `hyperoc.control.revolve.schedule(N, s)`;
    start : index of its first `Reverse` (the forward pass did the actions before it); snapshots :
    ``{level: (y0, y1)}`` stored by those actions (at most s), (n,) each; current : ``(y0, y1)`` at level
    N-1; y0_last : ``y0`` at level N, (n,) (the reversal of step N-1 reads it).
    """

    grid: TimeGrid
    xi: np.ndarray
    loads: np.ndarray
    V0: float
    actions: tuple
    start: int
    snapshots: dict
    current: tuple
    y0_last: jax.Array
    p_steps: np.ndarray
    kept: dict

    @property
    def stored_states(self) -> int:
        """Level states held between the forward and the backward pass: snapshots, kept levels, the
        state at N-1 and ``y0_N`` (half a state, counted as one)."""
        return len(self.snapshots) + len(self.kept) + 2


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
    def advance(self):
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
            lam, (gxi0, gxi1, gdt) = self.march_stepwise(lam, gY0, gY1, self._inputs(Y0, Y1, P, Xi, F, dt, V0, gP))
            gXi = self._control_totals(Xi, gxi0, gxi1)
        return lam, np.asarray(gXi), np.asarray(gdt)

    def backward(self, Y0, Y1, P, Xi, F, dt, V0, gY0, gY1, gP):
        """Totals ``(dJ/dxi (N+1, n_ctrl), dJ/ddt (N,))`` from the whole stored state and J's partials
        (gY0, gY1 : (N+1, n), gP : (N,)): one `sweep` over all steps."""
        _, gXi, gdt = self.sweep((gY0[-1], gY1[-1]), Y0, Y1, P, Xi, F, dt, V0, gY0[:-1], gY1[:-1], gP)
        return gXi, gdt

    # --- checkpointing ----------------------------------------------------------------------------
    def record(self, grid: TimeGrid, xi, loads, u0, v0, every: int, keep=()) -> Checkpoints:
        """Forward solve keeping the level states at ``0, every, 2 every, ...`` and at the levels
        ``keep``; raises `SolverError` (step, cause) like `TimeStepper.run` when a step fails."""
        N = grid.num_steps
        bounds = np.append(np.arange(0, N, every), N)
        V0, y0, y1 = self._initial_state(u0, v0)
        kept = {0: (y0, y1)} if 0 in keep else {}
        states, P, its, status, mindet = [], [], [], [], []
        for a, b in zip(bounds[:-1], bounds[1:]):
            states.append((y0, y1))
            out = self.stepper.march_levels(y0, y1, float(P[-1][-1]) if P else 0.0, grid.t[a:b + 1], xi[a:b + 1],
                               loads[a:b + 1], V0)
            for store, o in zip((P, its, status, mindet), out[2:6]):
                store.append(np.asarray(o))
            if np.any(status[-1] != 0):
                self.stepper.raise_on_failure(np.concatenate(status), grid, np.concatenate(its),
                                               np.concatenate(mindet))
            kept.update({k: (jnp.asarray(out[0][k - a - 1]), jnp.asarray(out[1][k - a - 1]))
                         for k in keep if a < k <= b})
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
            Y0n, Y1n, P = self.stepper.march_levels(y0, y1, float(ck.p_steps[a - 1]) if a else 0.0, ck.grid.t[a:b + 1],
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

    def _initial_state(self, u0, v0):
        """``(V0, y0, y1)``: the constrained volume ``int det F(u0)`` and the level-0 state as JAX arrays."""
        V0 = float(self.stepper.model.jitted["volume"](jnp.asarray(u0)))
        return V0, jnp.asarray(u0, dtype=jnp.float64), jnp.asarray(v0, dtype=jnp.float64)

    # --- binomial checkpointing -------------------------------------------------------------------
    @staticmethod
    def _step_inputs(grid: TimeGrid, xi, loads, V0):
        """``n -> (xi_n, xi_{n+1}, f_n, f_{n+1}, dt_n, V0)``, the inputs of `TimeStepper.step` with the
        argument types of `TimeStepper.march_stepwise` (so the jitted step compiles once for both)."""
        return lambda n: (xi[n], xi[n + 1], loads[n], loads[n + 1], grid.dt[n], V0)

    def _walk(self, inputs, y0, y1, p_prev, a: int, b: int):
        """Yields the stepper's outputs ``(y0, y1, p, iterations, status, min det F, max |grad u|)`` of
        the steps a .. b-1, from ``(y0, y1)`` at level a with Newton's first guess ``p_prev``
        (``p_{a-1/2}`` of the forward run, 0 at a = 0), one jitted step at a time."""
        carry = (y0, y1, jnp.asarray(p_prev, dtype=jnp.float64), jnp.asarray(False))
        for n in range(a, b):
            carry, out = self.stepper.advance(carry, inputs(n))
            yield out

    def record_revolve(self, grid: TimeGrid, xi, loads, u0, v0, snapshots: int, keep=()) -> RevolveRecord:
        """Forward solve for the binomial schedule with ``snapshots`` snapshots: keeps the snapshots of
        its first sweep, the levels ``keep``, the state at N-1 and ``y0_N``; raises `SolverError` (step,
        cause) like `TimeStepper.run` when a step fails."""
        N = grid.num_steps
        actions = schedule(N, snapshots)
        start = next(i for i, a in enumerate(actions) if isinstance(a, Reverse))
        stores = {a.level for a in actions[:start] if isinstance(a, Store)}
        V0, y0, y1 = self._initial_state(u0, v0)
        levels = {*stores, *keep, N - 1}
        held = {0: (y0, y1)} if 0 in levels else {}
        monitors = []
        for n, out in enumerate(self._walk(self._step_inputs(grid, xi, loads, V0), y0, y1, 0.0, 0, N), start=1):
            monitors.append(out[2:6])
            if n in levels:
                held[n] = out[:2]
        P, its, status, mindet = (np.asarray(m) for m in zip(*jax.device_get(monitors)))  # on the host: a jnp.stack
        # of N arrays would compile an N-operand concatenation for every N
        self.stepper.raise_on_failure(status, grid, its, mindet)
        return RevolveRecord(grid, xi, loads, V0, actions, start, {k: held[k] for k in stores}, held[N - 1],
                             out[0], P, {k: held[k] for k in keep})

    def backward_revolve(self, rec: RevolveRecord, g_kept: dict, gP):
        """Totals ``(dJ/dxi (N+1, n_ctrl), dJ/ddt (N,))`` as `backward`, by the actions of ``rec`` after its
        forward pass; J's partials ``g_kept = {level: (dJ/dy0, dJ/dy1)}`` (zero at the other levels), ``gP`` (N,)."""
        N = rec.grid.num_steps
        inputs, gP = self._step_inputs(rec.grid, rec.xi, rec.loads, rec.V0), np.asarray(gP)
        zero = jnp.zeros_like(rec.y0_last)
        lam = g_kept.get(N, (zero, zero))
        snapshots, (y0, y1), y0_next = dict(rec.snapshots), rec.current, rec.y0_last
        outs = [None] * N
        for action in rec.actions[rec.start:]:
            match action:
                case Advance(a, b):
                    y0, y1 = deque(self._walk(inputs, y0, y1, rec.p_steps[a - 1] if a else 0.0, a, b), maxlen=1)[0][:2]
                case Store(k):
                    snapshots[k] = (y0, y1)
                case Restore(k):
                    y0, y1 = snapshots[k]
                case Free(k):
                    del snapshots[k]
                case Reverse(n):
                    step_in = (y0_next, rec.p_steps[n], y0, y1, *inputs(n), gP[n])
                    lam, outs[n] = self._reverse_step(lam, step_in, g_kept.get(n))
                    y0_next = y0
        gxi0, gxi1, gdt = (np.stack(o) for o in zip(*jax.device_get(outs)))
        return np.asarray(self._control_totals(rec.xi, gxi0, gxi1)), gdt

    def _reverse_step(self, lam, inputs, g=None):
        """`step` (jitted) from the totals ``lam`` at level n+1; adds J's partials ``g = (dJ/dy0_n,
        dJ/dy1_n)`` when given. Returns the totals at level n and the step's derivatives."""
        (l0, l1), out = self.advance(lam, inputs)
        return ((l0, l1) if g is None else (l0 + g[0], l1 + g[1])), out

    def march_stepwise(self, lam, gY0, gY1, xs):
        N = xs[0].shape[0]
        carry = lam
        outs = [None] * N
        for n in reversed(range(N)):
            carry, outs[n] = self._reverse_step(carry, tuple(jnp.asarray(a[n]) for a in xs), (gY0[n], gY1[n]))
        return carry, tuple(jnp.stack([o[k] for o in outs]) for k in range(3))

"""Exact gradient of the discrete objective by a backward adjoint recursion (discretize-then-optimize).

Step n maps the level state ``(y0_n, y1_n)`` to ``x = (y0_{n+1}, p_{n+1/2})`` through the step
residual ``F(x; y0_n, y1_n, xi_n, xi_{n+1}, dt_n) = 0`` and ``y1_{n+1} = v(y0_{n+1}, y0_n, y1_n, dt_n)``.
Going backwards with ``lambda = (dJ/dy0_{n+1}, dJ/dy1_{n+1})`` (totals, future included):

    g_x = (lambda0 + (dv/dy0_{n+1})^T lambda1,  dJ/dp_{n+1/2})
    F_x^T w = g_x                                      (transposed bordered step matrix)
    dJ/d(y0_n, y1_n, xi_n, xi_{n+1}, dt_n) += (dv/d.)^T lambda1 - (dF/d.)^T w

A constraint that carries a state beyond p (the circulation's ``s = (p, Pa, phase)``,
`hyperoc.dynamics.constraint`) adds its total ``lambda_s = dJ/ds_{n+1}`` to the carry: it enters g_x through
``s_{n+1} = next_state(s_n, x, y0_n, dt_n)`` and flows to s_n through next_state and the residual's row
(`Adjoint.step`); the phase sequence is held fixed.

All partial derivatives are vector-Jacobian products of the same JAX residual that Newton solves,
so the gradient is exact for the discrete J up to the Newton and linear-solver tolerances. This is
the discrete counterpart of the paper's optimality conditions; ``dJ/dtau = sum_n dJ/ddt_n ddt_n/dtau``.

Checkpointing: `Adjoint.record` runs the forward pass and keeps what a schedule
(`hyperoc.control.revolve.Schedule`: `StoreAll`, `EveryK`, `Binomial`) asks for, the level states
the caller reads and the N + 1 carried multiplier states (one scalar each, or the circulation's three);
`Adjoint.backward` runs the schedule's reverse actions on that `Record`. Both advance and reverse by the
schedule's loops: a compiled schedule uses the stepper's own loop (`TimeStepper.march_levels`) and the compiled reverse
loop (one `jax.lax.scan` over a range when the solver is traced), the binomial one the jitted step
and the jitted `step` (one compilation each, whatever the lengths). A recomputation starts from a
kept state with the Newton warm start ``p_{a-1/2}`` of the forward run and the loop of the forward
pass, so recomputed states equal the forward ones bit for bit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from .._jax import on_device
from ..dynamics.stepper import TimeStepper
from ..dynamics.timegrid import TimeGrid
from ..errors import InputError
from .revolve import Advance, Free, Restore, Reverse, Schedule, Store

__all__ = ["Adjoint", "Record"]


@dataclass(eq=False)
class Record:
    """A forward solve and the level states a schedule keeps (made by `Adjoint.record`).

    grid : TimeGrid, N steps; xi : (N+1, n_ctrl) controls; loads : (N+1, n) external loads (a
    broadcast view when constant); V0 : the constrained quantity of the initial state (tissue or cavity
    volume, length^d); schedule :
    the `Schedule`; keep : the levels asked for, ascending (J's partials are given there); p_steps :
    (N,) step multipliers (all kept); levels : (K,) the kept levels, ascending (the schedule's and
    keep); y0, y1 : (K, n) the states there; newton_iterations, min_det_F, max_grad : (N,) the steps'
    monitors (as in `hyperoc.dynamics.stepper.StateSolution`); wall_time : seconds of the forward solve;
    carried : (N+1,) or (N+1, k) the constraint's carried multiplier states at the levels (the initial one, then
    after each step: the multipliers themselves, or the circulation's ``(p, Pa, phase)``).
    """

    grid: TimeGrid
    xi: np.ndarray
    loads: np.ndarray
    V0: float
    schedule: Schedule
    keep: tuple
    p_steps: np.ndarray
    levels: np.ndarray
    y0: np.ndarray
    y1: np.ndarray
    newton_iterations: np.ndarray | None = None
    min_det_F: np.ndarray | None = None
    max_grad: np.ndarray | None = None
    wall_time: float = 0.0
    carried: np.ndarray | None = None

    @property
    def stored_states(self) -> int:
        """Level states held between the forward and the backward pass."""
        return len(self.levels)

    @cached_property
    def dt(self) -> np.ndarray:
        """The steps, (N,)."""
        return self.grid.dt

    def step_inputs(self, n: int) -> tuple:
        """``(xi_n, xi_{n+1}, f_n, f_{n+1}, dt_n, V0, t_n)``, the inputs of `TimeStepper.step` (and of `Adjoint.step`
        after the states) with the argument types of `TimeStepper.march_stepwise`, so that a jitted step
        compiles once for both."""
        return self.xi[n], self.xi[n + 1], self.loads[n], self.loads[n + 1], self.dt[n], self.V0, self.grid.t[n]

    def at(self, levels) -> tuple[np.ndarray, np.ndarray]:
        """The states at kept ``levels`` (ascending), (len(levels), n) each."""
        i = np.searchsorted(self.levels, levels)
        return self.y0[i], self.y1[i]

    def span(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The states at the levels a .. b, (b - a + 1, n) each (views), when all are kept; else None."""
        i = int(np.searchsorted(self.levels, a))
        j = i + b - a
        if j < len(self.levels) and self.levels[i] == a and self.levels[j] == b:
            return self.y0[i:j + 1], self.y1[i:j + 1]
        return None


class Adjoint:
    """Backward recursion for a `TimeStepper` (multiplier="step" only)."""

    def __init__(self, stepper: TimeStepper):
        if stepper.scheme.multiplier != "step":
            raise InputError("exact gradients are implemented for multiplier='step' (the default)")
        self.stepper = stepper

    def step(self, carry, inputs):
        """One backward step, the adjoint of step n: carry = ``(lambda0, lambda1, lambda_s)`` at level n+1,
        totals, (n,) each and lambda_s of the shape of the constraint's carried state s; inputs = ``(y0_{n+1},
        s_{n+1}, s_n, y0_n, y1_n, xi_n, xi_{n+1}, f_n, f_{n+1}, dt_n, V0, t_n, dJ/dp_{n+1/2})`` (s_{n+1} the
        state after the step, whose multiplier is p_{n+1/2}; s_n the one before). Returns the totals at level n
        without J's partials there, and the step's ``(dJ/dxi_n, dJ/dxi_{n+1} (n_ctrl,), dJ/ddt_n, dJ/dt_n)``
        (the last through the time laws of the step's terms: t_n moves with every earlier step,
        `_Reversal.totals`).

        The carried state ``s_{n+1} = next_state(s_n, x, y0_n, dt_n)`` (`hyperoc.dynamics.constraint`) takes
        lambda_s, J's partial in p included, back to x, y0_n, dt_n and s_n; the step residual's dependence on
        s_n (the circulation's row reads Pa_n) adds ``-(dF/ds_n)^T w``. For the constraints whose state is the
        multiplier p' itself (and the "step" weighting, where p_n enters no residual) lambda_s is J's partial
        in p_{n+1/2} alone and nothing flows to s_n. The circulation's phase is held fixed: the derivative is
        that of the run's phase sequence (exact where a perturbation does not change it).

        The Jacobian's transpose: the bordered solve with ``col`` and ``row`` swapped and, when a term is
        not symmetric (follower pressure on an open surface, viscosity), the element blocks transposed
        (the assembled transpose is the sum of the transposed blocks on the same pattern). The right-hand
        side is ``(dsplit/dx)^T (lambda0 + dv/dy0'^T lambda1, dJ/dp)``, the unknown x mapped to the step's
        ``(y0', p')`` by the constraint (`hyperoc.dynamics.constraint`)."""
        system, partial = self.transposed_system(carry, inputs)
        w_u, w_p = self.stepper.solver.solve(*system)
        return self.step_totals(jnp.concatenate([w_u, w_p[None]]), partial, inputs)

    def transposed_system(self, carry, inputs):
        """The first half of `step`, up to its linear solve: ``(system, partial)``, the arguments of the
        solver's bordered solve ``(blocks, col, row, rhs_u, rhs_c, corner, low_rank)`` of the transposed step
        Jacobian, and the totals that do not go through it ``(v_y0, v_y1, v_dt, n_s, n_y0, n_dt)`` (through the
        velocity update and the carried state)."""
        st, con = self.stepper, self.stepper.constraint
        lam0, lam1, lam_s = carry
        y0n, s_new, s_prev, y0, y1, xi0, xi1, f0, f1, dt, V0, t0, gp = inputs
        x = con.unknown(y0n, s_new)
        _, vjp_v = jax.vjp(st.velocity, y0n, y0, y1, dt)
        v_y0n, v_y0, v_y1, v_dt = vjp_v(lam1)
        lam_s = lam_s + jax.vjp(con.pressure, s_new)[1](jnp.asarray(gp, dtype=x.dtype))[0]
        _, vjp_next = jax.vjp(con.next_state, s_prev, x, y0, dt)
        n_s, n_x, n_y0, n_dt = vjp_next(lam_s)
        blocks, col, row, corner, low_rank = st.jacobian_parts(x, y0, dt, y1, t0, s_prev)
        if not st.symmetric:
            blocks = jnp.swapaxes(blocks, 1, 2)
        _, vjp_split = jax.vjp(con.split, x)
        rhs = vjp_split((lam0 + v_y0n, jnp.zeros((), x.dtype)))[0] + n_x
        # the transpose: col <-> row (the low-rank part is symmetric)
        return (blocks, row, col, rhs[:-1], rhs[-1], corner, low_rank), (v_y0, v_y1, v_dt, n_s, n_y0, n_dt)

    def step_totals(self, w, partial, inputs):
        """The second half of `step`, from the solution w (n + 1,) of `transposed_system` and its ``partial``
        totals: `step`'s results."""
        st, con = self.stepper, self.stepper.constraint
        y0n, s_new, s_prev, y0, y1, xi0, xi1, f0, f1, dt, V0, t0, gp = inputs
        v_y0, v_y1, v_dt, n_s, n_y0, n_dt = partial
        x = con.unknown(y0n, s_new)
        res = lambda y0, y1, s, xi0, xi1, dt, t0: st.residual(x, (y0, y1, s), (xi0, xi1), (f0, f1), dt, V0, t0)
        _, vjp_r = jax.vjp(res, y0, y1, s_prev, xi0, xi1, dt, t0)
        r_y0, r_y1, r_s, r_xi0, r_xi1, r_dt, r_t0 = vjp_r(w)
        return (v_y0 - r_y0 + n_y0, v_y1 - r_y1, n_s - r_s), (-r_xi0, -r_xi1, v_dt - r_dt + n_dt, -r_t0)

    def host_step(self, carry, inputs):
        """`step` for a host solver: its two halves jitted apart (programs without host callbacks, which the
        compilation cache keeps), the transposed solve between them on the host (``try_solve``: NaN if it
        fails, as `step`'s solve returns)."""
        system, totals = self._host_kernels
        args, partial = system(carry, inputs)
        w = self.stepper.solver.try_solve(*jax.device_get(args))
        return totals(w, partial, inputs)

    @cached_property
    def _host_kernels(self):
        return jax.jit(self.transposed_system), jax.jit(self.step_totals)

    @cached_property
    def _jitted_step(self):
        """`step` compiled once for a traced solver; `host_step` for a host solver."""
        return jax.jit(self.step) if self.stepper.solver.traced else self.host_step

    @cached_property
    def _scan(self):
        """`step` over a range of L steps, last first, in one compiled loop: ``(lam, levels, steps, partials)``
        with ``levels = (Y0, Y1 (L+1, n), S (L+1, ...), Xi (L+1, n_ctrl), F (L+1, n))`` (S the carried states at
        the levels), ``steps = (dt (L,), V0, t0 (L,))`` and J's partials ``(gY0, gY1 (L, n), gP (L,))``, to the
        totals at the range's first level and the steps' derivatives ``(dJ/dxi_n, dJ/dxi_{n+1} (L, n_ctrl),
        dJ/ddt_n, dJ/dt_n (L,))``."""
        def run(lam, levels, steps, partials):
            (Y0, Y1, S, Xi, F), (dt, V0, t0), (gY0, gY1, gP) = levels, steps, partials

            def body(carry, inp):
                (l0, l1, ls), out = self.step(carry, inp[:-2])
                g0, g1 = inp[-2:]
                return (l0 + g0, l1 + g1, ls), out

            xs = (Y0[1:], S[1:], S[:-1], Y0[:-1], Y1[:-1], Xi[:-1], Xi[1:], F[:-1], F[1:], dt,
                  jnp.full(dt.shape[0], V0), t0, gP, gY0, gY1)
            return jax.lax.scan(body, lam, xs, reverse=True)

        return jax.jit(run)

    def record(self, grid: TimeGrid, xi, loads, u0, v0, schedule: Schedule, keep=()) -> Record:
        """Forward solve on ``grid`` (N steps) with controls xi (N+1, n_ctrl), external loads (N+1, n) and
        the initial state ``(u0, v0)``, (n,) each, keeping the level states ``schedule`` asks for and
        those at the levels ``keep``; raises `SolverError` (step, cause) like `TimeStepper.run` when a
        step fails."""
        N, n = grid.num_steps, loads.shape[1]
        bounds, levels = schedule.forward(N)
        hold = {*levels, *keep}
        V0, y0, y1 = self._initial_state(u0, v0, grid.t)
        rec = Record(grid, xi, loads, V0, schedule, tuple(sorted(set(keep))), np.zeros(N), *_block({}, n))
        start_state = np.asarray(self.stepper.constraint.carried(0.0), dtype=np.float64)
        rec.carried = np.zeros((N + 1, *start_state.shape))
        rec.carried[0] = start_state
        blocks = [_block({0: (y0, y1)} if 0 in hold else {}, n)]
        its, status, mindet, maxgrad = np.zeros(N, int), np.zeros(N, int), np.zeros(N), np.zeros(N)
        state, start = (y0, y1), time.perf_counter()
        for a, b in zip(bounds[:-1], bounds[1:]):
            kept, state, monitors = self._steps(rec, state, a, b, hold)
            blocks.append(kept)
            rec.carried[a + 1:b + 1], its[a:b], status[a:b], mindet[a:b], maxgrad[a:b] = (
                np.asarray(m) for m in jax.device_get(monitors))
            rec.p_steps[a:b] = np.asarray(self.stepper.constraint.pressure(rec.carried[a + 1:b + 1]))
            self.stepper.raise_on_failure(status, grid, its, mindet)
        rec.levels, rec.y0, rec.y1 = (np.concatenate(parts) for parts in zip(*blocks))
        rec.newton_iterations, rec.min_det_F, rec.max_grad = its, mindet, maxgrad
        rec.wall_time = time.perf_counter() - start
        return rec

    def _initial_state(self, u0, v0, t):
        """``(V0, y0, y1)``: the constrained quantity of u0 (`TimeStepper.constraint_reference`, its target
        checked on the levels t) and the level-0 state as JAX arrays."""
        V0 = self.stepper.constraint_reference(u0, t)
        return V0, on_device(u0), on_device(v0)

    def _steps(self, rec: Record, state, a: int, b: int, hold=()):
        """The steps a .. b-1 from ``state = (y0, y1)`` at level a with Newton's first guess ``p_{a-1/2}`` (0
        at a = 0), by the loop of ``rec.schedule``: the stepper's own loop or one jitted step at a time.
        Returns the states at the levels ``hold`` in a+1 .. b as a `_block` (only those stay in memory), the
        state at level b and the steps' ``(carried state, iterations, status, min det F, max |grad u|)``, (b - a,)
        each (on the device for the jitted steps)."""
        s = rec.carried[a]
        p_prev = float(s) if s.ndim == 0 else s  # a number as `TimeStepper.run` passes it: the loops are shared
        if rec.schedule.compiled:
            out = self.stepper.march_levels(*state, p_prev, rec.grid.t[a:b + 1], rec.xi[a:b + 1], rec.loads[a:b + 1],
                                            rec.V0)
            Y0, Y1, *monitors = (np.asarray(o) for o in out[:7])
            rows = np.flatnonzero([n in hold for n in range(a + 1, b + 1)])
            return (rows + a + 1, Y0[rows], Y1[rows]), (Y0[-1], Y1[-1]), monitors
        carry, kept, monitors = (*state, jnp.asarray(p_prev, dtype=jnp.float64), jnp.asarray(False)), {}, []
        for n in range(a + 1, b + 1):
            carry, out = self.stepper.advance(carry, rec.step_inputs(n - 1))
            monitors.append(out[2:7])
            if n in hold:
                kept[n] = out[:2]
        return _block(kept, rec.loads.shape[1]), out[:2], list(zip(*monitors))

    def backward(self, rec: Record, g_kept, gP):
        """Totals ``(dJ/dxi (N+1, n_ctrl), dJ/ddt (N,))`` of the state's dependence, by the reverse actions of
        ``rec.schedule``, from J's partials ``g_kept = (dJ/dy0, dJ/dy1)`` at the levels ``rec.keep``,
        (len(keep), n) each (zero at the other levels), and ``gP = dJ/dp`` (N,)."""
        reversal = _Reversal(self, rec, g_kept, np.asarray(gP))
        for action in rec.schedule.reverse(rec.grid.num_steps):
            reversal.run(action)
        return reversal.totals()


def _block(states: dict, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Level states on the host, ``(levels (k,), y0 (k, n), y1 (k, n))``, from ``{level: (y0, y1)}``."""
    pairs = list(states.values())
    return (np.array(list(states), dtype=int), np.reshape([y0 for y0, _ in pairs], (-1, n)),
            np.reshape([y1 for _, y1 in pairs], (-1, n)))


class _Reversal:
    """The reverse pass over a `Record`: the snapshots (the kept states, then as the actions store and
    free them), the current state, the first level of the part reversed so far with its state, the
    totals ``lam = (dJ/dy0, dJ/dy1, dJ/ds)`` there (s the constraint's carried state) and the derivatives of
    the steps reversed."""

    def __init__(self, adjoint: Adjoint, rec: Record, g_kept, gP: np.ndarray):
        N = rec.grid.num_steps
        self.adjoint, self.rec, self.gP = adjoint, rec, gP
        self.g, self.g_row = [np.asarray(g) for g in g_kept], {k: i for i, k in enumerate(rec.keep)}
        self.snapshots, self.current = dict(zip(rec.levels.tolist(), zip(rec.y0, rec.y1))), None
        self.top = {N: self.snapshots[N]} if N in self.snapshots else {}
        self.lam = (*(self._partial(N) or (np.zeros(rec.loads.shape[1]),) * 2), np.zeros_like(rec.carried[0]))
        self.derivatives = []

    def run(self, action) -> None:
        match action:
            case Advance(a, b):
                self.current = self.adjoint._steps(self.rec, self.current, a, b)[1]
            case Store(k):
                self.snapshots[k] = self.current
            case Restore(k):
                self.current = self.snapshots[k]
            case Free(k):
                del self.snapshots[k]
            case Reverse(a, b):
                Y0, Y1 = self._states(a, b)
                self.derivatives.append((a, b, self._reverse(a, b, Y0, Y1)))
                self.top = {a: (Y0[0], Y1[0])}

    def _states(self, a: int, b: int):
        """The states at the levels a .. b, ``(y0s, y1s)`` with b - a + 1 rows each: the record's when it
        keeps them all; otherwise the current state, then the snapshots and the top when they hold all of
        a+1 .. b, or else the states recomputed from the current one."""
        span = self.rec.span(a, b)
        if span is not None:
            return span
        levels = range(a + 1, b + 1)
        held = {**self.snapshots, **self.top}
        if all(k in held for k in levels):
            rest = [held[k] for k in levels]
        else:
            rest = zip(*self.adjoint._steps(self.rec, self.current, a, b, levels)[0][1:])
        return tuple(zip(self.current, *rest))

    def _reverse(self, a: int, b: int, Y0, Y1):
        """`Adjoint.step` over the steps a .. b-1, last first, from the states ``Y0, Y1`` at the levels a .. b:
        moves ``lam`` to level a; returns the steps' ``(dJ/dxi_n, dJ/dxi_{n+1} (L, n_ctrl), dJ/ddt_n,
        dJ/dt_n (L,))``."""
        rec, adjoint = self.rec, self.adjoint
        if rec.schedule.compiled and adjoint.stepper.solver.traced:
            levels = tuple(on_device(x) for x in (Y0, Y1, rec.carried[a:b + 1], rec.xi[a:b + 1], rec.loads[a:b + 1]))
            steps = (on_device(rec.dt[a:b]), rec.V0, on_device(rec.grid.t[a:b]))
            partials = (*(on_device(g) for g in self._partials(a, b)), on_device(self.gP[a:b]))
            self.lam, out = adjoint._scan(self.lam, levels, steps, partials)
            return out
        outs = [None] * (b - a)
        for n in reversed(range(a, b)):
            step_in = (Y0[n - a + 1], rec.carried[n + 1], rec.carried[n], Y0[n - a], Y1[n - a], *rec.step_inputs(n),
                       self.gP[n])
            (l0, l1, ls), outs[n - a] = adjoint._jitted_step(self.lam, step_in)
            g = self._partial(n)
            self.lam = (l0, l1, ls) if g is None else (l0 + g[0], l1 + g[1], ls)
        return tuple(zip(*outs))

    def _partial(self, k: int) -> tuple | None:
        """J's partials ``(dJ/dy0, dJ/dy1)`` at level k, (n,) each, or None unless given there."""
        i = self.g_row.get(k)
        return None if i is None else (self.g[0][i], self.g[1][i])

    def _partials(self, a: int, b: int) -> np.ndarray:
        """J's partials ``(dJ/dy0, dJ/dy1)`` at the levels a .. b-1, (2, b - a, n) (zero where not given)."""
        keep = np.asarray(self.rec.keep, dtype=int)
        i, j = np.searchsorted(keep, [a, b])
        g = np.zeros((2, b - a, self.rec.loads.shape[1]))
        g[:, keep[i:j] - a] = self.g[0][i:j], self.g[1][i:j]
        return g

    def totals(self) -> tuple[np.ndarray, np.ndarray]:
        """``(dJ/dxi (N+1, n_ctrl), dJ/ddt (N,))`` from the derivatives of all steps. The level t_n =
        t_0 + sum_{k<n} dt_k moves with every earlier step, so ``dJ/ddt_k`` gathers ``dJ/dt_n`` of the
        steps n > k."""
        xi = self.rec.xi
        gxi0, gxi1, gdt, gt = np.zeros_like(xi[1:]), np.zeros_like(xi[1:]), np.zeros(len(xi) - 1), np.zeros(len(xi) - 1)
        for a, b, (d0, d1, ddt, dt0) in jax.device_get(self.derivatives):
            gxi0[a:b], gxi1[a:b], gdt[a:b], gt[a:b] = d0, d1, ddt, dt0
        gdt[:-1] += np.cumsum(gt[::-1])[::-1][1:]
        gXi = np.zeros_like(xi)
        gXi[:-1] += gxi0
        gXi[1:] += gxi1
        return gXi, gdt

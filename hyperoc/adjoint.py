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
"""

from __future__ import annotations

from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from . import _jax  # noqa: F401
from .dynamics import TimeStepper
from .errors import InputError

__all__ = ["Adjoint"]


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

    @cached_property
    def _scan(self):
        def run(lamN, gY0, gY1, xs):
            def body(carry, inp):
                (l0, l1), out = self.step(carry, inp[:-2])
                g0, g1 = inp[-2:]
                return (l0 + g0, l1 + g1), out

            _, out = jax.lax.scan(body, lamN, xs + (gY0[:-1], gY1[:-1]), reverse=True)
            return out

        return jax.jit(run)

    @cached_property
    def _jit_step(self):
        return jax.jit(self.step)

    def backward(self, Y0, Y1, P, Xi, F, dt, V0, gY0, gY1, gP):
        """Totals ``(dJ/dxi (N+1, n_ctrl), dJ/ddt (N,))`` from the state and J's partial derivatives."""
        N = dt.shape[0]
        Vs = jnp.full(N, V0)
        xs = (Y0[1:], P, Y0[:-1], Y1[:-1], Xi[:-1], Xi[1:], F[:-1], F[1:], dt, Vs, gP)
        lamN = (gY0[-1], gY1[-1])
        if self.stepper.solver.traced:
            gxi0, gxi1, gdt = self._scan(lamN, gY0, gY1, tuple(jnp.asarray(a) for a in xs))
        else:
            gxi0, gxi1, gdt = self._python_loop(lamN, gY0, gY1, xs)
        gXi = jnp.zeros_like(Xi).at[:-1].add(gxi0).at[1:].add(gxi1)
        return np.asarray(gXi), np.asarray(gdt)

    def _python_loop(self, lamN, gY0, gY1, xs):
        N = xs[0].shape[0]
        carry = lamN
        outs = [None] * N
        for n in reversed(range(N)):
            (l0, l1), out = self._jit_step(carry, tuple(jnp.asarray(a[n]) for a in xs))
            carry = (l0 + gY0[n], l1 + gY1[n])
            outs[n] = out
        return tuple(jnp.stack([o[k] for o in outs]) for k in range(3))

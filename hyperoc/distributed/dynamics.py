"""The theta scheme and its exact adjoint on MPI ranks: `TimeStepper`'s step residual and Jacobian on
each rank's cells, Newton and the adjoint's transposed solves on PETSc.

Step ``n -> n+1`` is the serial one (`hyperoc.dynamics.stepper`): with ``x = (y0', p')``,

    F_u(x) = sum_e F_u^e(y0', p'; y0, y1, dt) - dt (theta L(xi', f') + (1 - theta) L(xi, f)) = 0,
    F_c(x) = sum_r share_r(x; y0) + row_offset(p'; V0, t', s, dt) = 0,

the element parts ``F_u^e`` (inertia, damping, internal force, multiplier, the step terms: Robin boundaries
and follower pressure on the facets of the rank's cells, prescribed tension, viscosity, their time laws at
the step's levels) computed by the serial `TimeStepper.residual_at` of the model restricted to the rank's
cells, summed into the owners' rows, the loads ``L = B xi + f`` applied on the owned rows (B and f are
assembled already; ``L(xi, f, t) = B (g(t) xi) + f`` with the control's time profile g, as in
`TimeStepper.load`). The constraint (`hyperoc.dynamics.constraint`: the tissue volume ``c = int det F``, the
cavity volume ``c = V_cav`` held at ``V0 + dV(t)``, or the cavity closed by the circulation) is the serial one
restricted to the rank's cells: its share of the row (``c`` of the rank's cells; the cavity: of the wall
facets they own, the lid's apex the serial fixed point; the circulation: their volume change), its force and
tangent on those cells; the shares are summed over the ranks and the serial rest of the row (``-target``, or
the circulation's ``g (p' - p_ref)``) and its corner ``g`` added once. The carried multiplier state s (p',
or the circulation's ``(p, Pa, phase)``) follows the serial ``next_state`` on the serial vectors (the same on
every rank). The adjoint step (`hyperoc.control.adjoint`) solves
the transposed bordered step matrix by the same Schur elimination with ``col`` and ``row`` swapped (and the
element blocks transposed when a term is not symmetric), and takes the vector-Jacobian products of the same
local residual and of the owned rows' loads, in the states, the controls, dt and the level t0 (g's rate
through the loads), summed over the ranks, plus, once, those of the row's rest and of ``next_state`` (the
carried state's total, as `Adjoint.step` carries it).

States cross this module's boundary in the serial numbering, the same vector on every rank (each
step ends with an allgather of the new state): `Adjoint.record`, the checkpointing schedules and
`ReducedFunctional` then run unchanged, every rank taking the same decisions on the same values.
Memory: n floats per rank for each state the schedule holds (`hyperoc.control.revolve.Binomial`
bounds their number); the tangent, its factorization and the element kernels are distributed.
"""

from __future__ import annotations

from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np
from mpi4py import MPI

from ..control.adjoint import Adjoint
from ..dynamics.constraint import DISTRIBUTED_CONSTRAINTS, make_constraint
from ..dynamics.stepper import Scheme, StepStatus, TimeStepper
from ..errors import InputError
from ..mechanics import operators
from ..mechanics.model import StateModel
from ..solvers.linsolve import eliminate_border
from ..solvers.newton import NewtonOptions, NewtonStatus
from .layout import Layout
from .newton import KeptJacobian, newton

__all__ = ["DistributedStepper", "DistributedAdjoint"]


class DistributedStepper(TimeStepper):
    """`TimeStepper` for ``model`` (a `StateModel`, built on every rank) with Newton on PETSc over
    ``comm`` (`Layout`; ``solver`` the PC lu package or ``"gamg"``). ``scheme`` as in one process
    (multiplier "step"): with ``newton="auto"`` (default) or ``"chord"`` chord Newton keeps a
    factorization across iterations and steps, ``"full"`` factors at every iteration; Newton takes full
    steps (no line search). `run`, `march_stepwise`, `solution` and the monitors are the serial ones,
    driven one `advance` at a time.

    constraint : "tissue_volume" (default), "cavity_volume" (the endocardium's cavity held at its initial
        volume) or a constraint object of the kinds `DISTRIBUTED_CONSTRAINTS` (`hyperoc.dynamics.constraint`,
        e.g. ``CavityVolumeConstraint(model, "endocardium", change=law)``, ``Circulation(model, ...)``) or "none"
        (Newton then solves ``K dy0' = -F_u`` without a border, the adjoint ``K^T w = ...``).

    terms : the step terms of the serial model (`hyperoc.dynamics.terms`: Robin boundaries, follower pressure,
        prescribed tension, viscosity), each on the rank's cells (a boundary term on the facets whose owner
        cell is the rank's); their time laws are evaluated at the step's levels, and when one is not
        symmetric the adjoint factors the transposed element blocks (the assembled transpose).
    local : the serial `TimeStepper` of the model restricted to the rank's cells, with its terms restricted
        to the facets of those cells (each facet on the rank of its owner cell), without control and loads
        (they enter on the owned rows): the single source of the step's element terms.
    """

    def __init__(self, model: StateModel, scheme: Scheme = Scheme(), *, comm=MPI.COMM_WORLD, solver: str = "mumps",
                 terms=(), constraint="tissue_volume"):
        self.terms = tuple(terms)
        if hasattr(model, "n_u"):
            raise InputError("DistributedStepper: the dynamics of a Taylor-Hood model is not implemented")
        if scheme.multiplier != "step":
            raise InputError("DistributedStepper: multiplier must be 'step' (the adjoint's scheme)")
        self.model, self.scheme = model, scheme
        self.constraint = make_constraint(model, constraint)
        if self.constraint.kind not in DISTRIBUTED_CONSTRAINTS:
            raise InputError(f"DistributedStepper: the {self.constraint.kind!r} constraint is not implemented on the "
                             f"distributed path (only {', '.join(map(repr, DISTRIBUTED_CONSTRAINTS))})")
        self.layout = self.solver = Layout(model, comm, solver)
        #: whether a multiplier and its row border the step; without a constraint Newton solves ``K dy0' = -F_u``
        self.constrained = self.constraint.has_multiplier
        self.chord = scheme.chord_with(self.layout, auto=True)
        self._kept = KeptJacobian()  # chord Newton's Jacobian, kept across iterations and steps
        # the restricted model has no control or traction: B xi + f is assembled, it enters on the owned rows
        cells, dofs = self.layout.cells, self.layout.dofs
        local = model.restricted(cells, dofs)
        self.local = TimeStepper(local, scheme, solver=None,
                                 terms=tuple(term.restricted(model, local, cells, dofs) for term in self.terms),
                                 constraint=self.constraint.restricted(model, local, cells, dofs))
        # B's owned rows (JAX sparse) and the control's time profile g: the load B (g(t) xi) of `TimeStepper.load`
        self._B = operators.to_bcoo(model.control.load[self.layout.owned_serial]) if model.control is not None else None
        self._profile = model.control.profile if model.control is not None else None

    @cached_property
    def mass(self):
        """The serial mass matrix M (JAX sparse), for objective terms that read it."""
        return operators.to_bcoo(self.model.mass)

    @cached_property
    def _kernels(self):
        """The jitted local functions of the step on the rank's unknowns (m,) (`TimeStepper`'s, on the
        restricted model, loads zero)."""
        st = self.local
        zero = jnp.zeros(st.model.n)

        def residual(yl0, yl1, dt, t0, x):
            """The element rows (m,) and the rank's share of the constraint's value at ``x = (y0' (m,), p')``, the
            step from level t0."""
            return st.residual(x, (yl0, yl1, 0.0), (None, None), (zero, zero), dt, 0.0, t0)

        def residual_vjp(yl0, yl1, dt, t0, x, w):
            return jax.vjp(lambda a, b, c, s: residual(a, b, c, s, x), yl0, yl1, dt, t0)[1](w)

        return {"known": jax.jit(lambda yl0, yl1, dt, t0: st.known_terms(yl0, yl1, None, None, zero, zero, dt, t0)),
                "residual_at": jax.jit(lambda x, known, yl0, yl1, dt, t0: st.residual_at(x, known, yl0, yl1, 0.0, dt,
                                                                                         0.0, t0)),
                "jacobian": jax.jit(lambda x, yl0, yl1, dt, t0: st.jacobian_parts(x, yl0, dt, yl1, t0)),
                "residual_vjp": jax.jit(residual_vjp),
                "velocity_vjp": jax.jit(lambda a, b, c, dt, w: jax.vjp(st.velocity, a, b, c, dt)[1](w)),
                "owned_load": jax.jit(self.owned_load),
                "owned_load_vjp": jax.jit(lambda xi0, xi1, f0, f1, dt, t0, w: jax.vjp(
                    lambda a, b, c, d: self.owned_load(a, b, f0, f1, c, d), xi0, xi1, dt, t0)[1](w)),
                "volume": jax.jit(st.model.volume), "constraint_value": jax.jit(st.constraint.value),
                "min_det_F": jax.jit(st.model.min_det_F), "max_grad": jax.jit(st.model.max_grad),
                **self._serial_kernels}

    @cached_property
    def _serial_kernels(self):
        """The jitted functions of the serial constraint (scalars and serial vectors, the same on every rank):
        the row's rest, its corner, the carried state and their vector-Jacobian products."""
        con = self.constraint

        def offset_vjp(p, V0, t0, s, dt, w):
            return jax.vjp(lambda s, dt, t0: con.row_offset(p, V0, t0 + dt, s, dt), s, dt, t0)[1](w)

        return {"row_offset": jax.jit(lambda p, V0, t0, s, dt: con.row_offset(p, V0, t0 + dt, s, dt)),
                "corner": jax.jit(con.corner), "next_state": jax.jit(con.next_state),
                "offset_vjp": jax.jit(offset_vjp),
                "state_vjp": jax.jit(lambda s_new, s, x, y0, dt, gp, lam_s: jax.vjp(con.next_state, s, x, y0, dt)[1](
                    lam_s + jax.vjp(con.pressure, s_new)[1](gp)[0]))}

    def owned_load(self, xi0, xi1, f0, f1, dt, t0):
        """``-dt (theta L(xi1, f1, t0 + dt) + (1 - theta) L(xi0, f0, t0))`` on the owned rows (m_o,), traced:
        ``L(xi, f, t) = B (g(t) xi) + f`` (`TimeStepper.load`; g the control's time profile, 1 without one)."""
        o, th = self.layout.owned_serial, self.scheme.theta

        def load(xi, f, t):
            if self._B is None:
                return f[o]
            return f[o] + self._B @ (xi if self._profile is None else self._profile(t) * xi)

        return -dt * (th * load(xi1, f1, t0 + dt) + (1 - th) * load(xi0, f0, t0))

    def deformed_volume(self, y0) -> float:
        return self.layout.sum(self._kernels["volume"](jnp.asarray(np.asarray(y0)[self.layout.dofs])))

    def level_volumes(self, Y0) -> np.ndarray:
        return np.array([self.deformed_volume(y) for y in Y0])

    def constraint_value(self, y0) -> float:
        """The constrained quantity ``c(y0)`` of a serial state (n,): the ranks' shares summed."""
        return self.layout.sum(self._kernels["constraint_value"](jnp.asarray(np.asarray(y0)[self.layout.dofs])))

    def advance(self, carry, inputs):
        """One step, as `TimeStepper.advance`: carry ``(y0, y1, p, failed)``, inputs ``(xi0, xi1, f0, f1,
        dt, V0)``, the states and loads serial (n,); returns the new carry and ``(y0', y1', p', iterations,
        status, min det F, max |grad u|)``."""
        y0, y1, s_prev, failed = carry
        xi0, xi1, f0, f1, dt, V0, t0 = inputs
        y0, y1, dt, V0, t0 = np.asarray(y0), np.asarray(y1), float(dt), float(V0), float(t0)
        s_prev = jnp.asarray(s_prev, dtype=jnp.float64)
        if bool(failed):
            return carry, (y0, y1, _host(s_prev), 0, int(StepStatus.AFTER_FAILURE), np.nan, np.nan)
        L, k, sch = self.layout, self._kernels, self.scheme
        d, o = L.dofs, L.owned_serial
        yl0, yl1 = jnp.asarray(y0[d]), jnp.asarray(y1[d])
        with L.clock("kernels"):
            known = k["known"](yl0, yl1, dt, t0)
        with L.clock("kernels"):
            load = np.asarray(k["owned_load"](*(jnp.asarray(a) for a in (xi0, xi1, f0, f1)), dt, t0))

        def residual(xl, q):
            with L.clock("kernels"):
                r = np.asarray(k["residual_at"](jnp.append(jnp.asarray(xl), q), known, yl0, yl1, dt, t0))
            if not self.constrained:  # the local gauge row is not a row of the step
                return L.add(r[:-1]) + load
            with L.clock("kernels"):
                offset = float(k["row_offset"](q, V0, t0, s_prev, dt))
            return np.append(L.add(r[:-1]) + load, L.sum(r[-1]) + offset)

        def jacobian(xl, q):
            with L.clock("kernels"):
                parts = k["jacobian"](jnp.append(jnp.asarray(xl), q), yl0, yl1, dt, t0)
                # the parts' corners are 0, and a restricted constraint has no low-rank part (a fixed apex)
                blocks, col, row = (np.asarray(a) for a in parts[:3])
            return (blocks, L.add(col), L.add(row)) if self.constrained else (blocks, None, None)

        p0 = float(self.constraint.pressure(s_prev))
        guess = y0[o] + dt * y1[o]
        options = NewtonOptions(sch.rtol, sch.atol, sch.max_iter)
        x, it, status = newton(residual, jacobian, L, np.append(guess, p0) if self.constrained else guess, options,
                               constrained=self.constrained, kept=self._kept if self.chord else None,
                               corner=float(k["corner"](s_prev, dt)))
        y0n, pn = L.serial(x[:L.owned_size]), x[-1] if self.constrained else 0.0
        with L.clock("kernels"):
            pn = _host(k["next_state"](s_prev, jnp.append(jnp.asarray(y0n), pn), jnp.asarray(y0), dt))
        with L.clock("kernels"):
            mindet, maxgrad = (f(k[name](jnp.asarray(y0n[d]))) for f, name in ((L.min, "min_det_F"),
                                                                                (L.max, "max_grad")))
        if status == NewtonStatus.CONVERGED and not mindet > 0:
            status = StepStatus.DET_F
        y1n = np.asarray(self.velocity(y0n, y0, y1, dt))
        return (y0n, y1n, pn, status != NewtonStatus.CONVERGED), (y0n, y1n, pn, it, int(status), mindet, maxgrad)


def _host(state):
    """A carried multiplier state on the host: a float (the multiplier), or an array (the circulation's)."""
    state = np.asarray(state, dtype=np.float64)
    return float(state) if state.ndim == 0 else state


class DistributedAdjoint(Adjoint):
    """`Adjoint` of a `DistributedStepper`: the backward step on the ranks, one step at a time (the
    forward pass and the checkpointing schedules are `Adjoint`'s)."""

    stepper: DistributedStepper

    def __init__(self, stepper: DistributedStepper):
        if not isinstance(stepper, DistributedStepper):
            raise InputError("DistributedAdjoint needs a DistributedStepper")
        super().__init__(stepper)

    @property
    def _jitted_step(self):
        """The backward step the reversal calls (`Adjoint`'s is compiled; this one runs on the host)."""
        return self.step

    def step(self, carry, inputs):
        """`Adjoint.step` with the states, the totals and the loads serial (n,): the transposed bordered
        solve on PETSc, the vector-Jacobian products of the local residual summed into the owned rows,
        the control's and dt's parts reduced over the ranks."""
        st = self.stepper
        L, k = st.layout, st._kernels
        d, o = L.dofs, L.owned_serial
        lam0, lam1, lam_s = (np.asarray(c) for c in carry)
        y0n, s_new, s_prev, y0, y1, xi0, xi1, f0, f1, dt, V0, t0, gp = inputs
        y0n, y0, y1, dt, V0 = np.asarray(y0n), np.asarray(y0), np.asarray(y1), float(dt), float(V0)
        s_new, s_prev = (jnp.asarray(a, dtype=jnp.float64) for a in (s_new, s_prev))
        t0 = jnp.asarray(float(t0))
        pn = st.constraint.pressure(s_new)
        with L.clock("kernels"):
            v_y0n, v_y0, v_y1, v_dt = (np.asarray(a) for a in k["velocity_vjp"](y0n[o], y0[o], y1[o], dt, lam1[o]))
            # the carried state's total (J's partial in p' included) back to x, y0, dt and the previous state
            n_s, n_x, n_y0, n_dt = (np.asarray(a) for a in k["state_vjp"](
                s_new, s_prev, jnp.append(jnp.asarray(y0n), pn), jnp.asarray(y0), dt, jnp.asarray(float(gp)),
                jnp.asarray(lam_s)))
            x = jnp.append(jnp.asarray(y0n[d]), pn)
            parts = k["jacobian"](x, jnp.asarray(y0[d]), jnp.asarray(y1[d]), dt, t0)
            blocks, col, row = (np.asarray(a) for a in parts[:3])  # the parts' corners are 0, no low-rank part
            corner = float(k["corner"](s_prev, dt))
        if not st.symmetric:  # the assembled transpose: the transposed blocks on the same pattern
            blocks = np.swapaxes(blocks, 1, 2)
        L.factor(blocks)
        if st.constrained:
            w_u, w_p = eliminate_border(L.solve(lam0[o] + v_y0n + n_x[:-1][o], L.add(row)), L.add(col),
                                        float(n_x[-1]), dot=L.dot, corner=corner)  # transpose: col <-> row
        else:  # K^T w = the totals; the gauge's transposed row gives w_p = 0 (`NoConstraint`)
            w_u, w_p = L.solve(lam0[o] + v_y0n + n_x[:-1][o])[:, 0], 0.0
        with L.clock("kernels"):
            w = jnp.append(jnp.asarray(L.local_of_owned(w_u)), w_p)
            r_y0, r_y1, r_dt, r_t0 = (np.asarray(a) for a in k["residual_vjp"](jnp.asarray(y0[d]), jnp.asarray(y1[d]),
                                                                               dt, t0, x, w))
            # the loads' part -dt (th L1 + (1 - th) L0) on the owned rows, in the controls, dt and t0
            l_xi0, l_xi1, l_dt, l_t0 = (np.asarray(a) for a in k["owned_load_vjp"](
                *(jnp.asarray(a) for a in (xi0, xi1, f0, f1)), dt, t0, jnp.asarray(w_u)))
            # the row's rest, added once after the sum of the shares (no row without a constraint)
            o_s, o_dt, o_t0 = ((np.asarray(a) for a in k["offset_vjp"](pn, V0, t0, s_prev, dt, jnp.asarray(w_p)))
                               if st.constrained else (np.zeros_like(np.asarray(lam_s)), 0.0, 0.0))
        lam = (L.serial(v_y0 - L.add(r_y0)) + n_y0, L.serial(v_y1 - L.add(r_y1)), n_s - o_s)
        return lam, (-L.sum_array(l_xi0), -L.sum_array(l_xi1),
                     L.sum(float(v_dt) - float(r_dt) - float(l_dt)) + float(n_dt) - float(o_dt),
                     -L.sum(float(r_t0) + float(l_t0)) - float(o_t0))

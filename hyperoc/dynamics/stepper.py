"""Theta-scheme time stepping of the damped hyperelastic system with a global volume constraint.

First-order system ``y0 = u``, ``y1 = u_t``; step ``n -> n+1`` of size ``dt``:

    y0' = y0 + dt (theta y1' + (1 - theta) y1)
    M (y1' - y1) + dt [theta A(y0', y1', t') + (1 - theta) A(y0, y1, t)] + dt p' [theta G(y0') + (1 - theta) G(y0)]
                 = dt [theta L(xi') + (1 - theta) L(xi)]
    c(y0') = target(V0, t')

with ``A(y0, y1, t) = kappa K y1 + R(y0) + sum_j A_j(y0, y1, t)`` (damping kappa = ``StateModel.damping``;
``A_j`` the stepper's ``terms``, `hyperoc.dynamics.terms`: Robin boundaries, time-dependent follower
pressure, prescribed active tension, viscosity), ``L(xi) = B xi + g``, t and t' = t + dt the step's
levels. The unknown of a step is ``x = (y0', p')``; ``y1'`` follows from the first line. ``p'`` is the
step's multiplier, a second-order approximation of p at the mid-step; pressures at time levels are
interpolated from the two adjacent steps (second order on non-uniform grids too). The constraint is one
of a family (`hyperoc.dynamics.constraint`): the paper's tissue volume (``c = vol``, ``G = dvol/du``,
target V0, the initial volume), the cavity volume (``c = V_cav``, ``G = -dV_cav/du``, target
``V0 + dV(t)``: p is then the cavity pressure acting on its wall), or none (no multiplier, the last row a
gauge, the reported pressure 0).

``multiplier="theta"`` weights the multiplier as ``theta p' G' + (1 - theta) p G`` (the paper's
and GetFEM's choice), with ``p`` at t = 0 from the consistent initial acceleration. It is kept for
comparison: at theta = 1/2 it carries an undamped alternating mode (see `tests/`).

When the linear solver is traced (dense, tridiagonal) one step is a JAX function (Newton with
backtracking inside a ``while_loop``) and the whole time loop one compiled ``lax.scan``. With a host
solver (sparse LU, PARDISO) the same Newton iteration runs on the host (`hyperoc.solvers.host_newton`),
the step's residual and Jacobian jitted apart: programs without host callbacks, which the persistent
compilation cache keeps from one process to the next.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field
from enum import IntEnum
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from .._jax import on_device
from ..errors import InputError, SolverError
from ..mechanics.model import StateModel
from ..mechanics.operators import combined_matvec
from ..solvers.host_newton import Reductions, host_newton, solver_steps
from ..solvers.linsolve import make_solver
from ..solvers.newton import NewtonOptions, NewtonStatus, newton
from .constraint import make_constraint
from .timegrid import TimeGrid

__all__ = ["Scheme", "StateSolution", "StepRecord", "StepStatus", "TimeStepper", "solve_state", "level_pressure",
           "level_pressure_steps"]


class StepStatus(IntEnum):
    """How a time step ended (the compiled loop's traced int): `NewtonStatus`, then what the step adds."""

    OK = NewtonStatus.CONVERGED
    NEWTON = NewtonStatus.MAX_ITERATIONS
    NON_FINITE = NewtonStatus.NON_FINITE
    #: Newton converged to a state with an inverted element (min det F <= 0)
    DET_F = 3
    #: an earlier step failed; this one made no Newton iteration
    AFTER_FAILURE = 4

    @property
    def cause(self) -> str:
        """The name `StepRecord.status` and `hyperoc.errors.SolverError` give it."""
        return _CAUSES[self]


_CAUSES = {StepStatus.OK: "ok", StepStatus.NEWTON: "newton", StepStatus.NON_FINITE: "nonfinite",
           StepStatus.DET_F: "detF", StepStatus.AFTER_FAILURE: "after a failed step"}

# Steps per block of the compiled time loop (`TimeStepper.march`): long enough that a block's dispatch is
# small beside its steps, short enough that the padding of the last block (inactive steps, a few
# microseconds each on the traced 1D path) is too, and that a progress bar moves.
MARCH_BLOCK = 128


@dataclass(frozen=True)
class Scheme:
    """Time-stepping options.

    theta : 1/2 (Crank-Nicolson, second order) ... 1 (implicit Euler).
    multiplier : "step" (default) or "theta" (paper/GetFEM weighting, comparison only).
    rtol : Newton stops when ``|dy0|_inf <= rtol |y0'|_inf + atol``.
    atol : absolute floor of that test, in displacement units.
    max_iter : Newton iterations per step before the step is declared failed.
    newton : "auto" (default): in time stepping, chord Newton with a kept factorization
        (`hyperoc.solvers.newton.newton`'s ``chord``) where the linear solver factors on the host
        (the sparse solvers but MINRES), full Newton where it is traced (dense, tridiagonal: a
        factorization there costs about a solve); in static solves full Newton (a load step changes
        the tangent too much for a kept one to pay). "full" or "chord" to choose.
    """

    theta: float = 0.5
    multiplier: str = "step"
    rtol: float = 1e-11
    atol: float = 1e-15
    max_iter: int = 30
    newton: str = "auto"

    def __post_init__(self):
        if not 0.5 <= self.theta <= 1.0:
            raise InputError(f"theta must lie in [1/2, 1], got {self.theta}")
        if self.multiplier not in ("step", "theta"):
            raise InputError(f"multiplier must be 'step' or 'theta', got {self.multiplier!r}")
        if self.newton not in ("auto", "full", "chord"):
            raise InputError(f"newton must be 'auto', 'full' or 'chord', got {self.newton!r}")
        if not (0 < self.rtol < 1 and self.atol >= 0 and self.max_iter >= 1):
            raise InputError("Newton options: need 0 < rtol < 1, atol >= 0, max_iter >= 1")

    def chord_with(self, solver, auto: bool) -> bool:
        """Whether Newton runs as chord Newton with ``solver``: ``newton`` "chord" or "full", or for
        "auto" ``auto`` where the solver can (time stepping: True, static solves: False).
        `InputError` for "chord" with a solver that keeps no factorization."""
        can = getattr(solver, "chord", False)
        if self.newton == "chord" and not can:
            raise InputError("chord Newton needs a sparse solver that factors (lu, lu_reuse, pardiso...)")
        return can and (self.newton == "chord" or (self.newton == "auto" and auto))


def level_pressure(p_steps, dt, multiplier: str = "step"):
    """Pressure at the N+1 time levels from the N step multipliers (works on numpy and JAX arrays).

    "step": interior levels by linear interpolation of the neighbouring mid-step values
    ``p_{n-1/2}`` (at ``t_n - dt_{n-1}/2``) and ``p_{n+1/2}`` (at ``t_n + dt_n/2``); end levels by
    linear extrapolation from the two nearest mid-steps. "theta": the multipliers are level values
    already; ``p_steps`` then has N+1 entries (p_0 first) and is returned as is.
    """
    xp = jnp if isinstance(p_steps, jax.Array) else np
    if multiplier == "theta":
        return p_steps
    if p_steps.shape[0] == 1:
        return xp.concatenate([p_steps, p_steps])
    a, b = dt[:-1], dt[1:]
    interior = (b * p_steps[:-1] + a * p_steps[1:]) / (a + b)
    first = p_steps[0] - (p_steps[1] - p_steps[0]) * dt[0] / (dt[0] + dt[1])
    last = p_steps[-1] + (p_steps[-1] - p_steps[-2]) * dt[-1] / (dt[-1] + dt[-2])
    return xp.concatenate([first[None], interior, last[None]])


def _padded_after_failure(outputs: list, num_steps: int) -> list:
    """The stacked outputs of the steps run (the last one failed, if fewer than ``num_steps``) padded to
    ``num_steps`` so that indices match the grid: the last values repeated, status `StepStatus.AFTER_FAILURE`."""
    done = len(outputs[0])
    if done == num_steps:
        return outputs
    padded = [np.concatenate([o, np.repeat(o[-1:], num_steps - done, axis=0)]) for o in outputs]
    padded[4][done:] = StepStatus.AFTER_FAILURE
    return padded


def level_pressure_steps(level: int, num_steps: int) -> int:
    """How many leading step multipliers the pressure at ``level`` depends on (`level_pressure`, "step"):
    an interior level interpolates the steps on both sides of it, an end level extrapolates from the two
    nearest."""
    return min(max(level + 1, 2), num_steps)


@dataclass(frozen=True)
class StepRecord:
    """One time step ``t_n -> t_{n+1}``, as a monitor sees it when the step ends.

    step : n (0-based; the step `hyperoc.errors.SolverError` names).
    t : t_{n+1}, the time level reached.
    newton_iterations : Newton iterations of the step.
    min_det_F : the smallest det F over the quadrature points at t_{n+1}.
    volume_drift : ``|c(u_{n+1}) - target| / |target|`` of the constrained volume (tissue or cavity;
        without a constraint the tissue volume's drift from V0): the constraint holds to Newton's tolerance.
        The circulation has no fixed target: this is then its cavity volume's relative change from V0.
    pressure : the step's multiplier p' (the mid-step pressure).
    status : `StepStatus.cause`: "ok", or the cause of the failure ("newton", "nonfinite", "detF"); a
        failed step is the last one a monitor sees before the solve raises.
    """

    step: int
    t: float
    newton_iterations: int
    min_det_F: float
    volume_drift: float
    pressure: float
    status: str

    def describe(self) -> str:
        """``its 3, min det F 0.912, dV 2.1e-15, p 0.0123`` (and the cause when the step failed)."""
        text = (f"its {self.newton_iterations}, min det F {self.min_det_F:.3g}, dV {self.volume_drift:.1e}, "
                f"p {self.pressure:.4g}")
        return text if self.status == "ok" else f"{text}, FAILED: {self.status}"


@dataclass(eq=False)
class StateSolution:
    """Result of a state solve on a time grid.

    Attributes
    ----------
    t : (N+1,) time levels.
    y0, y1 : (N+1, n) reduced displacement and velocity at the levels.
    p_steps : (N,) step multipliers (mid-step pressures); (N+1,) level values for multiplier="theta".
    pressure : (N+1,) pressure at the levels (second order for multiplier="step").
    volume : (N+1,) deformed volume ``int det F`` at the levels.
    newton_iterations, min_det_F, max_grad : (N,) per-step monitors.
    xi : (N+1, n_ctrl) control at the levels (or None).
    wall_time : seconds spent in the solve (excluding compilation when it was cached).
    warnings : regimes detected after the solve (loss of convexity, under-resolved fronts).
    multiplier_states : (N, k) the multiplier states carried after each step when the constraint carries more
        than its multiplier (`hyperoc.dynamics.constraint`), else None.
    constrained_volume : (N+1,) the volume a cavity constraint holds (with its apex), at the levels; None for
        the other constraints.
    """

    model: StateModel
    t: np.ndarray
    y0: np.ndarray
    y1: np.ndarray
    p_steps: np.ndarray
    pressure: np.ndarray
    volume: np.ndarray
    newton_iterations: np.ndarray
    min_det_F: np.ndarray
    max_grad: np.ndarray
    xi: np.ndarray | None = None
    wall_time: float = 0.0
    warnings: list = field(default_factory=list)
    multiplier_states: np.ndarray | None = None
    constrained_volume: np.ndarray | None = None

    @property
    def dt(self) -> np.ndarray:
        return np.diff(self.t)

    def displacement(self) -> np.ndarray:
        """Full nodal displacement history (N+1, num_nodes, dim)."""
        return self.model.expand(self.y0)

    def velocity(self) -> np.ndarray:
        return self.model.expand(self.y1)

    def volume_drift(self) -> float:
        """max_n |vol_n - vol_0| / vol_0."""
        return float(np.max(np.abs(self.volume - self.volume[0])) / abs(self.volume[0]))

    def energies(self) -> tuple[np.ndarray, np.ndarray]:
        """Kinetic ``y1^T M y1 / 2`` and strain ``Pi(y0)`` energies at the levels, (N+1,) each."""
        M = self.model.mass
        kinetic = 0.5 * np.einsum("ti,ti->t", self.y1, (M @ self.y1.T).T)
        pi = self.model.jitted["strain_energy"]
        strain = np.array([float(pi(jnp.asarray(y))) for y in self.y0])
        return kinetic, strain

    def summary(self) -> dict:
        return {
            "steps": int(self.t.size - 1),
            "T": float(self.t[-1]),
            "dofs": int(self.model.n),
            "pressure_max": float(np.max(self.pressure)),
            "t_pressure_max": float(self.t[int(np.argmax(self.pressure))]),
            "pressure_min": float(np.min(self.pressure)),
            "volume_drift": self.volume_drift(),
            "newton_iterations_total": int(np.sum(self.newton_iterations)),
            "newton_iterations_max": int(np.max(self.newton_iterations)),
            "min_det_F": float(np.min(self.min_det_F)),
            "max_grad_u": float(np.max(self.max_grad)),
            "wall_time_s": float(self.wall_time),
            "warnings": list(self.warnings),
        }


class TimeStepper:
    """Builds the traced step of the theta-scheme for a model and drives it over a grid.

    Parameters
    ----------
    model : StateModel
    scheme : Scheme
    solver : "auto" | "tridiagonal" | "dense" | a `hyperoc.solvers.linsolve.SparseSolver` method
        (``SparseSolver.methods``: "lu", "lu_reuse", "pardiso", "pardiso_reuse", "pardiso_single",
        "pardiso_single_reuse", "minres"), or a solver object: traced (``traced = True``: ``solve`` in JAX) or on the
        host (``traced = False``: ``try_solve`` and ``try_kept_solve``, as `hyperoc.solvers.linsolve.SparseSolver`).
    terms : the terms ``A_j`` of A (`hyperoc.dynamics.terms`), e.g. ``(RobinBoundary(...), Viscosity(...))``.
    constraint : "tissue_volume" (default, the paper's), "cavity_volume" (the endocardium's cavity held at
        its initial volume), "none", or a constraint object (`hyperoc.dynamics.constraint`, e.g.
        ``CavityVolumeConstraint(model, "endocardium", change=law)``).
    """

    def __init__(self, model: StateModel, scheme: Scheme = Scheme(), solver="auto", *, terms=(),
                 constraint="tissue_volume"):
        self.model, self.scheme = model, scheme
        self.terms = tuple(terms)
        self.constraint = make_constraint(model, constraint)
        if self.constraint.kind != "tissue_volume" and scheme.multiplier != "step":
            raise InputError("multiplier='theta' (the paper's weighting) is implemented for the tissue volume "
                             "constraint only")
        if not self.symmetric and solver == "minres":
            raise InputError("the step tangent is not symmetric (follower pressure, viscosity): MINRES does not apply")
        self.solver = make_solver(model, solver) if isinstance(solver, str) else solver
        M, K, B = model.jax_operators
        self._M, self._K, self._B = M, K, B
        self._profile = model.control.profile if model.control is not None else None
        self._mass_blocks = on_device(model.mass_blocks)
        self._lap_blocks = on_device(model.laplace_blocks)
        self._inertia_damping = combined_matvec(model.mass, model.laplace)  # (y, a, b) -> a M y + b K y
        self.chord = scheme.chord_with(self.solver, auto=True)

    # --- the step residual: single source of truth for Newton and adjoint -------------------------
    @property
    def symmetric(self) -> bool:
        """Whether the step's Jacobian is symmetric (every term's is); if not, the adjoint solves with the
        transposed element blocks."""
        return all(term.symmetric for term in self.terms)

    def terms_force(self, y0, y1, t):
        """``sum_j A_j(y0, y1, t)`` (n,)."""
        return sum((term.force(y0, y1, t) for term in self.terms), jnp.zeros(self.model.n))

    @property
    def mass(self):
        """The mass matrix M of the reduced dofs (JAX sparse, as the step uses it)."""
        return self._M

    def load(self, xi, f, t):
        """``L(t) = B (g(t) xi) + f`` on the reduced dofs (f: external load vector of the level at time t; g the
        control's time profile, `hyperoc.mechanics.controls.ControlData.profile`, 1 without one)."""
        if self._B is None:
            return f
        if self._profile is not None:
            xi = self._profile(t) * xi
        return self._B @ xi + f

    def velocity(self, y0_new, y0, y1, dt):
        th = self.scheme.theta
        return (y0_new - y0) / (th * dt) - (1 - th) / th * y1

    def residual(self, x, start, controls, loads, dt, V0, t0=0.0):
        """Step residual (n+1,) from the level t0 to t0 + dt: momentum rows then the constraint's row.
        ``start = (y0, y1, p_prev)`` the state and the constraint's carried state at t0, ``controls = (xi0, xi1)``
        and ``loads = (f0, f1)`` at the step's two levels."""
        y0, y1, p_prev = start
        known = self.known_terms(y0, y1, *controls, *loads, dt, t0)
        return self.residual_at(x, known, y0, y1, p_prev, dt, V0, t0)

    def known_terms(self, y0, y1, xi0, xi1, f0, f1, dt, t0=0.0):
        """The parts of the momentum rows that do not depend on the unknown x: computed once per step
        rather than at every Newton iterate.

        Returns ``c = -M y1 + dt (1 - th) A(y0, y1, t0) - dt (th L1 + (1 - th) L0)`` (n,),
        ``A(y0, y1, t) = kappa K y1 + f_int(y0) + sum_j A_j(y0, y1, t)``.
        """
        m, th = self.model, self.scheme.theta
        return (self._inertia_damping(y1, -1.0, dt * (1 - th) * m.damping)
                + dt * (1 - th) * (m.internal_force(y0) + self.terms_force(y0, y1, t0))
                - dt * (th * self.load(xi1, f1, t0 + dt) + (1 - th) * self.load(xi0, f0, t0)))

    def residual_at(self, x, known, y0, y1, p_prev, dt, V0, t0=0.0):
        """`residual` given the `known_terms` of the step."""
        m, th, con = self.model, self.scheme.theta, self.constraint
        y0n, _ = con.split(x)
        y1n = self.velocity(y0n, y0, y1, dt)
        A = m.internal_force(y0n) + self.terms_force(y0n, y1n, t0 + dt)
        Fu = (self._inertia_damping(y1n, 1.0, dt * th * m.damping) + dt * th * A
              + dt * con.momentum(x, y0, p_prev, th, self.scheme.multiplier) + known)
        return jnp.concatenate([Fu, jnp.reshape(con.row(x, V0, t0 + dt, y0, p_prev, dt), (1,))])

    def jacobian_parts(self, x, y0, dt, y1=None, t0=0.0, p_prev=0.0):
        """(element blocks of dFu/dy0', border column, border row, corner dF_c/dp', the dense low-rank part
        ``(U, W)`` of dFu/dy0' or None) at x (`hyperoc.dynamics.constraint`, `hyperoc.solvers.linsolve`); ``y1``
        (the level's velocity) is needed when a term depends on the velocity, ``p_prev`` (the carried multiplier
        state) when the constraint's row does."""
        m, th, con = self.model, self.scheme.theta, self.constraint
        y0n, _ = con.split(x)
        blocks = con.add_tangent(self._mass_blocks / (th * dt) + m.damping * self._lap_blocks
                                 + dt * th * m.tangent_blocks(y0n, 1.0, con.tangent_weight(x)), x, dt * th)
        if self.terms:
            y1n = self.velocity(y0n, y0, y1, dt)
            for term in self.terms:
                blocks = term.add_tangent(blocks, y0n, y1n, t0 + dt, dt * th, 1.0)
        col, row = con.border(blocks, x, y0, dt, th, self.scheme.multiplier)
        return blocks, col, row, con.corner(p_prev, dt), con.low_rank(x, dt * th)

    def step(self, carry, inputs):
        """One time step on traced arrays.

        carry = (y0, y1, p_prev, failed); inputs = (xi0, xi1, f0, f1, dt, V0, t0) with f the external
        load vectors at both ends of the step and t0 its first level. ``p_prev`` is the constraint's carried
        multiplier state (`hyperoc.dynamics.constraint`: the step multiplier, or a small vector whose first
        entry it is), carried as the outputs' p.
        """
        y0, y1, p_prev, failed = carry
        xi0, xi1, f0, f1, dt, V0, t0 = inputs
        m, sch, con = self.model, self.scheme, self.constraint
        known = self.known_terms(y0, y1, xi0, xi1, f0, f1, dt, t0)

        # After a failed step no Newton iteration is made (max_iter 0: x stays at the old state);
        # a traced bound rather than a lax.cond, which costs XLA's CPU runtime more per step.
        x, it, status = newton(lambda x: self.residual_at(x, known, y0, y1, p_prev, dt, V0, t0),
                               lambda x: self.jacobian_parts(x, y0, dt, y1, t0, p_prev),
                               self.solver, con.unknown(y0 + dt * y1, p_prev),
                               rtol=sch.rtol, atol=sch.atol, max_iter=jnp.where(failed, 0, sch.max_iter),
                               chord=self.chord)
        y0n, _ = con.split(x)
        pn = con.next_state(p_prev, x, y0, dt)
        mindet, maxgrad = m.min_det_F(y0n), m.max_grad(y0n)
        status = jnp.where(failed, int(StepStatus.AFTER_FAILURE),
                           jnp.where((status == int(NewtonStatus.CONVERGED)) & ~(mindet > 0), int(StepStatus.DET_F),
                                     status))
        y1n = self.velocity(y0n, y0, y1, dt)
        failed = failed | (status != 0)
        return (y0n, y1n, pn, failed), (y0n, y1n, pn, it, status, mindet, maxgrad)

    def march(self, y0, y1, p0, xis, fs, ts, V0, on_block=None):
        """The compiled loop over levels: from the state ``(y0, y1)`` (n,) with Newton's first multiplier
        guess p0, controls xis (L+1, n_ctrl), loads fs (L+1, n), levels ts (L+1,) and the reference volume
        V0, the outputs of `step` stacked over the L steps (NumPy): (y0, y1 (L, n), p, iterations,
        status, min det F, max |grad u| (L,)).

        The steps run in blocks of `MARCH_BLOCK` (one block when fewer), the last block padded with
        inactive steps, so that a whole solve, a gradient's shorter horizon and a progress bar's blocks
        share one compiled loop (`_block_scan`). No block runs after one in which a step failed; the
        outputs are then padded as `march_stepwise` pads them. ``on_block(done)``: called after each
        block with the steps done so far."""
        ts = np.asarray(ts, dtype=np.float64)
        dts, t0s = np.diff(ts), ts[:-1]
        L = len(dts)
        size = min(L, MARCH_BLOCK)
        carry = (on_device(y0), on_device(y1), on_device(p0), jnp.asarray(False))
        xis, fs = np.asarray(xis), np.asarray(fs)
        outs = []
        for start in range(0, L, size):
            levels = np.minimum(np.arange(start, start + size + 1), L)  # the last level repeated as padding
            steps = np.minimum(np.arange(start, start + size), L - 1)
            carry, out = self._block_scan(carry, xis[levels], fs[levels], dts[steps], np.full(size, V0), t0s[steps],
                                          np.arange(start, start + size) < L)
            outs.append(out)
            if on_block is not None:
                on_block(min(start + size, L))
            if bool(carry[3]):  # a step failed: the others would make no Newton iteration
                break
        done = min(len(outs) * size, L)
        return _padded_after_failure([np.concatenate([np.asarray(o[k]) for o in outs])[:done]
                                      for k in range(len(outs[0]))], L)

    @cached_property
    def _block_scan(self):
        """`march`'s compiled loop over one block of steps from a carry, returning the final carry and the
        outputs: ``(carry, xis (B+1, n_ctrl), fs (B+1, n), dts (B,), V (B,), t0s (B,), active (B,))``. An inactive step
        makes no Newton iteration (it is run as after a failure) and leaves the carry as it was."""
        def masked_step(carry, inputs):
            *step_inputs, active = inputs
            y0, y1, p, failed = carry
            new, out = self.step((y0, y1, p, failed | ~active), tuple(step_inputs))
            return jax.tree.map(lambda a, b: jnp.where(active, a, b), new, carry), out

        def run(carry, xis, fs, dts, V, t0s, active):
            return jax.lax.scan(masked_step, carry, (xis[:-1], xis[1:], fs[:-1], fs[1:], dts, V, t0s, active))

        return jax.jit(run)

    def _march_with_bar(self, y0, y1, p0, xis, fs, grid, V0):
        """`march` with a progress bar updated between its blocks: "compiling" until the first block has
        run, then the steps."""
        from tqdm.auto import tqdm

        bar = tqdm(total=grid.num_steps, desc="compiling", leave=False)

        def advanced(done):
            if bar.n == 0:  # the ETA from here on counts steps, not the compilation
                bar.set_description("time steps", refresh=False)
                bar.reset()
            bar.update(done - bar.n)

        try:
            return self.march(y0, y1, p0, xis, fs, grid.t, V0, on_block=advanced)
        finally:
            bar.close()

    @cached_property
    def advance(self):
        """One step, ``advance(carry, inputs) -> (carry, outputs)``: carry ``(y0, y1, p, failed)``, inputs
        ``(xi0, xi1, f0, f1, dt, V0, t0)``, outputs as in `march`; `step` jitted for a traced solver, else
        `host_step`."""
        return jax.jit(self.step) if self.solver.traced else self.host_step

    def host_step(self, carry, inputs):
        """`step` for a host solver: the same Newton iteration driven from the host
        (`hyperoc.solvers.host_newton.host_newton`), its residual and Jacobian parts jitted apart
        (`_host_kernels`), the bordered solves by the solver on the host (``try_solve``, ``try_kept_solve``)."""
        y0, y1, p_prev, failed = carry
        xi0, xi1, f0, f1, dt, V0, t0 = inputs
        if bool(failed):
            return carry, (y0, y1, p_prev, 0, int(StepStatus.AFTER_FAILURE), np.nan, np.nan)
        k, sch, solver = self._host_kernels, self.scheme, self.solver
        known = k["known"](y0, y1, xi0, xi1, f0, f1, dt, t0)

        fresh, kept = solver_steps(solver, lambda x: k["jacobian"](x, y0, dt, y1, t0, p_prev), self.chord)
        x0 = np.asarray(k["guess"](y0, y1, dt, p_prev))
        x, it, status = host_newton(lambda x: np.asarray(k["residual_at"](x, known, y0, y1, p_prev, dt, V0, t0)),
                                    fresh, kept, x0, NewtonOptions(sch.rtol, sch.atol, sch.max_iter),
                                    Reductions(x0.size - 1), chord=self.chord, refresh=False)
        y0n, y1n, pn, mindet, maxgrad = jax.device_get(k["after"](x, y0, y1, p_prev, dt))
        status = int(StepStatus.DET_F if status == NewtonStatus.CONVERGED and not mindet > 0 else status)
        return (y0n, y1n, pn, status != 0), (y0n, y1n, pn, it, status, mindet, maxgrad)

    @cached_property
    def _host_kernels(self):
        """The jitted parts of `host_step`: the step's known terms, residual, Jacobian parts, Newton's first
        guess and what follows the solve (the new state, the carried multiplier state, min det F, max |grad u|)."""
        m, con = self.model, self.constraint

        def after(x, y0, y1, p_prev, dt):
            y0n, _ = con.split(x)
            return (y0n, self.velocity(y0n, y0, y1, dt), con.next_state(p_prev, x, y0, dt), m.min_det_F(y0n),
                    m.max_grad(y0n))

        return {"known": jax.jit(self.known_terms), "residual_at": jax.jit(self.residual_at),
                "jacobian": jax.jit(self.jacobian_parts),
                "guess": jax.jit(lambda y0, y1, dt, p: con.unknown(y0 + dt * y1, p)), "after": jax.jit(after)}

    def march_levels(self, y0, y1, p_prev, t, xi, loads, V0):
        """This stepper's own loop (`march`, or `march_stepwise` for host solvers) over the levels
        ``t`` (L+1,) from ``(y0, y1)`` with previous multiplier ``p_prev`` (Newton's initial guess; a
        Python float, as `run` passes it, so that the compiled loops are shared); xi (L+1, n_ctrl),
        loads (L+1, n). Returns the outputs of `march` for the levels after the first."""
        if self.solver.traced:
            return self.march(y0, y1, p_prev, xi, loads, t, V0)
        return self.march_stepwise(y0, y1, p_prev, xi, loads, TimeGrid(t), V0, False)

    # --- driver ---------------------------------------------------------------------------------
    def consistent_pressure(self, y0, y1, xi, f, t=0.0):
        """The pressure consistent with the state (second time derivative of the constraint), traced.

        ``G^T a + y1^T H y1 = 0`` with ``M a = L(xi, f) - A(y0, y1) - p G`` gives
        ``p = (G^T M^-1 (L - A) + y1^T H y1) / (G^T M^-1 G)``; differentiable in all arguments.
        """
        m = self.model
        G = m.volume_gradient(y0)
        _, Hy1 = jax.jvp(m.volume_gradient, (y0,), (y1,))
        rhs = self.load(xi, f, t) - m.damping * (self._K @ y1) - m.internal_force(y0) - self.terms_force(y0, y1, t)
        MinvG = m.apply_mass_inverse(G)
        return (MinvG @ rhs + y1 @ Hy1) / (G @ MinvG)

    def initial_pressure(self, y0, y1, xi0, f0, t0: float = 0.0) -> float:
        """p(t0) from the consistent initial acceleration (`consistent_pressure` at the first level t0)."""
        return float(self.consistent_pressure(*(jnp.asarray(a) for a in (y0, y1, xi0, f0)), t0))

    def run(self, grid: TimeGrid, xi=None, *, u0=None, v0=None, external=None, progress: bool = False,
            monitor=None, diagnose: bool = True) -> StateSolution:
        """Integrate on ``grid`` with nodal controls ``xi`` (N+1, n_ctrl) (None = no control).

        ``diagnose``: run `detect_regimes` on the result (optimizers skip it inside their loops).

        ``monitor``: called with a `StepRecord` as each step ends (a failed step included, before
        `SolverError` is raised), e.g. ``monitor=lambda r: print(r.step, r.describe())``. With a
        monitor the steps are driven from Python even when the linear solver is traced (one
        dispatch per step instead of one compiled loop). ``progress``: a bar over the steps,
        labelled "compiling" until the first step has run; where the steps are driven from Python
        (a host solver, or a monitor) it shows the last record, where they are compiled it advances
        by blocks of steps (`march`).

        ``external``: external load vectors per level, (N+1, n), or a callable ``t -> (n,)``
        (e.g. ``lambda t: model.load_vector(traction=g, t=t)``); default: the model's constant traction.
        """
        m = self.model
        N = grid.num_steps
        y0 = np.zeros(m.n) if u0 is None else np.asarray(u0, dtype=np.float64)
        y1 = np.zeros(m.n) if v0 is None else np.asarray(v0, dtype=np.float64)
        xis = self._controls(xi, N)
        fs = self.external_loads(external, grid)
        self._check_initial_velocity(y0, y1, grid.t[0])
        V0 = self.constraint_reference(y0, grid.t)
        p0 = self.initial_pressure(y0, y1, xis[0], fs[0], grid.t[0]) if self.scheme.multiplier == "theta" else 0.0
        p0 = self.constraint.carried(p0)
        start = _time.perf_counter()
        if self.solver.traced and monitor is None and progress:
            out = self._march_with_bar(y0, y1, p0, xis, fs, grid, V0)
        elif self.solver.traced and monitor is None:
            out = self.march(y0, y1, p0, xis, fs, grid.t, V0)
        else:
            out = self.march_stepwise(y0, y1, p0, xis, fs, grid, V0, progress, monitor)
        wall = _time.perf_counter() - start
        Y0n, Y1n, P, its, status, mindet, maxgrad = out
        self.raise_on_failure(status, grid, its, mindet)
        Y0 = np.concatenate([y0[None], Y0n])
        Y1 = np.concatenate([y1[None], Y1n])
        if self.scheme.multiplier == "theta":
            P = np.concatenate([[p0], P])
        return self.solution(grid, Y0, Y1, P, (its, mindet, maxgrad), xis, wall, diagnose)

    def solution(self, grid, Y0, Y1, P, monitors, xi, wall_time: float = 0.0, diagnose: bool = False) -> StateSolution:
        """The `StateSolution` of a solve on ``grid``: the level states Y0, Y1 (N+1, n), the multipliers P
        (as in `StateSolution.p_steps`), the steps' ``monitors = (newton_iterations, min_det_F, max_grad)``
        (N,) each, the controls xi (N+1, n_ctrl); P may be carried states (N, k) whose first column is the
        multiplier, kept as `StateSolution.multiplier_states`; the level volumes (and a cavity constraint's) and
        pressures are computed here, the
        regimes (`detect_regimes`) with ``diagnose``."""
        m = self.model
        vol = self.level_volumes(Y0)
        states = np.asarray(P) if np.ndim(P) == 2 else None
        P = np.asarray(self.constraint.pressure(P))
        cavity = getattr(self.constraint, "cavity", None)
        sol = StateSolution(m, grid.t, Y0, Y1, P, level_pressure(P, grid.dt, self.scheme.multiplier), vol,
                            *monitors, xi if m.control is not None else None, wall_time, multiplier_states=states,
                            constrained_volume=None if cavity is None else cavity.volumes(Y0))
        if diagnose:
            sol.warnings = detect_regimes(sol)
        return sol

    @cached_property
    def _volumes(self):
        return jax.jit(jax.vmap(self.model.volume))

    def level_volumes(self, Y0) -> np.ndarray:
        """The deformed volumes (L,) of the states Y0 (L, n)."""
        return np.asarray(self._volumes(on_device(Y0)))

    def deformed_volume(self, y0) -> float:
        """vol(y0) = int det(I + grad y0) dx of a state (n,)."""
        return float(self.model.jitted["volume"](on_device(y0)))

    @cached_property
    def _constraint_value(self):
        return jax.jit(self.constraint.value)

    def constraint_value(self, y0) -> float:
        """The constrained quantity ``c(y0)`` of a state (n,): the tissue volume, or the cavity volume."""
        return float(self._constraint_value(on_device(y0)))

    def constraint_reference(self, y0, t) -> float:
        """V0, the constrained quantity of the initial state y0 (n,), that every step's target starts from;
        `InputError` if the constraint's target is not finite on the levels ``t`` (a time law's singularity)."""
        self.constraint.check_targets(t)
        return self.constraint_value(y0)

    def _controls(self, xi, N) -> np.ndarray:
        nc = self.model.control.size if self.model.control is not None else 0
        if xi is None:
            return np.zeros((N + 1, nc))
        xi = np.asarray(xi, dtype=np.float64)
        if xi.shape != (N + 1, nc):
            raise InputError(f"control array must have shape (N+1, n_ctrl) = {(N + 1, nc)}, got {xi.shape}")
        return xi

    def _check_initial_velocity(self, y0, y1, t0: float = 0.0) -> None:
        """The constraint's time derivative ``dc/du(u0) . v0 = d target/dt (t0)`` must hold (0 for the tissue
        volume and an isovolumic cavity): an incompatible v0 would leave an undamped alternating velocity
        at the constrained boundary."""
        con = self.constraint
        if not np.any(y1) or not con.has_multiplier:
            return
        G = np.asarray(con.value_gradient(jnp.asarray(y0)))
        rate = float(con.target_rate(t0))
        scale = np.linalg.norm(G) * max(np.linalg.norm(y1), 1e-300) + abs(rate)
        if abs(G @ y1 - rate) > 1e-10 * scale:
            raise InputError(f"initial velocity violates the volume constraint: G(u0).v0 = {G @ y1:.3g}, the "
                             f"target's rate {rate:.3g} (they must agree; project v0 onto G(u0)^perp)")

    def external_loads(self, external, grid) -> np.ndarray:
        n, N = self.model.n, grid.num_steps
        if external is None:
            return np.broadcast_to(self.model.traction_load, (N + 1, n))
        if callable(external):
            return np.stack([np.asarray(external(t), dtype=np.float64) for t in grid.t])
        ext = np.asarray(external, dtype=np.float64)
        if ext.shape != (N + 1, n):
            raise InputError(f"external loads must have shape (N+1, n) = {(N + 1, n)}, got {ext.shape}")
        return ext

    def march_stepwise(self, y0, y1, p0, xis, fs, grid, V0, progress, monitor=None):
        """`march` driven from Python, one `advance` at a time, on the TimeGrid ``grid``: a progress bar
        (``progress``), ``monitor(StepRecord)`` after each step, and a stop at the first failed step
        (the outputs padded to the grid with status ``StepStatus.AFTER_FAILURE``)."""
        from tqdm.auto import tqdm

        carry = (on_device(y0), on_device(y1), on_device(p0), jnp.asarray(False))
        outs = []
        steps = tqdm(range(grid.num_steps), disable=not progress, desc="compiling", leave=False)
        for n in steps:
            inputs = (jnp.asarray(xis[n]), jnp.asarray(xis[n + 1]), jnp.asarray(fs[n]), jnp.asarray(fs[n + 1]),
                      grid.dt[n], V0, grid.t[n])
            carry, out = self.advance(carry, inputs)
            out = [np.asarray(o) for o in out]
            outs.append(out)
            if n == 0 and progress:  # the ETA from here on counts steps, not the compilation
                steps.set_description("time steps", refresh=False)
                steps.reset()
            if monitor is not None or progress:
                record = self._record(n, grid, out, V0)
                steps.set_postfix_str(record.describe(), refresh=False)
                if monitor is not None:
                    monitor(record)
            if int(out[4]) != StepStatus.OK:
                break
        return _padded_after_failure([np.stack([o[k] for o in outs]) for k in range(7)], grid.num_steps)

    def _record(self, n, grid, out, V0) -> StepRecord:
        """The `StepRecord` of step n from the step's outputs (y0', y1', p', its, status, min det F, max grad)."""
        y0n, _, pn, its, status, mindet, _ = out
        target = float(self.constraint.target(V0, grid.t[n + 1]))
        drift = abs(self.constraint_value(y0n) - target) / abs(target)
        return StepRecord(n, float(grid.t[n + 1]), int(its), float(mindet), drift, float(self.constraint.pressure(pn)),
                          StepStatus(int(status)).cause)

    def raise_on_failure(self, status, grid, its, mindet):
        """`SolverError` naming the first step whose status (L,) is not 0, its time on ``grid`` and the
        cause (Newton iterations ``its``, ``mindet`` = min det F per step); nothing if all steps passed."""
        bad = np.flatnonzero(np.asarray(status) != StepStatus.OK)
        if bad.size == 0:
            return
        n = int(bad[0])
        cause = StepStatus(int(status[n])).cause
        detail = {
            "newton": f"Newton did not converge in {int(its[n])} iterations (try a smaller dt, or a larger damping)",
            "nonfinite": "NaN/Inf in the Newton iterate, or in the residual at every line-search step "
                         "(e.g. an element inverted all along the Newton direction; try a smaller dt)",
            "detF": f"min det F = {float(mindet[n]):.3g} <= 0: an element is inverted",
        }.get(cause, "")
        raise SolverError(n, grid.t[n + 1], cause, detail)


def detect_regimes(sol: StateSolution) -> list:
    """Flag regimes where the discrete solution should not be trusted as is.

    - loss of strong ellipticity (acoustic tensor not positive definite; SVK in strong compression),
      checked at every level for small problems, at 21 levels otherwise;
    - fronts at mesh scale: the jump of grad u between neighbouring cells is comparable to grad u
      itself (only checked for 1D P1, where cells are ordered and u_x is constant per cell: the
      difference quotients of the nodal values over the cell lengths).
    """
    m = sol.model
    out = []
    count = len(sol.t) if m.n * len(sol.t) <= 2_000_000 else 21
    levels = np.unique(np.linspace(0, len(sol.t) - 1, count).astype(int))
    eig = m.min_acoustic_eigenvalues(sol.y0[levels])
    if np.any(eig < 0):
        k = levels[int(np.argmax(eig < 0))]
        out.append(f"loss of strong ellipticity from t = {sol.t[k]:.4g} "
                   f"(min acoustic-tensor eigenvalue {eig.min():.3g}): "
                   "the material is unstable there (e.g. Saint Venant-Kirchhoff in strong compression)")
    if m.dim == 1 and m.space.degree == 1:
        ux = np.diff(sol.displacement()[..., 0], axis=1) / np.diff(m.space.nodes[:, 0])[None, :]
        jump = np.max(np.abs(np.diff(ux, axis=1)), axis=1)
        ratio = jump / np.maximum(np.max(np.abs(ux), axis=1), 1e-300)
        k = int(np.argmax(ratio))
        if np.max(np.abs(ux[k])) > 1e-3 and ratio[k] > 0.5:
            out.append(f"front at mesh scale at t = {sol.t[k]:.4g}: the jump of u_x between neighbouring cells is "
                       f"{ratio[k]:.2f} of max|u_x| (refine h or increase the damping)")
    return out


def solve_state(model: StateModel, grid: TimeGrid, xi=None, *, u0=None, v0=None, external=None,
                scheme: Scheme = Scheme(), solver="auto", progress: bool = False, monitor=None) -> StateSolution:
    """Convenience wrapper: ``TimeStepper(model, scheme, solver).run(grid, xi, ...)``."""
    return TimeStepper(model, scheme, solver).run(grid, xi, u0=u0, v0=v0, external=external, progress=progress,
                                                  monitor=monitor)

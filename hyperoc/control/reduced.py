"""The reduced functional ``J(m)``, ``m = (xi~, tau)``, of the hybrid optimal control problem.

The control ``xi~`` lives on the fixed s-grid of a `TimeTransform` (nodal values on the control
nodes at every s-level, shape (N+1, n_ctrl)); tau sets the t-grid through the step sizes. The
gradient is the exact gradient of the discrete J (`hyperoc.control.adjoint`), its xi-part returned as the
Riesz representative in the control space (`hyperoc.control.control_space.ControlSpace`): L2(0, 2; L2(omega))
for the paper's cost, H^1(0, 2; L2(omega)) when the objective penalizes ``d xi/dt`` (``beta > 0``),
so that optimizers see mesh- and step-independent quantities.

The value and the gradient come from one forward solve recorded under a checkpointing schedule
(`hyperoc.control.revolve`, `ReducedFunctional.schedule`): every level state by default (`StoreAll`);
with ``schedule=EveryK(k)`` they never hold the whole trajectory: the forward pass keeps every k-th
level state, the levels the objective reads and the step multipliers, and the adjoint recomputes each
segment from its checkpoint. With ``schedule=Binomial(s)`` it follows the binomial schedule instead
(s snapshots, the least number of recomputed steps).

The forward solve of the value and the gradient stops after the last step the objective reads
(``horizon="objective"``, `hyperoc.control.objectives.Objective.steps_read`): for ``p(tau)`` the step
after tau, so about tau / T of the steps. The state after that step changes neither J nor its gradient
(the time stepping is causal and the adjoint vanishes there), so both equal those of the whole solve.
What changes is which controls are admissible: one whose state fails after that step has a value and a
gradient; with ``horizon="full"`` the solve covers [0, T] and such a control is rejected.

The forward solves of the last point are kept (`ReducedFunctional.record` and `ReducedFunctional.state`
share them): the record made for the value and the gradient, and the whole state trajectory, which
is read from that record when it holds every level (no checkpointing) and costs one more solve
otherwise.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from .._jax import on_device
from ..dynamics.stepper import Scheme, StateSolution, TimeStepper
from ..dynamics.timegrid import TimeTransform
from ..errors import InputError
from ..mechanics.model import StateModel
from .adjoint import Adjoint, Record
from .control_space import ControlSpace, control_space
from .objectives import Objective, Trajectory
from .revolve import Schedule, StoreAll, checkpoint_schedule

__all__ = ["ControlPoint", "ReducedFunctional", "LevelStates"]


class LevelStates:
    """Some level states of a trajectory, indexed like the (N+1, n) array they stand for.

    ``states[k]`` (an int, negative from the end) returns the stored level k, (n,); a slice stacks
    its levels. With checkpointing, objective terms see ``traj.y0`` and ``traj.y1`` as these: terms
    that read single levels (``traj.y1[-1]``, ``traj.y0[traj.tau_index]``) work unchanged, terms that
    use the whole array do not (they need the schedule `StoreAll`).

    num_levels : N+1; levels : the stored level indices (ascending); values : (len(levels), n).
    """

    def __init__(self, num_levels: int, levels, values):
        self.num_levels, self.values = num_levels, values
        self.rows = {int(k): i for i, k in enumerate(levels)}

    def __len__(self) -> int:
        return self.num_levels

    def __getitem__(self, index):
        if isinstance(index, slice):
            return jnp.stack([self._level(k) for k in range(*index.indices(self.num_levels))])
        if not isinstance(index, (int, np.integer)):
            raise InputError("with checkpointing, objective terms index traj.y0 / traj.y1 by static levels "
                             f"(ints or slices), got {type(index).__name__}")
        k = int(index) + (self.num_levels if index < 0 else 0)
        if not 0 <= k < self.num_levels:
            raise IndexError(f"level {index} out of range for {self.num_levels} levels")
        return self._level(k)

    def _level(self, k: int):
        return self.values[self.rows[k]]


class _LevelRecorder(LevelStates):
    """Notes the levels an objective reads (zeros stand in for the states)."""

    def __init__(self, num_levels: int, n: int):
        super().__init__(num_levels, (), None)
        self.n, self.read = n, set()

    def _level(self, k: int):
        self.read.add(k)
        return jnp.zeros(self.n)


@dataclass(frozen=True, eq=False)
class ControlPoint:
    """A point (or direction) ``m = (xi, tau)``: xi (N+1, n_ctrl) on the s-levels, tau scalar."""

    xi: np.ndarray
    tau: float

    def __add__(self, other: "ControlPoint") -> "ControlPoint":
        return ControlPoint(self.xi + other.xi, self.tau + other.tau)

    def __sub__(self, other: "ControlPoint") -> "ControlPoint":
        return ControlPoint(self.xi - other.xi, self.tau - other.tau)

    def __mul__(self, a: float) -> "ControlPoint":
        return ControlPoint(a * self.xi, a * self.tau)

    __rmul__ = __mul__

    def flat(self) -> np.ndarray:
        return np.concatenate([self.xi.ravel(), [self.tau]])


@dataclass(eq=False)
class _Solves:
    """The forward solves made at one point ``key = (tau, xi bytes)``: its `Record` and its `StateSolution`,
    each None until asked for."""

    key: tuple
    record: Record | None = None
    state: StateSolution | None = None


class ReducedFunctional:
    """``J(m)`` and its exact gradient for a model, a time transform and an objective (maximized). The paper's
    optimize-then-discretize gradient is `hyperoc.control.continuous_adjoint.ContinuousReducedFunctional`'s.

    Parameters
    ----------
    model : StateModel with a control operator.
    transform : TimeTransform (its eps must match the objective's when the objective uses one).
    objective : Objective.
    scheme, solver : time-stepping options (multiplier "step").
    u0, v0 : initial state (reduced vectors), zero by default.
    schedule : the checkpointing schedule of the value and the gradient (`hyperoc.control.revolve`):
        `StoreAll()` (default: every level state ``(y0, y1)``, 2 (N+1) n floats), `EveryK(k)`: the level
        states at ``0, k, 2k, ...`` only, plus the levels the objective reads, each segment of k steps
        recomputed from its checkpoint during the adjoint sweep (memory ``ceil(N/k) + k + 1`` level
        states, least near ``k = sqrt(N)``, one more forward solve per gradient), or `Binomial(s)`:
        Griewank's revolve with s snapshots (memory s + 2 level states, ``t(N, s) + 1`` step evaluations
        per gradient, `hyperoc.control.revolve.minimal_advances`: N (N-1)/2 + 1 for s = 1, N for
        s >= N - 1, e.g. 4.5 N for N = 3000, s = 10). With checkpoints the objective's terms must read
        ``traj.y0`` / ``traj.y1`` by static levels (see `LevelStates`); the gradient equals the stored
        one to round-off (same compiled step, same Newton warm start); `state` still returns the whole
        trajectory (for reports). The attribute may be set between evaluations.
    space : the control space (`ControlSpace`); by default L2 in time, or H^1 in time with the time
        scale ``(2/T) sqrt(beta/alpha)`` of the objective's `hyperoc.control.objectives.ControlRateCost`.
    horizon : "objective" (default): the value and the gradient solve the steps the objective reads
        (`steps_solved`), "full": all N steps (the state must exist on [0, T]). The gradient is the
        same; `state` always solves all N steps.
    adjoint : the state solver and its adjoint recursion, an `Adjoint` of a stepper of ``model``
        (default ``Adjoint(TimeStepper(model, scheme, solver))``; ``scheme`` and ``solver`` are not
        used when it is given); e.g. `hyperoc.distributed.dynamics.DistributedAdjoint` to solve on MPI ranks.
    checkpoint_every, checkpoint_snapshots : deprecated spellings of ``schedule=EveryK(k)`` and
        ``schedule=Binomial(s)``.
    """

    def __init__(self, model: StateModel, transform: TimeTransform, objective: Objective, *,
                 scheme: Scheme = Scheme(), solver="auto", u0=None, v0=None, schedule: Schedule = StoreAll(),
                 space: ControlSpace | None = None, adjoint: Adjoint | None = None, horizon: str = "objective",
                 checkpoint_every: int | None = None, checkpoint_snapshots: int | None = None):
        if horizon not in ("objective", "full"):
            raise InputError(f"horizon must be 'objective' or 'full', got {horizon!r}")
        self.horizon = horizon
        if model.control is None:
            raise InputError("the optimal control problem needs a model with a control operator")
        if objective.eps and abs(transform.eps - objective.eps) > 1e-14:
            raise InputError(f"time transform eps = {transform.eps} differs from the objective's eps = {objective.eps}")
        self.model, self.transform, self.objective = model, transform, objective
        if space is None:
            alpha, beta = objective.control_weights
            space = control_space(transform, model.control, alpha, beta)
        self.space = space
        self.adjoint = Adjoint(TimeStepper(model, scheme, solver)) if adjoint is None else adjoint
        self.stepper = self.adjoint.stepper
        self.u0 = np.zeros(model.n) if u0 is None else np.asarray(u0, float)
        self.v0 = np.zeros(model.n) if v0 is None else np.asarray(v0, float)
        self.N = transform.num_steps
        self.counts = {"state": 0, "adjoint": 0}
        self._solves = _Solves(None)
        if checkpoint_every is not None or checkpoint_snapshots is not None:
            warnings.warn("ReducedFunctional(checkpoint_every=k / checkpoint_snapshots=s) is deprecated: pass "
                          "schedule=EveryK(k) / Binomial(s) (hyperoc.control.revolve)", DeprecationWarning,
                          stacklevel=2)
            schedule = checkpoint_schedule(checkpoint_every, checkpoint_snapshots)
        self.schedule = schedule
        from jax.experimental import sparse as jsparse

        # Built eagerly: a cached property first touched inside a traced function would leak tracers.
        self._control_mass = jsparse.BCOO.from_scipy_sparse(model.control.mass.tocoo())

    @property
    def schedule(self) -> Schedule:
        """The checkpointing schedule of the value and the gradient (`hyperoc.control.revolve.Schedule`)."""
        return self._schedule

    @schedule.setter
    def schedule(self, schedule: Schedule) -> None:
        if not all(hasattr(schedule, name) for name in ("forward", "reverse", "compiled")):
            raise InputError(f"schedule must be a hyperoc.control.revolve.Schedule (StoreAll, EveryK, Binomial), "
                             f"got {schedule!r}")
        self._schedule = schedule
        self._solves.record = None  # made under the previous schedule

    @property
    def checkpointed(self) -> bool:
        """Whether the value and the gradient use checkpoints (any schedule but `StoreAll`)."""
        return not isinstance(self._schedule, StoreAll)

    @property
    def steps_solved(self) -> int:
        """K, the steps the value and the gradient solve: those the objective reads (``horizon="objective"``)
        or all N. Fixed for the transform (tau moves the levels, not their indices)."""
        if self.horizon == "full":
            return self.N
        n1, n2, _ = self.transform.steps
        return max(1, self.objective.steps_read(n1, n1 + n2, self.N))

    # --- geometry of the control space -----------------------------------------------------------
    @property
    def s_weights(self) -> np.ndarray:
        """Trapezoid weights of the s-levels, (N+1,)."""
        return self.space.weights

    def zero(self, tau: float) -> ControlPoint:
        return ControlPoint(np.zeros((self.N + 1, self.model.control.size)), float(tau))

    def inner(self, a: ControlPoint, b: ControlPoint) -> float:
        """The inner product of `space` (L2 or H^1 in s, times L2(omega), plus ``a.tau b.tau``)."""
        return self.space.inner(a, b)

    def norm(self, a: ControlPoint) -> float:
        return self.space.norm(a)

    def riesz(self, dual: ControlPoint) -> ControlPoint:
        """Riesz representative of a derivative (dual vector) for `inner`."""
        return self.space.riesz(dual)

    def dual(self, g: ControlPoint) -> ControlPoint:
        """Inverse of `riesz`: the dual vector ``d`` with ``d.xi . v.xi + d.tau v.tau = <g, v>``."""
        return self.space.dual(g)

    # --- evaluation ------------------------------------------------------------------------------
    def _check(self, m: ControlPoint) -> None:
        if m.xi.shape != (self.N + 1, self.model.control.size):
            raise InputError(f"control must have shape {(self.N + 1, self.model.control.size)}, got {m.xi.shape}")
        self.transform.check_tau(m.tau)

    def _solves_at(self, m: ControlPoint) -> _Solves:
        """The solves kept for m: those of the last point if m is that point, else none yet."""
        self._check(m)
        key = (m.tau, m.xi.tobytes())
        if key != self._solves.key:
            self._solves = _Solves(key)
        return self._solves

    def state(self, m: ControlPoint) -> StateSolution:
        """The whole state trajectory for m (cached for the last point): from m's `record` when it
        holds every level, else one forward solve."""
        solves = self._solves_at(m)
        if solves.state is None:
            rec = solves.record
            span = None if rec is None else rec.span(0, self.N)
            if span is not None:
                solves.state = self.stepper.solution(rec.grid, *span, rec.p_steps,
                                                     (rec.newton_iterations, rec.min_det_F, rec.max_grad), rec.xi,
                                                     rec.wall_time)
            else:
                sol = self.stepper.run(self.transform.grid(m.tau), m.xi, u0=self.u0, v0=self.v0, diagnose=False)
                self.counts["state"] += 1
                solves.state = sol
        return solves.state

    def trajectory(self, sol: StateSolution) -> Trajectory:
        return self._trajectory(*self._solution_arrays(sol))

    def _trajectory(self, y0, y1, p_steps, xi, dt) -> Trajectory:
        n1, n2, _ = self.transform.steps
        return Trajectory(y0, y1, p_steps, xi, dt, n1, n1 + n2, self._control_mass, self.stepper.mass, self.model)

    def objective_terms(self, sol: StateSolution) -> dict:
        """Each objective term's value on the state ``sol`` (`Objective.parts`), in one compiled call."""
        return {name: float(v) for name, v in self._objective_terms(*self._solution_arrays(sol)).items()}

    @staticmethod
    def _solution_arrays(sol: StateSolution) -> tuple:
        return tuple(on_device(a) for a in (sol.y0, sol.y1, sol.p_steps, sol.xi, sol.dt))

    @cached_property
    def _objective_terms(self):
        return jax.jit(lambda *arrays: self.objective.parts(self._trajectory(*arrays)))

    def _objective_functions(self, states):
        """Jitted ``J(y0, y1, p, xi, dt)`` and its value and partial derivatives; ``states`` turns the
        y0 / y1 arguments into what the terms see (the arrays themselves, or `LevelStates`)."""
        def value(y0, y1, p, xi, dt):
            return self.objective.value(self._trajectory(states(y0), states(y1), p, xi, dt))

        return jax.jit(value), jax.jit(jax.value_and_grad(value, argnums=(0, 1, 2, 3, 4)))

    @cached_property
    def _objective_and_partials(self):
        return self._objective_functions(lambda y: y)

    @cached_property
    def objective_levels(self) -> tuple[int, ...]:
        """The levels at which the objective reads y0 or y1 (found by tracing it once, no solve)."""
        n1, n2, _ = self.transform.steps
        N, n, nc = self.N, self.model.n, self.model.control.size
        recorders = _LevelRecorder(N + 1, n), _LevelRecorder(N + 1, n)
        f64 = lambda *shape: jax.ShapeDtypeStruct(shape, jnp.float64)
        try:
            jax.eval_shape(lambda p, xi, dt: self.objective.value(
                Trajectory(*recorders, p, xi, dt, n1, n1 + n2, self._control_mass, self.stepper.mass, self.model)),
                f64(N), f64(N + 1, nc), f64(N))
        except (TypeError, AttributeError) as err:
            raise InputError(f"checkpointing: the objective uses traj.y0 / traj.y1 as whole arrays ({err}); "
                             "index single levels (traj.y1[-1]) or use the schedule StoreAll()") from err
        return tuple(sorted(recorders[0].read | recorders[1].read))

    @cached_property
    def _checkpointed_objective(self):
        return self._objective_functions(lambda y: LevelStates(self.N + 1, self.objective_levels, y))

    @property
    def _read_levels(self) -> tuple[int, ...]:
        """The levels whose states the objective receives: all of them, or with checkpointing those it reads."""
        return self.objective_levels if self.checkpointed else tuple(range(self.N + 1))

    @property
    def _objective_pair(self):
        """The jitted J and its value and partials (`_objective_functions`) on the states at `_read_levels`:
        whole arrays without checkpointing, `LevelStates` with it."""
        return self._checkpointed_objective if self.checkpointed else self._objective_and_partials

    def record(self, m: ControlPoint) -> Record:
        """The forward solve for m under `schedule`, keeping the level states the objective receives (all
        of them without checkpointing); cached for the last point."""
        solves = self._solves_at(m)
        if solves.record is None:
            K = self.steps_solved
            grid = self.transform.grid(m.tau).first(K)
            loads = self.stepper.external_loads(None, grid)
            solves.record = self.adjoint.record(grid, m.xi[:K + 1], loads, self.u0, self.v0, self.schedule,
                                                self._solved_reads)
            self.counts["state"] += 1
        return solves.record

    @property
    def _solved_reads(self) -> tuple[int, ...]:
        """The `_read_levels` among the solved ones (0 .. `steps_solved`)."""
        return tuple(k for k in self._read_levels if k <= self.steps_solved)

    def _record_arrays(self, rec: Record, m: ControlPoint):
        """The arguments ``(y0, y1, p, xi, dt)`` of the objective functions: the states at `_read_levels`,
        (len, n) each, the step multipliers (N,), the controls (N+1, n_ctrl) and the steps (N,); states and
        multipliers after the solved steps, which the objective does not read, are zeros."""
        Y0, Y1 = (np.pad(Y, ((0, len(self._read_levels) - len(Y)), (0, 0))) for Y in rec.at(self._solved_reads))
        p = np.pad(rec.p_steps, (0, self.N - rec.grid.num_steps))
        return tuple(on_device(a) for a in (Y0, Y1, p, m.xi, self.transform.grid(m.tau).dt))

    def __call__(self, m: ControlPoint) -> float:
        value, _ = self._objective_pair
        return float(value(*self._record_arrays(self.record(m), m)))

    def value_and_derivative(self, m: ControlPoint) -> tuple[float, ControlPoint]:
        """J(m) and dJ(m) as a dual vector: ``dJ.dm = sum(d.xi * dm.xi) + d.tau dm.tau``."""
        rec = self.record(m)
        _, vg = self._objective_pair
        J, (gY0, gY1, gP, gXi, gdt) = vg(*self._record_arrays(rec, m))
        K, kept = rec.grid.num_steps, len(rec.keep)
        gY0, gY1, gP = (np.asarray(g) for g in (gY0, gY1, gP))
        gXi_state, gdt_state = self.adjoint.backward(rec, (gY0[:kept], gY1[:kept]), gP[:K])
        self.counts["adjoint"] += 1
        dxi, ddt = np.array(gXi), np.array(gdt)
        dxi[:K + 1] += gXi_state
        ddt[:K] += gdt_state
        dtau = float(ddt @ self.transform.ddt_dtau())
        return float(J), ControlPoint(dxi, dtau)

    def derivative(self, m: ControlPoint) -> ControlPoint:
        return self.value_and_derivative(m)[1]

    def value_and_gradient(self, m: ControlPoint) -> tuple[float, ControlPoint]:
        """J(m) and its Riesz gradient (L2(0,2; L2(omega)) x R): `riesz` of the exact derivative."""
        J, d = self.value_and_derivative(m)
        return J, self.riesz(d)

    def gradient(self, m: ControlPoint) -> ControlPoint:
        return self.value_and_gradient(m)[1]

"""The global constraint of a time step, a family the configuration selects (``[dynamics] constraint``).

A step's Newton unknown is ``x = (z, q)`` (n + 1,) and its residual ``(F_u (n,), F_c)``: the bordered
system of `hyperoc.solvers.linsolve` (one factorization of the element-assembled K, a Schur complement on
the one border), so Newton, chord Newton, the linear solvers, the adjoint and checkpointing stay one path
whatever the constraint. A constraint says how ``x`` maps to the step's displacement ``y0'`` and
multiplier ``p'`` (`split`), what the multiplier adds to the momentum rows (`momentum`) and to their
element blocks (`tangent_weight`, `add_tangent`), what its row is (`row`, against `target`) and the
border of the Jacobian (`border`). ``V0`` is the constrained quantity of the initial state (`value`).

The step carries the constraint's multiplier state from one step to the next (`carried` at the first level,
`next_state` after each step, `pressure` its multiplier): the multiplier p' itself, but for the circulation.
A row may read the step's previous level (y0, the carried state, dt) and depend on p' (`corner`, the
bordered Jacobian's ``dF_c/dp'``, 0 but for the circulation).

A row is ``share(x, y0) + row_offset(p', V0, t', p_prev, dt)``: the part that is a sum over the cells (or the
wall's facets) and the rest. On MPI ranks (`hyperoc.distributed.dynamics`) a constraint is
``restricted(model, local, cells, dofs)`` to a rank's cells, as the step terms are: its row the share of
those cells (or of the wall facets they own), its force direction and tangent those of the part, its corner
0; the distributed step sums the shares over the ranks and adds the serial `row_offset` and corner once. The
tissue volume, the cavity volume and the circulation restrict so; without a constraint (`NoConstraint`, whose
gauge is a vector over all unknowns) the distributed step has no border and no row.

A constraint with a multiplier holds ``c(y0') = target(V0, t')`` with a force ``-p' G`` on the momentum
rows, ``G`` the *force direction* (`force_direction`) and ``c`` the constrained quantity; step weighting
(default): ``dt p' (theta G(y0') + (1 - theta) G(y0))``; "theta": ``dt (theta p' G' + (1 - theta) p G)``.

- `TissueVolume` (``"tissue_volume"``, the paper's): ``c = vol(y0) = int det F``, ``G = dc/dy0``
  (the multiplier pulls the body against its volume change), ``target = V0``.
- `CavityVolumeConstraint` (``"cavity_volume"``): ``c = V_cav(y0)``, the volume of the cavity bounded by a
  wall of the body (`hyperoc.mechanics.cavity.CavityVolume`, the lid's apex fixed or at the deformed rim's
  centroid: exact for P1 and P2, curved cells), held at ``target = V0 + dV(t)`` (``dV`` a time law,
  `hyperoc.dynamics.laws`; none: the initial volume, an isovolumic phase). Its multiplier is the cavity
  (left-ventricular) pressure, positive when it pushes the wall out of the cavity: the load ``p' dV_cav/du``
  (a follower pressure on the wall and the lid's reaction on the rim), so ``G = -dV_cav/du``; its stiffness
  ``-p' d2V_cav/du2`` is symmetric (a Hessian): its facet-local part added to the element blocks of the wall's
  cells, with the moving apex its dense rank-2d part the Jacobian's low-rank term (`low_rank`,
  `hyperoc.solvers.linsolve`).
- `Circulation` (``"circulation"``): the cavity of `CavityVolumeConstraint` closed by a lumped (0D) circulation,
  coupled monolithically: its multiplier p is still the cavity pressure, and the phase of the beat decides the
  row. Each phase of the linear 0D model, its own state eliminated, gives a row linear in the step's volume
  change and p': ``V_cav(y0') - V_cav(y0) + g (p' - p_ref) = 0`` (length^3), so the bordered Jacobian gains
  the corner ``g`` (`hyperoc.solvers.linsolve`):

  - isovolumic (both valves closed): ``g = 0``, the volume of the previous level held;
  - ejection (aortic valve open), a 3-element Windkessel (``R_c = 0``: 2-element) by the trapezoidal rule,
    outflow ``Q = -(V_cav(y0') - V_cav(y0)) / dt``: ``C (Pa' - Pa) / dt + (Pa + Pa') / (2 R) = Q`` and
    ``p' = (Pa + Pa') / 2 + R_c Q`` (p' is the step's, mid-step, pressure); eliminating Pa' with
    ``k = dt / (2 R C)``: ``Q = ((1 + k) p' - Pa) / (dt / (2 C) + R_c (1 + k))``, i.e.
    ``g = dt (1 + k) / (dt / (2 C) + R_c (1 + k))``, ``p_ref = Pa / (1 + k)``;
  - filling (mitral valve open): inflow ``(p_a - p') / R_m``, ``g = dt / R_m``, ``p_ref = p_a``.

  While the aortic valve is closed the Windkessel discharges on its own: ``Pa' = Pa (1 - k) / (1 + k)``.
  The 0D memory lives in the multiplier state the step carries (`carried`, `next_state`): for this
  constraint alone it is ``(p, Pa, phase)`` (3,) instead of the number p, so the stepper's carry, its
  compiled loops, the step outputs (`hyperoc.dynamics.stepper.StateSolution.circulation`) and the saved
  segments of a resumable run (`hyperoc.dynamics.resumable`) hold it with no other change; `pressure` reads
  p from it. The valves switch explicitly, from the converged step (the next step's row): from isovolumic the
  aortic valve opens when ``p' > Pa'``, the mitral one when ``p' < p_a``; ejection ends when ``Q <= 0``,
  filling when the inflow reverses (``p' >= p_a``). A switch therefore lags the condition by at most one
  step, and the phase sequence of a run is piecewise constant in the data. The exact adjoint
  (`hyperoc.control.adjoint`) carries the 0D state's total with the phase sequence held fixed.
- `NoConstraint` (``"none"``): only the material's own volumetric term controls the volume. The bordered
  solvers are reused through the gauge of `hyperoc.dynamics.statics`: ``y0' = w + s e`` with the unit
  vector ``e = (1, ..., 1) / sqrt(n)``, ``x = (w, s)``, ``F_c = e . w``, border ``(K e, e)``; the Schur
  complement ``e^T K^-1 K e = 1`` never vanishes and ``dy0' = dw + ds e`` is the plain Newton step
  ``K dy0' = -F_u``. There is no multiplier: the reported pressure is 0 at every level (the prescribed
  endocardial pressure, if any, is a load: `hyperoc.dynamics.terms.DynamicPressure`); its `value` is the
  tissue volume, reported as the drift.
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import InputError
from ..mechanics.cavity import CavityVolume
from ..mechanics.kernels import gather, scatter
from .laws import TimeLaw

__all__ = ["TissueVolume", "CavityVolumeConstraint", "Circulation", "NoConstraint", "make_constraint", "CONSTRAINTS",
           "DISTRIBUTED_CONSTRAINTS"]


class _Part:
    """A constraint restricted to a rank's cells (`restricted`, module docstring): ``part``'s methods, but the
    row is its share alone and the corner 0 (the offset and the corner enter once, on the distributed step)."""

    def __init__(self, part):
        self.part = part

    def __getattr__(self, name):
        if name == "part":  # not yet set (a copy being built): no recursion
            raise AttributeError(name)
        return getattr(self.part, name)

    def row(self, x, V0, t, y0=None, p_prev=None, dt=None):
        return self.part.share(x, y0)

    def corner(self, p_prev, dt):
        return 0.0


class _ScalarState:
    """A constraint whose row does not read its multiplier and whose carried state is the multiplier itself."""

    def corner(self, p_prev, dt):
        """``dF_c/dp'``, the bordered Jacobian's corner: 0 (the row does not depend on the multiplier)."""
        return 0.0

    def carried(self, p):
        """The multiplier state the step carries, starting from the multiplier p: p itself."""
        return p

    def pressure(self, state):
        """The multiplier (the reported pressure) of carried states (any leading shape): the states themselves."""
        return state

    def low_rank(self, x, scale):
        """The dense symmetric part ``(U, W)`` of the Jacobian beside its element blocks (`hyperoc.solvers.linsolve`),
        ``scale`` times the multiplier's stiffness as in `add_tangent`: none."""
        return None


class _HeldByMultiplier(_ScalarState):
    """A quantity ``c(y0)`` held at ``target(V0, t)`` by a multiplier whose force on the momentum rows is
    ``-p G(y0)`` (module docstring); subclasses give `value`, `value_gradient`, `force_direction`,
    `target` and the Hessian's part of the tangent."""

    has_multiplier = True

    def unknown(self, y0, p):
        """Newton's unknown x (n + 1,) for the displacement y0 (n,) and multiplier p."""
        return jnp.concatenate([y0, jnp.reshape(p, (1,))])

    def split(self, x):
        """``(y0' (n,), p')`` of the unknown x."""
        return x[:-1], x[-1]

    def momentum(self, x, y0, p_prev, theta, weighting):
        """The multiplier's part of the momentum rows, divided by dt, (n,)."""
        G_new, G_old = self.force_direction(x[:-1]), self.force_direction(y0)
        if weighting == "step":
            return x[-1] * (theta * G_new + (1 - theta) * G_old)
        return theta * x[-1] * G_new + (1 - theta) * p_prev * G_old

    def row(self, x, V0, t, y0=None, p_prev=None, dt=None):
        """The constraint's residual ``share + row_offset`` at the step's new level t: ``c(y0') - target(V0, t)``
        (the step's previous level ``y0``, multiplier state ``p_prev`` and ``dt`` enter no row of this family but
        the circulation's)."""
        return self.share(x, y0) + self.row_offset(x[-1], V0, t, p_prev, dt)

    def share(self, x, y0=None):
        """The row's part that is a sum over the cells (or the wall's facets): ``c(y0')``."""
        return self.value(x[:-1])

    def row_offset(self, p, V0, t, p_prev=None, dt=None):
        """The row's other part, of the new multiplier p, at the new level t: ``-target(V0, t)``."""
        return -self.target(V0, t)

    def next_state(self, state, x, y0, dt):
        """The state carried to the next step from the converged unknown x: its multiplier p'."""
        return x[-1]

    def check_targets(self, t) -> None:
        """`InputError` if the target is not finite at a level of ``t`` (k,): nothing to check for a constant."""

    def target_rate(self, t):
        """``d target / dt`` at t (the rate the initial velocity must give the constrained quantity)."""
        return jax.grad(lambda s: self.target(0.0, s))(jnp.asarray(t, dtype=jnp.float64))

    def border(self, blocks, x, y0, dt, theta, weighting):
        """``(col, row)`` (n,) each of the bordered Jacobian, given the element blocks of dF_u/dy0'."""
        G_new = self.force_direction(x[:-1])
        row = self.value_gradient(x[:-1])
        if weighting == "step":
            return dt * (theta * G_new + (1 - theta) * self.force_direction(y0)), row
        return dt * theta * G_new, row


class TissueVolume(_HeldByMultiplier):
    """The volume of the tissue held at its initial value by the multiplier p (the paper's constraint)."""

    kind = "tissue_volume"

    def __init__(self, model):
        self.model = model

    def value(self, y0):
        """``int det F`` (length^d) of the displacement y0 (n,)."""
        return self.model.volume(y0)

    def value_gradient(self, y0):
        return self.model.volume_gradient(y0)

    def force_direction(self, y0):
        return self.model.volume_gradient(y0)

    def target(self, V0, t):
        return V0 + 0.0 * t

    def restricted(self, model, local, cells, dofs):
        """The tissue volume of ``local = model.restricted(cells, dofs)``: the part of ``int det F`` on ``cells``
        (`restricted` of the family: module docstring)."""
        return _Part(TissueVolume(local))

    def tangent_weight(self, x):
        """The weight b of ``det F``'s Hessian in the element tangent (`StateModel.tangent_blocks`)."""
        return x[-1]

    def add_tangent(self, blocks, x, scale):
        """The element blocks plus ``scale`` times the multiplier's stiffness not in `tangent_weight`: none."""
        return blocks


class CavityVolumeConstraint(_HeldByMultiplier):
    """The volume of the cavity bounded by ``boundary`` (`hyperoc.mechanics.cavity.CavityVolume`) held at
    ``V0 + change(t)`` (``change``: a `hyperoc.dynamics.laws.TimeLaw` of the volume change in length^d, or None:
    isovolumic) by the cavity pressure p (stress units, positive pushing the wall out of the cavity). ``apex``:
    the lid's apex, ``"fixed"`` (the reference rim's centroid) or ``"rim"`` (the deformed rim's centroid: the
    volume codes and clinicians report; its stiffness has a dense part, `low_rank`; not on the distributed
    path). `InputError` for a boundary the mesh lacks, one that encloses no volume, or another apex."""

    kind = "cavity_volume"
    APEXES = ("fixed", "rim")

    def __init__(self, model, boundary: str = "endocardium", change: TimeLaw | None = None, apex: str = "fixed"):
        if boundary not in model.mesh.boundaries:
            raise InputError(f"cavity volume: the mesh has no boundary {boundary!r} (its boundaries: "
                             f"{', '.join(sorted(model.mesh.boundaries))})")
        if change is not None and not isinstance(change, TimeLaw):
            raise InputError(f"cavity volume: the volume change must be a time law, got {change!r}")
        if apex not in self.APEXES:
            raise InputError(f"cavity volume: apex must be one of {', '.join(self.APEXES)}, got {apex!r}")
        self.model, self.boundary, self.change, self.apex = model, boundary, change, apex
        self.cavity = CavityVolume(model, boundary, apex="rim" if apex == "rim" else None)

    def value(self, y0):
        """``V_cav(y0)`` (length^d)."""
        return self.cavity.volume(y0)

    def value_gradient(self, y0):
        return self.cavity.gradient(y0)

    def force_direction(self, y0):
        return -self.cavity.gradient(y0)

    def target(self, V0, t):
        return V0 + (0.0 * t if self.change is None else self.change(t))

    def check_targets(self, t) -> None:
        """`InputError` if the volume change is not finite at every level of ``t`` (k,)."""
        if self.change is None:
            return
        values = self.change.values(np.asarray(t, dtype=np.float64))
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            k = int(bad[0])
            raise InputError(f"cavity volume change is {values[k]} at t = {t[k]:g} (it must be finite on the whole "
                             "time grid)")

    def restricted(self, model, local, cells, dofs):
        """The part of the cavity volume from the wall facets whose owner cell is among ``cells``, on
        ``local = model.restricted(cells, dofs)`` (`CavityVolume.restricted`: the serial apex; module docstring)."""
        out = copy.copy(self)
        out.model = local
        out.cavity = self.cavity.restricted(model, local, cells, dofs)
        return _Part(out)

    def tangent_weight(self, x):
        return 0.0

    def add_tangent(self, blocks, x, scale):
        """The element blocks plus ``scale`` times the pressure's stiffness ``-p' d2V_cav/du2`` (with the moving
        apex its facet-local part, `low_rank` the rest)."""
        return self.cavity.add_hessian(blocks, x[:-1], -scale * x[-1])

    def low_rank(self, x, scale):
        """With the moving apex the dense part ``(U, W)`` of ``-scale p' d2V_cav/du2`` (`CavityVolume.low_rank`),
        else None."""
        return self.cavity.low_rank(x[:-1], -scale * x[-1])


class Circulation(CavityVolumeConstraint):
    """The cavity closed by a lumped (0D) circulation: a Windkessel afterload behind the aortic valve, a constant
    atrial pressure behind the mitral valve (module docstring, "circulation").

    resistance R (peripheral, stress time / length^3, e.g. Pa s/m^3) > 0; compliance C (length^3 / stress) > 0;
    characteristic_resistance R_c >= 0 (0: the 2-element Windkessel); atrial_pressure p_a (stress, finite);
    mitral_resistance R_m > 0; aortic_pressure Pa(0) (stress, finite); phase: the phase at the first level,
    "isovolumic", "ejection" or "filling". `InputError` for a value out of range (one line).
    """

    kind = "circulation"
    PHASES = ("isovolumic", "ejection", "filling")

    def __init__(self, model, boundary: str = "endocardium", *, resistance: float, compliance: float,
                 atrial_pressure: float, mitral_resistance: float, aortic_pressure: float,
                 characteristic_resistance: float = 0.0, phase: str = "filling", apex: str = "fixed"):
        values = {"resistance": resistance, "compliance": compliance, "mitral_resistance": mitral_resistance,
                  "characteristic_resistance": characteristic_resistance, "atrial_pressure": atrial_pressure,
                  "aortic_pressure": aortic_pressure}
        for name, value in values.items():
            if not isinstance(value, (int, float)) or not np.isfinite(value):
                raise InputError(f"circulation: {name} must be a finite number, got {value!r}")
        for name in ("resistance", "compliance", "mitral_resistance"):
            if not values[name] > 0:
                raise InputError(f"circulation: {name} must be > 0, got {values[name]!r}")
        if not characteristic_resistance >= 0:
            raise InputError(f"circulation: characteristic_resistance must be >= 0, got {characteristic_resistance!r}")
        if phase not in self.PHASES:
            raise InputError(f"circulation: phase must be one of {', '.join(self.PHASES)}, got {phase!r}")
        super().__init__(model, boundary, apex=apex)
        self.R, self.C, self.Rc = float(resistance), float(compliance), float(characteristic_resistance)
        self.p_atrial, self.R_mitral = float(atrial_pressure), float(mitral_resistance)
        self.Pa0 = float(aortic_pressure)
        self.phase0 = self.PHASES.index(phase)

    def carried(self, p):
        """The carried state ``(p, Pa, phase)`` (3,) at the first level: the multiplier p, Pa(0), the phase (its
        index in `PHASES` as a number: 0 isovolumic, 1 ejection, 2 filling)."""
        return jnp.array([p, self.Pa0, self.phase0], dtype=jnp.float64)

    def pressure(self, state):
        return state[..., 0]

    def unknown(self, y0, state):
        return super().unknown(y0, state[0])

    def _ejection(self, Pa, dt):
        """``(g, p_ref)`` of the ejection row ``V' - V + g (p' - p_ref) = 0`` (module docstring): ``k = dt / (2 R C)``,
        ``g = dt (1 + k) / (dt / (2 C) + R_c (1 + k))``, ``p_ref = Pa / (1 + k)``."""
        k = dt / (2 * self.R * self.C)
        return dt * (1 + k) / (dt / (2 * self.C) + self.Rc * (1 + k)), Pa / (1 + k)

    def _conductance(self, state, dt):
        """``(g, p_ref)`` of the phase of ``state``: 0 and 0 isovolumic, the Windkessel's in ejection,
        ``(dt / R_m, p_a)`` in filling."""
        g_ej, p_ej = self._ejection(state[1], dt)
        phase = state[2]
        g = jnp.where(phase == 1, g_ej, jnp.where(phase == 2, dt / self.R_mitral, 0.0))
        p_ref = jnp.where(phase == 1, p_ej, jnp.where(phase == 2, self.p_atrial, 0.0))
        return g, p_ref

    def share(self, x, y0=None):
        """The volume change ``V_cav(y0') - V_cav(y0)`` (length^3), a sum over the wall's facets."""
        return self.value(x[:-1]) - self.value(y0)

    def row_offset(self, p, V0, t, p_prev=None, dt=None):
        """``g (p - p_ref)`` (length^3), ``(g, p_ref)`` those of the carried phase (the row: ``share + row_offset``)."""
        g, p_ref = self._conductance(p_prev, dt)
        return g * (p - p_ref)

    def corner(self, p_prev, dt):
        return self._conductance(p_prev, dt)[0]

    def outflow(self, state, x, y0, dt):
        """The step's outflow through the aortic valve minus the inflow through the mitral one,
        ``Q = -(V_cav(y0') - V_cav(y0)) / dt`` (length^3 / time)."""
        return -(self.value(x[:-1]) - self.value(y0)) / dt

    def next_state(self, state, x, y0, dt):
        """``(p', Pa', phase')`` after the converged step x: the Windkessel's Pa by the trapezoidal rule (the
        aortic valve open: ``Pa_mid = p' - R_c Q``, ``Pa' = 2 Pa_mid - Pa``; closed: the free decay
        ``Pa' = Pa (1 - k) / (1 + k)``), the phase by the valve conditions at the step's values (module
        docstring)."""
        p, Pa, phase = x[-1], state[1], state[2]
        Q = self.outflow(state, x, y0, dt)
        k = dt / (2 * self.R * self.C)
        Pa_new = jnp.where(phase == 1, 2 * (p - self.Rc * Q) - Pa, Pa * (1 - k) / (1 + k))
        opens_aortic, opens_mitral = p > Pa_new, p < self.p_atrial
        isovolumic_next = jnp.where(opens_aortic, 1.0, jnp.where(opens_mitral, 2.0, 0.0))
        phase_new = jnp.where(phase == 1, jnp.where(Q > 0, 1.0, 0.0),
                              jnp.where(phase == 2, jnp.where(p < self.p_atrial, 2.0, 0.0), isovolumic_next))
        return jnp.stack([p, Pa_new, phase_new]).astype(x.dtype)


class NoConstraint(_ScalarState):
    """No global constraint: the gauge ``y0' = w + s e``, ``e . w = 0`` (module docstring); pressure 0."""

    kind = "none"
    has_multiplier = False

    def __init__(self, model):
        self.model = model
        self.e = jnp.full(model.n, model.n ** -0.5)

    def unknown(self, y0, p=None):
        s = self.e @ y0
        return jnp.concatenate([y0 - s * self.e, s[None]])

    def split(self, x):
        return x[:-1] + x[-1] * self.e, jnp.zeros((), x.dtype)

    def value(self, y0):
        """The tissue volume ``int det F`` (reported, not held)."""
        return self.model.volume(y0)

    def target(self, V0, t):
        return V0 + 0.0 * t

    def check_targets(self, t) -> None:
        """Nothing to check: the volume is not held."""

    def momentum(self, x, y0, p_prev, theta, weighting):
        return jnp.zeros(self.model.n, x.dtype)

    def row(self, x, V0, t, y0=None, p_prev=None, dt=None):
        return self.e @ x[:-1]

    def next_state(self, state, x, y0, dt):
        return jnp.zeros((), x.dtype)

    def tangent_weight(self, x):
        return 0.0

    def add_tangent(self, blocks, x, scale):
        return blocks

    def border(self, blocks, x, y0, dt, theta, weighting):
        """``(K e, e)``: K e the assembled element blocks applied to e (exactly the Jacobian's column)."""
        index = self.model.element_gather
        Ke = jnp.einsum("ckl,cl->ck", blocks, gather(self.e, index))
        return scatter(Ke, index, self.model.n), self.e

    def restricted(self, model, local, cells, dofs):
        """No constraint on ``local`` (the rank's cells): the distributed step solves ``K dy0' = -F_u`` without a
        border (`hyperoc.distributed.newton` unconstrained), so the gauge's multiplier s stays 0 and the local
        ``split`` returns the displacement as it is."""
        return NoConstraint(local)


#: the kinds with a form on a rank's cells (`restricted`, module docstring): the distributed path's
DISTRIBUTED_CONSTRAINTS = ("tissue_volume", "cavity_volume", "circulation", "none")

CONSTRAINTS = {"tissue_volume": TissueVolume, "cavity_volume": CavityVolumeConstraint, "none": NoConstraint}


def make_constraint(model, kind="tissue_volume"):
    """The constraint of ``kind`` (a name of `CONSTRAINTS`, built with its defaults, or a constraint object,
    returned as is)."""
    if not isinstance(kind, str):
        return kind
    if kind == "circulation":
        raise InputError("the circulation constraint needs its parameters: pass Circulation(model, ...)")
    if kind not in CONSTRAINTS:
        raise InputError(f"constraint must be one of {sorted(CONSTRAINTS)}, got {kind!r}")
    return CONSTRAINTS[kind](model)

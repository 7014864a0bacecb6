"""The global constraint of a time step, a family the configuration selects (``[dynamics] constraint``).

A step's Newton unknown is ``x = (z, q)`` (n + 1,) and its residual ``(F_u (n,), F_c)``: the bordered
system of `hyperoc.solvers.linsolve` (one factorization of the element-assembled K, a Schur complement on
the one border), so Newton, chord Newton, the linear solvers, the adjoint and checkpointing stay one path
whatever the constraint. A constraint says how ``x`` maps to the step's displacement ``y0'`` and
multiplier ``p'`` (`split`), what the multiplier adds to the momentum rows (`momentum`) and to their
element blocks (`tangent_weight`, `add_tangent`), what its row is (`row`, against `target`) and the
border of the Jacobian (`border`). ``V0`` is the constrained quantity of the initial state (`value`).

The step carries the constraint's multiplier state from one step to the next (`carried` at the first level,
`next_state` after each step, `pressure` its multiplier): the multiplier p' itself. A row may read the
step's previous level (y0, the carried state, dt) and depend on p' (`corner`, the bordered Jacobian's
``dF_c/dp'``, 0 here).

A constraint with a multiplier holds ``c(y0') = target(V0, t')`` with a force ``-p' G`` on the momentum
rows, ``G`` the *force direction* (`force_direction`) and ``c`` the constrained quantity; step weighting
(default): ``dt p' (theta G(y0') + (1 - theta) G(y0))``; "theta": ``dt (theta p' G' + (1 - theta) p G)``.

- `TissueVolume` (``"tissue_volume"``, the paper's): ``c = vol(y0) = int det F``, ``G = dc/dy0``
  (the multiplier pulls the body against its volume change), ``target = V0``.
- `CavityVolumeConstraint` (``"cavity_volume"``): ``c = V_cav(y0)``, the volume of the cavity bounded by a
  wall of the body (`hyperoc.mechanics.cavity.CavityVolume`, fixed apex: exact for P1 and P2, curved
  cells), held at ``target = V0 + dV(t)`` (``dV`` a time law, `hyperoc.dynamics.laws`; none: the
  initial volume, an isovolumic phase). Its multiplier is the cavity (left-ventricular) pressure, positive
  when it pushes the wall out of the cavity: the load ``p' dV_cav/du`` (a follower pressure on the wall
  and the lid's reaction on the rim), so ``G = -dV_cav/du``; its stiffness ``-p' d2V_cav/du2`` is
  symmetric (a Hessian), added to the element blocks of the wall's cells.
- `NoConstraint` (``"none"``): only the material's own volumetric term controls the volume. The bordered
  solvers are reused through the gauge of `hyperoc.dynamics.statics`: ``y0' = w + s e`` with the unit
  vector ``e = (1, ..., 1) / sqrt(n)``, ``x = (w, s)``, ``F_c = e . w``, border ``(K e, e)``; the Schur
  complement ``e^T K^-1 K e = 1`` never vanishes and ``dy0' = dw + ds e`` is the plain Newton step
  ``K dy0' = -F_u``. There is no multiplier: the reported pressure is 0 at every level (the prescribed
  endocardial pressure, if any, is a load: `hyperoc.dynamics.terms.DynamicPressure`); its `value` is the
  tissue volume, reported as the drift.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import InputError
from ..mechanics.cavity import CavityVolume
from ..mechanics.kernels import gather, scatter
from .laws import TimeLaw

__all__ = ["TissueVolume", "CavityVolumeConstraint", "NoConstraint", "make_constraint", "CONSTRAINTS"]


class _HeldByMultiplier:
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
        """The constraint's residual ``c(y0') - target(V0, t)`` at the step's new level t (the step's previous
        level ``y0``, multiplier state ``p_prev`` and ``dt`` enter no row of this family)."""
        return self.value(x[:-1]) - self.target(V0, t)

    def corner(self, p_prev, dt):
        """``dF_c/dp'``, the bordered Jacobian's corner: 0 (the row does not depend on the multiplier)."""
        return 0.0

    def carried(self, p):
        """The multiplier state the step carries, starting from the multiplier p: p itself."""
        return p

    def pressure(self, state):
        """The multiplier (the reported pressure) of carried states (any leading shape): the states themselves."""
        return state

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

    def tangent_weight(self, x):
        """The weight b of ``det F``'s Hessian in the element tangent (`StateModel.tangent_blocks`)."""
        return x[-1]

    def add_tangent(self, blocks, x, scale):
        """The element blocks plus ``scale`` times the multiplier's stiffness not in `tangent_weight`: none."""
        return blocks


class CavityVolumeConstraint(_HeldByMultiplier):
    """The volume of the cavity bounded by ``boundary`` (`hyperoc.mechanics.cavity.CavityVolume`, fixed apex)
    held at ``V0 + change(t)`` (``change``: a `hyperoc.dynamics.laws.TimeLaw` of the volume change in
    length^d, or None: isovolumic) by the cavity pressure p (stress units, positive pushing the wall out
    of the cavity). `InputError` for a boundary the mesh lacks or one that encloses no volume."""

    kind = "cavity_volume"

    def __init__(self, model, boundary: str = "endocardium", change: TimeLaw | None = None):
        if boundary not in model.mesh.boundaries:
            raise InputError(f"cavity volume: the mesh has no boundary {boundary!r} (its boundaries: "
                             f"{', '.join(sorted(model.mesh.boundaries))})")
        if change is not None and not isinstance(change, TimeLaw):
            raise InputError(f"cavity volume: the volume change must be a time law, got {change!r}")
        self.model, self.boundary, self.change = model, boundary, change
        self.cavity = CavityVolume(model, boundary)

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

    def tangent_weight(self, x):
        return 0.0

    def add_tangent(self, blocks, x, scale):
        """The element blocks plus ``scale`` times the pressure's stiffness ``-p' d2V_cav/du2``."""
        return self.cavity.add_hessian(blocks, x[:-1], -scale * x[-1])


class NoConstraint:
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

    def corner(self, p_prev, dt):
        return 0.0

    def carried(self, p):
        return p

    def pressure(self, state):
        return state

    def next_state(self, state, x, y0, dt):
        return jnp.zeros((), x.dtype)

    def tangent_weight(self, x):
        return 0.0

    def add_tangent(self, blocks, x, scale):
        return blocks

    def border(self, blocks, x, y0, dt, theta, weighting):
        """``(K e, e)``: K e the assembled element blocks applied to e (exactly the Jacobian's column)."""
        index = self.model._element_gather
        Ke = jnp.einsum("ckl,cl->ck", blocks, gather(self.e, index))
        return scatter(Ke, index, self.model.n), self.e


CONSTRAINTS = {"tissue_volume": TissueVolume, "cavity_volume": CavityVolumeConstraint, "none": NoConstraint}


def make_constraint(model, kind="tissue_volume"):
    """The constraint of ``kind`` (a name of `CONSTRAINTS`, built with its defaults, or a constraint object,
    returned as is)."""
    if not isinstance(kind, str):
        return kind
    if kind not in CONSTRAINTS:
        raise InputError(f"constraint must be one of {sorted(CONSTRAINTS)}, got {kind!r}")
    return CONSTRAINTS[kind](model)

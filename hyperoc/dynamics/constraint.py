"""The global constraint of a time step, a family the configuration selects (``[model] constraint``).

A step's Newton unknown is ``x = (z, q)`` (n + 1,) and its residual ``(F_u (n,), F_c)``: the bordered
system of `hyperoc.solvers.linsolve` (one factorization of the element-assembled K, a Schur complement on
the one border), so Newton, chord Newton, the linear solvers, the adjoint and checkpointing stay one path
whatever the constraint. A constraint says how ``x`` maps to the step's displacement ``y0'`` and
multiplier ``p'`` (`split`), what the multiplier adds to the momentum rows and what its row is.

- `TissueVolume` (``"tissue_volume"``, the paper's): ``x = (y0', p')``, the momentum rows get
  ``dt p' (theta G(y0') + (1 - theta) G(y0))`` ("step" weighting; "theta": ``dt (theta p' G' + (1 -
  theta) p G)``), ``F_c = vol(y0') - V0``, border ``(dt (theta G' + (1 - theta) G), G')``.
- `NoConstraint` (``"none"``): only the material's own volumetric term controls the volume. The bordered
  solvers are reused through the gauge of `hyperoc.dynamics.statics`: ``y0' = w + s e`` with the unit
  vector ``e = (1, ..., 1) / sqrt(n)``, ``x = (w, s)``, ``F_c = e . w``, border ``(K e, e)``; the Schur
  complement ``e^T K^-1 K e = 1`` never vanishes and ``dy0' = dw + ds e`` is the plain Newton step
  ``K dy0' = -F_u``. There is no multiplier: the reported pressure is 0 at every level (the prescribed
  endocardial pressure, if any, is a load: `hyperoc.dynamics.terms.DynamicPressure`).

A constraint whose multiplier is the cavity pressure acting as a follower load on the endocardium (the LV
cavity volume prescribed) fits the same interface: its `momentum` is ``-p'`` times the follower force per
unit pressure, its `row` the cavity volume, its `tangent_weight` the follower stiffness's factor.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..errors import InputError
from ..mechanics.kernels import gather, scatter

__all__ = ["TissueVolume", "NoConstraint", "make_constraint", "CONSTRAINTS"]


class TissueVolume:
    """The volume of the tissue held at its initial value by the multiplier p (the paper's constraint)."""

    kind = "tissue_volume"
    has_multiplier = True

    def __init__(self, model):
        self.model = model

    def unknown(self, y0, p):
        """Newton's unknown x (n + 1,) for the displacement y0 (n,) and multiplier p."""
        return jnp.concatenate([y0, jnp.reshape(p, (1,))])

    def split(self, x):
        """``(y0' (n,), p')`` of the unknown x."""
        return x[:-1], x[-1]

    def momentum(self, x, y0, p_prev, theta, weighting):
        """The multiplier's part of the momentum rows, divided by dt, (n,)."""
        G_new, G_old = self.model.volume_gradient(x[:-1]), self.model.volume_gradient(y0)
        if weighting == "step":
            return x[-1] * (theta * G_new + (1 - theta) * G_old)
        return theta * x[-1] * G_new + (1 - theta) * p_prev * G_old

    def row(self, x, V0):
        """The constraint's residual ``vol(y0') - V0``."""
        return self.model.volume(x[:-1]) - V0

    def tangent_weight(self, x):
        """The weight b of ``det F``'s Hessian in the element tangent (`StateModel.tangent_blocks`)."""
        return x[-1]

    def border(self, blocks, x, y0, dt, theta, weighting):
        """``(col, row)`` (n,) each of the bordered Jacobian, given the element blocks of dF_u/dy0'."""
        G_new = self.model.volume_gradient(x[:-1])
        if weighting == "step":
            return dt * (theta * G_new + (1 - theta) * self.model.volume_gradient(y0)), G_new
        return dt * theta * G_new, G_new


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

    def momentum(self, x, y0, p_prev, theta, weighting):
        return jnp.zeros(self.model.n, x.dtype)

    def row(self, x, V0):
        return self.e @ x[:-1]

    def tangent_weight(self, x):
        return 0.0

    def border(self, blocks, x, y0, dt, theta, weighting):
        """``(K e, e)``: K e the assembled element blocks applied to e (exactly the Jacobian's column)."""
        index = self.model._element_gather
        Ke = jnp.einsum("ckl,cl->ck", blocks, gather(self.e, index))
        return scatter(Ke, index, self.model.n), self.e


CONSTRAINTS = {"tissue_volume": TissueVolume, "none": NoConstraint}


def make_constraint(model, kind="tissue_volume"):
    """The constraint of ``kind`` (a name of `CONSTRAINTS`, or a constraint object, returned as is)."""
    if not isinstance(kind, str):
        return kind
    if kind not in CONSTRAINTS:
        raise InputError(f"constraint must be one of {sorted(CONSTRAINTS)}, got {kind!r}")
    return CONSTRAINTS[kind](model)

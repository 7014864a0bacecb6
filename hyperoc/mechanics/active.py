"""Active fibre tension as a state-dependent load of the quasi-static solver.

An active tension ``T`` (stress units, e.g. kPa) along the reference fibre ``f0`` adds the second
Piola-Kirchhoff stress ``S_a = T f0 (x) f0`` to the passive one (Land et al. 2015, problem 3; the
first Piola-Kirchhoff stress is ``P_a = F S_a = T (F f0) (x) f0``: it turns with the fibre). For a given
T it derives from the energy

    A(u) = T int_Omega w(X) E_ff dX,   E_ff = f0 . E f0 = (|F f0|^2 - 1) / 2,

which is quadratic in u; ``w`` is an optional activation profile (1 by default, the benchmark). The
load on the body is ``f_a(u) = -dA/du`` and the stiffness it adds to the
Newton tangent, ``-df_a/du = T int w (grad N_a . f0) (grad N_b . f0) delta_ik dX`` per element, does
not depend on u.

This is the active-stress law of the cardiac mechanics benchmarks. The control of the optimal control
problem, `hyperoc.mechanics.controls.ActiveStress`, is different: a prescribed first Piola-Kirchhoff stress
``xi f0 (x) f0``, linear in xi and independent of u (the paper's setting, where the control enters
the state equation as a load).
"""

from __future__ import annotations

import copy
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import InputError

__all__ = ["FibreTension", "axis_taper"]


class FibreTension:
    """Active tension ``tension`` along the fibres of ``model`` (row 0 of its ``frames``).

    Used like `hyperoc.mechanics.follower.FollowerPressure` in `hyperoc.dynamics.statics.solve_static` (``follower=``):
    methods take the model's unknowns u (n,) (for `hyperoc.mechanics.mixed.TaylorHoodModel` the displacement and
    the pressures) and a load ``factor``; the tension applied is ``factor * tension * profile(X)``.

    profile : optional callable ``X (..., d) -> (...)``, the dimensionless activation at reference points
        (default 1 everywhere), evaluated once at the quadrature points; e.g. `axis_taper`.
    """

    def __init__(self, model, tension: float, profile=None):
        if not math.isfinite(tension):
            raise InputError(f"fibre tension must be finite, got {tension}")
        if model.material_frames is None:
            raise InputError("FibreTension needs a model with fibre frames (StateModel(..., frames=...))")
        self.model, self.tension, self.n = model, float(tension), model.n
        q = model.quad
        w = q.wdx if profile is None else q.wdx * np.broadcast_to(np.asarray(profile(q.x), np.float64), q.wdx.shape)
        if not np.all(np.isfinite(w)):
            raise InputError("the activation profile must be finite at every quadrature point")
        self._w = jnp.asarray(w)  # quadrature weights times the profile, (nc, nq)
        f0 = np.asarray(model.material_frames)[..., 0, :]  # (nc, nq, d)
        self._f0 = jnp.asarray(f0)
        g = np.einsum("cqaj,cqj->cqa", q.dN, f0)  # grad N_a . f0
        self._G = jnp.asarray(np.einsum("cq,cqa,cqb->cab", w, g, g))  # (nc, nloc, nloc)

    def restricted(self, model, local, cells: np.ndarray, dofs: np.ndarray) -> "FibreTension":
        """This tension on ``cells`` of ``model`` only, acting on ``local = model.restricted(cells, dofs)``:
        forces on its unknowns (m,), stiffness added to its element blocks (`FollowerPressure.restricted`'s
        interface)."""
        restricted = copy.copy(self)
        restricted.model, restricted.n = local, local.n
        restricted._w, restricted._f0, restricted._G = self._w[cells], self._f0[cells], self._G[cells]
        return restricted

    def fibre_strain(self, u):
        """``E_ff = (|F f0|^2 - 1) / 2`` at every quadrature point, (nc, nq)."""
        Ff = jnp.einsum("cqij,cqj->cqi", self.model.deformation_gradient(u), self._f0)
        return 0.5 * (jnp.sum(Ff * Ff, axis=-1) - 1.0)

    def energy(self, u, factor=1.0):
        """``factor T int w E_ff dX`` (energy units)."""
        return factor * self.tension * jnp.sum(self._w * self.fibre_strain(u))

    def force(self, u, factor=1.0):
        """``f_a(u) = -dA/du`` (n,): the nodal force of the active stress on the body."""
        return -jax.grad(self.energy)(u, factor)

    def element_stiffness(self, factor=1.0):
        """``-df_a/du`` per cell, (nc, k, k), k = nloc d, node-major (the displacement block of the
        model's element matrices)."""
        nc, nloc, _ = self._G.shape
        d = self.model.dim
        K = jnp.einsum("cab,ik->caibk", self._G, jnp.eye(d)).reshape(nc, nloc * d, nloc * d)
        return factor * self.tension * K

    def add_stiffness(self, cell_blocks, u, factor=1.0):
        """``cell_blocks`` (nc, k', k') plus the stiffness in their leading (displacement) k x k block
        (``u`` is not used: the stiffness is constant; it is there for the load interface of `solve_static`)."""
        K = self.element_stiffness(factor)
        k = K.shape[1]
        return cell_blocks.at[:, :k, :k].add(K)


def axis_taper(radius: float, axis=(0.0, 0.0, 1.0)):
    """Activation profile ``w(X) = min(1, rho^2 / radius^2)``, rho the distance of X to the line through
    the origin along ``axis``: zero on the axis, one beyond ``radius`` (mm). Prolate fibres are singular
    on the long axis (at the apices); this takes the active tension away there."""
    if not (math.isfinite(radius) and radius > 0):
        raise InputError(f"axis_taper: the radius must be > 0, got {radius}")
    e = np.asarray(axis, np.float64)
    e = e / np.linalg.norm(e)

    def profile(x):
        x = np.asarray(x, np.float64)
        rho2 = np.sum(x * x, axis=-1) - (x @ e) ** 2
        return np.minimum(1.0, np.maximum(rho2, 0.0) / radius**2)

    return profile

"""Terms of the step's ``A(y0, y1, t)``: boundary springs and dashpots, time-dependent follower pressure,
prescribed active tension and the viscous pseudo-potential.

The step of `hyperoc.dynamics.stepper.TimeStepper` solves

    M (y1' - y1) + dt [theta A(y0', y1', t') + (1 - theta) A(y0, y1, t)] + (constraint) = dt [theta L' + (1 - theta) L]

with ``A(y0, y1, t) = kappa K y1 + R(y0) + sum_j A_j(y0, y1, t)``. Each term here is one ``A_j`` (n,),
on the internal-force side (a load f enters as ``A_j = -f``), with

- ``force(y0, y1, t)``: ``A_j`` (n,) on the reduced dofs;
- ``add_tangent(blocks, y0, y1, t, a, b)``: the element blocks (nc, k, k) plus ``a dA_j/dy0 + b dA_j/dy1``
  in the element blocks of the cells (a boundary term in its facets' owner cells), so the step's
  Jacobian keeps the model's sparsity pattern (the step passes ``a = theta dt``, ``b = 1``);
- ``symmetric``: whether ``dA_j/dy0`` and ``dA_j/dy1`` are symmetric (else the adjoint solves with the
  transposed blocks);
- ``restricted(model, local, cells, dofs)``: the term on a rank's cells (`hyperoc.distributed`).

Every law of time (`hyperoc.dynamics.laws`) is evaluated inside the traced step at the step's time levels,
so that derivatives in t (and through the t-grid in tau) are exact.

Terms:

- `RobinBoundary`: spring-dashpot on a tagged boundary, traction ``-(k u + c u_t)`` ("full") or
  ``-(k u.N + c u_t.N) N`` ("normal"), N the reference outward unit normal, on the reference surface:
  ``A = (k S) y0 + (c S) y1`` with the boundary matrix ``S_(ai)(bj) = int_Gamma N_a N_b P_ij dA``,
  ``P = I`` or ``N N^T``. Units: k in stress/length (Pa/m), c in stress time/length (Pa s/m).
  Stored energy ``k/2 y0.S y0``, dissipation rate ``c y1.S y1``.
- `DynamicPressure`: the follower pressure ``p(t)`` (`hyperoc.mechanics.follower.FollowerPressure`,
  positive pushes into the body) on the deformed boundary; ``A = -p(t) f_1(y0)``. Its load stiffness is
  not symmetric on an open surface.
- `PrescribedTension`: the active tension ``T_a(t)`` along the fibres
  (`hyperoc.mechanics.active.FibreTension`), second Piola stress ``T_a f0 (x) f0``, beside the control.
- `Viscosity`: the pseudo-potential ``D = (eta/2) tr(Edot^2)``, ``Edot = sym(F^T grad v)``, whose second
  Piola stress is ``S_v = eta Edot``: ``A = (F S_v, grad phi) = dD/dv`` (JAX gradient of the element
  function; its tangent in closed form, `Viscosity._element_tangent`). Dissipation rate
  ``y1.A = eta int tr(Edot^2) >= 0``.
  Units: eta in stress time (Pa s).
"""

from __future__ import annotations

import copy
import math

import jax
import jax.numpy as jnp

from ..errors import InputError
from ..mechanics import kernels
from ..mechanics.active import FibreTension
from ..mechanics.follower import BoundaryFacets, FollowerPressure, area_vector
from .laws import Constant, TimeLaw

__all__ = ["RobinBoundary", "DynamicPressure", "PrescribedTension", "Viscosity"]


def _law(law) -> TimeLaw:
    """A `TimeLaw`, or a constant one for a number."""
    return law if isinstance(law, TimeLaw) else Constant(float(law))


class RobinBoundary(BoundaryFacets):
    """Spring ``stiffness`` k and dashpot ``damping`` c on ``boundary`` of ``model``, along ``direction``
    "full" (every component) or "normal" (the reference normal only). See the module docstring."""

    symmetric = True

    def __init__(self, model, boundary: str, stiffness: float, damping: float = 0.0, direction: str = "full"):
        if direction not in ("full", "normal"):
            raise InputError(f"Robin boundary {boundary!r}: direction must be 'full' or 'normal', got {direction!r}")
        if not (math.isfinite(stiffness) and math.isfinite(damping) and stiffness >= 0 and damping >= 0):
            raise InputError(f"Robin boundary {boundary!r}: need finite stiffness >= 0 and damping >= 0, "
                             f"got {stiffness}, {damping}")
        super().__init__(model, boundary, degree=2 * model.space.degree)  # N_a N_b exactly on a flat facet
        self.stiffness, self.damping, self.direction = float(stiffness), float(damping), direction
        self._S = self._facet_matrices()

    def _facet_matrices(self):
        """``S_f`` (nf, m d, m d), node-major: ``sum_q w_q |a_q| N_a N_b P_ij(N_q)`` on each reference facet,
        ``a_q`` the area vector at the quadrature point (constant on a flat facet, where the rule of degree
        2k is exact; a curved P2 facet, `hyperoc.fem.mesh.Mesh.curved_edges`, gets the area and normal of
        its isoparametric map at each point)."""
        tangents = jnp.einsum("qaj,fai->fqij", self._dN, self._X)
        a = jax.vmap(jax.vmap(area_vector))(tangents)  # (nf, nq, d)
        area = jnp.linalg.norm(a, axis=-1)
        nf, m, d = self._X.shape
        if self.direction == "full":
            P = jnp.broadcast_to(jnp.eye(d), (*area.shape, d, d))
        else:
            normal = a / area[..., None]
            P = jnp.einsum("fqi,fqj->fqij", normal, normal)
        S = jnp.einsum("q,fq,qa,qb,fqij->faibj", self._w, area, self._N, self._N, P)
        return S.reshape(nf, m * d, m * d)

    def _restricted(self, mine):
        self._S = self._S[mine]

    def _apply(self, v):
        """``S v`` (n,) for v (n,)."""
        ve = kernels.gather(v, self._gather)
        return kernels.scatter(jnp.einsum("fij,fj->fi", self._S, ve), self._gather, self.n)

    def force(self, y0, y1, t):
        return self.stiffness * self._apply(y0) + self.damping * self._apply(y1)

    def add_tangent(self, blocks, y0, y1, t, a, b):
        return self.add_facet_blocks(blocks, (a * self.stiffness + b * self.damping) * self._S)

    def stored_energy(self, y0):
        """``k/2 y0.S y0`` (energy)."""
        return 0.5 * self.stiffness * y0 @ self._apply(y0)

    def dissipation_rate(self, y1):
        """``c y1.S y1`` (power)."""
        return self.damping * y1 @ self._apply(y1)


class _ScaledLoad:
    """A state-dependent load ``f(y0)`` of unit amplitude (`load`: `FollowerPressure`, `FibreTension`, with
    ``force(u, factor)``, ``add_stiffness(blocks, u, factor)`` and ``restricted``) times ``law(t)``:
    ``A = -law(t) f(y0)``, its tangent ``a law(t) K(y0)`` (K = -df/du, the load's stiffness)."""

    def restricted(self, model, local, cells, dofs):
        out = copy.copy(self)
        out.load = self.load.restricted(model, local, cells, dofs)
        return out

    def force(self, y0, y1, t):
        return -self.load.force(y0, self.law(t))

    def add_tangent(self, blocks, y0, y1, t, a, b):
        return self.load.add_stiffness(blocks, y0, a * self.law(t))

    def power(self, y0, y1, t):
        """The load's power ``law(t) f(y0) . y1``."""
        return self.load.force(y0, self.law(t)) @ y1


class DynamicPressure(_ScaledLoad):
    """Follower pressure ``law(t)`` (stress units; positive pushes into the body) on the deformed ``boundary``."""

    symmetric = False

    def __init__(self, model, boundary: str, law):
        self.load = FollowerPressure(model, boundary, 1.0)
        self.law, self.boundary = _law(law), boundary


class PrescribedTension(_ScaledLoad):
    """Active tension ``law(t)`` (stress units) along the fibres of ``model`` times ``profile(X)`` (default 1)."""

    symmetric = True

    def __init__(self, model, law, profile=None):
        self.load = FibreTension(model, 1.0, profile)
        self.law = _law(law)


class Viscosity:
    """The viscous pseudo-potential ``(eta/2) tr(Edot^2)`` of ``model`` (a `StateModel`: displacement unknowns)."""

    symmetric = False

    def __init__(self, model, eta: float):
        if hasattr(model, "n_u"):
            raise InputError("viscosity: not implemented for mixed (Taylor-Hood) models")
        if not (math.isfinite(eta) and eta >= 0):
            raise InputError(f"viscosity must be finite and >= 0, got {eta}")
        self.model, self.eta = model, float(eta)

    def restricted(self, model, local, cells, dofs):
        out = copy.copy(self)
        out.model = local
        return out

    def _element_dissipation(self, ue, ve, dN, w):
        """``(eta/2) int_e tr(Edot^2)`` of one cell, ue, ve (k,) node-major, dN (nq, nloc, d), w (nq,)."""
        d = self.model.dim
        F = kernels.element_F(ue.reshape(-1, d), dN)
        L = jnp.einsum("qaj,ai->qij", dN, ve.reshape(-1, d))
        FtL = jnp.einsum("qki,qkj->qij", F, L)
        Edot = 0.5 * (FtL + jnp.swapaxes(FtL, 1, 2))
        return 0.5 * self.eta * jnp.einsum("q,qij,qij->", w, Edot, Edot)

    def _element_force(self, ue, ve, dN, w):
        return jax.grad(self._element_dissipation, argnums=1)(ue, ve, dN, w)

    def _cells(self, y0, y1):
        """``(y0_e, y1_e, dN, w)``: each cell's displacements and velocities and its quadrature data."""
        ue, dN, w, _ = self.model.element_args(y0)
        return ue, kernels.gather(y1, self.model.element_gather), dN, w

    def force(self, y0, y1, t):
        m = self.model
        forces = m.map_cells(lambda xs: self._element_force(*xs), self._cells(y0, y1))
        return kernels.scatter(forces, m.element_gather, m.n)

    def _element_tangent(self, ue, ve, dN, w, a, b):
        """``a dA_e/due + b dA_e/dve`` (k, k) of one cell in closed form, rows ``(a_, i)`` and columns ``(b_, k)``
        node-major. With ``g_b = F dN_b``, ``h_a = L dN_a``, ``G_ab = dN_a . dN_b`` at each point
        (``A_e[a_, i] = eta sum_q w_q (F Edot dN_a)_i``):

            dA/du[a_ i, b_ k] = eta sum_q w_q (delta_ik dN_a . Edot dN_b + (g_b,i h_a,k + (F L^T)_ik G_ab) / 2),
            dA/dv[a_ i, b_ k] = eta sum_q w_q ((F F^T)_ik G_ab + g_b,i g_a,k) / 2,

        the derivatives of `_element_force` (checked against ``jax.jacfwd`` of it), at the cost of a few
        products per point instead of k forward passes through its reverse-mode gradient."""
        d = self.model.dim
        F = kernels.element_F(ue.reshape(-1, d), dN)
        L = jnp.einsum("qaj,ai->qij", dN, ve.reshape(-1, d))
        FtL = jnp.einsum("qki,qkj->qij", F, L)
        Edot = 0.5 * (FtL + jnp.swapaxes(FtL, 1, 2))
        g, h = jnp.einsum("qiJ,qbJ->qbi", F, dN), jnp.einsum("qkL,qaL->qak", L, dN)
        G = jnp.einsum("qaJ,qbJ->qab", dN, dN)
        ew = self.eta * w
        dyadic = a * jnp.einsum("qiJ,qkJ->qik", F, L) + b * jnp.einsum("qiJ,qkJ->qik", F, F)
        K = 0.5 * (jnp.einsum("q,qab,qik->aibk", ew, G, dyadic) + jnp.einsum("q,qbi,qak->aibk", ew, g, a * h + b * g))
        K = K + a * jnp.einsum("q,qaJ,qJL,qbL,ik->aibk", ew, dN, Edot, dN, jnp.eye(d))
        n = K.shape[0] * d
        return K.reshape(n, n)

    def add_tangent(self, blocks, y0, y1, t, a, b):
        return blocks + self.model.map_cells(lambda xs: self._element_tangent(*xs, a, b), self._cells(y0, y1))

    def dissipation_rate(self, y0, y1):
        """``eta int tr(Edot^2)`` (power) = ``y1 . A``."""
        return self.force(y0, y1, 0.0) @ y1

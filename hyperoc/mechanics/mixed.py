"""Taylor-Hood (P2-P1) mixed displacement-pressure model for quasi-static, nearly or exactly
incompressible solids.

The unknown is ``x = (u, p)``: the reduced P2 displacement u (n_u,) and a continuous P1 field p
(n_p,) on the mesh vertices. The discrete problem is stationarity of the perturbed Lagrangian

    L(u, p) = int_Omega W_rest(E) + p (J - 1) - p^2 / (2 bulk_modulus) dx,        J = det F,

where ``W_rest`` is the law without its bulk term (`hyperoc.mechanics.materials.Material.volumetric_split`)
and ``bulk_modulus`` its small-strain bulk modulus ``U''(1)``: dL/dp = 0 says ``J - 1 = p / bulk_modulus``
against every P1 test function, and eliminating p pointwise would give the quadratic bulk
energy ``bulk_modulus/2 (J - 1)^2`` (the law's ``U(J)`` to second order at J = 1, and the same limit). With
``bulk_modulus = inf`` the constraint is exact: ``int N_a (J - 1) = 0`` for every vertex hat ``N_a``, hence
the deformed volume equals the reference one. p is a tension (positive when J > 1); with
``J sigma = P F^T`` the Cauchy stress contains ``+ p I``.

P2-P1 satisfies the inf-sup condition on triangles and tetrahedra (Taylor-Hood), so it does not
lock as the bulk modulus grows and the pressure converges too, unlike the pure displacement form
(`StateModel` ``volumetric="pointwise"``) or the cell-mean form, which constrains only each cell's
mean J. The saddle-point tangent is symmetric and indefinite; the sparse LU of `hyperoc.solvers.linsolve`
(threshold pivoting) factors it.

The model plugs into `hyperoc.dynamics.statics.solve_static` (``constraint="none"``) and
`hyperoc.mechanics.follower.FollowerPressure` as a `StateModel` whose unknown vector has ``n = n_u + n_p``
entries, the pressures last; it has no dynamics (no mass on p) and no control.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from ..errors import InputError
from ..fem.assembly import relabel_index
from ..fem.mesh import Mesh
from ..fem.spaces import VectorSpace, prolong, reference_shape
from .kernels import at_points, element_F, element_tangent
from .materials import Material, det
from .model import StateModel

__all__ = ["TaylorHoodModel"]

def _bulk_modulus(material: Material, bulk_modulus) -> tuple[Material, float]:
    """``(W_rest, bulk modulus)``: the law without its bulk term, and ``bulk_modulus`` or, if None, the law's U''(1)."""
    rest, bulk = material.volumetric_split()
    if bulk_modulus is None:
        if bulk is None:
            raise InputError(f"TaylorHoodModel: {type(material).__name__} has no separate bulk term; "
                             "pass bulk_modulus (kPa, or inf for an incompressible body)")
        bulk_modulus = float(jax.grad(jax.grad(bulk))(1.0))
    value = float(bulk_modulus)
    if not (value > 0 and not math.isnan(value)):
        raise InputError(f"TaylorHoodModel: the bulk modulus must be > 0 (or inf), got {bulk_modulus}")
    return rest, value


class TaylorHoodModel(StateModel):
    """P2 displacement, P1 pressure; see the module docstring for the Lagrangian.

    Parameters
    ----------
    mesh, material : as `StateModel`; the law's bulk term U(J) is replaced by the pressure field.
    bulk_modulus : kPa; None (default): the law's ``U''(1)`` (Guccione, Holzapfel-Ogden: its
        ``bulk_modulus``; neo-Hookean: ``lambda``); ``math.inf``: exactly incompressible.
    **kwargs : the boundary and frame arguments of `StateModel` (``dirichlet``,
        ``dirichlet_components``, ``pin_rigid``, ``frames``, ``neumann``, ``traction``).

    Attributes
    ----------
    n_u : int
        Displacement unknowns.
    n_p : int
        Pressure unknowns (mesh vertices).
    n : int
        Their sum.
    cell_dofs : (nc, k_u + d + 1) array of int
        The element unknowns, displacement first (node-major), then the cell's vertex pressures.
    """

    def __init__(self, mesh: Mesh, material: Material, *, bulk_modulus: float | None = None, **kwargs):
        for name in ("degree", "volumetric", "control", "damping", "density"):
            if name in kwargs:
                raise InputError(f"TaylorHoodModel: {name!r} is fixed (P2-P1, quasi-static, no control)")
        self.n_p = mesh.points.shape[0]  # before StateModel's init, whose traction load goes through load_vector
        super().__init__(mesh, material, degree=2, **kwargs)
        self._point_material, self.bulk_modulus = _bulk_modulus(self.material, bulk_modulus)
        self.n_u = self.n
        self.n = self.n_u + self.n_p
        # `pattern` is built from these
        self._set_cell_dofs(np.concatenate([self.cell_dofs, mesh.cells + self.n_u], axis=1))
        self._Np = jnp.asarray(reference_shape(self.dim, 1, self.quad.xi)[0])  # (nq, d + 1) P1 hats at the points

    # --- unknowns ---------------------------------------------------------------------------------
    def displacement_part(self, x):
        """The reduced displacement x[:n_u]."""
        return x[..., : self.n_u]

    def pressure(self, x):
        """The vertex pressures x[n_u:] (n_p,) (kPa, tension positive)."""
        return x[..., self.n_u:]

    def unknowns(self, u, p=None) -> np.ndarray:
        """``x = (u, p)`` (n,) from a reduced displacement (n_u,) and vertex pressures (n_p,) (default 0)."""
        p = np.zeros(self.n_p) if p is None else np.asarray(p, dtype=np.float64)
        return np.concatenate([np.asarray(u, dtype=np.float64), p])

    def expand(self, x) -> np.ndarray:
        return super().expand(self.displacement_part(np.asarray(x)))

    def restrict(self, full) -> np.ndarray:
        """Full nodal displacement -> ``x`` (n,) with zero pressure."""
        return self.unknowns(super().restrict(full))

    def load_vector(self, **kwargs) -> np.ndarray:
        return self.unknowns(super().load_vector(**kwargs))

    def prolong(self, coarse: "TaylorHoodModel", x) -> np.ndarray:
        """`StateModel.prolong` of the displacement, and the vertex pressures interpolated (P1 on
        the coarse cells) at this mesh's vertices."""
        p1 = lambda mesh: VectorSpace(mesh, 1, components=1)
        return self.unknowns(super().prolong(coarse, x)[: self.n_u],
                             prolong(p1(coarse.mesh), p1(self.mesh), coarse.pressure(np.asarray(x))))

    #: quasi-static: no mass or damping blocks
    PER_CELL = ("_dN", "_w", "material_frames", "_cell_volume")

    def restricted(self, cells: np.ndarray, dofs: np.ndarray) -> "TaylorHoodModel":
        """`StateModel.restricted`; among ``dofs`` the displacements come first (serial order), then the
        pressures, so that `displacement_part` and `pressure` split the m local unknowns as they split n."""
        local = super().restricted(cells, dofs)
        displacements = dofs[dofs < self.n_u]
        local.n_u, local.n_p = displacements.size, dofs.size - displacements.size
        local._gather = jnp.asarray(relabel_index(np.asarray(self._gather)[cells], self.n_u, displacements))
        return local

    @property
    def mass_blocks(self):
        raise InputError("TaylorHoodModel is quasi-static (hyperoc.dynamics.statics.solve_static): it has no mass on p")

    # --- traced kernels -------------------------------------------------------------------------------
    def deformation_gradient(self, x):
        return super().deformation_gradient(self.displacement_part(x))

    def _element_energy(self, xe, dN, w, frames):
        """One cell's share of the Lagrangian ``L(u, p)``, ``sum_q w_q (W(F_q) + p_q (det F_q - 1) -
        p_q^2 / (2 bulk_modulus))``, xe (k,) = (u_e node-major, vertex pressures); its gradient in x, summed
        over the cells, is the residual (force, constraint) (`StateModel.internal_force`)."""
        ue, pe = self._split_element(xe)
        F = element_F(ue, dN)
        p = self._Np @ pe
        density = at_points(self._point_material.energy_of_F, F, frames) + p * (det(F) - 1.0) \
            - self._compliance(p)
        return jnp.sum(w * density)

    def _compliance(self, p):
        """``p^2 / (2 bulk_modulus)``, exactly 0 for an incompressible body."""
        return 0.0 if math.isinf(self.bulk_modulus) else p * p / (2.0 * self.bulk_modulus)

    def tangent_blocks(self, x, a, b):
        """Element Hessians of ``a L_e + b int_e det F`` in the element unknowns ``(u_e, p_e)``,
        (nc, k, k), k = 10 d + (d + 1) in 3D (6 d + 3 in 2D): displacement rows node-major, then
        the vertex pressures. Cells go ``tangent_chunk_points // nq`` at a time.

        ``[[K_uu, G], [G^T, -a M_p / bulk_modulus]]``: K_uu is `hyperoc.mechanics.kernels.element_tangent` of
        ``W_rest`` with the det F Hessian weighted by ``b + a p`` at each point; ``G_(ai),c = a sum_q w_q (cof F_q)_iJ
        dN_aJ N^p_c`` couples the pressures to dJ; ``M_p = sum_q w_q N^p N^p^T`` (0 when bulk_modulus = inf).
        """
        return self.map_cells(lambda xs: self._element_block(*self._split_element(xs[0]), *xs[1:], a, b),
                              self.element_args(x))

    def _split_element(self, xe):
        """One cell's unknowns xe (k,) -> ``(u_e (nloc, d), vertex pressures (d + 1,))``."""
        return xe[: -self.dim - 1].reshape(-1, self.dim), xe[-self.dim - 1:]

    def _element_block(self, ue, pe, dN, w, frames, a, b):
        """The (k, k) saddle-point block of one cell (`tangent_blocks`); ue (nloc, d), pe (d + 1,)."""
        Kuu = element_tangent(self._point_material, None, ue, dN, w, frames, a, b + a * (self._Np @ pe))
        F = element_F(ue, dN)
        dJ = jnp.einsum("qiJ,qaJ->qai", jax.vmap(jax.grad(det))(F), dN).reshape(len(w), -1)  # (nq, k_u)
        G = a * jnp.einsum("q,qk,qc->kc", w, dJ, self._Np)
        Mp = jnp.zeros((pe.size, pe.size)) if math.isinf(self.bulk_modulus) else \
            (a / self.bulk_modulus) * jnp.einsum("q,qc,qe->ce", w, self._Np, self._Np)
        return jnp.block([[Kuu, G], [G.T, -Mp]])

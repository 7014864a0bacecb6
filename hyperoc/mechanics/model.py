"""The discrete state system: spaces, operators and the JAX functions every solver shares.

Everything nonlinear derives from two scalar functionals of the reduced displacement vector u
(free dofs only, Dirichlet dofs are zero):

    Pi(u)  = int_Omega W(E(u)) dx        (strain energy)     -> R(u) = dPi/du  (P, grad phi)
    vol(u) = int_Omega det(I + grad u)   (deformed volume)   -> G(u) = dvol/du (cof F, grad phi)

so the hyperelastic force and the volume-constraint vector are gradients, and the step tangent is
the element Hessian of ``a W(F) + b det F`` at each quadrature point, all by JAX.

With ``volumetric="cell-mean"`` the law's bulk term ``U(J)`` is evaluated on the cell average of J
instead (``Pi = int W_rest dx + sum_e |e| U(theta_e)``, ``theta_e = |e|^-1 int_e J dx``): the
mixed displacement-pressure formulation with a pressure constant on each cell, condensed cell by
cell (see `StateModel`).

`StateModel` composes four modules: `hyperoc.mechanics.constraints` (the reduced dofs, the pins,
the volume constraint), `hyperoc.mechanics.kernels` (the element energy and tangent),
`hyperoc.mechanics.operators` (mass and damping operators, loads) and
`hyperoc.mechanics.diagnostics` (the monitors' min det F, max |grad u|, ellipticity).
"""

from __future__ import annotations

import copy
import inspect
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

from .._jax import on_device
from ..errors import InputError
from ..fem.assembly import SparsePattern, dump_index, relabel_index
from ..fem.mesh import Mesh
from ..fem.spaces import VectorSpace, prolong
from . import constraints, diagnostics, kernels, operators
from .kernels import VOLUMETRIC
from .materials import Material, det

__all__ = ["StateModel", "det", "VOLUMETRIC"]


class StateModel:
    """Damped hyperelastic body with a global volume constraint, discretized in space.

    Parameters
    ----------
    mesh : Mesh with boundaries ``dirichlet`` (u = 0) and optionally ``neumann`` (traction).
    material : strain energy W(E).
    degree : Lagrange degree (1 or 2).
    damping : viscous damping coefficient kappa (``kappa (grad u_t, grad phi)``), >= 0.
    density : mass density (the paper uses 1).
    control : a control operator (`BodyForce`, `ActiveStress`) or None.
    traction : traction g on the Neumann boundary, constant vector or callable ``(x, t)``, evaluated at
        t = 0 (pass time-dependent loads to the stepper as ``external``), or None.
    frames : optional callable ``x (nc, nq, dim) -> (nc, nq, k, dim)`` of material directions.
    dirichlet : boundary where every component of u is 0 (clamped), or None for none.
    dirichlet_components : ``{boundary: components}``, e.g. ``{"base": (2,)}``: only those components
        of u are 0 there, the others slide freely (a sliding base: u_z = 0 on the plane z = const).
        Combines with ``dirichlet``.
    pin_rigid : what to do with the rigid motions ``a + w x X`` that the constraints leave free
        (a sliding plane alone leaves the in-plane translations and the rotation about its normal).
        True (default): fix as many single dofs of the ``dirichlet_components`` boundaries as there
        are such motions, chosen by QR with column pivoting of the motions' values there (the
        best-conditioned choice; `pinned_dofs`). The support is then isostatic: it removes exactly
        the rigid motions and, for loads with no net force or moment along them, carries no
        reaction, so the deformation is the one of the free-sliding body. False: keep them
        (`rigid_modes`); the dynamics stays well posed through the mass matrix (the rigid motion
        is then driven by the net load), a static solve does not (its K is singular).
        Rigid motions left by ``dirichlet`` alone (e.g. a degenerate Gamma_D) are only reported.
    volumetric : how the material's bulk term ``U(J)`` (`Material.volumetric_split`: Guccione and
        Holzapfel-Ogden ``bulk_modulus/4 (J^2 - 1 - 2 ln J)``, neo-Hookean ``lambda/2 (ln J)^2``) enters.
        ``"pointwise"`` (default): ``U(J)`` at every quadrature point, the pure displacement
        formulation, which locks (is too stiff on coarse meshes) as the bulk modulus grows.
        ``"cell-mean"``: ``|e| U(theta_e)`` with ``theta_e`` the mean of J over the cell e. This is
        the mixed displacement-pressure formulation with a pressure ``p_e`` constant per cell
        (P2-P0, P1-P0) and the constraint ``theta_e - 1 = p_e / U''(1)`` in the weak sense, after
        eliminating ``p_e = U'(theta_e)`` cell by cell (mean dilatation: Nagtegaal, Parks & Rice
        1974; Simo, Taylor & Pister 1985); same unknowns and sparsity as "pointwise". It
        constrains one volume per cell instead of one per quadrature point. P2-P0 satisfies the
        inf-sup condition on triangles (P1-P0 does not, and locks); on tetrahedra we know no proof,
        but the Land beam does not lock (`tests/test_volumetric.py`). J is then free *inside* a
        cell, held only by the rest of the law: one that stays bounded as J -> 0 (Guccione on the
        full strain) lets a cell fold under its mean at large strain (Land problem 2: det F = 0 at
        3.6 kPa of 10); a rest that grows without bound as J -> 0 (`Guccione` ``isochoric=True``
        unless the point keeps its shape, neo-Hookean's ``-mu ln J``) resists it, and problem 2
        reaches 10 kPa. The pressure is one constant per cell, so on coarse meshes the solution
        can be far softer than the limit.

    Attributes
    ----------
    rigid_modes : (n, m) array
        Orthonormal reduced vectors of the rigid motions that the constraints (with pins) leave
        free; m = 0 normally.
    pinned_dofs : array of int
        Global dofs (``node * dim + component``) fixed by ``pin_rigid``.
    material_frames : (nc, nq, d, d) array or None
        The material frame at every quadrature point (rows: fibre, sheet, normal), from ``frames``;
        None without frames (isotropic laws).
    element_gather : (nc, k) int array
        Each cell's reduced dofs, constrained ones pointing at a dump slot n (`kernels.gather` reads 0 there).
    """

    def __init__(self, mesh: Mesh, material: Material, *, degree: int = 1, damping: float = 0.0, density: float = 1.0,
                 control=None, traction=None, dirichlet: str | None = "gamma_d", neumann: str = "gamma_n", frames=None,
                 dirichlet_components: dict | None = None, pin_rigid: bool = True, volumetric: str = "pointwise"):
        if damping < 0 or density <= 0:
            raise InputError(f"need damping >= 0 and density > 0, got damping = {damping}, density = {density}")
        self.mesh, self.material = mesh, material.validate()
        self.volumetric = volumetric
        self._point_material, self._bulk = kernels.split_law(self.material, volumetric)
        self.damping, self.density = float(damping), float(density)
        self.space = VectorSpace(mesh, degree)
        self.dim = mesh.dim
        self.free, self.to_reduced, self.pinned_dofs, self.rigid_modes = constraints.constrain(
            self.space, dirichlet, dirichlet_components or {}, pin_rigid)
        self.n = self.free.size
        self.quad = self.space.quadrature(0 if degree == 1 else 4)
        self.control = control.build(self.space, self.to_reduced) if control is not None else None
        self.neumann = neumann
        self.traction_load = self.load_vector(traction=traction) if traction is not None else np.zeros(self.n)
        self.material_frames = None if frames is None else on_device(frames(self.quad.x))
        self._dN = on_device(self.quad.dN)
        self._w = on_device(self.quad.wdx)
        self._cell_volume = jnp.sum(self._w, axis=1)  # (nc,)
        self._set_cell_dofs(self.to_reduced[self.space.cell_dofs])
        # the displacement's gather (`deformation_gradient`); a subclass appending unknowns to the
        # element (Taylor-Hood's pressures) resets `element_gather` only, so this one stays the displacement's
        self._gather = self.element_gather

    #: per-cell data (leading axis the cells) that `restricted` slices: attributes and cached properties
    PER_CELL = ("_dN", "_w", "material_frames", "_cell_volume", "mass_blocks", "laplace_blocks")
    #: the compiled kernels and solvers cached on the model (`release_kernels`)
    KERNEL_CACHES = ("jitted", "_ellipticity_fn", "_static_solves", "_static_solvers")

    def _set_cell_dofs(self, cell_dofs: np.ndarray) -> None:
        """Set ``cell_dofs`` (nc, k) (-1 = constrained) and ``element_gather``, the same with constrained
        entries pointing at a dump slot n (read as 0, `kernels.gather`). Set eagerly (an array created
        while a kernel is traced would become that trace's constant)."""
        self.cell_dofs = cell_dofs
        self.element_gather = on_device(dump_index(cell_dofs, self.n), dtype=None)

    # --- constant operators (`hyperoc.mechanics.operators`) ----------------------------------------
    @cached_property
    def mass_blocks(self) -> np.ndarray:
        """Element mass matrices (nc, k, k): ``density int N_a N_b delta_ij``."""
        return operators.mass_blocks(self.space, self.density)

    @cached_property
    def laplace_blocks(self) -> np.ndarray:
        """Element vector-Laplacian matrices (nc, k, k): ``int grad N_a . grad N_b delta_ij``."""
        return operators.laplace_blocks(self.space)

    @cached_property
    def mass(self):
        return self.pattern.matrix(self.mass_blocks)

    @cached_property
    def laplace(self):
        return self.pattern.matrix(self.laplace_blocks)

    @cached_property
    def mass_lu(self):
        """Sparse LU factorization of the mass matrix (consistent pressure, terminal projections)."""
        return spla.splu(self.mass.tocsc())

    def apply_mass_inverse(self, v):
        """``M^-1 v`` inside traced code (a host solve; linear, so its JVP is itself)."""
        return operators.apply_inverse(lambda x: self.mass_lu.solve(x), v)

    @cached_property
    def jax_operators(self):
        """(M, K, B) as JAX sparse matrices for traced matvecs (B is None without control)."""
        B = operators.to_bcoo(self.control.load) if self.control is not None else None
        return operators.to_bcoo(self.mass), operators.to_bcoo(self.laplace), B

    def load_vector(self, *, body_force=None, traction=None, t: float = 0.0, neumann: str | None = None) -> np.ndarray:
        """External load ``int_Omega f . phi + int_{Gamma_N} g . phi`` on the reduced dofs, (n,).

        ``body_force`` and ``traction`` are constant vectors (dim,) or callables ``(x, t) -> (..., dim)``
        with x of shape (..., dim); ``neumann`` names the boundary of g (default: the model's Gamma_N).
        """
        return operators.load_vector(self.space, self.free, body_force=body_force, traction=traction, t=t,
                                     neumann=neumann or self.neumann)

    def control_values(self, fn, t) -> np.ndarray:
        """Nodal control values (len(t), n_ctrl) of a callable ``xi(x, t)``, x of shape (n_nodes, dim),
        returning (n_nodes,) or (n_nodes, components) (a prescribed control as a Python function)."""
        return operators.control_values(self.control, self.space, fn, t)

    @cached_property
    def pattern(self) -> SparsePattern:
        """CSR pattern of the matrices assembled from element blocks on ``cell_dofs`` (n, n); built on
        first use, after a subclass has extended ``cell_dofs`` (`hyperoc.mechanics.mixed.TaylorHoodModel`), so
        only the pattern in use is built (at 145k Taylor-Hood cells one build sorts 1.7e8 keys)."""
        return SparsePattern(self.cell_dofs, self.n)

    # --- fields (`hyperoc.mechanics.constraints`) --------------------------------------------------
    def expand(self, u) -> np.ndarray:
        """Reduced vector(s) (..., n) -> full nodal displacement (..., num_nodes, dim)."""
        return constraints.expand(self.space, self.free, u)

    def restrict(self, full) -> np.ndarray:
        """Full nodal field (num_nodes, dim) or flat (num_dofs,) -> reduced vector (n,)."""
        return constraints.restrict(self.free, full)

    def prolong(self, coarse: "StateModel", u) -> np.ndarray:
        """This model's reduced vector (n,) of the state ``u`` (coarse.n,) of ``coarse``, the same
        problem on a mesh this one uniformly refines (`hyperoc.fem.spaces.prolong`: the displacement
        at each node is the coarse one at that material point; Dirichlet values are dropped), moved
        by the rigid motion that puts it back on this model's pins (`repin`). A starting point for
        Newton on this mesh (`solve_static`'s ``guess``)."""
        return self.restrict(self.repin(prolong(coarse.space, self.space, coarse.expand(u).reshape(-1))))

    def repin(self, full) -> np.ndarray:
        """``full + r`` (num_dofs,) for a full displacement ``full`` (num_dofs,), r the rigid motion
        that makes it vanish on the `pinned_dofs` (`hyperoc.mechanics.constraints.repin`)."""
        return constraints.repin(self.space, self.free, self.pinned_dofs, full)

    def interpolate(self, fn) -> np.ndarray:
        """Reduced nodal interpolant of ``fn(x: (n, dim)) -> (n, dim)``; Dirichlet values are dropped."""
        return self.restrict(self.space.interpolate(fn))

    # --- traced kernels (`hyperoc.mechanics.kernels`) ----------------------------------------------
    def deformation_gradient(self, u):
        """F = I + grad u at every quadrature point, (nc, nq, d, d)."""
        ue = kernels.gather(u, self._gather)
        return kernels.deformation_gradient(ue.reshape(ue.shape[0], -1, self.dim), self._dN)

    def pointwise(self, fn, F):
        """``fn(F, frame)`` at every quadrature point, F (nc, nq, d, d), frame the point's `material_frames`
        row (None without frames); e.g. the first Piola stress of the law at the model's frames."""
        return kernels.pointwise(fn, F, self.material_frames)

    def strain_energy(self, u):
        """Pi(u) = int W(E) dx, or with ``volumetric="cell-mean"`` int W_rest(E) dx + sum_e |e| U(theta_e),
        theta_e = |e|^-1 int_e det F dx (scalar): the sum of `_element_energy` over the cells."""
        return jnp.sum(self.map_cells(lambda xs: self._element_energy(*xs), self.element_args(u)))

    def internal_force(self, u):
        """R(u) = (P(F), grad phi) = dPi/du, (n,): each cell's gradient of `_element_energy` in its own
        unknowns, summed into the dofs. Cells go `map_cells` chunks at a time, so the intermediates
        reverse mode keeps are one chunk's, not the mesh's (3.6 GB at 145k Taylor-Hood cells)."""
        forces = self.map_cells(lambda xs: jax.grad(self._element_energy)(*xs), self.element_args(u))
        return kernels.scatter(forces, self.element_gather, self.n)

    def element_args(self, x):
        """``(x_e (nc, k), dN (nc, nq, nloc, d), w (nc, nq), frames)``: each cell's unknowns of x (n,), 0 on
        constrained dofs, its shape gradients, quadrature weights times |det J| and `material_frames`; the
        per-cell arguments of `_element_energy` and of element terms (`map_cells`)."""
        return kernels.gather(x, self.element_gather), self._dN, self._w, self.material_frames

    def _element_energy(self, ue, dN, w, frames):
        """One cell's `kernels.element_energy` (scalar) of its unknowns ue (k,), node-major; a model
        with other element unknowns overrides it (`hyperoc.mechanics.mixed`)."""
        return kernels.element_energy(self._point_material, self._bulk, ue.reshape(-1, self.dim), dN, w, frames)

    def volume(self, u):
        """vol(u) = int det(I + grad u) dx (scalar)."""
        return constraints.volume(self.deformation_gradient(u), self._w)

    def volume_gradient(self, u):
        """G(u) = (cof F, grad phi), (n,)."""
        return jax.grad(self.volume)(u)

    #: `tangent_blocks` works on at most this many quadrature points at a time (bounds its memory).
    tangent_chunk_points = 1 << 16

    def tangent_blocks(self, u, a, b):
        """Element Hessians of ``int (a W(F) + b det F)``, (nc, k, k), k = nloc * dim, rows and
        columns node-major (``a * dim + i``); the same values as ``jax.hessian`` of the element
        energy, to round-off. With a = 1, b = p this is the element form of ``K_T(u) + p H(u)``.

        Cells are processed ``tangent_chunk_points // nq`` at a time (`kernels.element_tangent` on each).
        """
        return self.map_cells(lambda xs: kernels.element_tangent(self._point_material, self._bulk,
                                                                  xs[0].reshape(-1, self.dim), *xs[1:], a, b),
                              self.element_args(u))

    def map_cells(self, kernel, xs):
        """``kernel`` on each cell's slice of the per-cell arrays ``xs`` (leading axis the cells), stacked:
        `kernels.map_cells`, ``tangent_chunk_points // nq`` cells at a time (bounds the intermediates' memory)."""
        return kernels.map_cells(kernel, xs, max(1, self.tangent_chunk_points // self._w.shape[1]))

    def _voigt_derivatives(self, e, frame):
        """`kernels.voigt_derivatives` of the law at the points: ``(d2W/de2 (nv, nv), dW/de (nv,))``."""
        return kernels.voigt_derivatives(self._point_material, self.dim, e, frame)

    # --- diagnostics (`hyperoc.mechanics.diagnostics`) ---------------------------------------------
    def min_det_F(self, u):
        """min det F over the quadrature points (scalar)."""
        return diagnostics.min_det_F(self.deformation_gradient(u))

    def max_grad(self, u):
        """max |grad u| (Frobenius) over quadrature points."""
        return diagnostics.max_grad(self.deformation_gradient(u))

    def cell_mean_J(self, u):
        """theta_e = |e|^-1 int_e det F dx per cell, (nc,): the dilatation "cell-mean" constrains."""
        return diagnostics.cell_mean(det(self.deformation_gradient(u)), self._w, self._cell_volume)

    @cached_property
    def _ellipticity_fn(self):
        # one compiled loop over the states, each over its cells in `map_cells` chunks: the acoustic tensors of
        # one chunk in memory at a time (a whole P2 ventricle's take gigabytes)
        def cell(xs):
            F, frames = xs
            return diagnostics.min_acoustic_eigenvalue(self.material, F[None],
                                                       None if frames is None else frames[None])

        return jax.jit(lambda U: jax.lax.map(lambda u: jnp.min(self.map_cells(
            cell, (self.deformation_gradient(u), self.material_frames))), U))

    def min_acoustic_eigenvalues(self, U) -> np.ndarray:
        """`hyperoc.mechanics.diagnostics.min_acoustic_eigenvalue` of the full law, for each state of
        ``U`` (levels, n): (levels,). Negative: loss of strong ellipticity."""
        return np.asarray(self._ellipticity_fn(on_device(U)))

    # --- compiled kernels cached on the model --------------------------------------------------------
    @cached_property
    def jitted(self):
        """Jitted host-callable versions of the scalar functionals and their gradients."""
        return {
            "volume": jax.jit(self.volume),
            "strain_energy": jax.jit(self.strain_energy),
            "internal_force": jax.jit(self.internal_force),
            "volume_gradient": jax.jit(self.volume_gradient),
            "min_det_F": jax.jit(self.min_det_F),
            "max_grad": jax.jit(self.max_grad),
        }

    def release_kernels(self):
        """Drop the compiled kernels cached on this model: `jitted`, the acoustic-tensor kernel and the
        static Newton solves (`hyperoc.dynamics.statics`) with their linear solver, which holds its last
        factorization. They are rebuilt on next use. For a model kept only for its mesh and state,
        e.g. the coarse level of a nested solve, whose factorization would otherwise sit beside the
        fine level's."""
        for name in self.KERNEL_CACHES:
            self.__dict__.pop(name, None)

    def restricted(self, cells: np.ndarray, dofs: np.ndarray) -> "StateModel":
        """This model on ``cells`` only, its unknowns the serial ``dofs`` (m,), increasing (the unknowns of
        those cells, `hyperoc.distributed.partition.local_dofs`): a shallow copy whose `PER_CELL` data keep
        the rows of ``cells`` and whose gathers index the m unknowns. Its kernels (`internal_force`,
        `tangent_blocks`, `volume`, ...) are this model's, on those cells: forces (m,), element blocks
        (len(cells), k, k). Every other cached property and the `KERNEL_CACHES` (the sparsity pattern, the
        assembled operators, compiled kernels) are left out, to be rebuilt from the restricted data on
        first use. It carries no control and no traction: assembled loads belong to the serial unknowns
        (a distributed solve applies them on the rows each rank owns)."""
        cached = {name for name in dir(type(self))
                  if isinstance(inspect.getattr_static(type(self), name), cached_property)}
        local = copy.copy(self)
        local.__dict__ = {k: v for k, v in self.__dict__.items() if k not in cached and k not in self.KERNEL_CACHES}
        for name in self.PER_CELL:
            if name in cached:  # computed for the whole mesh only if not yet, and then not kept on this model
                value = self.__dict__[name] if name in self.__dict__ else getattr(type(self), name).func(self)
            else:
                value = getattr(self, name)
            local.__dict__[name] = None if value is None else value[cells]
        local._gather = jnp.asarray(relabel_index(np.asarray(self._gather)[cells], self.n, dofs))
        local.n, local.control, local.traction_load = dofs.size, None, np.zeros(dofs.size)
        local._set_cell_dofs(np.where(self.cell_dofs[cells] >= 0, np.searchsorted(dofs, self.cell_dofs[cells]), -1))
        return local

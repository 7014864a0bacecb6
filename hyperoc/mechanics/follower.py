"""Follower pressure: a pressure acting on the deformed configuration of a tagged boundary.

A pressure ``p_ext`` on the boundary part ``Gamma`` pushes against the *current* outward normal
``n`` with the *current* area ``da``. With ``x = X + u`` the deformed position, its virtual work is
``-p_ext int_Gamma(x) n . phi da``, and on each reference facet, parametrized by the reference simplex
coordinates ``xi`` (``d - 1`` of them), ``n da = a(x) dxi`` with the area vector

    a = dx/dxi1 x dx/dxi2      (3D: cross product of the two facet tangents)
    a = (dx/dxi2, -dx/dxi1)    (2D: the tangent dx/dxi turned clockwise)

(no inverse, no cofactor). Facets are ordered so that ``a`` points out of the body. With the facet
interpolation ``x(xi) = sum_a N_a(xi) x_a`` (the P1 / P2 trace of the displacement space on the
affine reference facet) the nodal force is

    f_a = -p_ext int_{ref facet} N_a(xi) a(xi) dxi        (vector, one per facet node),

summed over the facets of ``Gamma``. The integrand is a polynomial (degree
``k + (d - 1)(k - 1)`` for Lagrange degree k), integrated exactly. Units: lengths in the model's
unit (mm), ``p_ext`` in its stress unit (kPa), forces in stress x area (kPa mm^2 = mN), the same
units as the internal force ``R(u)`` of `hyperoc.mechanics.model.StateModel`.

The load depends on u, so Newton needs its derivative ``K_p = -df/du`` (the load stiffness),
computed here per facet by ``jax.jacfwd`` ((m d) x (m d) blocks, m nodes per facet) and added into
the element blocks of the cell that owns the facet, so it fits the model's sparsity pattern
(`hyperoc.fem.assembly.SparsePattern`) and every bordered solver of `hyperoc.solvers.linsolve` unchanged.
``K_p`` is not symmetric in general (symmetric when ``Gamma`` is closed or its rim is fixed).

Conservative case. For a closed ``Gamma`` the enclosed volume ``V(x) = (1/d) int_Gamma x . n da``
(exact for the discrete surface too: ``V = (1/d) sum_facets int x . a dxi``) has gradient
``dV/dx_a = int N_a a dxi``, so ``f = -p_ext grad V``: a potential load, ``K_p = p_ext Hess V``
symmetric, and at any state ``sum_a f_a = -p_ext int n da = 0`` (no net force from a uniform
pressure on a closed surface).
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from ..errors import InputError
from ..fem.assembly import dump_index, relabel_index
from ..fem.quadrature import simplex_rule
from ..fem.spaces import reference_shape
from .kernels import gather, scatter

__all__ = ["BoundaryFacets", "FollowerPressure"]


def area_vector(T):
    """Area vector ``a`` (dim,) of the facet tangents ``T`` (dim, dim - 1): ``n da = a dxi``."""
    if T.shape[0] == 3:
        return jnp.cross(T[:, 0], T[:, 1])
    return jnp.stack([T[1, 0], -T[0, 0]])


def _outward_facets(mesh, facets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Facets (nf, dim) reordered so that their area vector points out of the body, and their owner cells (nf,)."""
    dim, nv = mesh.dim, mesh.points.shape[0]
    if dim not in (2, 3):
        raise InputError(f"follower pressure needs a 2D or 3D mesh, got dim = {dim}")
    facets = np.array(facets, dtype=np.int64).reshape(-1, dim)
    key = lambda f: np.sort(f, axis=1) @ (nv ** np.arange(dim - 1, -1, -1))
    cell_faces = np.concatenate([np.delete(mesh.cells, k, axis=1) for k in range(dim + 1)])
    opposite = np.concatenate([mesh.cells[:, k] for k in range(dim + 1)])
    owner_of_face = np.tile(np.arange(mesh.num_cells), dim + 1)
    order = np.argsort(key(cell_faces), kind="stable")
    sorted_keys = key(cell_faces)[order]
    pos = np.searchsorted(sorted_keys, key(facets))
    pos = np.minimum(pos, sorted_keys.size - 1)
    if facets.size and not np.all(sorted_keys[pos] == key(facets)):
        raise InputError("follower pressure: some facets are not faces of the mesh")
    if facets.size and not np.all(np.searchsorted(sorted_keys, key(facets), side="right") - pos == 1):
        raise InputError("follower pressure: some facets are interior (shared by two cells), not boundary facets")
    owner, opp = owner_of_face[order[pos]], opposite[order[pos]]
    X = mesh.points[facets]
    a = np.asarray(jax.vmap(area_vector)(jnp.asarray(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2))))
    inward = np.einsum("fi,fi->f", a, mesh.points[opp] - X[:, 0]) > 0
    facets[inward, 0], facets[inward, 1] = facets[inward, 1].copy(), facets[inward, 0].copy()
    return facets, owner


class BoundaryFacets:
    """The facets of the boundary part ``boundary`` of ``model``'s mesh, oriented outward, with what a
    boundary term integrates on them: their reduced dofs, reference node positions, owner cells and
    the positions of their dofs in the owner's element block, and a facet quadrature rule of degree
    ``degree`` (default ``k + (d - 1)(k - 1)``, exact for the follower force; k the Lagrange degree).

    Attributes: ``num_facets``; ``_gather`` (nf, m d) reduced dofs (n = dump slot); ``_X`` (nf, m, d)
    reference nodes; ``_owner`` (nf,), ``_local`` (nf, m d); ``_w`` (nq,), ``_N`` (nq, m), ``_dN``
    (nq, m, d - 1) on the reference facet.
    """

    def __init__(self, model, boundary: str, degree: int | None = None):
        space, dim = model.space, model.dim
        facets, owner = _outward_facets(model.mesh, model.mesh.boundary(boundary))
        nodes = space.facet_nodes(facets)  # (nf, m)
        nf, m = nodes.shape
        self.boundary, self.n, self.dim = boundary, model.n, dim
        self.num_facets = nf
        red = model.to_reduced[space.node_dofs(nodes.ravel()).reshape(nf, m * dim)]
        self._gather = jnp.asarray(dump_index(red, model.n))  # (nf, m d)
        self._X = jnp.asarray(space.nodes[nodes])  # (nf, m, dim)
        # Local positions of the facet dofs inside the owner cell's element block.
        loc = np.argmax(space.cell_nodes[owner][:, None, :] == nodes[:, :, None], axis=2)  # (nf, m)
        self._owner = jnp.asarray(owner)
        self._local = jnp.asarray((loc[:, :, None] * dim + np.arange(dim)).reshape(nf, m * dim))
        k = space.degree
        xi, w = simplex_rule(dim - 1, k + (dim - 1) * (k - 1) if degree is None else degree)
        N, dN = reference_shape(dim - 1, k, xi)
        self._w, self._N, self._dN = jnp.asarray(w), jnp.asarray(N), jnp.asarray(dN)  # (nq,), (nq, m), (nq, m, d-1)

    def restricted(self, model, local, cells: np.ndarray, dofs: np.ndarray):
        """This term on the facets whose owner cell is among ``cells`` of the serial ``model`` (the one
        it was built on), its unknowns the serial ``dofs`` (m,), increasing: the term of
        ``local = model.restricted(cells, dofs)``, forces (m,), stiffness added to its element blocks
        (the interface of a load a distributed solve restricts, `hyperoc.distributed.statics`)."""
        local = copy.copy(self)
        position = np.full(model.mesh.num_cells, -1, dtype=np.int64)
        position[cells] = np.arange(cells.size)
        owner = position[np.asarray(self._owner)]
        mine = np.flatnonzero(owner >= 0)
        local._owner, local._local, local._X = jnp.asarray(owner[mine]), self._local[mine], self._X[mine]
        local._gather = jnp.asarray(relabel_index(np.asarray(self._gather)[mine], model.n, dofs))
        local.num_facets, local.n = mine.size, dofs.size
        local._restricted(mine)
        return local

    def _restricted(self, mine: np.ndarray) -> None:
        """Restrict further per-facet data of a subclass to the facets ``mine`` (called by `restricted`)."""

    def add_facet_blocks(self, cell_blocks, facet_blocks):
        """``cell_blocks`` (nc, k, k) plus ``facet_blocks`` (nf, m d, m d), each scattered into its facet's
        owner cell (so the sum fits the model's sparsity pattern)."""
        c = self._owner[:, None, None]
        return cell_blocks.at[c, self._local[:, :, None], self._local[:, None, :]].add(facet_blocks)


class FollowerPressure(BoundaryFacets):
    """Pressure ``pressure`` (kPa) on the deformed boundary part ``boundary`` of ``model``'s mesh.

    Methods take the reduced displacement u (n,) and a load ``factor`` (the load step ``s``: the
    pressure applied is ``factor * pressure``).

    Parameters
    ----------
    model : `hyperoc.mechanics.model.StateModel` (2D or 3D, P1 or P2); its reduced dof numbering is used.
    boundary : name of a facet set of the mesh (``mesh.boundary(name)``), e.g. ``"endocardium"``.
    pressure : ``p_ext``, positive pushes into the body (against the outward normal), stress units.
    """

    def __init__(self, model, boundary: str, pressure: float):
        if not np.isfinite(pressure):
            raise InputError(f"follower pressure must be finite, got {pressure}")
        super().__init__(model, boundary)
        self.pressure = float(pressure)

    # --- per facet ------------------------------------------------------------------------------
    def _area_vectors(self, x):
        """Area vectors at the quadrature points of one facet with nodal positions x (m, dim) -> (nq, dim)."""
        T = jnp.einsum("qaj,ai->qij", self._dN, x)
        return jax.vmap(area_vector)(T)

    def _facet_force(self, x):
        """``int N_a a dxi`` (m dim,) for unit pressure on one facet with nodal positions x (m, dim)."""
        return -jnp.einsum("q,qa,qi->ai", self._w, self._N, self._area_vectors(x)).reshape(-1)

    def _positions(self, u):
        """Deformed facet nodes ``x = X + u`` (nf, m, dim) from the reduced displacement u (n,)."""
        ue = gather(u, self._gather)
        return self._X + ue.reshape(self._X.shape)

    # --- assembled ------------------------------------------------------------------------------
    def facet_forces(self, u, factor=1.0):
        """Force of each facet on each of its nodes, (nf, m dim) node-major, Dirichlet nodes included
        (their sum over facets and nodes is the resultant of the pressure on ``boundary``)."""
        return factor * self.pressure * jax.vmap(self._facet_force)(self._positions(u))

    def force(self, u, factor=1.0):
        """Nodal force ``f(u)`` (n,) on the reduced dofs of ``factor * pressure`` on the deformed boundary."""
        return scatter(self.facet_forces(u, factor), self._gather, self.n)

    def facet_stiffness(self, u, factor=1.0):
        """Load stiffness ``K_p = -df/dx`` per facet, (nf, m dim, m dim), node-major facet dofs."""
        nf, m, d = self._X.shape
        J = jax.vmap(jax.jacfwd(self._facet_force))(self._positions(u))  # (nf, m d, m, d)
        return -factor * self.pressure * J.reshape(nf, m * d, m * d)

    def add_stiffness(self, cell_blocks, u, factor=1.0):
        """``cell_blocks`` (nc, k, k) plus the load stiffness, scattered into each facet's owner cell."""
        return self.add_facet_blocks(cell_blocks, self.facet_stiffness(u, factor))

    def enclosed_volume(self, u):
        """``(1/d) sum_facets int x . a dxi`` (scalar, length^d): the volume enclosed by the deformed
        facets when they form a closed surface (outward orientation)."""
        x = self._positions(u)
        xq = jnp.einsum("qa,fai->fqi", self._N, x)
        a = jax.vmap(self._area_vectors)(x)
        return jnp.einsum("q,fqi,fqi->", self._w, xq, a) / self.dim

"""The volume of a cavity bounded by a wall of the body: the left ventricle's blood volume.

The endocardium ``Gamma`` is a boundary part of the body; with the base open it is closed by a cone
from a fixed apex point ``c`` (by default the centroid of its rim in the reference configuration) to
its deformed rim. The volume enclosed by the deformed wall and that cone is, by the divergence theorem
with ``div (x - c) = 3``,

    V(u) = (1/3) int_{Gamma(x)} (x - c) . n_cav da  =  -(1/3) sum_facets int (x - c) . a(x) dxi,

where ``x = X + u`` on the facet and ``a`` is the area vector of the facet parametrization
(`hyperoc.mechanics.follower`: ``n da = a dxi``, pointing out of the body, i.e. into the cavity, hence
the sign; on the cone ``x - c`` is tangent, so the cone adds nothing). The integrand is a polynomial of
the facet coordinates (degree ``k + 1 + (d - 1)(k - 1)`` for Lagrange degree k) and is integrated
exactly, so V is the exact volume of the discrete P1 or P2 (curved) surface. In 2D the same formula
with 1/2 gives the area of the cavity's section.

A closed ``Gamma`` (no rim) encloses a volume that does not depend on c. With a rim, the cone from c
is the lid. Two apexes: a fixed point (by default the reference rim's centroid), and ``apex="rim"``, the
deformed rim's centroid, which moves with the rim. With a fixed apex the cone is the flat lid while the
deformed rim stays in a plane through c (a base sliding in its plane, or clamped); a rim that leaves that
plane adds the volume between the flat lid and the cone (first order in the rim's out-of-plane motion).
With ``apex="rim"`` the volume does not change under rigid motions of the whole, and the cone is the flat
lid whenever the rim stays planar: the volume the benchmark codes and a clinician report.

With a fixed apex V is a sum over facets of the facet's nodal positions, so its gradient (the load of a
cavity pressure, ``P dV/du``: the follower pressure on ``Gamma`` plus the cone's reaction on the rim) and its
Hessian (that load's stiffness) are facet-local and fit the element blocks of the facets' owner cells.
With the moving apex ``c(u)``, the rim's mean position, write ``V(u) = F(x, c(u))`` with F the fixed-apex sum.
F is linear in c with ``dF/dc = A(u) / d``, ``A = sum_facets int a dxi`` (the wall's area vector), so

    dV/du = F_x(x, c) + (dc/du)^T A / d,
    d2V/du2 = F_xx(x, c) + (1/d) [(dA/du)^T (dc/du) + (dc/du)^T (dA/du)],

the first part facet-local (the fixed-apex Hessian at the current apex), the second a dense symmetric term
of rank 2d, coupling every rim dof to every wall dof: ``U W U^T`` with ``U = [(dc/du)^T, (dA/du)^T]`` (n, 2d)
and ``W = (1/d) [[0, I], [I, 0]]`` (`low_rank`), which the bordered solvers take beside the element blocks
(`hyperoc.solvers.linsolve`, by the Woodbury identity on the one factorization).
"""

from __future__ import annotations

import copy
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import InputError
from ..fem.assembly import dump_index
from .follower import FollowerPressure
from .kernels import gather, scatter


def _point(apex, dim: int) -> np.ndarray:
    c = np.asarray(apex, dtype=np.float64)
    if c.shape != (dim,) or not np.all(np.isfinite(c)):
        raise InputError(f"cavity apex must be {dim} finite numbers or 'rim', got {apex!r}")
    return c

__all__ = ["CavityVolume", "rim_nodes"]


def _mean_jacobian(index: np.ndarray, n: int):
    """``dc/du`` (dim, n) of the mean ``c`` of the nodes whose reduced dofs are ``index`` (m, dim) (dump slot n for
    a held dof): a constant, since c is linear in u."""
    m, dim = index.shape
    J = np.zeros((dim, n + 1))
    np.add.at(J, (np.broadcast_to(np.arange(dim), index.shape), index), 1.0 / m)
    return jnp.asarray(J[:, :n])


def rim_nodes(space, facets: np.ndarray) -> np.ndarray:
    """The nodes on the rim of the boundary part ``facets`` (nf, dim) of ``space``'s mesh: the vertices
    (and, P2, the edge nodes) of the facet edges (3D) or facet vertices (2D) that belong to a single
    facet of the part. Empty for a closed surface."""
    facets = np.asarray(facets, dtype=np.int64)
    k = facets.shape[1]
    if k == 2:  # 2D: a facet is an edge, its "edges" are its two vertices
        ends, counts = np.unique(facets.ravel(), return_counts=True)
        return ends[counts == 1]
    pairs = np.sort(np.concatenate([facets[:, [i, j]] for i in range(k) for j in range(i + 1, k)]), axis=1)
    unique, counts = np.unique(pairs, axis=0, return_counts=True)
    rim = unique[counts == 1]
    if rim.size == 0:
        return np.zeros(0, dtype=np.int64)
    nodes = [rim.ravel()]
    if space.degree == 2:
        nodes.append(space.edge_nodes(rim[:, None, :]).ravel())
    return np.unique(np.concatenate(nodes))


class CavityVolume:
    """Volume (area in 2D) ``V(u)`` of the cavity bounded by ``boundary`` of ``model``'s mesh (module
    docstring), in the model's length unit cubed (squared in 2D).

    Parameters
    ----------
    model : `hyperoc.mechanics.model.StateModel` (2D or 3D, P1 or P2); its reduced dofs are used.
    boundary : the cavity wall, e.g. ``"endocardium"``.
    apex : the cone's apex c (dim,); default the centroid of the rim's reference nodes (of all the
        wall's nodes when the wall is closed); ``"rim"``: the deformed rim's centroid (its Hessian has the
        dense part `low_rank` beside the facet blocks; `restricted` refuses it).
    """

    def __init__(self, model, boundary: str = "endocardium", apex=None):
        self.surface = FollowerPressure(model, boundary, 1.0)
        self.boundary, self.dim, self.n = boundary, model.dim, model.n
        facets = model.mesh.boundary(boundary)
        self.rim = rim_nodes(model.space, facets)
        around = self.rim if self.rim.size else np.unique(model.space.facet_nodes(facets))
        self.moving = isinstance(apex, str) and apex == "rim"
        index = dump_index(model.to_reduced[model.space.node_dofs(around)], model.n)
        self._around = jnp.asarray(index)
        self._around_X = jnp.asarray(model.space.nodes[around])
        # dc/du of the moving apex (dim, n): constant, built once rather than differentiated at every Jacobian
        self._apex_jacobian = _mean_jacobian(index.reshape(len(around), self.dim), model.n) if self.moving else None
        c = np.mean(model.space.nodes[around], axis=0) if apex is None or self.moving else _point(apex, self.dim)
        self.apex = c
        if self.volume(np.zeros(model.n)) <= 0:
            raise InputError(f"the cavity bounded by {boundary!r} has no positive volume: is it the inner wall of "
                             "the body, closed or open on a single rim?")

    def apex_at(self, u):
        """The apex c (dim,) for the reduced displacement u (n,): fixed, or the deformed rim's centroid."""
        if not self.moving:
            return jnp.asarray(self.apex)
        return jnp.mean(self._around_X + gather(u, self._around).reshape(self._around_X.shape), axis=0)

    def facet_volumes(self, u):
        """Each facet's ``-(1/d) int (x - c) . a dxi`` (nf,), their sum the volume."""
        s = self.surface
        x = s._positions(u)
        xq = jnp.einsum("qa,fai->fqi", s._N, x) - self.apex_at(u)
        a = jax.vmap(s._area_vectors)(x)
        return -jnp.einsum("q,fqi,fqi->f", s._w, xq, a) / self.dim

    def volume(self, u):
        """V(u) (scalar) of the reduced displacement u (n,)."""
        return jnp.sum(self.facet_volumes(u))

    def volumes(self, U) -> np.ndarray:
        """V at each state of ``U`` (L, n): (L,)."""
        return np.asarray(self._volumes(jnp.asarray(U)))

    @cached_property
    def _volumes(self):
        return jax.jit(jax.vmap(self.volume))

    def restricted(self, model, local, cells: np.ndarray, dofs: np.ndarray) -> "CavityVolume":
        """The part of V from the facets whose owner cell is among ``cells`` of the serial ``model``, on the
        unknowns ``dofs`` (m,) of ``local = model.restricted(cells, dofs)`` (`FollowerPressure.restricted`):
        its `volume`, `gradient` (m,) and `add_hessian` (into ``local``'s element blocks) summed over a
        partition of the cells are the serial ones. The apex stays the serial one (the lid is not a sum
        over facets: every part uses the same fixed point); `InputError` for the moving apex."""
        self._fixed_apex()
        out = copy.copy(self)
        out.__dict__.pop("_volumes", None)  # compiled for the serial unknowns
        out.surface = self.surface.restricted(model, local, cells, dofs)
        out.n = local.n
        return out

    def _fixed_apex(self) -> None:
        if self.moving:
            raise InputError("the cavity volume with apex='rim' is not a sum over the ranks' facets (its lid moves "
                             "with the whole rim): use a fixed apex on the distributed path")

    def _facet_volume(self, x, c):
        """One facet's volume term of its nodal positions x (m, dim) with the apex c (dim,)."""
        s = self.surface
        return -jnp.einsum("q,qi,qi->", s._w, s._N @ x - c, s._area_vectors(x)) / self.dim

    def area_vector(self, u):
        """``A(u) = sum_facets int a dxi`` (dim,): the wall's area vector, pointing into the cavity (length^(d-1))."""
        s = self.surface
        a = jax.vmap(s._area_vectors)(s._positions(u))
        return jnp.einsum("q,fqi->i", s._w, a)

    def gradient(self, u):
        """dV/du (n,): facet by facet, summed into the reduced dofs (Dirichlet dofs dropped), plus with the
        moving apex its part ``(dc/du)^T A / d`` (module docstring)."""
        s = self.surface
        c = self.apex_at(u)
        g = jax.vmap(jax.grad(self._facet_volume), in_axes=(0, None))(s._positions(u), c)
        g = scatter(g.reshape(g.shape[0], -1), s._gather, self.n)
        if not self.moving:
            return g
        return g + self._apex_jacobian.T @ (self.area_vector(u) / self.dim)

    def facet_hessians(self, u, factor=1.0):
        """``factor d2F/dx2`` per facet at the apex of u, (nf, m dim, m dim), node-major facet dofs: with a fixed
        apex the whole ``factor d2V/du2`` (the stiffness of a cavity pressure ``factor`` is
        ``-factor d2V/du2``), with the moving one its facet-local part (`low_rank` the rest)."""
        s = self.surface
        x = s._positions(u)
        nf, m, d = x.shape
        H = jax.vmap(jax.hessian(self._facet_volume), in_axes=(0, None))(x, self.apex_at(u))
        return factor * H.reshape(nf, m * d, m * d)

    def low_rank(self, u, factor=1.0):
        """``(U, W)``, ``U`` (n, 2 dim), ``W`` (2 dim, 2 dim): the dense part ``U W U^T`` of ``factor d2V/du2``
        with the moving apex (module docstring); None with a fixed apex."""
        if not self.moving:
            return None
        dA = jax.jacrev(self.area_vector)(u)  # (dim, n)
        eye = jnp.eye(self.dim)
        zero = jnp.zeros_like(eye)
        W = factor / self.dim * jnp.block([[zero, eye], [eye, zero]])
        return jnp.concatenate([self._apex_jacobian, dA]).T, W

    def add_hessian(self, cell_blocks, u, factor=1.0):
        """``cell_blocks`` (nc, k, k) plus ``factor d2V/du2``, scattered into each facet's owner cell."""
        s = self.surface
        c = s._owner[:, None, None]
        return cell_blocks.at[c, s._local[:, :, None], s._local[:, None, :]].add(self.facet_hessians(u, factor))

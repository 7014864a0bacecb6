"""Constraints on the displacement: which dofs are unknowns, and the global volume constraint.

The unknown of the state model is the reduced vector u (n,): the values of the free dofs of a
vector Lagrange space, in increasing global order (global dof ``node * dim + component``). A dof is
constrained (u = 0 there) when it lies on the clamped boundary, is a fixed component on a sliding
boundary, or is one of the pins that remove the rigid motions a sliding boundary leaves free.

The volume constraint ``vol(u) = int_Omega det(I + grad u) dx = V(t)`` couples all dofs; its
multiplier is the pressure of the state equation.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import scipy.linalg

from .. import _jax  # noqa: F401
from ..errors import InputError
from ..fem.assembly import reduced_numbering
from ..fem.spaces import VectorSpace
from .materials import det

__all__ = ["Constraints", "constrain", "dirichlet_dofs", "expand", "free_motions", "isostatic_pins", "repin",
           "restrict", "rigid_motions", "volume"]


class Constraints(NamedTuple):
    """The reduced numbering of a space's dofs under its boundary conditions (`constrain`)."""

    #: (n,) the global dofs that are unknowns, increasing.
    free: np.ndarray
    #: (num_dofs,) the reduced index of each global dof, -1 where constrained.
    to_reduced: np.ndarray
    #: the global dofs fixed to remove rigid motions (`isostatic_pins`), increasing.
    pinned_dofs: np.ndarray
    #: (n, m) orthonormal reduced vectors of the rigid motions the constraints leave free.
    rigid_modes: np.ndarray


def constrain(space: VectorSpace, dirichlet: str | None, components: dict, pin_rigid: bool) -> Constraints:
    """The reduced numbering of ``space`` with every component 0 on the boundary ``dirichlet`` (or
    None), the ``components`` ``{boundary: (i, ...)}`` 0 on theirs, and, with ``pin_rigid``, single
    dofs of those sliding boundaries pinned against the rigid motions the rest leaves free.
    `InputError` if no dof is left free."""
    constrained, sliding = dirichlet_dofs(space, dirichlet, components)
    rigid = rigid_motions(space.nodes)
    pinned = isostatic_pins(rigid, constrained, sliding) if pin_rigid and sliding.size else np.zeros(0, int)
    constrained = np.union1d(constrained, pinned)
    free, to_reduced = reduced_numbering(space.num_dofs, constrained)
    if free.size == 0:
        raise InputError("every dof is on the Dirichlet boundary: nothing to solve")
    return Constraints(free, to_reduced, pinned, free_motions(rigid, constrained)[free])


def dirichlet_dofs(space: VectorSpace, dirichlet: str | None, components: dict) -> tuple[np.ndarray, np.ndarray]:
    """``(constrained, sliding)``: the global dofs fixed by ``dirichlet`` (all components) and
    ``components`` ``{boundary: (i, ...)}`` (those components), increasing, and the other dofs of
    the nodes on the ``components`` boundaries (the candidates for `isostatic_pins`)."""
    d = space.components
    fixed = [space.node_dofs(space.boundary_nodes(dirichlet))] if dirichlet is not None else []
    sliding = []
    for name, comps in components.items():
        comps = np.atleast_1d(np.asarray(comps))
        if comps.size == 0 or comps.dtype.kind not in "iu" or len(set(comps.tolist())) != comps.size \
                or comps.min() < 0 or comps.max() >= d:
            raise InputError(f"dirichlet_components[{name!r}]: need distinct component indices in "
                             f"0..{d - 1}, got {comps.tolist()}")
        nodes = space.boundary_nodes(name)
        if fixed and np.all(np.isin(space.node_dofs(nodes), fixed[0])):
            raise InputError(f"dirichlet_components[{name!r}]: that boundary is already clamped by "
                             f"dirichlet = {dirichlet!r}; pass dirichlet=None to let it slide")
        fixed.append((nodes[:, None] * d + comps).ravel())
        sliding.append(space.node_dofs(nodes))
    fixed = np.unique(np.concatenate(fixed)) if fixed else np.zeros(0, np.int64)
    sliding = np.setdiff1d(np.concatenate(sliding), fixed) if sliding else np.zeros(0, np.int64)
    return fixed, sliding


def rigid_motions(x: np.ndarray) -> np.ndarray:
    """Nodal values of the rigid motions (translations e_i, rotations e_k x (X - centre)) as flat dof
    vectors (nodes * d, d (d + 1) / 2); the centre is the mean node, for conditioning."""
    n, d = x.shape
    x = x - x.mean(axis=0)
    modes = [np.tile(np.eye(d)[i], n) for i in range(d)]
    if d == 2:
        modes.append(np.stack([-x[:, 1], x[:, 0]], axis=1).ravel())
    elif d == 3:
        modes += [np.cross(np.eye(3)[k], x).ravel() for k in range(3)]
    return np.stack(modes, axis=1)


def free_motions(rigid: np.ndarray, constrained: np.ndarray) -> np.ndarray:
    """Orthonormal basis (num_dofs, m) of the rigid motions that vanish on the constrained dofs."""
    k = rigid.shape[1]
    R = np.linalg.qr(rigid[constrained], mode="r") if constrained.size else np.zeros((0, k))
    # The SVD of the small triangular factor, padded to (k, k), gives all k right singular vectors.
    _, sv, Vt = np.linalg.svd(np.vstack([R, np.zeros((k - R.shape[0], k))]) if R.shape[0] < k else R)
    rank = int(np.sum(sv > 1e-10 * max(sv.max(initial=0.0), 1e-300)))
    free = rigid @ Vt[rank:].T
    return np.linalg.qr(free)[0] if free.shape[1] else free


def isostatic_pins(rigid: np.ndarray, constrained: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """The fewest dofs among ``candidates`` whose fixing removes the rigid motions left by
    ``constrained``: one per motion, picked by QR with column pivoting of the motions' values at the
    candidates (each pick removes the motion that moves it most, so the support is well conditioned)."""
    free = free_motions(rigid, constrained)
    m = free.shape[1]
    if m == 0:
        return np.zeros(0, np.int64)
    _, R, piv = scipy.linalg.qr(free[candidates].T, pivoting=True, mode="economic")
    if len(piv) < m or abs(R[m - 1, m - 1]) <= 1e-10 * abs(R[0, 0]):
        raise InputError(f"the Dirichlet conditions leave {m} rigid motion(s) that no single dof of the "
                         "dirichlet_components boundaries removes; constrain more components")
    return np.sort(candidates[piv[:m]])


def expand(space: VectorSpace, free: np.ndarray, u) -> np.ndarray:
    """Reduced vector(s) u (..., n) -> full nodal field (..., num_nodes, components), 0 where constrained."""
    u = np.asarray(u)
    full = np.zeros(u.shape[:-1] + (space.num_dofs,))
    full[..., free] = u
    return full.reshape(u.shape[:-1] + (space.num_nodes, space.components))


def restrict(free: np.ndarray, full) -> np.ndarray:
    """Full nodal field (num_nodes, components) or flat (num_dofs,) -> reduced vector (n,)."""
    return np.asarray(full, dtype=np.float64).reshape(-1)[free]


def repin(space: VectorSpace, free: np.ndarray, pinned_dofs: np.ndarray, full) -> np.ndarray:
    """``full + r`` (num_dofs,) for a full displacement ``full`` (num_dofs,): r the rigid motion,
    among those the constraints other than the pins leave free, that makes ``full + r`` vanish on
    ``pinned_dofs`` (unique, the support being isostatic); ``full`` itself without pins.

    Why: the pins are picked on each mesh anew, so on a refined mesh they are other material
    points, where a coarse solution is not 0 (Land problem 2, sliding base, level 0 -> 1: up to
    4.6 mm, the base's radial expansion that the coarse pins turned into a translation).
    Dropping those values would leave a spike at each pin, and Newton failed from such a guess.
    The pinned solution is only defined up to this motion, so adding it loses nothing; r is the
    linearized motion ``a + w x X``: exact for translations, for a rotation by w it adds a strain
    of order w^2."""
    full = np.asarray(full, dtype=np.float64).reshape(-1)
    if not pinned_dofs.size:
        return full
    fixed = np.setdiff1d(np.setdiff1d(np.arange(space.num_dofs), free), pinned_dofs)
    motions = free_motions(rigid_motions(space.nodes), fixed)  # (num_dofs, pins)
    return full - motions @ np.linalg.solve(motions[pinned_dofs], full[pinned_dofs])


def volume(F, w):
    """The deformed volume ``vol = int_Omega det F dx = sum_cq w_cq det F_cq`` (scalar, the mesh's
    length unit cubed), F (nc, nq, d, d) at the quadrature points, w (nc, nq) their weights times
    |det J|."""
    return jnp.sum(w * det(F))

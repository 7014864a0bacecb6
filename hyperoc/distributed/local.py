"""A model and its follower loads restricted to one rank's cells, on the rank's local unknowns.

The restricted objects are shallow copies whose per-cell (per-facet) data keep only the rank's
cells (the facets those cells own) and whose gathers index the rank's local unknowns: the serial
dofs of its cells, in increasing serial index (so a Taylor-Hood model's displacements still come
before its pressures). Their methods (`StateModel.internal_force`, ``tangent_blocks``, ``volume``,
``volume_gradient``, ``min_det_F``, `FollowerPressure.force`, ``add_stiffness``) then run the
package's element kernels unchanged on those cells: forces, volume gradient (m,) on the m local
unknowns, element blocks (nc_local, k, k) on the local cells.
"""

from __future__ import annotations

import copy

import jax.numpy as jnp
import numpy as np

from ..fem.assembly import dump_index
from ..mechanics.follower import FollowerPressure
from ..mechanics.model import StateModel

__all__ = ["local_dofs", "restrict_model", "restrict_follower"]


def local_dofs(model: StateModel, cells: np.ndarray) -> np.ndarray:
    """The serial indices (m,) of the unknowns of ``cells``, increasing."""
    dofs = model.cell_dofs[cells]
    return np.unique(dofs[dofs >= 0])


def _relabel(index: np.ndarray, n: int, dofs: np.ndarray) -> np.ndarray:
    """A gather ``index`` over n serial unknowns (dump slot n) relabelled onto ``dofs`` (m,) (dump slot m)."""
    to_local = np.full(n + 1, dofs.size, dtype=np.int64)
    to_local[dofs] = np.arange(dofs.size)
    return to_local[index]


def restrict_model(model: StateModel, cells: np.ndarray, dofs: np.ndarray) -> StateModel:
    """``model`` on ``cells`` only, its unknowns the serial ``dofs`` (m,) (`local_dofs`)."""
    local = copy.copy(model)
    local.__dict__ = {k: v for k, v in model.__dict__.items() if k not in ("jitted", "pattern", "_static_solves",
                                                                          "_static_solvers", "_ellipticity_fn")}
    take = lambda a: None if a is None else jnp.asarray(np.asarray(a)[cells])
    local._dN, local._w, local._frames, local._cell_volume = (take(model._dN), take(model._w), take(model._frames),
                                                             take(model._cell_volume))
    local._gather = jnp.asarray(_relabel(np.asarray(model._gather)[cells], model.n, dofs))
    local.cell_dofs = np.where(model.cell_dofs[cells] >= 0, np.searchsorted(dofs, model.cell_dofs[cells]), -1)
    local._element_gather = jnp.asarray(dump_index(local.cell_dofs, dofs.size))
    if hasattr(model, "n_u"):
        local.n_u = int(np.searchsorted(dofs, model.n_u))
    local.n = dofs.size
    return local


def restrict_follower(follower: FollowerPressure, model: StateModel, cells: np.ndarray,
                      dofs: np.ndarray) -> FollowerPressure:
    """``follower`` on the facets whose owner cell is in ``cells``, on the local unknowns ``dofs``."""
    local = copy.copy(follower)
    position = np.full(model.mesh.num_cells, -1, dtype=np.int64)
    position[cells] = np.arange(cells.size)
    owner = position[np.asarray(follower._owner)]
    mine = np.flatnonzero(owner >= 0)
    local._owner = jnp.asarray(owner[mine])
    local._local = follower._local[mine]
    local._X = follower._X[mine]
    local._gather = jnp.asarray(_relabel(np.asarray(follower._gather)[mine], model.n, dofs))
    local.num_facets, local.n = mine.size, dofs.size
    return local

"""Cell partition of the mesh and the owned/ghost numbering of the unknowns.

The cells are split by METIS on the dual graph (cells adjacent through a facet). A dof belongs to
the lowest rank among the cells that hold it; the distributed numbering lists rank 0's dofs first,
then rank 1's, ..., each in increasing serial index, so every rank owns one contiguous range (the
layout of a PETSc Vec). A rank's ghosts are the dofs of its cells that another rank owns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["Partition", "local_dofs", "partition_cells"]


def local_dofs(model, cells: np.ndarray) -> np.ndarray:
    """The serial indices (m,) of the unknowns of ``cells`` of ``model`` (its ``cell_dofs``), increasing:
    a rank's local unknowns, on which ``model.restricted(cells, dofs)`` works."""
    dofs = model.cell_dofs[cells]
    return np.unique(dofs[dofs >= 0])


def partition_cells(cells: np.ndarray, parts: int) -> np.ndarray:
    """Part (0 .. parts - 1) of each cell (nc,) of the simplex mesh ``cells`` (nc, d + 1): METIS on
    the dual graph whose edges are shared facets (d common vertices)."""
    if parts < 1 or parts > cells.shape[0]:
        raise InputError(f"partition_cells: need 1 <= parts <= {cells.shape[0]} cells, got {parts}")
    if parts == 1:
        return np.zeros(cells.shape[0], dtype=np.int64)
    import pymetis

    result = pymetis.part_mesh(parts, cells.tolist(), gtype=pymetis.GType.DUAL, ncommon=cells.shape[1] - 1)
    return np.asarray(result.element_part, dtype=np.int64)


@dataclass
class Partition:
    """The distribution of ``n`` unknowns over ``parts`` ranks.

    cell_part : (nc,) rank of each cell.
    dof_owner : (n,) rank owning each serial dof.
    to_global : (n,) distributed index of each serial dof (a permutation).
    ranges : (parts + 1,) the owned range of rank r is ``ranges[r] : ranges[r + 1]``.
    """

    cell_part: np.ndarray
    dof_owner: np.ndarray
    to_global: np.ndarray
    ranges: np.ndarray

    @classmethod
    def build(cls, cells: np.ndarray, cell_dofs: np.ndarray, n: int, parts: int) -> "Partition":
        """From the mesh's ``cells`` (nc, d + 1) and the element unknowns ``cell_dofs`` (nc, k)
        (serial indices, -1 on constrained dofs) of ``n`` unknowns."""
        cell_part = partition_cells(cells, parts)
        owner = np.full(n, parts, dtype=np.int64)
        free = cell_dofs >= 0
        np.minimum.at(owner, cell_dofs[free], np.broadcast_to(cell_part[:, None], cell_dofs.shape)[free])
        if np.any(owner == parts):
            raise InputError("Partition: some unknowns belong to no cell")
        order = np.lexsort((np.arange(n), owner))  # serial dofs in distributed order
        to_global = np.empty(n, dtype=np.int64)
        to_global[order] = np.arange(n)
        ranges = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=parts))])
        return cls(cell_part, owner, to_global, ranges)

    def cells_of(self, rank: int) -> np.ndarray:
        """Indices of the cells rank ``rank`` assembles."""
        return np.flatnonzero(self.cell_part == rank)

    def owned(self, rank: int) -> tuple[int, int]:
        """The distributed range ``[start, stop)`` rank ``rank`` owns."""
        return int(self.ranges[rank]), int(self.ranges[rank + 1])

"""One rank's share of a distributed model: its cells, its local and owned unknowns, the PETSc
tangent and direct solver, and the reductions over the ranks.

Three views of a vector of the n unknowns meet here:

- serial (n,): the model's numbering, as every serial function takes it;
- owned (m_o,): the entries this rank owns, in the distributed order (`Partition`), the rank's
  part of a PETSc Vec; the rows of the residual it assembles;
- local (m,): the unknowns of the rank's cells, in increasing serial index (owned and ghosts), what
  the element kernels of the restricted model (`hyperoc.mechanics.model.StateModel.restricted`) read.

`local_of_owned` fills the ghosts by a PETSc scatter; `add` sums the ranks' local contributions into
the owners' rows; `serial` gathers the owned parts into the serial vector on every rank.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import numpy as np
from mpi4py import MPI

from ..mechanics.model import StateModel
from .partition import Partition, local_dofs
from .petsc import Ghosts, PETSc, coo_matrix, linear_solver, vector

__all__ = ["Layout"]


class Layout:
    """``model``'s unknowns distributed over ``comm`` by a METIS partition of its cells (made on rank 0,
    broadcast), with the tangent's COO pattern of the rank's cells and a PETSc solver
    (``solver``: the PC lu package, ``"mumps"`` or ``"superlu_dist"``, or ``"gamg"``: GMRES with
    algebraic multigrid, `hyperoc.distributed.petsc.iterative_solver`).

    cells : (nc_local,) the rank's cells; dofs : (m,) their unknowns (serial indices, increasing);
    owned_serial : (m_o,) the serial index of each owned entry; n_u : for a model with a pressure
    field (Taylor-Hood), the number of owned entries that are displacements (they come first), else
    None (the blocks of `hyperoc.solvers.newton.small_increment`; every rank has the same number of them).
    """

    #: as a stepper's solver (`hyperoc.dynamics.stepper.TimeStepper.solver`): solves on the host, one
    #: step at a time, and can keep a factorization for chord Newton (`hyperoc.distributed.newton`)
    traced = False
    chord = True

    def __init__(self, model: StateModel, comm=MPI.COMM_WORLD, solver: str = "mumps"):
        self.comm, self.n = comm, model.n
        self.part = comm.bcast(Partition.build(model.mesh.cells, model.cell_dofs, model.n, comm.size)
                               if comm.rank == 0 else None)
        self.cells = self.part.cells_of(comm.rank)
        self.dofs = local_dofs(model, self.cells)
        start, stop = self.part.owned(comm.rank)
        petsc_comm = PETSc.Comm(comm)
        self._x = vector(petsc_comm, stop - start, model.n)
        self._y = self._x.duplicate()
        self._ghosts = Ghosts(self._x, self.part.to_global[self.dofs])
        cell_dofs = model.cell_dofs[self.cells]
        self.A = coo_matrix(petsc_comm, stop - start, model.n,
                            np.where(cell_dofs >= 0, self.part.to_global[np.maximum(cell_dofs, 0)], -1))
        self.ksp = linear_solver(self.A, solver)
        self.owned_serial = np.argsort(self.part.to_global)[start:stop]
        self.n_u = int(np.sum(self.owned_serial < model.n_u)) if hasattr(model, "n_u") else None
        self.split: dict[str, float] = {}
        self.factorizations = 0  # counts `factor` calls (and `forget_factorization`): which factorization is held

    @property
    def owned_size(self) -> int:
        return self.owned_serial.size

    # --- the three views --------------------------------------------------------------------------
    def local_of_owned(self, owned: np.ndarray) -> np.ndarray:
        """The local values (m,) of a vector given by each rank's owned values (m_o,) (ghosts scattered)."""
        with self.clock("assembly"):
            self._x.setArray(owned)
            return self._ghosts.gather(self._x)

    def add(self, local: np.ndarray) -> np.ndarray:
        """The owned rows (m_o,) of the sum over the ranks of their local contributions (m,)."""
        with self.clock("assembly"):
            return self._ghosts.add(np.asarray(local), self._y).getArray().copy()

    def serial(self, owned: np.ndarray) -> np.ndarray:
        """The serial vector (n,) on every rank from each rank's owned values (m_o,)."""
        full = np.concatenate(self.comm.allgather(np.asarray(owned)))
        return full[self.part.to_global]

    # --- reductions over the ranks ----------------------------------------------------------------
    def sum(self, value) -> float:
        return self.comm.allreduce(float(value), op=MPI.SUM)

    def sum_array(self, v: np.ndarray) -> np.ndarray:
        """The elementwise sum over the ranks of their arrays ``v`` (same shape on every rank)."""
        v = np.ascontiguousarray(v, dtype=np.float64)
        out = np.empty_like(v)
        self.comm.Allreduce(v, out, op=MPI.SUM)
        return out

    def dot(self, u: np.ndarray, v: np.ndarray) -> float:
        """``u . v`` of two distributed vectors given by their owned parts."""
        return self.sum(np.dot(u, v))

    def inf_norm(self, v: np.ndarray) -> float:
        """``max |v|`` of a distributed vector given by its owned part (0 for no entries)."""
        return self.comm.allreduce(float(np.max(np.abs(v), initial=0.0)), op=MPI.MAX)

    def min(self, value) -> float:
        return self.comm.allreduce(float(value), op=MPI.MIN)

    def max(self, value) -> float:
        return self.comm.allreduce(float(value), op=MPI.MAX)

    def all_finite(self, v: np.ndarray) -> bool:
        return bool(self.comm.allreduce(bool(np.all(np.isfinite(v))), op=MPI.LAND))

    # --- the tangent and its solves ---------------------------------------------------------------
    def factor(self, blocks: np.ndarray) -> None:
        """Assemble the element blocks (nc_local, k, k) of the rank's cells into the tangent and factor it."""
        with self.clock("assembly"):
            self.A.setValuesCOO(np.asarray(blocks).ravel(), PETSc.InsertMode.INSERT_VALUES)
            self.A.assemble()
        with self.clock("solve"):
            self.ksp.setOperators(self.A)
        self.factorizations += 1

    def forget_factorization(self) -> None:
        """Make the factorization held stale for chord Newton (`hyperoc.distributed.newton.KeptJacobian`), so
        that its next iteration factors afresh: a checkpoint segment then takes the iterations it takes after a
        resume (`hyperoc.dynamics.resumable`)."""
        self.factorizations += 1

    def solve(self, *rhs: np.ndarray) -> np.ndarray:
        """``K^-1 r`` for each right-hand side's owned part r (m_o,), with the last factorization, as the
        columns of (m_o, len(rhs)); NaN where the solver fails."""
        out = np.empty((self.owned_size, len(rhs)))
        with self.clock("solve"):
            for j, r in enumerate(rhs):
                self._y.setArray(r)
                self.ksp.solve(self._y, self._x)
                out[:, j] = self._x.getArray() if self.ksp.getConvergedReason() >= 0 else np.nan
        return out

    @contextmanager
    def clock(self, part: str):
        """Add the wall time of the block to ``split[part]``."""
        t0 = time.perf_counter()
        yield
        self.split[part] = self.split.get(part, 0.0) + time.perf_counter() - t0

    def slowest_split(self) -> dict:
        """`split`, each part the largest over the ranks (seconds)."""
        return {part: self.max(value) for part, value in sorted(self.split.items())}

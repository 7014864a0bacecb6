"""PETSc objects of a distributed solve: vectors, the tangent with COO preallocation, the ghost
scatter and the direct solver.

The distributed numbering is `hyperoc.distributed.partition.Partition`'s. A rank's element blocks
go into the matrix as COO values (`Mat.setValuesCOO`), in the order of the (row, column) pairs given
once to `Mat.setPreallocationCOO`; pairs on constrained dofs carry index -1, which PETSc drops;
entries owned by another rank are sent to it. The ghost scatter moves the owned values of a
distributed vector to the rank's local unknowns (forward, insert) and adds the local
contributions back into the owners' entries (reverse, add).
"""

from __future__ import annotations

import dolfinx_solver  # noqa: F401  (loads MPI ahead of the bindings)
import numpy as np
from petsc4py import PETSc

from ..errors import InputError

__all__ = ["PETSc", "Ghosts", "coo_matrix", "direct_solver", "iterative_solver", "linear_solver", "vector"]

#: the PC lu packages of the wheel's PETSc, and the iterative solver
DIRECT, ITERATIVE = ("mumps", "superlu_dist"), ("gamg",)


def vector(comm, owned: int, size: int) -> PETSc.Vec:
    """A distributed vector of ``size`` entries, ``owned`` of them on this rank."""
    return PETSc.Vec().createMPI((owned, size), comm=comm)


def coo_matrix(comm, owned: int, size: int, cell_dofs: np.ndarray) -> PETSc.Mat:
    """A (size, size) AIJ matrix preallocated for the element blocks on the distributed indices
    ``cell_dofs`` (nc_local, k) (-1 on constrained dofs): values come as blocks (nc_local, k, k), row-major."""
    k = cell_dofs.shape[1]
    rows = np.repeat(cell_dofs, k, axis=1).ravel().astype(PETSc.IntType)
    cols = np.tile(cell_dofs, (1, k)).ravel().astype(PETSc.IntType)
    A = PETSc.Mat().create(comm=comm)
    A.setSizes(((owned, size), (owned, size)))
    A.setType(PETSc.Mat.Type.AIJ)
    A.setPreallocationCOO(rows, cols)
    return A


class Ghosts:
    """The scatter between a distributed vector and this rank's local unknowns ``dofs`` (distributed
    indices, (m,))."""

    def __init__(self, x: PETSc.Vec, dofs: np.ndarray):
        self.local = PETSc.Vec().createSeq(dofs.size, comm=PETSc.COMM_SELF)
        index = PETSc.IS().createGeneral(np.asarray(dofs, dtype=PETSc.IntType), comm=PETSc.COMM_SELF)
        self.scatter = PETSc.Scatter().create(x, index, self.local, None)

    def gather(self, x: PETSc.Vec) -> np.ndarray:
        """The values (m,) of ``x`` at the local unknowns."""
        self.scatter.scatter(x, self.local, PETSc.InsertMode.INSERT_VALUES, PETSc.ScatterMode.FORWARD)
        return self.local.getArray(readonly=True).copy()

    def add(self, values: np.ndarray, y: PETSc.Vec) -> PETSc.Vec:
        """``y`` = the sum over ranks of their local ``values`` (m,) at their unknowns (``y`` zeroed first)."""
        y.zeroEntries()
        self.local.setArray(values)
        self.scatter.scatter(self.local, y, PETSc.InsertMode.ADD_VALUES, PETSc.ScatterMode.REVERSE)
        return y


def direct_solver(A: PETSc.Mat, package: str = "mumps") -> PETSc.KSP:
    """KSP preonly + PC lu with the parallel direct solver ``package`` (MUMPS by default): one
    factorization per `KSP.setOperators`, any number of solves against it."""
    ksp = PETSc.KSP().create(comm=A.getComm())
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.LU)
    pc.setFactorSolverType(package)
    ksp.setOperators(A)
    return ksp


def iterative_solver(A: PETSc.Mat, rtol: float = 1e-13) -> PETSc.KSP:
    """GMRES (restart 200) preconditioned by smoothed-aggregation algebraic multigrid (PC gamg), to the
    relative residual ``rtol``: the preconditioner is set up once per `KSP.setOperators`. Suited to the
    time step's matrix ``M / (theta dt) + kappa L + theta dt K`` (the mass term keeps it well conditioned
    for small dt); a solve that does not reach ``rtol`` in 1000 iterations reports divergence."""
    ksp = PETSc.KSP().create(comm=A.getComm())
    ksp.setType(PETSc.KSP.Type.GMRES)
    ksp.setGMRESRestart(200)
    ksp.getPC().setType(PETSc.PC.Type.GAMG)
    ksp.setTolerances(rtol=rtol, atol=0.0, max_it=1000)
    ksp.setOperators(A)
    return ksp


def linear_solver(A: PETSc.Mat, solver: str) -> PETSc.KSP:
    """`direct_solver` for a PC lu package of `DIRECT`, `iterative_solver` for ``"gamg"``."""
    if solver in ITERATIVE:
        return iterative_solver(A)
    if solver not in DIRECT:
        raise InputError(f"distributed solver must be one of {DIRECT + ITERATIVE}, got {solver!r}")
    return direct_solver(A, solver)

"""Distributed static solves on MPI + PETSc with the package's JAX element kernels.

Each rank assembles the cells of its part of a graph partition of the mesh (`partition`) with the
model's own element kernels restricted to those cells (`local`); PETSc holds the distributed
tangent and vectors and solves with KSP/PC (`petsc`); the Newton load stepping and the volume
constraint's bordered solve run on them (`statics`). Needs the ``mpi`` extra (petsc4py, Python >= 3.12):
see docs/distributed.md. The mesh and the model are built on every rank (replicated set-up); the
unknowns, the assembly and the linear solves are distributed.
"""

from .partition import Partition, partition_cells

__all__ = ["Partition", "partition_cells"]

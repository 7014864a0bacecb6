"""Distributed static solves, time stepping and exact gradients on MPI + PETSc with the package's JAX
element kernels.

Each rank assembles the cells of its part of a graph partition of the mesh (`partition`) with the
model's own element kernels restricted to those cells (`hyperoc.mechanics.model.StateModel.restricted`);
PETSc holds the distributed tangent and vectors and solves with KSP/PC (`petsc`); `layout` joins them
for one rank, `newton` solves on it; the load stepping (`statics`), the theta scheme and its adjoint
(`dynamics`) run on that Newton. Their command lines are `hyperoc.app.distributed_statics` and
`hyperoc.app.distributed_gradient`. Needs the ``mpi`` extra
(petsc4py, Python >= 3.12): see docs/distributed.md. The mesh and the model are built on every rank
(replicated set-up); the unknowns, the assembly and the linear solves are distributed.
"""

from .partition import Partition, local_dofs, partition_cells

__all__ = ["Partition", "local_dofs", "partition_cells"]

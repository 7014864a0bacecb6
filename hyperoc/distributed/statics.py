"""Distributed quasi-static equilibrium: Newton with load stepping on PETSc, the residual and the
tangent from the JAX element kernels on each rank's cells.

The same discrete problem as `hyperoc.dynamics.statics.solve_static`: with the volume constraint
(``constrained=True``) find ``(u, p)`` with

    R(u) + p G(u) = sum_j f_j(u; s),      vol(u) = V(s),

else ``R(u) = sum_j f_j(u; s)``, the follower loads f_j and the target volume ramped over the load
factor s (`hyperoc.dynamics.statics._step_load`, shared). Each Newton iteration solves

    [ K   G ] [du]   [ -r           ]
    [ G^T 0 ] [dp] = [ -(vol - V)    ]

by the Schur complement (`hyperoc.solvers.linsolve._eliminate`): ``K a = -r``, ``K b = G`` against one
MUMPS factorization, ``dp = (G.a + vol - V) / (G.b)``, ``du = a - dp b``; unconstrained, ``K du = -r``.
``vol`` and the dot products reduce over the ranks (MPI allreduce); p lives on every rank. Full Newton
steps (the Land benchmarks' ``line_search=False``), stopped as the serial solve, per block
(displacement, then Taylor-Hood pressure): ``|du_b|_inf <= rtol |u_b + du_b|_inf + atol``.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np
from mpi4py import MPI

from ..dynamics.statics import _step_load
from ..dynamics.stepper import Scheme
from ..errors import InputError
from ..mechanics.follower import FollowerPressure
from ..mechanics.model import StateModel
from ..solvers.newton import NewtonStatus
from .local import local_dofs, restrict_follower, restrict_model
from .partition import Partition
from .petsc import Ghosts, PETSc, coo_matrix, direct_solver, vector

__all__ = ["DistributedStatics", "DistributedSolution"]


@dataclass(eq=False)
class DistributedSolution:
    """Equilibrium ``u`` (n,) in the serial numbering (on every rank), multiplier ``p`` (0 when
    unconstrained), Newton iterations per accepted load increment, rejected ones, seconds of the solve,
    and its split (seconds, the largest over the ranks): ``kernels`` (the JAX residual and element
    blocks, compilation included), ``assembly`` (ghost scatters, COO values into the matrix),
    ``solve`` (factorization and the KSP solves)."""

    u: np.ndarray
    p: float
    newton_iterations: np.ndarray
    rejected_iterations: int
    seconds: float
    split: dict


class DistributedStatics:
    """``model`` (a `StateModel` or `hyperoc.mechanics.mixed.TaylorHoodModel`, built on every rank) and its
    follower loads, distributed over ``comm`` by a METIS partition of the cells.

    ``solver``: the PETSc direct solver package of PC lu (``"mumps"``, ``"superlu_dist"``).
    """

    def __init__(self, model: StateModel, follower=(), *, comm=MPI.COMM_WORLD, constrained: bool = True,
                 solver: str = "mumps"):
        self.model, self.comm, self.constrained = model, comm, constrained
        followers = (follower,) if not isinstance(follower, (tuple, list)) else tuple(follower)
        for f in followers:
            if not isinstance(f, FollowerPressure):
                raise InputError(f"DistributedStatics: the loads are follower pressures; {type(f).__name__} "
                                 "is not distributed yet")
        self.part = comm.bcast(Partition.build(model.mesh.cells, model.cell_dofs, model.n, comm.size)
                               if comm.rank == 0 else None)
        cells = self.part.cells_of(comm.rank)
        dofs = local_dofs(model, cells)
        self.local = restrict_model(model, cells, dofs)
        self.followers = tuple(restrict_follower(f, model, cells, dofs) for f in followers)
        start, stop = self.part.owned(comm.rank)
        petsc_comm = PETSc.Comm(comm)
        self.x = vector(petsc_comm, stop - start, model.n)
        self.ghosts = Ghosts(self.x, self.part.to_global[dofs])
        gdofs = np.append(self.part.to_global[dofs], -1)  # local index m (constrained) -> -1
        self.A = coo_matrix(petsc_comm, stop - start, model.n, gdofs[self.local._element_gather])
        self.ksp = direct_solver(self.A, solver)
        serial = np.argsort(self.part.to_global)[start:stop]  # serial index of each owned entry
        n_u = getattr(model, "n_u", model.n)
        self._blocks = [serial < n_u] + ([serial >= n_u] if n_u < model.n else [])

    # --- local kernels ---------------------------------------------------------------------------
    @cached_property
    def _kernels(self):
        """Jitted local kernels of the rank's unknowns xl (m,): force balance, element blocks,
        volume and its gradient, min det F."""
        local, followers = self.local, self.followers

        def force(xl, s):
            return local.internal_force(xl) - sum((f.force(xl, s) for f in followers), jnp.zeros(local.n))

        def blocks(xl, p, s):
            K = local.tangent_blocks(xl, 1.0, p)
            for f in followers:
                K = f.add_stiffness(K, xl, s)
            return K

        return {"force": jax.jit(force), "blocks": jax.jit(blocks), "volume": jax.jit(local.volume),
                "volume_gradient": jax.jit(local.volume_gradient), "min_det_F": jax.jit(local.min_det_F)}

    def _sum(self, value: float) -> float:
        return self.comm.allreduce(float(value), op=MPI.SUM)

    def volume(self, xl) -> float:
        """vol(u) = int det F dx over the whole body, from the local unknowns."""
        return self._sum(self._kernels["volume"](xl))

    # --- Newton ------------------------------------------------------------------------------------
    def _newton(self, x0: np.ndarray, V: float, s: float, scheme: Scheme):
        """Newton from ``x0`` (owned values, then p when constrained) at load factor s and target
        volume V: ``(x, iterations, NewtonStatus, min det F)``."""
        k, clock = self._kernels, self._clock
        x = x0.copy()
        owned = self.x.getLocalSize()
        r, G, a, b = (self.x.duplicate() for _ in range(4))
        for it in range(1, scheme.max_iter + 1):
            self.x.setArray(x[:owned])
            p = x[owned] if self.constrained else 0.0
            with clock("assembly"):
                xl = jnp.asarray(self.ghosts.gather(self.x))
            with clock("kernels"):
                f = np.asarray(k["force"](xl, s))
                gl = np.asarray(k["volume_gradient"](xl)) if self.constrained else None
                blocks = np.asarray(k["blocks"](xl, p, s))
            with clock("assembly"):
                if self.constrained:
                    self.ghosts.add(gl, G)
                    f = f + p * gl
                self.ghosts.add(-f, r)
                self.A.setValuesCOO(blocks.ravel(), PETSc.InsertMode.INSERT_VALUES)
                self.A.assemble()
            with clock("solve"):
                self.ksp.setOperators(self.A)
                self.ksp.solve(r, a)
                du = a.getArray().copy()
                step = [du]
                if self.constrained:  # the bordered step, the Schur complement of linsolve._eliminate
                    self.ksp.solve(G, b)
                    dp = (G.dot(a) + self.volume(xl) - V) / G.dot(b)
                    du = du - dp * b.getArray()
                    step = [du, [dp]]
            if self.ksp.getConvergedReason() < 0 or not self._finite(du):
                return x, it, NewtonStatus.NON_FINITE, np.nan
            x = x + np.concatenate(step)
            if self._small(x[:owned], du, scheme):
                self.x.setArray(x[:owned])
                xl = jnp.asarray(self.ghosts.gather(self.x))
                mindet = self.comm.allreduce(float(k["min_det_F"](xl)), op=MPI.MIN)
                return x, it, NewtonStatus.CONVERGED, mindet
        return x, scheme.max_iter, NewtonStatus.MAX_ITERATIONS, np.nan

    @contextmanager
    def _clock(self, part: str):
        """Add the wall time of the block to ``part`` of the solve's split."""
        t0 = time.perf_counter()
        yield
        self._split[part] = self._split.get(part, 0.0) + time.perf_counter() - t0

    def _finite(self, du) -> bool:
        return bool(self.comm.allreduce(bool(np.all(np.isfinite(du))), op=MPI.LAND))

    def _small(self, u, du, scheme: Scheme) -> bool:
        """The serial stopping test (`hyperoc.solvers.newton._small`) on every block, maxima over the ranks."""
        for mask in self._blocks:
            big = lambda v: self.comm.allreduce(float(np.max(np.abs(v[mask]), initial=0.0)), op=MPI.MAX)
            if big(du) > scheme.rtol * big(u) + scheme.atol:
                return False
        return True

    def solve(self, *, steps: int = 1, cutbacks: int = 0, volume: float | None = None,
              scheme: Scheme = Scheme(), predictor: str = "previous") -> DistributedSolution:
        """Equilibrium at the full load, ramped in ``steps`` increments from u = 0, each halved up to
        ``cutbacks`` times in total on failure (`hyperoc.dynamics.statics.solve_static`'s load stepping).
        ``volume``: the target volume (default the reference one); constrained solves only."""
        if not self.constrained and volume is not None:
            raise InputError("DistributedStatics.solve: a target volume needs the volume constraint")
        self.comm.Barrier()
        t0, self._split = MPI.Wtime(), {}
        x = np.zeros(self.x.getLocalSize() + (1 if self.constrained else 0))
        V0 = self.volume(jnp.zeros(self.local.n))
        V = V0 if volume is None else float(volume)
        solve = lambda x0, fk, Vk, s: self._newton(x0, Vk, s, scheme)
        # no linear solver object: a failed KSP solve ends Newton as NON_FINITE
        x, iters, rejected = _step_load(None, solve, x, 0.0, V0, V, steps=steps, cutbacks=cutbacks,
                                        predictor=predictor)
        seconds = MPI.Wtime() - t0
        split = {part: self.comm.allreduce(value, op=MPI.MAX) for part, value in sorted(self._split.items())}
        return DistributedSolution(self.gather(x[: self.x.getLocalSize()]), float(x[-1]) if self.constrained else 0.0,
                                   np.array(iters), rejected, seconds, split)

    def gather(self, owned: np.ndarray) -> np.ndarray:
        """The serial vector (n,) on every rank from each rank's owned values."""
        full = np.concatenate(self.comm.allgather(owned))
        return full[self.part.to_global]

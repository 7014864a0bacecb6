"""Distributed quasi-static equilibrium: Newton with load stepping on PETSc, the residual and the
tangent from the JAX element kernels on each rank's cells.

The same discrete problem as `hyperoc.dynamics.statics.solve_static`: with the volume constraint
(``constrained=True``) find ``(u, p)`` with

    R(u) + sum_k k_k S_k u + p G(u) = sum_j f_j(u; s),      vol(u) = V(s),

else without p and the volume, the springs ``k_k S_k`` of the Robin boundaries
(`hyperoc.dynamics.terms.RobinBoundary`, at rest: no dashpot), the follower loads f_j and the target volume
ramped over the load factor s (`hyperoc.dynamics.statics.step_load`, shared). Each Newton iteration solves

    [ K   G ] [du]   [ -r           ]
    [ G^T 0 ] [dp] = [ -(vol - V)    ]

by the Schur complement against one MUMPS factorization (`hyperoc.distributed.newton`); ``vol`` and the
dot products reduce over the ranks (MPI allreduce); p lives on every rank. Full Newton steps (the Land
benchmarks' ``line_search=False``), stopped as the serial solve.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np
from mpi4py import MPI

from ..dynamics.statics import add_spring_tangent, robin_terms, spring_force, step_load
from ..dynamics.stepper import Scheme
from ..errors import InputError
from ..mechanics.active import FibreTension
from ..mechanics.follower import FollowerPressure
from ..mechanics.model import StateModel
from ..solvers.newton import NewtonOptions, NewtonStatus
from .layout import Layout
from .newton import newton

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
    loads (`FollowerPressure`, `FibreTension`: ``follower`` as in `hyperoc.dynamics.statics.solve_static`) and
    Robin springs (``robin``: `RobinBoundary` terms of the model, as in ``solve_static``), distributed over
    ``comm`` by a METIS partition of the cells (`Layout`); each load and spring acts on the facets whose owner
    cell is the rank's.

    ``solver``: the PETSc direct solver package of PC lu (``"mumps"``, ``"superlu_dist"``).
    """

    def __init__(self, model: StateModel, follower=(), *, robin=(), comm=MPI.COMM_WORLD, constrained: bool = True,
                 solver: str = "mumps"):
        self.model, self.comm, self.constrained = model, comm, constrained
        followers = (follower,) if not isinstance(follower, (tuple, list)) else tuple(follower)
        for f in followers:
            if not isinstance(f, (FollowerPressure, FibreTension)):
                raise InputError(f"DistributedStatics: the loads are follower pressures and fibre tensions; "
                                 f"{type(f).__name__} is not distributed")
        robin = robin_terms(model, robin, "DistributedStatics")
        self.layout = Layout(model, comm, solver)
        cells, dofs = self.layout.cells, self.layout.dofs
        self.local = model.restricted(cells, dofs)
        self.followers = tuple(f.restricted(model, self.local, cells, dofs) for f in followers)
        self.robin = tuple(term.restricted(model, self.local, cells, dofs) for term in robin)

    # --- local kernels ---------------------------------------------------------------------------
    @cached_property
    def _kernels(self):
        """Jitted local kernels of the rank's unknowns xl (m,): force balance, element blocks,
        volume and its gradient, min det F."""
        local, followers, robin = self.local, self.followers, self.robin

        def force(xl, s):
            return (local.internal_force(xl) + spring_force(robin, xl)
                    - sum((f.force(xl, s) for f in followers), jnp.zeros(local.n)))

        def blocks(xl, p, s):
            K = local.tangent_blocks(xl, 1.0, p)
            for f in followers:
                K = f.add_stiffness(K, xl, s)
            return add_spring_tangent(robin, K, xl)

        return {"force": jax.jit(force), "blocks": jax.jit(blocks), "volume": jax.jit(local.volume),
                "volume_gradient": jax.jit(local.volume_gradient), "min_det_F": jax.jit(local.min_det_F)}

    def volume(self, xl) -> float:
        """vol(u) = int det F dx over the whole body, from the local unknowns."""
        return self.layout.sum(self._kernels["volume"](xl))

    # --- Newton ------------------------------------------------------------------------------------
    def _newton(self, x0: np.ndarray, V: float, s: float, scheme: Scheme):
        """Newton from ``x0`` (owned values, then p when constrained) at load factor s and target
        volume V: ``(x, iterations, NewtonStatus, min det F)``."""
        k, layout = self._kernels, self.layout

        def residual(xl, p):
            with layout.clock("kernels"):
                f = np.asarray(k["force"](xl, s))
                if self.constrained:
                    f = f + p * np.asarray(k["volume_gradient"](xl))
            r = layout.add(f)
            return np.append(r, self.volume(xl) - V) if self.constrained else r

        def jacobian(xl, p):
            with layout.clock("kernels"):
                blocks = np.asarray(k["blocks"](xl, p, s))
                G = layout.add(np.asarray(k["volume_gradient"](xl))) if self.constrained else None
            return blocks, G, G

        x, it, status = newton(residual, jacobian, layout, x0, NewtonOptions(scheme.rtol, scheme.atol, scheme.max_iter),
                               constrained=self.constrained)
        mindet = np.nan
        if status == NewtonStatus.CONVERGED:
            mindet = layout.min(k["min_det_F"](layout.local_of_owned(x[:layout.owned_size])))
        return x, it, status, mindet

    def solve(self, *, steps: int = 1, cutbacks: int = 0, volume: float | None = None,
              scheme: Scheme = Scheme(), predictor: str = "previous") -> DistributedSolution:
        """Equilibrium at the full load, ramped in ``steps`` increments from u = 0, each halved up to
        ``cutbacks`` times in total on failure (`hyperoc.dynamics.statics.solve_static`'s load stepping).
        ``volume``: the target volume (default the reference one); constrained solves only."""
        if not self.constrained and volume is not None:
            raise InputError("DistributedStatics.solve: a target volume needs the volume constraint")
        layout = self.layout
        self.comm.Barrier()
        t0, layout.split = MPI.Wtime(), {}
        x = np.zeros(layout.owned_size + (1 if self.constrained else 0))
        V0 = self.volume(jnp.zeros(self.local.n))
        V = V0 if volume is None else float(volume)
        solve = lambda x0, fk, Vk, s: self._newton(x0, Vk, s, scheme)
        # no linear solver object: a failed KSP solve ends Newton as NON_FINITE
        x, iters, rejected = step_load(None, solve, x, 0.0, V0, V, steps=steps, cutbacks=cutbacks,
                                        predictor=predictor)
        seconds = MPI.Wtime() - t0
        return DistributedSolution(layout.serial(x[: layout.owned_size]), float(x[-1]) if self.constrained else 0.0,
                                   np.array(iters), rejected, seconds, layout.slowest_split())

"""Can a finer level of Land problem 2 start from the coarser solution (nested iteration) instead of
ramping the load from zero? Solve level 0, prolong its displacement to level 1
(`hyperoc.spaces.prolong`: the nodal interpolant at the fine nodes' material points) and print

- min det F of the coarse solution at its quadrature points, and of the prolonged field at the
  fine quadrature points (the fine rule samples the coarse cells nearer their corners);
- the first full Newton step from the prolonged field at full load (max |du|, mm);
- `solve_static` from it at full load (``steps=1``, halving the increment on failure);
- a residual homotopy ``R(u) = (1 - lam) R(u_prolonged)`` for lam from 0 to 1 (u_prolonged solves
  lam = 0 exactly), increments of ``1 / --homotopy-steps`` halved on failure: the lam reached
  within ``--budget`` halvings.

    nice taskset -c 0 python bench/probe_nested_start.py --kappa 1000                                   # ~2 min
    nice taskset -c 0 python bench/probe_nested_start.py --kappa 10000 --volumetric cell-mean --isochoric --steps 40
"""

from __future__ import annotations

import argparse
import time

import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

import hyperoc  # noqa: F401  (before JAX: hyperoc._jax sets JAX's flags)
from hyperoc.benchmarks import ventricle_problem
from hyperoc.dynamics import Scheme
from hyperoc.errors import SolverError
from hyperoc.linsolve import make_solver
from hyperoc.materials import det
from hyperoc.spaces import prolong
from hyperoc.statics import _compiled_solve, initial_unknown, solve_static


def min_det(model, u) -> float:
    return float(np.min(np.asarray(det(model.deformation_gradient(jnp.asarray(u))))))


def homotopy(model, load, u0, steps: int, budget: int) -> tuple[float, int]:
    """Largest lam reached (and the Newton iterations spent) on ``R(u) = (1 - lam) R(u0)``."""
    lin = make_solver(model, "auto")
    solve, _ = _compiled_solve(model, lin, Scheme(), (load,), False, False)
    r0 = model.internal_force(jnp.asarray(u0)) - load.force(jnp.asarray(u0), 1.0)
    x = initial_unknown(model, u0, constrained=False)
    lam, dlam, cuts, its = 0.0, 1.0 / steps, 0, 0
    while lam < 1.0 and cuts <= budget:
        trial = min(1.0, lam + dlam)
        failed = lin.stats["failed"]
        x_new, it, status, mindet = solve(x, (1.0 - trial) * r0, 0.0, 1.0)
        its += int(it)
        if int(status) == 0 and float(mindet) > 0 and lin.stats["failed"] == failed:
            x, lam, dlam = x_new, trial, min(2 * dlam, 1.0 / steps)
        else:
            dlam, cuts = dlam / 2, cuts + 1
    return lam, its


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--h0", type=float, default=6.0)
    ap.add_argument("--kappa", type=float, default=1000.0)
    ap.add_argument("--volumetric", default="pointwise", choices=["pointwise", "cell-mean"])
    ap.add_argument("--isochoric", action="store_true")
    ap.add_argument("--steps", type=int, default=10, help="load steps of the level-0 solve")
    ap.add_argument("--homotopy-steps", type=int, default=1)
    ap.add_argument("--budget", type=int, default=12, help="halvings allowed in the homotopy")
    args = ap.parse_args()
    opts = dict(kappa=args.kappa, volumetric=args.volumetric, isochoric=args.isochoric)

    coarse, coarse_load = ventricle_problem(args.h0, refinements=0, **opts)
    t0 = time.perf_counter()
    sol = solve_static(coarse, follower=coarse_load, constrained=False, steps=args.steps, line_search=False,
                       cutbacks=80)
    print(f"level 0: {coarse.n} dofs, {sol.newton_iterations.sum()} Newton its, {time.perf_counter() - t0:.1f} s, "
          f"min det F {min_det(coarse, sol.u):.3f}", flush=True)
    fine, load = ventricle_problem(args.h0, refinements=1, **opts)
    u0 = fine.restrict(prolong(coarse.space, fine.space, coarse.expand(sol.u).ravel()))
    print(f"level 1: {fine.n} dofs; prolonged field: min det F {min_det(fine, u0):.3f}", flush=True)

    blocks = load.add_stiffness(fine.tangent_blocks(jnp.asarray(u0), 1.0, 0.0), jnp.asarray(u0), 1.0)
    K = fine.pattern.matrix(np.asarray(blocks).reshape(fine.pattern.element_shape)).tocsc()
    r = np.asarray(fine.internal_force(jnp.asarray(u0)) - load.force(jnp.asarray(u0), 1.0))
    du = spla.splu(K).solve(-r)
    print(f"first full Newton step: max |du| = {np.abs(du).max():.3g} mm (|u0| max {np.abs(u0).max():.3g} mm)",
          flush=True)
    try:
        out = solve_static(fine, follower=load, constrained=False, steps=1, u0=u0, line_search=False, cutbacks=12)
        print(f"solve_static from the prolonged field: converged, Newton its {out.newton_iterations.tolist()}")
    except SolverError as err:
        print(f"solve_static from the prolonged field: {err}")
    lam, its = homotopy(fine, load, u0, args.homotopy_steps, args.budget)
    print(f"residual homotopy: lam reached {lam:.4g} of 1 with {args.budget} halvings allowed ({its} Newton its)")


if __name__ == "__main__":
    main()

"""Where Land problem 3 converges and where it does not: the deformed z of fixed material points near
the apex on nested levels (Taylor-Hood P2-P1, kappa = inf, isochoric Guccione, clamped base).

The vertices of level 0 are vertices of every finer level (uniform refinement keeps them), so their
deformed positions form a convergence sequence like the apex's. Printed per level: the endocardial and
epicardial apex z, the z of the ``--ring`` level-0 endocardial and epicardial vertices nearest to each
apex (their distance from the apex axis in mm), where min det F sits (distance of that quadrature point
from the endocardial apex), and the fibre-strain extremes. ``--npz`` keeps the nodes and displacements.

    nice taskset -c 0 python bench/probe_contraction_apex.py --levels 0,1,2 --npz results/p3-apex.npz
"""

from __future__ import annotations

import argparse
import math
import time

from hyperoc.benchmarks import contraction_problem, node_position  # first: hyperoc sets JAX's environment
from hyperoc.materials import det
from hyperoc.statics import solve_static

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402


def nearest_wall_vertices(model, wall: str, apex, count: int, limit: int) -> np.ndarray:
    """The ``count`` vertices of ``wall`` among the first ``limit`` (level 0) nearest to ``apex``, apex excluded."""
    verts = np.unique(model.mesh.boundary(wall))
    verts = verts[verts < limit]
    dist = np.linalg.norm(model.mesh.points[verts] - apex, axis=1)
    order = np.argsort(dist)
    return verts[order[dist[order] > 1e-9][:count]]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--h0", type=float, default=6.0)
    ap.add_argument("--levels", default="0,1,2")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--ring", type=int, default=4, help="level-0 wall vertices tracked near each apex")
    ap.add_argument("--npz", default=None)
    args = ap.parse_args()
    levels = [int(v) for v in args.levels.split(",")]
    apexes = {"endocardium": np.array([0.0, 0.0, -17.0]), "epicardium": np.array([0.0, 0.0, -20.0])}
    coarse, _ = contraction_problem(args.h0, kappa=math.inf, volumetric="taylor-hood", isochoric=True)
    nv0 = coarse.mesh.points.shape[0]
    tracked = {wall: nearest_wall_vertices(coarse, wall, apex, args.ring, nv0) for wall, apex in apexes.items()}
    saved = {}
    for level in levels:
        model, loads = contraction_problem(args.h0, kappa=math.inf, volumetric="taylor-hood", isochoric=True,
                                           refinements=level)
        assert np.array_equal(model.mesh.points[:nv0], coarse.mesh.points)  # nested: level-0 vertices first
        t0 = time.perf_counter()
        sol = solve_static(model, follower=loads, constrained=False, steps=args.steps, line_search=False, cutbacks=40)
        U = model.expand(sol.u)
        x = model.space.nodes + U
        print(f"level {level}: {model.n} unknowns, {int(sol.newton_iterations.sum())} Newton its, "
              f"{time.perf_counter() - t0:.0f} s")
        for wall, apex in apexes.items():
            ring = ", ".join(f"{x[v, 2]:.5f} (rho {np.hypot(*model.mesh.points[v, :2]):.2f})" for v in tracked[wall])
            print(f"  {wall}: apex z {node_position(model, sol.u, apex)[2]:.5f}; level-0 vertices: {ring}")
        u = jnp.asarray(sol.u)
        J = np.asarray(det(model.deformation_gradient(u)))
        c, q = np.unravel_index(np.argmin(J), J.shape)
        where = np.linalg.norm(model.quad.x[c, q] - apexes["endocardium"])
        Eff = np.asarray(loads[1].fibre_strain(u))
        print(f"  min det F {J.min():.4f} at {where:.2f} mm from the endocardial apex; E_ff in "
              f"[{Eff.min():.3f}, {Eff.max():.3f}]", flush=True)
        saved[f"nodes_{level}"], saved[f"u_{level}"] = model.space.nodes, U
    if args.npz:
        np.savez_compressed(args.npz, **saved)


if __name__ == "__main__":
    main()

"""Why the mixed P2-P0 form fails on Land problem 2, and whether a pressure on vertex patches would
do better: load-step the level-0 ventricle and print min det F per accepted step.

Modes (Guccione, kappa in kPa; the bulk term ``U(J) = kappa/4 (J^2 - 1 - 2 ln J)``):

- ``pointwise``: U(J) at every quadrature point (hyperoc's default);
- ``cell-mean``: U on each cell's mean J (`StateModel(volumetric="cell-mean")`, mixed P2-P0);
- ``vertex-mean``: ``sum_a m_a U(theta_a)``, ``theta_a = int N_a J / m_a``, ``m_a = int N_a`` with
  N_a the P1 hat functions: the condensed form of a continuous P1 pressure with a lumped pressure
  mass, i.e. the penalty analogue of Taylor-Hood P2-P1. Not in hyperoc (its tangent couples vertex
  patches, outside the cell-block pattern); here only as an energy.

To compare the three on equal terms the script differentiates the energy itself: residual by
``jax.grad``, a *dense* Jacobian by ``jax.jacfwd`` (slow: about 20 s per Newton iteration at the
1,602 dofs of level 0), host Newton, full steps, increments of 1/20 halved on failure.

    nice taskset -c 0 python bench/probe_mixed_fold.py --mode vertex-mean --stop 0.5   # ~25 min
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import hyperoc  # noqa: F401  (before JAX: hyperoc._jax sets JAX's flags)
from hyperoc.benchmarks import ventricle_problem
from hyperoc.materials import det
from hyperoc.quadrature import simplex_rule
from hyperoc.spaces import reference_shape


def vertex_mean_energy(model):
    """``int W_rest dx + sum_a m_a U(theta_a)`` (see the module docstring) as a function of u."""
    rest, U = model.material.volumetric_split()
    xi, _ = simplex_rule(model.dim, 4)  # the model's P2 rule (`StateModel.quad`)
    N1 = jnp.asarray(reference_shape(model.dim, 1, xi)[0])  # (nq, d + 1) hat functions
    cells, w = jnp.asarray(model.mesh.cells[:, : model.dim + 1]), model._w
    nv = model.mesh.points.shape[0]
    m = jnp.zeros(nv).at[cells].add(w @ N1)
    used = m > 0

    def energy(u):
        F = model.deformation_gradient(u)
        theta = jnp.zeros(nv).at[cells].add((w * det(F)) @ N1) / jnp.where(used, m, 1.0)
        bulk = jnp.where(used, m * U(jnp.where(used, theta, 1.0)), 0.0)
        return jnp.sum(w * model._pointwise(rest.energy_of_F, F)) + jnp.sum(bulk)

    return energy


def newton(res, jac, x, s, max_iter=25):
    """Full Newton steps on ``res(x, s) = 0``; (x, iterations) or (None, iterations)."""
    for it in range(1, max_iter + 1):
        dx = np.linalg.solve(np.asarray(jac(jnp.asarray(x), s)), -np.asarray(res(jnp.asarray(x), s)))
        x = x + dx
        if not np.all(np.isfinite(x)):
            return None, it
        if np.max(np.abs(dx)) <= 1e-10 * np.max(np.abs(x)):
            return x, it
    return None, max_iter


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mode", choices=["pointwise", "cell-mean", "vertex-mean"], default="vertex-mean")
    ap.add_argument("--kappa", type=float, default=1000.0)
    ap.add_argument("--level", type=int, default=0, help="uniform refinements of the h0 = 6 mm ventricle")
    ap.add_argument("--stop", type=float, default=1.0, help="last load factor (of 10 kPa)")
    ap.add_argument("--cutbacks", type=int, default=8)
    args = ap.parse_args()
    model, follower = ventricle_problem(6.0, kappa=args.kappa, refinements=args.level,
                                        volumetric="cell-mean" if args.mode == "cell-mean" else "pointwise")
    energy = vertex_mean_energy(model) if args.mode == "vertex-mean" else model.strain_energy
    residual = lambda u, s: jax.grad(energy)(u) - follower.force(u, s)
    res, jac, min_det = jax.jit(residual), jax.jit(jax.jacfwd(residual)), jax.jit(model.min_det_F)
    u, s_done, ds, cuts, t0 = np.zeros(model.n), 0.0, 0.05, 0, time.perf_counter()
    print(f"{args.mode}, kappa {args.kappa:g} kPa, level {args.level}: {model.n} dofs")
    while s_done < args.stop - 1e-12:
        s = min(args.stop, s_done + ds)
        x, its = newton(res, jac, u.copy(), s)
        md = float(min_det(jnp.asarray(x))) if x is not None else float("nan")
        if x is not None and md > 0:
            u, s_done, ds = x, s, min(2 * ds, 0.05)
            print(f"load {s:.4f} ({10 * s:.3f} kPa): {its} Newton its, min det F {md:.3f}  "
                  f"[{time.perf_counter() - t0:.0f} s]",
                  flush=True)
        elif cuts < args.cutbacks:
            cuts, ds = cuts + 1, ds / 2
            print(f"load {s:.4f}: failed (min det F {md:.3g}), halving the increment", flush=True)
        else:
            print(f"stopped at load {s_done:.4f} ({10 * s_done:.3f} kPa): {args.cutbacks} cutbacks used")
            return


if __name__ == "__main__":
    main()

"""Element tangent on 3D meshes: the reference route (``jax.hessian`` of ``a W(F) + b det F`` at
every quadrature point, then one einsum with the shape gradients, defined here as the
baseline) against `StateModel.tangent_blocks` (Voigt second derivatives
of W(E), B^T H B per cell, stress and det F Hessian in closed form, cells in chunks).

Per case, same process, variants interleaved (old, new, old, new, ...; best of ``--reps``):

- ``pointwise``: the 4th-order tangent at every quadrature point (old: d^4 entries of the F-Hessian
  of ``a W + b det``; new: the nv x nv Voigt Hessian of W(E) and dW/dE),
- ``contract``: old einsum of the pointwise tangent with dN (given the tangent),
- ``total``: the whole element-block computation, jitted (what a Newton iteration calls),
- ``scatter``: `SparsePattern.data` (np.bincount into the CSR data), ``lu`` (with ``--lu``): one
  sparse LU factorization and solve of the step matrix (`SparseSolver("lu")`, ordering computed before).

``--newton STEPS`` also runs STEPS time steps of the dynamic problem (theta = 1/2, dt = 0.01, a
uniform downward body force 0.1 / L ramped by sin^2, `SparseSolver("lu_reuse")`) with each
tangent and splits seconds per Newton iteration into the host linear solve and the JAX rest
(tangent, residuals, line search).

    nice python bench/bench_tangent.py                                  # all cases
    nice python bench/bench_tangent.py --cases shell-p1-nh --newton 2

Writes ``bench/results/bench_tangent.json`` (`bench/results.py`): the ``total`` part per case, and the
Newton figures with ``--newton``.
"""

from __future__ import annotations

import argparse
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np

import hyperoc as ho
from hyperoc.fem.geometry import thick_shell, ventricle
from hyperoc.mechanics.fibres import rule_based_fibres
from hyperoc.mechanics.materials import det
from hyperoc.solvers.linsolve import SparseSolver
from results import Table, command_line, write_results


class HessianTangentModel(ho.StateModel):
    """`StateModel` with the element tangent as it was: pointwise ``jax.hessian``, then an einsum."""

    def pointwise_hessian(self, u, a, b):
        F = self.deformation_gradient(u)

        def psi(G, frame):
            return a * self.material.energy_of_F(G, frame) + b * det(G)

        return self.pointwise(jax.hessian(psi), F)  # (nc, nq, d, d, d, d)

    def contract(self, A):
        Ke = jnp.einsum("cq,cqaj,cqijkl,cqbl->caibk", self._w, self._dN, A, self._dN)
        nc, k = Ke.shape[0], self.space.nloc * self.dim
        return Ke.reshape(nc, k, k)

    def tangent_blocks(self, u, a, b):
        return self.contract(self.pointwise_hessian(u, a, b))


def new_pointwise(model, u):
    """The pointwise part of the new route alone: Voigt Hessian and gradient of W at every point."""
    from hyperoc.mechanics.kernels import VOIGT as _VOIGT

    I, J = _VOIGT[model.dim][:2]
    F = model.deformation_gradient(u)
    e = (0.5 * (jnp.einsum("cqkI,cqkJ->cqIJ", F, F) - jnp.eye(model.dim)))[..., I, J]
    return model.pointwise(model._voigt_derivatives, e)


def shell_frames(x):
    """Fibre frames for the thick shell: f horizontal-circumferential, s radial (any orthonormal field)."""
    r = x / np.linalg.norm(x, axis=-1, keepdims=True)
    f = np.cross([0.0, 0.0, 1.0], r)
    f = np.where(np.linalg.norm(f, axis=-1, keepdims=True) < 1e-8, [1.0, 0.0, 0.0], f)
    f /= np.linalg.norm(f, axis=-1, keepdims=True)
    return np.stack([f, r, np.cross(f, r)], axis=-2)


@functools.cache
def mesh_of(kind, h):
    return thick_shell(0.5, 1.0, h=h) if kind == "shell" else ventricle(h)


CASES = {
    # name: ((mesh kind, h), degree, material, frames builder or None)
    "shell-p1-svk": (("shell", 0.063), 1, ho.SaintVenantKirchhoff(1.0, 5.0), None),
    "shell-p1-nh": (("shell", 0.063), 1, ho.NeoHookean(1.0, 5.0), None),
    "shell-p1-guccione": (("shell", 0.063), 1, ho.Guccione(), lambda mesh: shell_frames),
    "lv-p1-guccione": (("lv", 1.0), 1, ho.Guccione(), rule_based_fibres),
    "lv-p2-guccione": (("lv", 2.0), 2, ho.Guccione(), rule_based_fibres),
    "shell-p2-svk": (("shell", 0.15), 2, ho.SaintVenantKirchhoff(1.0, 5.0), None),
}


def build(name):
    mesh_key, degree, material, frames_fn = CASES[name]
    mesh = mesh_of(*mesh_key)
    frames = None if frames_fn is None else frames_fn(mesh)
    return {cls: cls(mesh, material, degree=degree, damping=0.01, frames=frames)
            for cls in (HessianTangentModel, ho.StateModel)}


def smooth_displacement(model):
    """A smooth displacement with |grad u| <= 0.1 (det F ~ 0.9-1.1 everywhere), scaled to the mesh size."""
    L = np.ptp(model.mesh.points, axis=0).max()
    return jnp.asarray(model.interpolate(lambda x: 0.01 * L * np.sin(3.0 * x / L + 0.3)[:, ::-1]))


def best_interleaved(fns: dict, reps: int) -> dict:
    """Best-of-reps seconds per function, run in the order A B C A B C ... (one untimed call first)."""
    for f in fns.values():
        jax.block_until_ready(f())
    times = {k: [] for k in fns}
    for _ in range(reps):
        for k, f in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f())
            times[k].append(time.perf_counter() - t0)
    return {k: min(v) for k, v in times.items()}


KERNELS = Table("Element tangents of one Newton iteration (jitted), best of the interleaved repetitions",
                ["case", "cells", "degree", "dofs", "old total (s)", "new total (s)", "new / old",
                 "max |K_new - K_old| / max |K_old|"],
                "old: jax.hessian of a W(F) + b det F at every quadrature point, then one einsum with the shape "
                "gradients (the reference route); new: StateModel.tangent_blocks.", echo=False)
NEWTON = Table("Dynamic steps (dt = 0.01, theta = 1/2, lu_reuse) per tangent variant",
               ["case", "tangent", "Newton iterations", "s / Newton iteration", "linear solve s / iteration",
                "JAX s / iteration"], echo=False)


def kernel_case(name, reps, lu):
    models = build(name)
    old, new = models[HessianTangentModel], models[ho.StateModel]
    u = smooth_displacement(new)
    a, b = 1.0, 0.3
    nq = new.quad.dN.shape[1]
    A = jax.jit(old.pointwise_hessian)(u, a, b)
    fns = {
        "old pointwise": lambda f=jax.jit(old.pointwise_hessian): f(u, a, b),
        "old contract": lambda f=jax.jit(old.contract): f(A),
        "old total": lambda f=jax.jit(old.tangent_blocks): f(u, a, b),
        "new pointwise": lambda f=jax.jit(lambda u: new_pointwise(new, u)): f(u),
        "new total": lambda f=jax.jit(new.tangent_blocks): f(u, a, b),
    }
    t = best_interleaved(fns, reps)
    K_old, K_new = (np.asarray(jax.jit(m.tangent_blocks)(u, a, b)) for m in (old, new))
    diff = np.max(np.abs(K_new - K_old)) / np.max(np.abs(K_old))
    t0 = time.perf_counter()
    new.pattern.data(K_new)
    t_scatter = time.perf_counter() - t0
    if lu:
        solver = SparseSolver(new, "lu")
        rhs = np.random.default_rng(0).standard_normal(new.n)
        G = np.asarray(jax.jit(new.volume_gradient)(u))
        solver.host_solve(K_new, G, G, rhs, 0.0)  # the ordering (first call)
        solver.reset_stats()
        solver.host_solve(K_new, G, G, rhs, 0.0)
    print(f"\n{name}: {new.mesh.num_cells} cells, P{new.space.degree}, {nq} quadrature points per cell "
          f"({new.mesh.num_cells * nq} points), {new.n} dofs, nnz(K) = {new.pattern.nnz}; "
          f"max |K_new - K_old| / max |K_old| = {diff:.1e}")
    print(f"  {'part':16s} {'old s':>8s} {'new s':>8s} {'new/old':>8s}")
    for part in ("pointwise", "contract", "total"):
        o, n_ = t.get(f"old {part}"), t.get(f"new {part}")
        row = f"  {part:16s} {o:8.3f} " + (f"{n_:8.3f} {n_ / o:8.3f}" if n_ is not None else f"{'-':>8s} {'-':>8s}")
        print(row)
    KERNELS.add(name, new.mesh.num_cells, new.space.degree, new.n, round(t["old total"], 3), round(t["new total"], 3),
                round(t["new total"] / t["old total"], 3), float(f"{diff:.1e}"))
    print(f"  {'scatter':16s} {t_scatter:8.3f}   (np.bincount into CSR, same for both)")
    if lu:
        print(f"  {'lu':16s} {solver.stats['host_s']:8.3f}   (factor {solver.stats['factor_s']:.3f} s "
              f"+ solves, same for both)")
    return models


def newton_case(name, models, steps):
    print(f"\n  {steps} time steps (dt = 0.01, theta = 1/2, lu_reuse), per variant:")
    print(f"  {'tangent':8s} {'Newton its':>10s} {'s/Newton':>9s} {'linear s/it':>12s} {'JAX s/it':>9s} {'p_end':>22s}")
    rows = {}
    for cls, label in ((HessianTangentModel, "old"), (ho.StateModel, "new")):
        model = models[cls]
        load = model.load_vector(body_force=(0.0, 0.0, -0.1 / np.ptp(model.mesh.points, axis=0).max()))
        solver = SparseSolver(model, "lu_reuse")
        st = ho.TimeStepper(model, ho.Scheme(), solver)
        grid = ho.uniform_grid(T=0.01 * steps, dt=0.01)
        ramp = lambda t: np.sin(np.pi * np.asarray(t) / (0.02 * steps))[:, None] ** 2 * load[None, :]
        st.run(ho.TimeGrid(grid.t[:2]), external=ramp(grid.t[:2]), diagnose=False)  # compile; ordering
        solver.reset_stats()
        t0 = time.perf_counter()
        sol = st.run(grid, external=ramp(grid.t), diagnose=False)
        wall = time.perf_counter() - t0
        its = int(np.sum(sol.newton_iterations))
        lin = solver.stats["host_s"]
        rows[label] = (wall / its, lin / its, (wall - lin) / its)
        print(f"  {label:8s} {its:10d} {wall / its:9.3f} {lin / its:12.3f} {(wall - lin) / its:9.3f} "
              f"{sol.pressure[-1]:22.15g}")
        NEWTON.add(name, label, its, round(wall / its, 3), round(lin / its, 3), round((wall - lin) / its, 3))
    o, n_ = rows["old"], rows["new"]
    print(f"  new/old: s/Newton {n_[0] / o[0]:.3f}, JAX part {n_[2] / o[2]:.3f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated subset of {', '.join(CASES)}")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--lu", action="store_true", help="also time one sparse LU of the step matrix")
    ap.add_argument("--newton", type=int, default=0, metavar="STEPS", help="also time STEPS dynamic steps per tangent")
    args = ap.parse_args()
    for name in args.cases.split(","):
        models = kernel_case(name, args.reps, args.lu)
        if args.newton:
            newton_case(name, models, args.newton)
    write_results("bench_tangent", command_line(), [KERNELS.as_dict()] + ([NEWTON.as_dict()] if NEWTON.rows else []))


if __name__ == "__main__":
    main()

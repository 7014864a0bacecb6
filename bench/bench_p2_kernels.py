"""The kernels of a P2 step on the cardiac benchmark ventricle: the step's residual, a fresh Jacobian, the
viscous term's tangent and the ellipticity check of one level, per kernel variant, in one run.

The problem is `hyperoc benchmark cardiac-elastodynamics --step 1 --degree 2` (the reference mesh: 17,625
curved P2 tetrahedra, 89,679 unknowns; Holzapfel-Ogden, viscosity, Robin epicardium and base, endocardial
pressure, active tension), at a smooth state (``u = 0.02 X``, ``v = 0.1 X`` in SI units). Variants, each its
own model and stepper:

- ``baseline``: the collapsed Gauss-Jacobi rule of degree 4 (27 points per cell), the viscous tangent by
  ``jax.jacfwd`` of the viscous element force, the acoustic tensors from the law's Hessian in F
  (``jax.hessian`` of ``W(F)``, contracted with the directions): the kernels as they were, defined here;
- ``closed forms``: the same rule, the viscous tangent in closed form
  (`hyperoc.dynamics.terms.Viscosity._element_tangent`) and the acoustic tensors from the strain
  derivatives (`hyperoc.mechanics.diagnostics.acoustic_tensors`);
- ``closed forms, 14-point rule``: what hyperoc runs (`hyperoc.fem.quadrature.simplex_rule`'s symmetric rule
  of degree 5 for degree 4 on tetrahedra).

Each time is the shortest of ``--repeat`` calls after a first (compiling) one; ratios are against the
baseline.

    python bench/bench_p2_kernels.py

Writes ``bench/results/bench_p2_kernels.json``.
"""

from __future__ import annotations

import argparse
import time
from contextlib import contextmanager

import jax
import jax.numpy as jnp
import numpy as np

import hyperoc.fem.spaces as spaces
from hyperoc.app.cardiac_benchmark import benchmark_config
from hyperoc.dynamics.terms import Viscosity
from hyperoc.fem.quadrature import _collapsed_gauss_jacobi, simplex_rule
from hyperoc.mechanics import diagnostics, kernels
from results import Table, command_line, write_results


class JacfwdViscosity(Viscosity):
    """The viscous term with its tangent by ``jax.jacfwd`` of the element force (k forward passes through the
    reverse-mode gradient per cell)."""

    def add_tangent(self, blocks, y0, y1, t, a, b):
        def element(xs):
            du, dv = jax.jacfwd(self._element_force, argnums=(0, 1))(*xs)
            return a * du + b * dv

        return blocks + self.model.map_cells(element, self._cells(y0, y1))


def hessian_min_acoustic_eigenvalue(material, F, frames):
    """The smallest acoustic eigenvalue from ``dP/dF = jax.hessian(W(F))`` (nc, nq, 3, 3, 3, 3)."""
    A = kernels.pointwise(jax.hessian(material.energy_of_F), F, frames)
    dirs = jnp.asarray(diagnostics.directions(F.shape[-1]))
    return jnp.min(diagnostics.min_symmetric_eigenvalue(jnp.einsum("cqijkl,nj,nl->cqnik", A, dirs, dirs)))


@contextmanager
def collapsed_rule():
    """Models built inside take the collapsed product rule for every degree."""
    spaces.simplex_rule = lambda dim, degree: _collapsed_gauss_jacobi(dim, degree) if degree > 2 else \
        simplex_rule(dim, degree)
    try:
        yield
    finally:
        spaces.simplex_rule = simplex_rule


def best_seconds(fn, repeat: int) -> float:
    """The shortest of ``repeat`` calls after a first (compiling) one: the least disturbed by other work."""
    fn()
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return min(times)


def measure(closed_forms: bool, repeat: int) -> dict:
    """Seconds per call of the step's residual, its fresh Jacobian, the viscous tangent and the ellipticity
    check at one level, and the points per cell."""
    cfg = benchmark_config("1", degree=2)
    model = cfg.model()
    st = cfg.stepper(model)
    if not closed_forms:
        st.terms = tuple(JacfwdViscosity(model, t.eta) if isinstance(t, Viscosity) else t for t in st.terms)
        diagnostics_fn = hessian_min_acoustic_eigenvalue
    else:
        diagnostics_fn = diagnostics.min_acoustic_eigenvalue
    X = model.interpolate(lambda x: x)
    y0, y1, dt, n = 0.02 * X, 0.1 * X, 1e-3, model.n
    k, z = st._host_kernels, np.zeros(model.control.size)
    known = k["known"](y0, y1, z, z, np.zeros(n), np.zeros(n), dt, 0.1)
    x = np.asarray(k["guess"](y0, y1, dt, 0.0))
    V0 = float(st.constraint_value(y0))
    viscous = next(t for t in st.terms if isinstance(t, Viscosity))
    blocks = jnp.zeros(model.mass_blocks.shape)
    tangent = jax.jit(lambda b, u, v: viscous.add_tangent(b, u, v, 0.1, dt / 2, 1.0))
    F = jax.jit(model.deformation_gradient)(jnp.asarray(y0))
    check = jax.jit(lambda F: jnp.min(model.map_cells(
        lambda xs: diagnostics_fn(model.material, xs[0][None], xs[1][None]), (F, model.material_frames))))
    return {
        "points": int(model._w.shape[1]),
        "residual": best_seconds(lambda: np.asarray(k["residual_at"](x, known, y0, y1, 0.0, dt, V0, 0.1)), repeat),
        "jacobian": best_seconds(lambda: jax.device_get(k["jacobian"](x, y0, dt, y1, 0.1, 0.0)), repeat),
        "viscous": best_seconds(lambda: jax.block_until_ready(tangent(blocks, y0, y1)), repeat),
        "check": best_seconds(lambda: float(check(F)), repeat),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    with collapsed_rule():
        runs = {"baseline": measure(False, args.repeat), "closed forms": measure(True, args.repeat)}
    runs["closed forms, 14-point rule"] = measure(True, args.repeat)
    base = runs["baseline"]
    table = Table("Kernels of a P2 step on the benchmark ventricle (89,679 unknowns), per variant",
                  ["variant", "points per cell", "residual (s)", "fresh Jacobian (s)", "viscous tangent (s)",
                   "ellipticity check, one level (s)", "residual / baseline", "Jacobian / baseline",
                   "check / baseline"],
                  notes="Baseline: the collapsed 27-point rule, the viscous tangent by jax.jacfwd, the acoustic "
                        "tensors from jax.hessian of W(F), in the same run. Fresh Jacobian: the step's element "
                        "blocks with every term's tangent, brought to the host. The shortest of repeated calls after a "
                        "compiling one.")
    for name, r in runs.items():
        table.add(name, r["points"], r["residual"], r["jacobian"], r["viscous"], r["check"],
                  r["residual"] / base["residual"], r["jacobian"] / base["jacobian"], r["check"] / base["check"])
    write_results("bench_p2_kernels", command_line(), [table.as_dict()])


if __name__ == "__main__":
    main()

"""Guccione's element tangent: closed-form strain derivatives (`Guccione.strain_derivatives`) against
JAX's Voigt Hessian of the energy (the route every other law takes), in the same process.

The baseline is the same law with ``strain_derivatives`` returning None (`AutodiffGuccione`), so
`StateModel` differentiates `Guccione.energy` by JAX. Printed per case: cells, points, the largest
difference of the element tangents relative to their largest entry, and best-of-``--reps`` seconds
of one jitted ``tangent_blocks`` call, the two variants interleaved. ``--gradient`` also times one
gradient of the ventricle example (``examples/ventricle-3d.toml``, from its initial point) per
variant, interleaved, best of ``--reps``.

    taskset -c 1 python bench/bench_guccione_tangent.py --gradient
"""

from __future__ import annotations

import argparse
import time
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path
from unittest import mock

import hyperoc as ho  # noqa: I001 - before jax (threads)
import jax
import jax.numpy as jnp
import numpy as np

import hyperoc.config
from hyperoc.config import parse_config
from hyperoc.materials import material_from_config
from hyperoc.fibres import rule_based_fibres
from hyperoc.geometry import ventricle
from hyperoc.workflows import build_reduced

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "ventricle-3d.toml"


@dataclass(frozen=True)
class AutodiffGuccione(ho.Guccione):
    """Guccione without the closed form: the element tangent differentiates `energy` by JAX."""

    def strain_derivatives(self, E, frame=None):
        return None


def best_interleaved(fns: dict, reps: int) -> dict:
    """Best-of-reps seconds per function, in the order A B A B ... (one untimed call first)."""
    for f in fns.values():
        jax.block_until_ready(f())
    times = {k: [] for k in fns}
    for _ in range(reps):
        for k, f in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f())
            times[k].append(time.perf_counter() - t0)
    return {k: min(v) for k, v in times.items()}


def tangent_case(h: float, degree: int, reps: int):
    mesh = ventricle(h)
    frames = rule_based_fibres(mesh)
    models = {name: ho.StateModel(mesh, law(), degree=degree, kappa=1.0, frames=frames)
              for name, law in (("autodiff", AutodiffGuccione), ("closed form", ho.Guccione))}
    model = models["closed form"]
    L = np.ptp(mesh.points, axis=0).max()
    u = jnp.asarray(model.interpolate(lambda x: 0.01 * L * np.sin(3.0 * x / L + 0.3)[:, ::-1]))
    kernels = {name: jax.jit(m.tangent_blocks) for name, m in models.items()}
    K = {name: np.asarray(k(u, 1.0, 0.3)) for name, k in kernels.items()}
    diff = np.max(np.abs(K["closed form"] - K["autodiff"])) / np.max(np.abs(K["autodiff"]))
    t = best_interleaved({name: (lambda k=k: k(u, 1.0, 0.3)) for name, k in kernels.items()}, reps)
    nq = model.quad.dN.shape[1]
    print(f"ventricle h = {h} mm, P{degree}: {mesh.num_cells} cells, {mesh.num_cells * nq} points, {model.n} dofs; "
          f"max |dK| / max |K| = {diff:.1e}; tangent_blocks autodiff {t['autodiff'] * 1e3:.2f} ms, closed form "
          f"{t['closed form'] * 1e3:.2f} ms, ratio {t['closed form'] / t['autodiff']:.3f}", flush=True)


def gradient_case(reps: int):
    cfg = parse_config(tomllib.loads(EXAMPLE.read_text()), base=EXAMPLE.parent)
    tau0 = float(cfg["optimize"]["tau0"])
    def autodiff_law(section):
        return AutodiffGuccione(**asdict(material_from_config(section)))

    with mock.patch.object(hyperoc.config, "material_from_config", autodiff_law):
        Js = {"autodiff": build_reduced(cfg, tau0)}
    Js["closed form"] = build_reduced(cfg, tau0)
    assert type(Js["autodiff"].model.material) is AutodiffGuccione and type(Js["closed form"].model.material) is ho.Guccione
    m = {name: J.zero(tau0) for name, J in Js.items()}
    values = {name: J.value_and_gradient(m[name]) for name, J in Js.items()}  # compile
    g = {name: v[1] for name, v in values.items()}
    rel = Js["autodiff"].norm(g["closed form"] - g["autodiff"]) / Js["autodiff"].norm(g["autodiff"])
    t = best_interleaved({name: (lambda J=J, name=name: J.value_and_gradient(m[name])[0]) for name, J in Js.items()},
                         reps)
    print(f"ventricle example gradient: |G_closed - G_autodiff| / |G| = {rel:.1e}; autodiff {t['autodiff']:.2f} s, "
          f"closed form {t['closed form']:.2f} s, ratio {t['closed form'] / t['autodiff']:.3f}", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--gradient", action="store_true", help="also time one gradient of the ventricle example")
    args = ap.parse_args()
    for h, degree in ((3.0, 1), (2.5, 1), (1.5, 1), (3.0, 2)):
        tangent_case(h, degree, args.reps)
    if args.gradient:
        gradient_case(args.reps)


if __name__ == "__main__":
    main()

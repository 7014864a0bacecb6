"""What the cell-mean bulk term costs: `StateModel` ``volumetric="cell-mean"`` (mixed P2-P0,
condensed) against ``"pointwise"`` (the baseline), same process, interleaved.

Per mesh (Land problem 2: idealized LV, curved P2, Guccione, bulk modulus 1000 kPa, nested levels of
h0 = 6 mm), both models are built and the jitted internal force and element tangents evaluated at
the same smooth displacement: first call (trace + compile + run) and the best of ``--reps`` later
calls, alternating the two formulations. Printed: seconds and the ratio cell-mean / pointwise.
The sparsity is the same (the condensed pressure lives in one cell), so a Newton iteration's
linear solve costs the same; only the element kernels differ.

    nice taskset -c 0 python bench/bench_volumetric.py --levels 0,1

Writes ``bench/results/bench_volumetric.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

import hyperoc  # noqa: F401  (before JAX: hyperoc._jax sets JAX's flags)
from hyperoc.cardiac.land import ventricle_problem
from hyperoc.mechanics.model import VOLUMETRIC as MODES  # the baseline, "pointwise", first
from results import Table, command_line, write_results


def kernels(model):
    """The jitted force and tangent of a model, and a smooth displacement with det F > 0."""
    fn = jax.jit(lambda u: (model.internal_force(u), model.tangent_blocks(u, 1.0, 0.0)))
    return fn, jnp.asarray(model.interpolate(lambda x: 0.01 * x * x[:, ::-1]))


def timed(fn, u) -> float:
    t0 = time.perf_counter()
    jax.block_until_ready(fn(u))
    return time.perf_counter() - t0


def level_row(h0: float, level: int, reps: int) -> dict:
    built = {m: kernels(ventricle_problem(h0, bulk_modulus=1000.0, refinements=level, volumetric=m)[0]) for m in MODES}
    first = {m: timed(*built[m]) for m in MODES}
    later = {m: float("inf") for m in MODES}
    for _ in range(reps):
        for m in MODES:
            later[m] = min(later[m], timed(*built[m]))
    dofs = int(built[MODES[0]][1].size)
    return {"level": level, "dofs": dofs, "first": first, "later": later}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--h0", type=float, default=6.0)
    ap.add_argument("--levels", default="0,1")
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args()
    out = Table(f"Internal force and element tangents, Land problem 2 (curved P2 LV, h0 = {args.h0:g} mm, "
                f"bulk modulus 1000 kPa): first call and best of {args.reps} later calls",
                ["level", "dofs", "1st call pointwise (s)", "1st call cell-mean (s)", "later pointwise (s)",
                 "later cell-mean (s)", "later cell-mean / pointwise"],
                "The first call includes tracing and XLA compilation. Same sparsity in both formulations, so "
                "the linear solves of a Newton iteration cost the same; only the element kernels differ.")
    for level in (int(v) for v in args.levels.split(",")):
        r = level_row(args.h0, level, args.reps)
        f, lt = r["first"], r["later"]
        out.add(level, r["dofs"], round(f["pointwise"], 2), round(f["cell-mean"], 2), round(lt["pointwise"], 3),
                round(lt["cell-mean"], 3), round(lt["cell-mean"] / lt["pointwise"], 2))
    write_results("bench_volumetric", command_line(), [out.as_dict()])


if __name__ == "__main__":
    main()

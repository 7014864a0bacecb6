"""Where the memory of a large Taylor-Hood solve goes, stage by stage, before any factorization: Land
problem 2 (kappa = inf, isochoric Guccione) on level ``--level`` of the nested h0 = 6 ventricle. Prints
the resident set (VmRSS) and the peak so far (ru_maxrss) after building the model, after one jitted
residual, after one jitted tangent (its element blocks' size) and after assembling K on the host. A
factorization comes on top (bench_pardiso.py: 12.0 GB for PARDISO at level 3).

    nice taskset -c 0 python bench/probe_memory_stages.py --level 3
"""

from __future__ import annotations

import argparse
import gc
import resource
import time

import jax
import jax.numpy as jnp
import numpy as np

import hyperoc  # noqa: F401  (before JAX: hyperoc._jax sets JAX's flags)
from hyperoc.benchmarks import ventricle_problem


def rss_gb() -> float:
    with open("/proc/self/status") as fh:
        return float(fh.read().split("VmRSS:")[1].split()[0]) / 2**20


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--level", type=int, default=2)
    ap.add_argument("--h0", type=float, default=6.0)
    args = ap.parse_args()
    t0 = time.perf_counter()

    def stage(name):
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
        print(f"{name}: {time.perf_counter() - t0:.0f} s, RSS {rss_gb():.2f} GB, peak {peak:.2f} GB", flush=True)

    model, load = ventricle_problem(args.h0, kappa=float("inf"), refinements=args.level, volumetric="taylor-hood",
                                    isochoric=True)
    stage(f"model, level {args.level} ({model.n} unknowns, {len(model.mesh.cells)} cells)")
    x = jnp.zeros(model.n)
    jax.jit(lambda x: model.internal_force(x) - load.force(x, 1.0))(x).block_until_ready()
    stage("one residual (jitted)")
    blocks = jax.jit(lambda x: load.add_stiffness(model.tangent_blocks(x, 1.0, 0.0), x, 1.0))(x).block_until_ready()
    stage(f"one tangent (jitted; element blocks {blocks.nbytes / 2**30:.2f} GB)")
    K = model.pattern.matrix(np.asarray(blocks).reshape(model.pattern.element_shape))
    stage(f"K assembled on the host ({K.nnz} nonzeros)")
    del blocks, K
    gc.collect()
    stage("blocks and K freed")


if __name__ == "__main__":
    main()

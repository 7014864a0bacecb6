"""Closed-over constants in the jitted kernels: passed to XLA as arguments (JAX with
``JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS=1``, which `hyperoc._jax` sets when hyperoc is imported
before JAX) or embedded in the program as literals (JAX's default),
on Land problem 2 (idealized LV, curved P2, bulk modulus 1000 kPa, clamped base) on a nested sequence
of meshes.

Each (level, mode) runs in a fresh subprocess with the variable set, since JAX reads it on import
(and XLA's memory is not returned between compilations). A child builds the model, compiles the
jitted Newton solve of one load step (`hyperoc.dynamics.statics`, the one `solve_static` runs) and times
that compilation, then evaluates the internal force and the element tangents at a fixed smooth
displacement (first call = trace + compile + run; then the fastest of five more calls: run only).
Printed per level and mode: compile seconds, first and later evaluation seconds, peak RSS of the
child (``ru_maxrss``, MB, as in bench_checkpoint.py), the number of XLA "Constant folding ... is
taking > 1s" alarms, and whether the force and tangents are bitwise the same in both modes; then the
ratios arguments / literals.

    nice taskset -c 0 python bench/bench_constants.py                  # levels 0, 1 of h0 = 6
    nice taskset -c 0 python bench/bench_constants.py --levels 0,1,2   # + 80k dofs

Writes ``bench/results/bench_constants.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import subprocess
import sys
import time

MODES = {"literals": "0", "arguments": "1"}


def child(h0: float, level: int) -> dict:
    """Measurements of one (level, mode); the mode comes from the environment."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from hyperoc.cardiac.land import ventricle_problem
    from hyperoc.dynamics.statics import _compiled_solve
    from hyperoc.dynamics.stepper import Scheme
    from hyperoc.solvers.linsolve import make_solver

    model, follower = ventricle_problem(h0, bulk_modulus=1000.0, refinements=level)
    lin = make_solver(model, "auto")
    solve, _ = _compiled_solve(model, lin, Scheme(), (follower,), False, False)
    x0, fk = jnp.zeros(model.n + 1), jnp.zeros(model.n)
    t0 = time.perf_counter()
    solve.lower(x0, fk, 0.0, 1.0).compile()
    compile_s = time.perf_counter() - t0

    u = jnp.asarray(model.interpolate(lambda x: 0.01 * x * x[:, ::-1]))  # smooth, det F > 0
    kernel = jax.jit(lambda u: (model.internal_force(u), model.tangent_blocks(u, 1.0, 0.0)))
    times, out = [], None
    for _ in range(6):
        t0 = time.perf_counter()
        out = jax.block_until_ready(kernel(u))
        times.append(time.perf_counter() - t0)
    digest = hashlib.sha256(b"".join(np.asarray(a).tobytes() for a in out)).hexdigest()
    return {"dofs": model.n, "compile_s": compile_s, "first_s": times[0], "later_s": min(times[1:]),
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "digest": digest}


def run_child(h0: float, level: int, mode: str) -> dict:
    env = dict(os.environ, JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS=MODES[mode])
    proc = subprocess.run([sys.executable, __file__, "--child", "--h0", str(h0), "--levels", str(level)],
                          env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"level {level}, {mode}: the child failed\n{proc.stderr[-2000:]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["folding_alarms"] = proc.stderr.count("Constant folding an instruction is taking")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--h0", type=float, default=6.0, help="Gmsh size of the coarsest LV mesh (mm)")
    ap.add_argument("--levels", default="0,1", help="uniform refinements, comma separated")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    levels = [int(v) for v in args.levels.split(",")]
    if args.child:
        print(json.dumps(child(args.h0, levels[0])))
        return
    from results import Table, command_line, write_results

    runs = Table(f"Land problem 2 (curved P2 LV, h0 = {args.h0:g} mm, bulk modulus 1000 kPa): the Newton solve's "
                 "compilation and the force and tangent kernels, each (level, mode) in a fresh process",
                 ["level", "dofs", "constants", "compile solve (s)", "1st eval (s)", "later eval (s)",
                  "peak RSS (MB)", "constant-folding alarms"],
                 "arguments: JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS=1 (set when hyperoc is imported before JAX); "
                 "literals: JAX's default.")
    ratios = Table("Arguments / literals", ["level", "compile solve", "1st eval", "later eval", "peak RSS",
                                            "force and tangents bitwise equal"])
    for level in levels:
        res = {mode: run_child(args.h0, level, mode) for mode in MODES}
        for mode, r in res.items():
            runs.add(level, r["dofs"], mode, round(r["compile_s"], 2), round(r["first_s"], 2), round(r["later_s"], 3),
                     round(r["peak_mb"]), r["folding_alarms"])
        a, b = res["arguments"], res["literals"]
        ratios.add(level, *(round(a[k] / b[k], 2) for k in ("compile_s", "first_s", "later_s", "peak_mb")),
                   a["digest"] == b["digest"])
    write_results("bench_constants", command_line(), [runs.as_dict(), ratios.as_dict()])


if __name__ == "__main__":
    main()

"""L-BFGS-B iterations against the scaling of tau (`hyperoc.control.optimize.tau_scaling`) on an example.

L-BFGS-B works on the scaled variables ``(sqrt(w) xi, c tau)``; xi's scaling follows the L2 geometry,
tau's factor c is a choice (tau and xi have unrelated units). For each c the script optimizes the
example config from its ``tau0`` to ``--gtol`` (relative projected gradient) within ``--max-iter``
iterations and prints iterations, whether it converged, J, tau, the final gradient ratio, the state
solves and the wall time, and the iterations relative to the first c given (the baseline).
``range`` is the default rule: both blocks normalized to their admissible ranges.

    nice taskset -c 1 python bench/bench_tau_scale.py --scales 1,range --max-iter 120 --gtol 1e-4   # ~13 min
    nice taskset -c 0 python bench/bench_tau_scale.py --scales 0.1,10,30 --max-iter 120 --gtol 1e-4

Writes ``bench/results/bench_tau_scale.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import hyperoc  # noqa: F401  (before JAX: hyperoc._jax sets JAX's flags)
from hyperoc.app.config import load_config
from hyperoc.app.workflows import build_reduced
from hyperoc.control.optimize import BoxProblem, lbfgsb, tau_scaling
from results import Table, command_line, write_results

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "ventricle-3d.toml"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default=str(EXAMPLE))
    ap.add_argument("--scales", default="1,range", help="comma-separated factors c, or 'range'")
    ap.add_argument("--max-iter", type=int, default=120)
    ap.add_argument("--gtol", type=float, default=1e-4)
    args = ap.parse_args()
    cfg = load_config(args.config)
    tau0 = cfg.tau_starts()[0]
    J = build_reduced(cfg, tau0)
    baseline = None
    out = Table(f"L-BFGS-B on {Path(args.config).name} to a relative projected gradient of {args.gtol:g} "
                f"(at most {args.max_iter} iterations) for each scaling c of tau",
                ["c", "iterations", "converged", "J", "tau", "final / initial gradient", "state solves",
                 "wall time (s)", "iterations / first c"],
                "range: the default rule, both blocks normalized to their admissible ranges.")
    for text in args.scales.split(","):
        scale = text.strip() if text.strip() == "range" else float(text)
        tau_range = BoxProblem.around(J, tau0, tau_margin=cfg["optimize"].get("tau_margin")).tau_range
        c = tau_scaling(J, scale, tau_range, cfg.xi_bounds())
        before = J.counts["state"]
        t0 = time.perf_counter()
        res = lbfgsb(J, J.zero(tau0), xi_bounds=cfg.xi_bounds(), gtol=args.gtol, max_iter=args.max_iter,
                     tau_scale=scale)
        seconds = time.perf_counter() - t0
        g = res.history["grad_norm"]
        baseline = baseline or res.iterations
        label = f"range ({c:.4g})" if scale == "range" else f"{c:g}"
        out.add(label, res.iterations, bool(res.converged), round(res.objective, 8), round(res.point.tau, 4),
                float(f"{g[-1] / g[0]:.2e}"), J.counts["state"] - before, round(seconds),
                round(res.iterations / baseline, 2))
    write_results("bench_tau_scale", command_line(), [out.as_dict()])


if __name__ == "__main__":
    main()

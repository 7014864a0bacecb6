"""How far does a round-off-sized change move the end point of the paper's bounded variant?

The bounded variant of `hyperoc reproduce paper-1d` (projected Algorithm 1, ``|xi| <= 0.05``, 100
iterations, not converged) is run from ``tau0 = 7.5 (1 + k eps)`` for a few k, eps = 2^-52: the
starting points differ by k units in the last place of tau0 and nothing else. Printed: the end
point (tau, J), the iterations, the projected gradient at the end, min det F, and the first
iteration at which the iterate differs from the unperturbed run's by more than 1e-6 in tau.

    taskset -c 0 python bench/probe_roundoff.py              # ~3 min
"""

from __future__ import annotations

import argparse

import numpy as np

import hyperoc  # noqa: F401  (before JAX: hyperoc._jax sets JAX's flags)
from hyperoc.paper import bounded_config
from hyperoc.workflows import optimize_single


def run(cfg, tau0: float) -> tuple[dict, float]:
    """The bounded variant from (0, tau0): its summary and min det F of its end state."""
    J, res = optimize_single(cfg, tau0)
    return res.summary(), float(J.state(res.point).min_det_F.min())


def first_departure(taus, reference, tol: float = 1e-6):
    """First iteration whose tau differs from the reference run's by more than ``tol``, or None."""
    n = min(len(taus), len(reference))
    far = np.flatnonzero(np.abs(np.asarray(taus[:n]) - np.asarray(reference[:n])) > tol)
    return int(far[0]) if far.size else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ulps", default="0,1,4,16", help="k: tau0 = 7.5 (1 + k 2^-52)")
    args = parser.parse_args()
    cfg = bounded_config()
    tau0 = float(cfg["optimize"]["tau0"])
    print(f"{'k':>3} {'tau0':>20} {'tau':>9} {'J':>9} {'its':>4} {'|g| end':>8} {'min det F':>9} {'departs at':>10}")
    reference = None
    for k in map(int, args.ulps.split(",")):
        start = tau0 * (1 + k * np.finfo(float).eps)
        s, mindet = run(cfg, start)
        reference = reference or s["tau_history"]
        print(f"{k:>3} {float(start)!r:>20} {s['tau']:>9.5f} {s['objective']:>9.6f} {s['iterations']:>4} "
              f"{s['grad_norm_history'][-1]:>8.3g} {mindet:>9.3f} {first_departure(s['tau_history'], reference)!s:>10}",
              flush=True)

if __name__ == "__main__":
    main()

"""The bounded variant of the paper's problem with tau held fixed: does the control problem alone converge,
and is J smooth where it stops?

For each tau, L-BFGS-B on xi only (``fix_tau=True``, ``|xi| <= 0.05``) from xi = 0; printed: J, iterations,
the stationarity measure ``||P(m + G) - m||`` at the start and the end, evaluations, seconds. With
``--probe``, at the end point of the first tau: J along two directions that keep the active bounds (the
derivative with its active-bound components removed, and a random one), scaled to a largest change of
0.01 at h = 1: the Taylor remainder ``J(m + h dm) - J(m) - h dJ`` and ``remainder / h^2`` (constant for a
smooth J: its curvature along dm).

    taskset -c 1 python bench/probe_fixed_tau.py --taus 5 7.5 10 12.5 14.9 --max-iter 300
    taskset -c 1 python bench/probe_fixed_tau.py --taus 7.5 --max-iter 150 --probe
    taskset -c 1 python bench/probe_fixed_tau.py --taus 7.5 --max-iter 150 --residual

``--residual``: where the projected gradient of the end point lies (`residual_structure`).
``--hessian``: the curvature ``<v, H v>`` there along the free gradient and a random free direction, by forward
and central differences of the exact gradient at 1 to 10^4 times `hyperoc.optimize.newton_cg`'s step
(`hessian_accuracy`):

    taskset -c 1 python bench/probe_fixed_tau.py --taus 7.5 --max-iter 150 --hessian
"""

import argparse
import json
import time

import numpy as np

import hyperoc as ho
from hyperoc.optimize import LumpedMetric, _free_values, _masked, _project
from hyperoc.paper import XI_MAX, bounded_config
from hyperoc.workflows import build_reduced


def optimize_fixed_tau(tau, max_iter):
    J = build_reduced(bounded_config(), tau)
    started = time.perf_counter()
    res = ho.lbfgsb(J, J.zero(tau), xi_bounds=(-XI_MAX, XI_MAX), fix_tau=True, max_iter=max_iter)
    g = res.history["grad_norm"]
    print(json.dumps({"tau": tau, "J": res.objective, "iterations": res.iterations, "converged": res.converged,
                      "stationarity_first_last": [g[0], g[-1]], "evaluations": res.evaluations,
                      "seconds": round(time.perf_counter() - started, 1)}), flush=True)
    return J, res.point


def probe_smoothness(J, m, seed=0):
    J0, d = J.value_and_derivative(m)
    active = np.abs(m.xi) >= XI_MAX * (1 - 1e-12)
    outward = active & (np.sign(m.xi) == np.sign(d.xi))
    free_derivative = np.where(outward, 0.0, d.xi)
    random = np.where(active, 0.0, np.random.default_rng(seed).standard_normal(m.xi.shape))
    print(f"J = {J0:.6g}; control values at a bound: {active.mean():.3f}")
    for name, direction in (("derivative without its active-bound part", free_derivative),
                            ("random, off the active set", random)):
        dx = direction / np.abs(direction).max() * 0.01
        dJ = float(np.sum(d.xi * dx))
        print(f"{name}: dJ = {dJ:.4e}")
        for h in (1.0, 0.1, 0.01, 1e-3, 1e-4):
            rem = J(m + ho.ControlPoint(dx, 0.0) * h) - J0 - h * dJ
            print(f"  h = {h:7.0e}   remainder {rem: .3e}   remainder / h^2 {rem / h**2: .4e}")


def residual_structure(J, m, windows=10):
    """Where the projected gradient ``r = P(m + G) - m`` (lumped metric, `hyperoc.optimize.LumpedMetric`) of
    the end point lies: per window of s in (0, 1) (s = 1 is tau), its share of ``||r||^2``, the largest |xi| and
    |G| there and the share of values on a bound; then the share of ``||r||^2`` carried by the free values
    with ``|G|`` larger than the box's half-width (values the gradient still pushes hard)."""
    metric = LumpedMetric(J)
    G = metric.gradient(J.value_and_gradient(m)[1])
    r = _project(J, m + G, (m.tau, m.tau), (-XI_MAX, XI_MAX)) - m
    share = metric.weights * r.xi**2
    total = share.sum()
    s = np.concatenate([[0.0], np.cumsum(J.transform.ds())])
    on_bound = np.abs(m.xi) >= XI_MAX * (1 - 4 * np.finfo(float).eps)
    print(f"projected gradient {np.sqrt(total):.4g}; by window of s (s = 1 is tau):")
    for lo, hi in zip(np.linspace(0, 1, windows + 1)[:-1], np.linspace(0, 1, windows + 1)[1:]):
        k = (s >= lo) & (s < hi)
        print(f"  s in [{lo:.1f}, {hi:.1f}): share {share[k].sum() / total:.3f}  max|xi| {np.abs(m.xi[k]).max():.4f}  "
              f"max|G| {np.abs(G.xi[k]).max():.3g}  on a bound {on_bound[k].mean():.2f}")
    print(f"  s >= 1: share {share[s >= 1].sum() / total:.3f}")
    pushed = ~on_bound & (np.abs(G.xi) > XI_MAX)
    print(f"free values with |G| > {XI_MAX}: {pushed.mean():.3f} of all values, share "
          f"{share[pushed].sum() / total:.3f}")


def hessian_accuracy(J, m):
    """Curvatures along unit directions (lumped metric) on the free values: forward against central differences."""
    metric = LumpedMetric(J)
    G = metric.gradient(J.value_and_gradient(m)[1])
    free = _free_values(J, m, G, (m.tau, m.tau), (-XI_MAX, XI_MAX))
    random = ho.ControlPoint(np.random.default_rng(0).standard_normal(m.xi.shape), 0.0)
    for name, v in (("free gradient", _masked(G, free)), ("random free direction", _masked(random, free))):
        v = v * (1.0 / metric.norm(v))
        h0 = np.sqrt(np.finfo(float).eps) * (1 + max(np.abs(m.xi).max(), m.tau)) / np.abs(v.xi).max()
        print(f"{name}: newton_cg's step h0 = {h0:.3g}")
        for factor in (1, 10, 100, 1000, 1e4):
            h = h0 * factor
            plus, minus = (metric.gradient(J.value_and_gradient(m + v * (sign * h))[1]) for sign in (1, -1))
            forward, central = (plus - G) * (1 / h), (plus - minus) * (0.5 / h)
            print(f"  h = {factor:g} h0: <v, Hv> forward {metric.inner(v, forward): .6e}, central "
                  f"{metric.inner(v, central): .6e}, |forward - central| / |central| "
                  f"{metric.norm(forward - central) / metric.norm(central):.2e}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--taus", type=float, nargs="+", default=[5.0, 7.5, 10.0, 12.5, 14.9])
    parser.add_argument("--max-iter", type=int, default=300)
    parser.add_argument("--probe", action="store_true", help="probe J's smoothness at the first tau's end point")
    parser.add_argument("--residual", action="store_true",
                        help="where the projected gradient lies at the first tau's end point")
    parser.add_argument("--hessian", action="store_true",
                        help="forward against central Hessian-vector products at the first tau's end point")
    args = parser.parse_args()
    for k, tau in enumerate(args.taus):
        J, m = optimize_fixed_tau(tau, args.max_iter)
        if args.probe and k == 0:
            probe_smoothness(J, m)
        if args.residual and k == 0:
            residual_structure(J, m)
        if args.hessian and k == 0:
            hessian_accuracy(J, m)


if __name__ == "__main__":
    main()

"""Bounded optimization on a problem with a nondegenerate maximizer: do projected BB and L-BFGS-B
reach the same KKT point, and does the stationarity measure say so?

`hyperoc.problems.vibrating_bar` (h = 0.05, dt = 0.1) with ``|xi| <= b``, b half the largest value
of the unconstrained maximizer (so that bounds are active), both optimizers from (0, 2) to
``gtol = 1e-6``. Printed per optimizer: converged, iterations, J, tau, the projected gradient
``||P(m + G) - m||`` at the start and the end, the share of control values on a bound, and the
largest ``|dJ/dxi_i| / w_i`` (the derivative in the lumped metric) over the free values at the end
point (zero at a KKT point). The measure and the steps are those of the code on the path: run it
against an older commit with ``PYTHONPATH=<its worktree>`` to compare.

    python bench/probe_bounded_metric.py
"""

import numpy as np

import hyperoc as ho
from hyperoc.problems import vibrating_bar


def main():
    J = vibrating_bar(0.05, 0.1)
    free_max = ho.lbfgsb(J, J.zero(2.0), max_iter=200, gtol=1e-7)
    b = 0.5 * np.max(np.abs(free_max.point.xi))
    weights = J.s_weights[:, None] * J.model.control.lumped_mass[None, :]
    print(f"bound b = {b:.6g}")
    for name, run in (("lbfgsb", ho.lbfgsb), ("bb", ho.barzilai_borwein)):
        res = run(J, J.zero(2.0), max_iter=400, gtol=1e-6, xi_bounds=(-b, b))
        d = J.dual(J.value_and_gradient(res.point)[1]).xi / weights
        on_bound = np.abs(res.point.xi) >= b * (1 - 4 * np.finfo(float).eps)
        g = res.history["grad_norm"]
        print(f"{name:7s} converged {res.converged!s:5s} iterations {res.iterations:3d} J {res.objective:.15g} "
              f"tau {res.point.tau:.10f} measure {g[0]:.3e} -> {g[-1]:.3e} on bound {on_bound.mean():.3f} "
              f"max free |dJ/dxi| / w {np.max(np.abs(d[~on_bound])):.2e}")


if __name__ == "__main__":
    main()

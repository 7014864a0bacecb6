"""Projected Newton-CG against L-BFGS-B and SPG on `hyperoc.problems.vibrating_bar`, without bounds and with
active bounds ``|xi| <= b`` (b half the largest value of the unconstrained maximizer Newton-CG finds, as
in tests/test_optimize.py), all to ``gtol = 1e-8`` from (0, 2). Printed per run: iterations, state solves
(Newton-CG: of which Hessian-vector products), the projected gradient relative to its start at the end
and at its least, J, tau, and the last steps.

    python bench/probe_newton_cg.py

``--paper N``: instead, N Newton-CG iterations on the paper's bounded variant from (0, 7.5) (as
``hyperoc optimize examples/paper-1d.toml --method newton --set "optimize.xi_bounds=[-0.05, 0.05]"``), then the
structure of the end point: the share of control values on a bound, per sixth control node the number of
switches of its bound status along s, and where the projected gradient lies (`probe_fixed_tau.residual_structure`):

    taskset -c 1 python bench/probe_newton_cg.py --paper 300 [--restart 40]

``--restart K``: then K more iterations started afresh from that end point (J, measure, message, counts).
"""

import argparse

import numpy as np
from probe_fixed_tau import residual_structure

import hyperoc as ho
from hyperoc.paper import XI_MAX, bounded_config
from hyperoc.problems import vibrating_bar
from hyperoc.workflows import build_reduced


def report(name, res):
    g = np.array(res.history["grad_norm"])
    ev = res.evaluations
    solves = f"{ev['state_solves']}" + (f" ({ev['hessian_products']})" if "hessian_products" in ev else "")
    print(f"| {name} | {res.iterations} | {solves} | {g[-1] / g[0]:.1e} ({g.min() / g[0]:.1e}) "
          f"| {res.objective:.12f} | "
          f"{res.point.tau:.7f} | {', '.join(f'{s:.2g}' for s in res.history['step'][-3:])} |")


def paper_end_point(iterations, restart=0):
    J = build_reduced(bounded_config(), 7.5)
    res = ho.newton_cg(J, J.zero(7.5), xi_bounds=(-XI_MAX, XI_MAX), max_iter=iterations)
    print(f"J = {res.objective:.8g}, tau = {res.point.tau:.6g}, {res.evaluations}")
    status = np.sign(res.point.xi) * (np.abs(res.point.xi) >= XI_MAX * (1 - 1e-12))  # +-1 on a bound, 0 free
    print(f"values on a bound: {np.abs(status).mean():.3f} (upper {(status > 0).mean():.3f}, lower "
          f"{(status < 0).mean():.3f})")
    for node in range(0, status.shape[1], 5):
        print(f"  control node {node}: {np.count_nonzero(np.diff(status[:, node]))} switches of bound status along s")
    residual_structure(J, res.point)
    if restart:
        again = ho.newton_cg(J, res.point, xi_bounds=(-XI_MAX, XI_MAX), max_iter=restart)
        print(f"restart: {again.iterations} iterations, J = {again.objective:.9g}, tau = {again.point.tau:.6g}, "
              f"projected gradient {again.history['grad_norm'][0]:.3g} -> {again.history['grad_norm'][-1]:.3g} "
              f"(least {min(again.history['grad_norm']):.3g}); {again.message}; {again.evaluations}")


def vibrating_bar_table():
    runs = {"Newton-CG": lambda J, **k: ho.newton_cg(J, J.zero(2.0), max_iter=100, **k),
            "L-BFGS-B": lambda J, **k: ho.lbfgsb(J, J.zero(2.0), max_iter=200, **k),
            "SPG (M = 10)": lambda J, **k: ho.barzilai_borwein(J, J.zero(2.0), max_iter=400, nonmonotone=10, **k)}
    print("| bounds | method | iterations | state solves (Hessian products) | measure end (least) / start "
          "| J | tau | last steps |")
    print("|---|---|---|---|---|---|---|---|")
    ref = None
    for bounded in (False, True):
        for name, run in runs.items():
            J = vibrating_bar(0.05, 0.1)  # a fresh functional: solve counts per run
            if bounded:
                b = 0.5 * np.max(np.abs(ref.xi))
                res = run(J, gtol=1e-8, xi_bounds=(-b, b))
            else:
                res = run(J, gtol=1e-8)
                ref = res.point if name == "Newton-CG" else ref  # the one that converges to 1e-8
            print("| active " if bounded else "| none ", end="")
            report(name, res)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--paper", type=int, metavar="N", help="N iterations on the paper's bounded variant instead")
    parser.add_argument("--restart", type=int, default=0, metavar="K", help="with --paper: K more from the end point")
    args = parser.parse_args()
    if args.paper:
        paper_end_point(args.paper, args.restart)
    else:
        vibrating_bar_table()


if __name__ == "__main__":
    main()

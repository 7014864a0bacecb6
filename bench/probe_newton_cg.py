"""Projected Newton-CG against L-BFGS-B and SPG on `hyperoc.problems.vibrating_bar`, without bounds and with
active bounds ``|xi| <= b`` (b half the largest value of the unconstrained maximizer Newton-CG finds, as
in tests/test_optimize.py), all to ``gtol = 1e-8`` from (0, 2). Printed per run: iterations, state solves
(Newton-CG: of which Hessian-vector products), the projected gradient relative to its start at the end
and at its least, J, tau, and the last steps.

    python bench/probe_newton_cg.py
"""

import numpy as np

import hyperoc as ho
from hyperoc.problems import vibrating_bar


def report(name, res):
    g = np.array(res.history["grad_norm"])
    ev = res.evaluations
    solves = f"{ev['state_solves']}" + (f" ({ev['hessian_products']})" if "hessian_products" in ev else "")
    print(f"| {name} | {res.iterations} | {solves} | {g[-1] / g[0]:.1e} ({g.min() / g[0]:.1e}) | {res.objective:.12f} | "
          f"{res.point.tau:.7f} | {', '.join(f'{s:.2g}' for s in res.history['step'][-3:])} |")


def main():
    runs = {"Newton-CG": lambda J, **k: ho.newton_cg(J, J.zero(2.0), max_iter=100, **k),
            "L-BFGS-B": lambda J, **k: ho.lbfgsb(J, J.zero(2.0), max_iter=200, **k),
            "SPG (M = 10)": lambda J, **k: ho.barzilai_borwein(J, J.zero(2.0), max_iter=400, nonmonotone=10, **k)}
    print("| bounds | method | iterations | state solves (Hessian products) | measure end (least) / start | J | tau | last steps |")
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


if __name__ == "__main__":
    main()

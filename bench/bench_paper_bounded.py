"""The paper's problem with the paper's bound (Remark rk-box as ``|xi| <= XI_MAX``, alpha = 2e-3, beta = 0):
its KKT points under refinement, and which method reaches them.

Every run is projected Newton-CG (`hyperoc.app.paper.FORMULATIONS`) to a relative projected gradient of 1e-6,
on the paper's setup with ``--formulation`` (``bounded``: omega = [0.75, 1] as in the paper's experiment;
``interior``: omega = [0.75, 0.95], compactly inside as its theory assumes; ``smooth``: the job's headline,
alpha = beta = 10 without a bound, e.g. from ``--tau0 11`` near its global maximum) and ``--observation`` (how
p(tau) is read from the step pressures: ``centred`` or ``causal``). Grids keep the wave speed's Courant
number ``c dt / h <= 1`` (c = sqrt((lambda + 2 mu) / rho) = 0.387), where the mass and time-stepping phase
errors do not add up.

    python bench/bench_paper_bounded.py --study ratio   # (h, dt) = (0.02, 0.04), (0.01, 0.02), (0.005, 0.01)
                                                        # (--levels 4: and (0.0025, 0.005))
    python bench/bench_paper_bounded.py --study dt      # h = 0.01, dt = 0.02 .. 0.0025, from tau0 = 6.3 and 7.5
    python bench/bench_paper_bounded.py --study grid    # the 3 x 3 grid h x dt at c dt / h <= 1, cold starts
    python bench/bench_paper_bounded.py --study methods # Newton-CG against L-BFGS-B, cold, two grids
    python bench/bench_paper_bounded.py --study mode    # the discrete control that loads only the wall node
    python bench/bench_paper_bounded.py --study weights --formulation smooth --tau0 11
                                                        # alpha = beta = 10, 100, 1000 on the paper's grid

``ratio`` and ``dt`` refine along a sequence, each run warm-started from the previous one's control
(`hyperoc.app.paper.transferred_control`) and stopped at 1e-6 times the projected gradient of the zero
control on its own grid (the same test as a cold start's); they report successive differences of tau* and
J*, the observed order and the Richardson estimate. ``grid`` starts every run cold and reports iterations
against their median. ``weights`` scales both weights of the formulation's cost (the smooth one's
alpha = beta) by 1, 10 and 100, cold from ``--tau0`` on the paper's grid: where the state is linear in the
control, J* scales by their inverse and tau* stays. ``mode``: the P1 control ``xi_{N-k} = r^k`` on
omega = [0.75, 1], r = -(2 - sqrt 3) (the root of r^2 + 4 r + 1 = 0, so the consistent load
h/6 (xi_{j-1} + 4 xi_j + xi_{j+1}) vanishes at every interior node), held on [6.5, 7.5]: its nodal loads and
p(7.5), det F under it. Results:
``bench_paper_bounded_<study>.json`` (``--levels`` keeps the first levels of a sequence).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench_wellposed import refinement_rows
from hyperoc.app.paper import PAPER_REPORT, formulation_config, transferred_control
from hyperoc.app.workflows import build_reduced
from hyperoc.control.optimize import BoxProblem, NewtonCGOptions, lbfgsb, newton_cg, stationarity
from hyperoc.control.reduced import ControlPoint
from results import command_line, table, write_results

WAVE_SPEED = np.sqrt(0.15)  # sqrt((lambda + 2 mu) / rho) of the paper's bar
COLUMNS = ["formulation", "observation", "method", "h", "dt", "c dt / h", "tau0", "start", "tau*", "J*",
           "iterations", "KKT (rel. projected gradient)", "converged", "min det F", "max |xi|", "state solves",
           "wall (s)"]
TAU, J_STAR, ITERATIONS = 8, 9, 10  # columns of a row


def solve(formulation: str, observation: str, h: float, dt: float, tau0: float, *, method: str = "newton",
          warm=None, max_iter: int = 300, changes: dict | None = None) -> tuple[list, tuple]:
    """One run from ``(0, tau0)`` or from ``warm = (J, point)`` transferred to this grid (``changes``: more
    configuration entries); its row and ``(J, point)``."""
    cfg = formulation_config(formulation, {"mesh.n": int(round(1 / h)), "dynamics.dt": dt,
                                           "objective.observation": observation, **(changes or {})})
    tau = tau0 if warm is None else warm[1].tau
    J = build_reduced(cfg, tau)
    bounds, tau_range = cfg.xi_bounds(), BoxProblem.around(J, tau).tau_range  # the optimizers' own range
    zero = J.zero(tau)
    cold = stationarity(J, zero, J.value_and_gradient(zero)[1], tau_range, bounds)
    m0 = zero if warm is None else ControlPoint(transferred_control(*warm, J, tau), tau)
    started = time.perf_counter()
    if method == "newton":
        res = newton_cg(J, m0, xi_bounds=bounds, gtol=0.0, gtol_abs=1e-6 * cold, max_iter=max_iter,
                        options=NewtonCGOptions(max_cg=20))
    else:  # cold starts only: its test relative to its start is the same
        res = lbfgsb(J, m0, xi_bounds=bounds, gtol=1e-6, max_iter=max_iter)
    wall = time.perf_counter() - started
    sol = J.state(res.point)
    k = J.transform.tau_index
    row = [formulation, observation, method, h, dt, WAVE_SPEED * dt / h, tau0, "cold" if warm is None else "warm",
           res.point.tau, res.objective, res.iterations, res.history["grad_norm"][-1] / cold,
           bool(res.history["grad_norm"][-1] <= 1e-6 * cold), float(sol.min_det_F[:k + 1].min()),
           float(np.abs(res.point.xi).max()), res.evaluations["state_solves"], wall]
    print("  ".join(f"{v:.6g}" if isinstance(v, float) else str(v) for v in row), flush=True)
    return row, (J, res.point)


def sequence(args, grids: list, tau0: float) -> list:
    """Runs along ``grids``, each warm-started from the previous one."""
    rows, warm = [], None
    for h, dt in grids:
        row, warm = solve(args.formulation, args.observation, h, dt, tau0, warm=warm)
        rows.append(row)
    return rows


def convergence(label: str, rows: list) -> list:
    """Successive differences, observed order and Richardson estimate of tau* and J* (three levels)."""
    if len(rows) < 3:
        return []
    return [refinement_rows(f"{name}: {label}", rows[-3:], key) for name, key in (("tau*", TAU), ("J*", J_STAR))]


def wall_mode(h: float, dt: float = 0.02, tau: float = 7.5) -> list:
    """The row of the ``mode`` table at mesh size h."""
    J = build_reduced(formulation_config("as_stated", {"mesh.n": int(round(1 / h)), "dynamics.dt": dt}), tau)
    x = J.model.control.coordinates(J.model.space)[:, 0]
    xi = (-(2 - np.sqrt(3))) ** np.round((1.0 - x) / h)  # xi_N = 1 at the wall
    load = np.abs(J.model.control.load @ xi)
    wall = int(np.argmax(load))  # the reduced dof the mode loads
    others = np.delete(load, wall).max()
    on = (J.transform.grid(tau).t > 6.5)[:, None]
    sol = J.state(ControlPoint(on * xi[None, :], tau))
    k = J.transform.tau_index
    return [h, load[wall] / h, np.sqrt(3) / 6, others, float(sol.pressure[k]),
            float(np.abs(sol.min_det_F[:k + 1] - 1).max())]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", choices=("ratio", "dt", "grid", "methods", "mode", "weights"), required=True)
    ap.add_argument("--formulation", choices=("bounded", "interior", "smooth"), default="bounded")
    ap.add_argument("--observation", choices=("centred", "causal"), default="centred")
    ap.add_argument("--levels", type=int, default=None,
                    help="keep the first LEVELS grids of a sequence (ratio: 3 of 4 by default)")
    ap.add_argument("--tau0", default=None, help="comma-separated starts (default 7.5; dt study: 6.3,7.5)")
    args = ap.parse_args()
    name = f"bench_paper_bounded_{args.study}_{args.formulation}_{args.observation}" + (
        f"_tau0_{args.tau0.replace(',', '_')}" if args.tau0 else "")
    cost = formulation_config(args.formulation)["objective"]
    setup = f"{args.formulation}, observation {args.observation}, alpha = {cost['alpha']:g}, beta = {cost['beta']:g}"
    conv_columns = ["sequence", "coarse", "middle", "fine", "difference 1", "difference 2", "observed order",
                    "Richardson estimate"]
    if args.study in ("ratio", "dt"):
        ratio = [(0.02, 0.04), (0.01, 0.02), (0.005, 0.01), (0.0025, 0.005)]
        grids = (ratio[:args.levels or 3] if args.study == "ratio"
                 else [(0.01, dt) for dt in (0.02, 0.01, 0.005, 0.0025)][:args.levels])
        starts = [float(t) for t in (args.tau0 or ("7.5" if args.study == "ratio" else "6.3,7.5")).split(",")]
        runs = {tau0: sequence(args, grids, tau0) for tau0 in starts}
        label = "h and dt halved (c dt / h = 0.77)" if args.study == "ratio" else "dt halved at h = 0.01"
        conv = [r for tau0, rows in runs.items() for r in convergence(f"{label}, tau0 = {tau0:g}", rows)]
        write_results(name, command_line(), [
            table(f"{setup}: Newton-CG along the refinement, each level warm-started from the previous",
                  COLUMNS, [r for rows in runs.values() for r in rows]),
            table("Convergence of the KKT point under refinement (the last three levels)", conv_columns, conv,
                  f"the paper reports tau ~ {PAPER_REPORT['tau']}")])
    elif args.study == "weights":
        cost = formulation_config(args.formulation)["objective"]
        rows = [solve(args.formulation, args.observation, 0.01, 0.02, float(args.tau0 or 7.5),
                      changes={"objective.alpha": s * cost["alpha"], "objective.beta": s * cost["beta"]})[0]
                + [s * cost["alpha"], s * cost["beta"]] for s in (1.0, 10.0, 100.0)]
        write_results(name, command_line(), [table(
            f"{args.formulation}: both weights of the cost scaled, Newton-CG cold from tau0 = {args.tau0 or 7.5} "
            "on the paper's grid", COLUMNS + ["alpha", "beta"], rows,
            "small amplitude (a state linear in the control): J* times the weights constant, tau* unchanged")])
    elif args.study == "mode":
        rows = [wall_mode(h) for h in (0.02, 0.01, 0.005)]
        for r in rows:
            print(r)
        write_results("bench_paper_bounded_mode", command_line(), [table(
            "The control xi_{N-k} = (-(2 - sqrt 3))^k on omega = [0.75, 1] (xi = 1 at the wall), held on [6.5, 7.5]",
            ["h", "wall node load / h", "sqrt(3)/6", "largest other nodal load", "p(7.5)", "max |det F - 1| to 7.5"],
            rows, "the load reaches only the constrained node, whose reaction is p: p rises with no strain")])
    elif args.study == "grid":
        hs = (0.02, 0.01, 0.005)[:args.levels]
        rows = [solve(args.formulation, args.observation, h, dt, 7.5)[0] for h in hs
                for dt in (2 * h, h, h / 2)]
        median = float(np.median([r[ITERATIONS] for r in rows]))
        write_results(name, command_line(), [
            table(f"{setup}: Newton-CG from (0, 7.5) on the grid h x dt (c dt / h <= 0.77)", COLUMNS, rows),
            table("Iterations against their median", ["h", "dt", "iterations", "relative to the median"],
                  [[r[3], r[4], r[ITERATIONS], r[ITERATIONS] / median - 1] for r in rows])])
    else:
        rows = [solve(args.formulation, args.observation, h, dt, 7.5, method=method)[0]
                for h, dt in ((0.02, 0.04), (0.01, 0.02))[:args.levels] for method in ("newton", "lbfgsb")]
        write_results(name, command_line(), [
            table(f"{setup}: projected Newton-CG and L-BFGS-B from (0, 7.5), 300 iterations at most", COLUMNS,
                  rows)])


if __name__ == "__main__":
    main()

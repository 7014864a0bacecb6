"""State solves on the sparse path: 2D annulus P2 (~20k dofs) and 3D thick shell P1 (~30k dofs).

Per linear-solver variant: seconds per step, per Newton iteration and per dof-step, and the split
between the host linear solve (`SparseSolver.stats`: blocks -> matrix, factorization, solves and
refinement) and the rest of the step (JAX: element tangents, residuals, line search, callback).
Ratios are against a baseline run in this same script: ``lu_colamd``, a plain sparse LU (CSR -> CSC
conversion and a COLAMD ordering at every factorization, a subclass defined here).

    python bench/bench_2d3d.py --case 2d                        # 500 steps, every variant
    python bench/bench_2d3d.py --case 3d --steps 10             # fewer steps (per-step figures)
    python bench/bench_2d3d.py --case 2d --methods lu,lu_reuse --steps 500

Writes ``bench/results/bench_2d3d_<case>.json`` (`bench/results.py`; not with ``--solver-only``).

Variants: ``lu_colamd`` (baseline), ``minres_amg`` (previous MINRES: smoothed-aggregation AMG of
|K| set up at every call), ``lu_mmd`` (``lu`` with the minimum-degree ordering instead of
nested dissection), and the current ``SparseSolver`` methods ``lu``, ``lu_reuse``,
``minres`` (see hyperoc/solvers/linsolve.py). All variants of one invocation run the same steps; the
first step of each is run once before timing (JIT compilation), then the solver is reset.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import scipy.sparse.linalg as spla

import hyperoc as ho
from hyperoc.fem.geometry import annulus, thick_shell
from hyperoc.solvers.linsolve import SparseSolver


class BaselineLU(SparseSolver):
    """The sparse LU as it was: CSR -> CSC and SuperLU with its default COLAMD ordering per call."""

    def host_solve(self, blocks, col, row, r_u, r_c):
        t0 = time.perf_counter()
        K = self.pattern.matrix(np.asarray(blocks)).tocsc()
        t1 = time.perf_counter()
        rhs = np.stack([np.asarray(r_u), np.asarray(col)], axis=1)
        lu = spla.splu(K)
        t2 = time.perf_counter()
        ab = lu.solve(rhs)
        t3 = time.perf_counter()
        a, b = ab[:, 0], ab[:, 1]
        row = np.asarray(row)
        q = (row @ a - float(r_c)) / (row @ b)
        s = self.stats
        s["calls"] += 1
        s["factorizations"] += 1
        s["assembly_s"] += t1 - t0
        s["factor_s"] += t2 - t1
        s["solve_s"] += t3 - t2
        s["host_s"] += time.perf_counter() - t0
        return np.concatenate([a - b * q, [q]])


class BaselineMinresAMG(SparseSolver):
    """The previous MINRES: SA-AMG of |K| built at every call, scipy's MINRES to rtol = 1e-13."""

    def host_solve(self, blocks, col, row, r_u, r_c):
        import pyamg

        t0 = time.perf_counter()
        K = self.pattern.matrix(np.asarray(blocks)).tocsc()
        t1 = time.perf_counter()
        ml = pyamg.smoothed_aggregation_solver(abs(K).tocsr(), symmetry="symmetric")
        t2 = time.perf_counter()
        out = []
        for rhs in (np.asarray(r_u), np.asarray(col)):
            count = [0]
            x, info = spla.minres(K, rhs, M=ml.aspreconditioner(), rtol=1e-13, maxiter=2000,
                                  callback=lambda _: count.__setitem__(0, count[0] + 1))
            self.stats["iterations"] += count[0]
            if info != 0:
                raise np.linalg.LinAlgError(f"MINRES did not converge (info = {info})")
            out.append(x)
        t3 = time.perf_counter()
        a, b = out
        row = np.asarray(row)
        q = (row @ a - float(r_c)) / (row @ b)
        s = self.stats
        s["calls"] += 1
        s["assembly_s"] += t1 - t0
        s["factor_s"] += t2 - t1  # AMG setup
        s["solve_s"] += t3 - t2
        s["host_s"] += time.perf_counter() - t0
        return np.concatenate([a - b * q, [q]])


def solver_for(model, name):
    if name == "lu_colamd":
        return BaselineLU(model, "lu")
    if name == "minres_amg":
        return BaselineMinresAMG(model, "minres")
    if name == "lu_mmd":  # minimum degree instead of the default nested dissection
        return SparseSolver(model, "lu", ordering="mmd")
    return SparseSolver(model, name)


def case_2d():
    """Annulus r in (0.5, 1), 16 x 152 structured cells, P2; outer circle clamped; active stress on a sector."""
    mesh = annulus(0.5, 1.0, structured=True, n_radial=16, n_theta=152)
    control = ho.ActiveStress(ho.Region("sector", r_range=(0.5, 1.0), theta_range=(-0.8, 0.8)))
    model = ho.StateModel(mesh, ho.NeoHookean(1.0, 5.0), degree=2, damping=0.01, control=control)
    T, dt, steps = 10.0, 0.02, 500
    profile = lambda t: 0.2 * np.sin(np.pi * t / 2) ** 2  # smooth, starts at rest
    return model, T, dt, steps, lambda t: profile(t)[:, None] * np.ones((1, model.control.size))


def case_3d(h=0.063):
    """Thick spherical shell r in (0.5, 1), Gmsh h = 0.063, P1; outer sphere clamped; body force on the cap z > 0.6."""
    mesh = thick_shell(0.5, 1.0, h=h)
    control = ho.BodyForce(ho.Region("box", lower=(-1.0, -1.0, 0.6), upper=(1.0, 1.0, 1.0)))
    model = ho.StateModel(mesh, ho.NeoHookean(1.0, 5.0), degree=1, damping=0.01, control=control)
    T, dt, steps = 2.0, 0.01, 200
    direction = np.tile([0.0, 0.0, -1.0], model.control.size // 3)  # push the cap inwards

    def xi(t):
        return 0.5 * np.sin(np.pi * t / 2)[:, None] ** 2 * direction[None, :]

    return model, T, dt, steps, xi


def run_variant(model, grid, xi, name):
    solver = solver_for(model, name)
    st = ho.TimeStepper(model, ho.Scheme(newton="full"), solver)  # the linear solvers compared on full Newton
    t0 = time.perf_counter()
    st.run(ho.TimeGrid(grid.t[:2]), xi[:2], diagnose=False)  # JIT compilation (and the ordering: set-up)
    setup = time.perf_counter() - t0
    solver._lu = None  # no factorization carried into the timed run
    solver.reset_stats()
    t0 = time.perf_counter()
    sol = st.run(grid, xi, diagnose=False)
    wall = time.perf_counter() - t0
    s = dict(solver.stats)
    its = int(np.sum(sol.newton_iterations))
    steps = grid.num_steps
    return {"method": name, "dofs": model.n, "steps": steps, "wall_s": wall, "setup_s": setup, "newton_its": its,
            "s_per_step": wall / steps, "s_per_newton": wall / its, "us_per_dof_step": 1e6 * wall / (steps * model.n),
            "linear_s": s["host_s"], "jax_s": wall - s["host_s"], "linear_frac": s["host_s"] / wall, **s,
            "pressure_final": float(sol.pressure[-1]), "volume_drift": sol.volume_drift(),
            "min_det_F": float(np.min(sol.min_det_F))}


def solver_only(model, dt, methods, reps):
    """Host linear solve alone, on the step matrix at rest, variants interleaved (A B C A B C ...) so that
    load drift on a shared machine hits them alike; each variant gets one untimed call first."""
    import jax.numpy as jnp

    st = ho.TimeStepper(model, ho.Scheme(), "dense" if model.n < 600 else "lu")
    x = jnp.zeros(model.n + 1)
    blocks, col, row = (np.asarray(a) for a in st.jacobian_parts(x, jnp.zeros(model.n), dt)[:3])
    rhs = np.random.default_rng(0).standard_normal(model.n)
    solvers = {name: solver_for(model, name) for name in methods}
    times = {name: [] for name in methods}
    for name, s in solvers.items():
        s.host_solve(blocks, col, row, rhs, 0.0)
    for _ in range(reps):
        for name, s in solvers.items():
            s._lu = None  # a fresh factorization every call (lu_reuse: the kept one is the point, skip it)
            t0 = time.perf_counter()
            s.host_solve(blocks * (1 + 1e-6 * len(times[name])), col, row, rhs, 0.0)
            times[name].append(time.perf_counter() - t0)
    base = np.median(times[methods[0]])
    print(f"{'method':11s} {'median s':>9s} {'min s':>8s} {'/ ' + methods[0]:>14s}")
    for name in methods:
        print(f"{name:11s} {np.median(times[name]):9.3f} {np.min(times[name]):8.3f} "
              f"{np.median(times[name]) / base:14.3f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", choices=("2d", "3d"), default="2d")
    ap.add_argument("--steps", type=int, default=None, help="measure only the first STEPS steps")
    ap.add_argument("--methods", default="lu_colamd,lu,lu_reuse,minres,minres_amg")
    ap.add_argument("--json", default=None)
    ap.add_argument("--solver-only", type=int, default=0, metavar="REPS",
                    help="time only one host linear solve (fresh factorization) per variant, REPS times")
    args = ap.parse_args()
    t0 = time.perf_counter()
    model, T, dt, full_steps, xi_of = case_2d() if args.case == "2d" else case_3d()
    steps = args.steps or full_steps
    grid = ho.uniform_grid(T=dt * steps, dt=dt)
    xi = xi_of(grid.t)
    print(f"case {args.case}: {model.n} free dofs, {model.mesh.num_cells} cells, nnz(K) = {model.pattern.nnz}, "
          f"{steps} of {full_steps} steps (dt = {dt}); set-up {time.perf_counter() - t0:.1f} s", flush=True)
    if args.solver_only:
        solver_only(model, dt, args.methods.split(","), args.solver_only)
        return
    rows = []
    for name in args.methods.split(","):
        try:
            r = run_variant(model, grid, xi, name)
        except (ho.SolverError, np.linalg.LinAlgError) as exc:
            print(f"  {name:11s} FAILED: {exc}", flush=True)
            continue
        rows.append(r)
        print(f"  {name:11s} {r['wall_s']:9.1f} s, {r['newton_its']} Newton its, {r['factorizations']} factorizations, "
              f"{r['iterations']} inner its; p_end = {r['pressure_final']:.10g}", flush=True)
    base = next((r for r in rows if r["method"] == "lu_colamd"), rows[0])
    print()
    print(f"{'method':11s} {'s/step':>8s} {'s/Newton':>9s} {'us/dof-step':>11s} {'linear %':>9s} {'factor s':>9s} "
          f"{'solve s':>8s} {'assem s':>8s} {'JAX s':>8s} {'facts':>6s} {'/ ' + base['method']:>14s}")
    for r in rows:
        print(f"{r['method']:11s} {r['s_per_step']:8.3f} {r['s_per_newton']:9.3f} {r['us_per_dof_step']:11.2f} "
              f"{100 * r['linear_frac']:8.1f}% {r['factor_s']:9.1f} {r['solve_s']:8.1f} {r['assembly_s']:8.2f} "
              f"{r['jax_s']:8.1f} {r['factorizations']:6d} {r['wall_s'] / base['wall_s']:14.3f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    from results import command_line, table, write_results

    write_results(f"bench_2d3d_{args.case}", command_line(), [table(
        f"Case {args.case}: {model.n} free dofs, {model.mesh.num_cells} cells, {steps} of {full_steps} steps "
        f"(dt = {dt}), per linear-solver variant",
        ["method", "s / step", "s / Newton iteration", "us / dof-step", "linear solve share (%)", "factorization (s)",
         "solves (s)", "assembly (s)", "JAX (s)", "factorizations", f"wall / {base['method']}"],
        [[r["method"], round(r["s_per_step"], 3), round(r["s_per_newton"], 3), round(r["us_per_dof_step"], 2),
          round(100 * r["linear_frac"], 1), round(r["factor_s"], 1), round(r["solve_s"], 1), round(r["assembly_s"], 2),
          round(r["jax_s"], 1), r["factorizations"], round(r["wall_s"] / base["wall_s"], 3)] for r in rows],
        "lu_colamd: the baseline sparse LU (CSR to CSC conversion and a COLAMD ordering at every factorization); "
        "minres_amg: MINRES with smoothed-aggregation AMG of |K| set up at every call; lu_mmd: lu with the "
        "minimum-degree ordering instead of nested dissection.")])


if __name__ == "__main__":
    main()

"""Paper's 1D case (N = 100 P1, 750 steps): state solve and gradient, after JIT warm-up.

Prints absolute times and the ratios against a baseline run in this same script: the same state
solve with the dense-LU solver instead of the tridiagonal one (both compiled into one lax.scan).

    python bench/bench_1d.py

Writes ``bench/results/bench_1d.json`` (`bench/results.py`).
"""

import time

import numpy as np

import hyperoc as ho
from hyperoc.app.workflows import build_reduced
from results import command_line, table, write_results


def best_of(fn, repeat=5):
    fn()  # warm-up (JIT compilation)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main():
    cfg = ho.load_config("examples/paper-1d.toml")
    model = cfg.model()
    grid = cfg.grid()
    xi = 0.05 * np.sin(2 * np.pi * grid.t / 3)[:, None] * np.ones((1, model.control.size))
    fs = np.zeros((grid.t.size, model.n))
    rows = {}
    for solver in ("tridiagonal", "dense"):
        st = ho.TimeStepper(model, cfg.scheme(), solver)
        V0 = float(model.volume(np.zeros(model.n)))
        zero = np.zeros(model.n)
        scan = lambda st=st, V0=V0: np.asarray(st.march(zero, zero, 0.0, xi, fs, grid.dt, V0)[0])
        rows[f"state solve (lax.scan, {solver})"] = best_of(scan)
        rows[f"state solve + diagnostics (TimeStepper.run, {solver})"] = best_of(lambda: st.run(grid, xi), repeat=3)
    for horizon in ("objective", "full"):
        cfg_h = ho.load_config("examples/paper-1d.toml", [f"optimize.horizon={horizon}"])
        J = build_reduced(cfg_h, 7.5, model)
        m = ho.ControlPoint(0.05 * np.ones((J.N + 1, model.control.size)), 7.5)
        k = [0]

        def grad(J=J, m=m, k=k):
            k[0] += 1  # a new point each time, so the state cache is not hit
            J.value_and_gradient(ho.ControlPoint(m.xi * (1 + 1e-9 * k[0]), 7.5))

        rows[f"gradient (state + adjoint + Riesz map), {J.steps_solved} of {J.N} steps (horizon = {horizon!r})"] = (
            best_of(grad))
    base = rows["state solve (lax.scan, dense)"]
    print(f"{'what':60s} {'seconds':>10s} {'/ dense-scan baseline':>22s}")
    for name, sec in rows.items():
        print(f"{name:60s} {sec:10.4f} {sec / base:22.3f}")
    write_results("bench_1d", command_line(), [table(
        "The paper's 1D case: 100 P1 elements, 750 steps; best of 5 (3 for TimeStepper.run) after JIT warm-up",
        ["what", "wall time (s)", "ratio to the dense-LU scan"],
        [[name, round(sec, 4), round(sec / base, 3)] for name, sec in rows.items()],
        "The baseline is the same state solve with the dense-LU solver instead of the tridiagonal one.")])


if __name__ == "__main__":
    main()

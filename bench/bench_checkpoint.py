"""One gradient evaluation with and without a checkpointed adjoint: seconds, peak memory, step evaluations.

Variants: store everything (None, `StoreAll`), every k-th level state (an int k, `EveryK`,
``checkpoint_every = k``), the binomial (revolve) schedule with s snapshots (``"s<s>"``, `Binomial`,
``checkpoint_snapshots = s``).

Each variant runs in a fresh subprocess (JAX buffers are invisible to tracemalloc), which reports
the process's peak resident set (``ru_maxrss``) at the end, the seconds of a first gradient
(JIT compilation included) and the best of three more at other points (compiled), and the bytes of the
level states held between the forward and the adjoint sweep, from their shapes:
``2 (N+1) n 8`` bytes when every level is stored, ``2 (ceil(N/k) + len(kept)) n 8`` with
``checkpoint_every = k`` (plus one segment of ``2 (k+1) n 8`` bytes during the backward sweep),
``2 (s' + len(kept) + 2) n 8`` with s snapshots (s' <= s stored by the forward pass; the backward
pass never holds more than s, plus the current state and y0 of the level above), and the forward
step evaluations of a gradient: N, 2 N (each segment recomputed once), ``t(N, s) + 1``
(`hyperoc.control.revolve.minimal_advances`; `tests/test_revolve.py` counts them).
Ratios are against the store-everything run of the same case, in this same script. On a shared
machine the load drifts between processes, so the time ratios are also measured in one process
alternating the variants (same compiled code, ``J.schedule``
switched; best of three rounds).

Cases:
  1d  the paper's 1D experiment (SVK, P1, h = 0.01, damping 2e-4, body force on [0.75, 1], phi1 =
      p(tau), alpha 2e-3) on a long grid T = 15, dt = 0.005 (3000 steps), tridiagonal solver
      (one compiled lax.scan per segment length); ``--n1d 1000`` repeats it with h = 0.001.
  lv  idealized left ventricle (Land et al. 2015 geometry, ``hyperoc.fem.geometry.ventricle(h)``),
      Guccione (C = 2 kPa, bf 8, bt 2, bfs 4, bulk modulus 100 kPa), rule-based fibres
      (+60 / -60 deg), active stress along the fibres on the whole wall, phi1 = pressure rise
      (p(tau + eps) - p(tau)) / eps with eps = 1 ms, alpha 5e-4; P1, T = 8 ms, dt = 0.5 ms (16
      steps), sparse LU (jitted step driven from Python); xi = -5 sin(pi t / T) kPa. Units mm, ms, kPa.
  lv-sizes  the LV gradient (store everything) for three mesh sizes (h = 4, 3, 2.5 mm): how time
      grows with dofs.

    nice -n 10 python bench/bench_checkpoint.py            # all cases (~ minutes on 2 shared cores)
    python bench/bench_checkpoint.py --cases 1d            # one case
    python bench/bench_checkpoint.py --cases 1d --n1d 1000 --variants 55 s10 s20   # some variants (+ baseline)

Writes ``bench/results/bench_checkpoint.json`` (`bench/results.py`).
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time

import numpy as np

from results import Table, command_line, markdown_table, table, write_results

CK_1D = (None, 10, 55, 300, 3000, "s10", "s20")  # k = 1: see the notes (per-segment overhead)
CK_LV = (None, 4, "s4")  # 4 = sqrt(16 steps)
LV_H = (4.0, 3.0, 2.5)
LV_STEPS = dict(T=8.0, dt=0.5, tau=4.0, eps=1.0)
NOTES = ("all (None): every level state stored (the baseline); every k: every k-th level state, segments "
         "recomputed; revolve s: the binomial schedule with s snapshots. Interleaved: the variants alternated "
         "in one process (same compiled code), best of three rounds.")


def build_1d(n: int):
    import hyperoc as ho

    model = ho.StateModel(ho.interval(n), ho.SaintVenantKirchhoff(mu=0.05, lam=0.05), damping=2e-4,
                          control=ho.BodyForce(ho.Region("box", lower=(0.75,), upper=(1.0,))))
    transform = ho.TimeTransform.for_step(15.0, 0.005, 7.5)
    objective = ho.Objective(running=(ho.ControlCost(2e-3),), at_tau=ho.PressureAt())
    t = np.linspace(0.0, 15.0, transform.num_steps + 1)
    shape = 0.05 * np.sin(2 * np.pi * t / 3)[:, None]
    return model, transform, objective, "auto", 7.5, shape


def build_lv(h: float):
    import hyperoc as ho
    from hyperoc.fem.geometry import ventricle
    from hyperoc.mechanics.fibres import rule_based_fibres

    mesh = ventricle(h)
    frames = rule_based_fibres(mesh, helix_endo=60.0, helix_epi=-60.0)
    model = ho.StateModel(mesh, ho.Guccione(C=2.0, bf=8.0, bt=2.0, bfs=4.0, bulk_modulus=100.0), damping=1.0,
                          density=1.0,
                          control=ho.ActiveStress(ho.Region(), fibres=frames.fibre), frames=frames)
    s = LV_STEPS
    transform = ho.TimeTransform.for_step(s["T"], s["dt"], s["tau"], s["eps"])
    objective = ho.Objective(running=(ho.ControlCost(5e-4),), at_tau=ho.PressureRise(s["eps"]))
    t = np.linspace(0.0, s["T"], transform.num_steps + 1)
    shape = -5.0 * np.sin(np.pi * t / s["T"])[:, None]  # kPa: fibre tension rising and falling
    return model, transform, objective, "lu", s["tau"], shape


def checkpointing(k):
    """The schedule of a variant: None (`StoreAll`), an int k (`EveryK`) or "s<s>" (`Binomial` with s snapshots)."""
    from hyperoc.control.revolve import Binomial, EveryK, StoreAll

    if isinstance(k, str):
        return Binomial(int(k[1:]))
    return StoreAll() if k is None else EveryK(k)


def parse_variant(text: str):
    """The variant of a command-line word: "none" -> None, "10" -> 10, "s10" -> "s10"."""
    return None if text == "none" else text if text.startswith("s") else int(text)


def step_evaluations(k, N: int) -> int:
    """Forward step evaluations of one gradient (the forward pass included): N, 2 N, ``t(N, s) + 1``."""
    from hyperoc.control.revolve import minimal_advances

    if isinstance(k, str):
        return minimal_advances(N, int(k[1:])) + 1
    return N if k is None else 2 * N


def child(case: str, size: float, k) -> dict:
    """Build the case, four gradients (compile + run, then best of three runs), report; runs in its own process."""
    import hyperoc as ho

    model, transform, objective, solver, tau, shape = build_1d(int(size)) if case == "1d" else build_lv(size)
    J = ho.ReducedFunctional(model, transform, objective, solver=solver, schedule=checkpointing(k))
    xi = shape * np.ones((1, model.control.size))
    times = []
    for scale in (1.0, 1.01, 1.02, 1.03):  # a new point each time: the state cache is not hit
        t0 = time.perf_counter()
        J.value_and_gradient(ho.ControlPoint(scale * xi, tau))
        times.append(time.perf_counter() - t0)
    N, n = J.N, model.n
    stored = N + 1 if k is None else J.record(ho.ControlPoint(1.03 * xi, tau)).stored_states
    segment = 2 * (min(k, N) + 1) * n * 8 if isinstance(k, int) else 0
    return {"case": case, "size": size, "k": k, "dofs": n, "steps": N, "first_s": times[0],
            "gradient_s": min(times[1:]),
            "stored_bytes": 2 * stored * n * 8, "segment_bytes": segment, "step_evaluations": step_evaluations(k, N),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


_DONE: dict = {}


def interleaved_child(case: str, size: float, ks: list) -> dict:
    """Gradient seconds for None and every k of ``ks`` in one process, alternating, best of three
    rounds: the ratios do not depend on how the load of a shared machine drifts between processes."""
    import hyperoc as ho

    model, transform, objective, solver, tau, shape = build_1d(int(size)) if case == "1d" else build_lv(size)
    J = ho.ReducedFunctional(model, transform, objective, solver=solver)
    xi = shape * np.ones((1, model.control.size))
    variants = [None, *ks]
    best = {str(k): math.inf for k in variants}
    for r in range(4):  # round 0 compiles
        for i, k in enumerate(variants):
            J.schedule = checkpointing(k)
            m = ho.ControlPoint((1 + 1e-3 * (r * len(variants) + i)) * xi, tau)  # new point: no cache hit
            t0 = time.perf_counter()
            J.value_and_gradient(m)
            if r:
                best[str(k)] = min(best[str(k)], time.perf_counter() - t0)
    return best


def sizes_child(hs: list) -> dict:
    """LV gradient seconds (store everything) for the mesh sizes ``hs`` in one process, alternating,
    best of three rounds."""
    import hyperoc as ho

    Js = {}
    for h in hs:
        model, transform, objective, solver, tau, shape = build_lv(h)
        Js[h] = (ho.ReducedFunctional(model, transform, objective, solver=solver),
                 shape * np.ones((1, model.control.size)))
    best = {str(h): math.inf for h in hs}
    for r in range(4):  # round 0 compiles
        for h, (J, xi) in Js.items():
            t0 = time.perf_counter()
            J.value_and_gradient(ho.ControlPoint((1 + 1e-3 * r) * xi, LV_STEPS["tau"]))
            if r:
                best[str(h)] = min(best[str(h)], time.perf_counter() - t0)
    return best


def run(case: str, size: float, k: int | str | None) -> dict:
    """One variant in a fresh process (each (case, size, k) once per script run); k may also be
    ``"interleaved:k1,s2,..."`` (`interleaved_child`)."""
    key = (case, float(size), k)
    if key not in _DONE:
        cmd = [sys.executable, __file__, "--child", case, str(size), "none" if k is None else str(k)]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            raise SystemExit(f"{key} failed:\n{out.stderr[-2000:]}")
        _DONE[key] = json.loads(out.stdout.strip().splitlines()[-1])
    return _DONE[key]


COLUMNS = ["variant", "dofs", "steps", "stored states (MB)", "+ segment (MB)", "peak RSS (MB)", "RSS / baseline",
           "step evaluations", "step evaluations / baseline", "gradient (s)", "time / baseline",
           "interleaved gradient (s)", "interleaved / baseline", "first call incl. JIT (s)"]


def table_rows(rows: list, base: dict, inter: dict) -> list[list]:
    """One row per variant; ``inter``: best seconds per k (str) from `interleaved_child`."""
    out = []
    for r in rows:
        k = r["k"]
        name = "all (None)" if k is None else f"revolve s = {k[1:]}" if isinstance(k, str) else f"every k = {k}"
        t = inter[str(k)]
        out.append([name, r["dofs"], r["steps"], round(r["stored_bytes"] / 1e6, 2), round(r["segment_bytes"] / 1e6, 2),
                    round(r["peak_rss_mb"]), round(r["peak_rss_mb"] / base["peak_rss_mb"], 3), r["step_evaluations"],
                    round(r["step_evaluations"] / base["step_evaluations"], 2), round(r["gradient_s"], 3),
                    round(r["gradient_s"] / base["gradient_s"], 2), round(t, 3), round(t / inter["None"], 2),
                    round(r["first_s"], 1)])
    return out


def interleaved(case: str, size: float, ks) -> dict:
    return run(case, size, "interleaved:" + ",".join(str(k) for k in ks))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["1d", "lv", "lv-sizes"], choices=["1d", "lv", "lv-sizes"])
    ap.add_argument("--n1d", type=int, nargs="+", default=[100], help="1D element counts (100 = the paper's h)")
    ap.add_argument("--lv-h", type=float, default=3.0, help="LV mesh size (mm) for the checkpoint comparison")
    ap.add_argument("--variants", nargs="+", type=parse_variant,
                    help="only these variants (k, or s<s> for revolve) besides the baseline; default all")
    ap.add_argument("--json", help="write all rows to this file")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        case, size, k = args.child
        if case == "lv-sizes":
            print(json.dumps(sizes_child([float(v) for v in k.split(",")])))
        elif k.startswith("interleaved:"):
            variants = [parse_variant(v) for v in k.split(":")[1].split(",")]
            print(json.dumps(interleaved_child(case, float(size), variants)))
        else:
            print(json.dumps(child(case, float(size), parse_variant(k))))
        return
    chosen = lambda variants: [k for k in variants if k is None or args.variants is None or k in args.variants]
    rows, tables = [], []
    for case in args.cases:
        if case == "1d":
            for n in args.n1d:
                ks = chosen(CK_1D)
                rs = [run("1d", n, k) for k in ks]
                inter = interleaved("1d", n, ks[1:])
                rows += rs + [{"case": "1d", "size": n, "interleaved": inter}]
                title = f"1D, n = {n} elements (T = 15, dt = 0.005), sqrt(N) = {math.sqrt(rs[0]['steps']):.0f}"
                tables.append(table(title, COLUMNS, table_rows(rs, rs[0], inter), NOTES))
                print(f"\n### {title}\n\n{markdown_table(COLUMNS, tables[-1]['rows'])}", flush=True)
        elif case == "lv":
            ks = chosen(CK_LV)
            rs = [run("lv", args.lv_h, k) for k in ks]
            inter = interleaved("lv", args.lv_h, ks[1:])
            rows += rs + [{"case": "lv", "size": args.lv_h, "interleaved": inter}]
            title = f"LV, h = {args.lv_h} mm"
            tables.append(table(title, COLUMNS, table_rows(rs, rs[0], inter), NOTES))
            print(f"\n### {title}\n\n{markdown_table(COLUMNS, tables[-1]['rows'])}", flush=True)
        else:
            hs = sorted({*LV_H, args.lv_h}, reverse=True)
            rs = [run("lv", h, None) for h in hs]
            inter = run("lv-sizes", 0, ",".join(str(h) for h in hs))
            rows += rs + [{"case": "lv-sizes", "interleaved": inter}]
            sizes = Table("LV gradient against mesh size (store everything)",
                          ["h (mm)", "dofs", "steps", "gradient (s)", "interleaved (s)",
                           "us per dof-step (interleaved)", "first call incl. JIT (s)", "peak RSS (MB)"])
            for r in rs:
                t = inter[str(r["size"])]
                sizes.add(r["size"], r["dofs"], r["steps"], round(r["gradient_s"], 2), round(t, 2),
                          round(1e6 * t / (r["dofs"] * r["steps"])), round(r["first_s"], 1), round(r["peak_rss_mb"]))
            tables.append(sizes.as_dict())
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    write_results("bench_checkpoint", command_line(), tables)


if __name__ == "__main__":
    main()

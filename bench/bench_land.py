"""Land et al. (2015) problems 1 to 3 under mesh refinement and penalty variation (hyperoc.cardiac.land).

Problem 1: beam 10 x 1 x 1 mm, ``10 n x n x n`` cubes of six P2 tetrahedra; reported: z of the deformed
point (10, 0.5, 1). Problem 2: idealized LV (Gmsh, target edge h mm), P2, isoparametric on the exact
ellipsoids (``--faceted``: straight-sided cells), base clamped (``--base sliding``: u_z = 0,
rigid in-plane motions pinned); reported: z of the deformed endocardial and epicardial apex and the
deformed cavity volume. Problem 3: the same ventricle, Guccione as in problem 1 with the analytic
fibres of the benchmark (helix +90 to -90 degrees), endocardial pressure 15 kPa and active fibre tension
60 kPa ramped together; the same values reported. ``--lv-refinements 0,1,2``: each size is the coarsest mesh of a nested
sequence of uniform refinements (`hyperoc.fem.mesh.refine`, h halved per level, new boundary vertices on
the exact ellipsoids), the setting in which the observed order and the Richardson limit mean
something (computed with h = h0 / 2^k; the "h" column stays the largest edge); Gmsh meshes of
decreasing size are unrelated to each other. Both:
Guccione with the volumetric penalty of bulk modulus k (kPa), no global volume constraint, follower pressure, full
Newton steps with load stepping (halving on failure).
``--volumetric cell-mean``: the penalty on each cell's mean J (mixed P2-P0 formulation, condensed;
`hyperoc.mechanics.model.StateModel`), which does not lock as k grows. ``--isochoric``: Guccione's Q on
the isochoric strain (`hyperoc.mechanics.materials.Guccione`), which problem 2 needs with ``cell-mean``.

For each k the values converge as h -> 0 to the compressible solution with that bulk modulus; as
k -> infinity that solution tends to the incompressible benchmark at O(1/k). The script prints
one Markdown table per (problem, k) with successive differences, the observed order and the
Richardson limit from the last three levels, and a first-order extrapolation in 1/k from the two
largest k at the finest level.

    nice python bench/bench_land.py --json results/land.json            # default study
    nice python bench/bench_land.py --problems 2 --bulk-moduli 1000 --base sliding --json results/land-slide.json
    nice python bench/bench_land.py --problems 2 --bulk-moduli 1000 --lv-sizes 6 --lv-refinements 0,1,2 --json results/land-nested.json
    nice python bench/bench_land.py --problems 1 --json results/land-beam.json   # one problem
    python bench/bench_land.py --beam-levels 1,2 --lv-sizes 4 --bulk-moduli 1000   # quick look
    nice python bench/bench_land.py --problems 1 --bulk-moduli 1000,100000 --volumetric cell-mean --json results/land-beam-p0.json
    nice python bench/bench_land.py --problems 2 --bulk-moduli 10000,100000 --lv-sizes 6 --lv-refinements 0,1 --lv-steps 80 --cutbacks 80 --volumetric cell-mean --isochoric
    nice python bench/bench_land.py --problems 3 --bulk-moduli inf --lv-sizes 6 --lv-refinements 0,1,2 --volumetric taylor-hood --isochoric
    nice python bench/bench_land.py --problems 3 --bulk-moduli inf --lv-sizes 6 --lv-refinements 0,1,2 --volumetric taylor-hood --isochoric --solver lu_reuse --taper 5
    nice taskset -c 0,1 python bench/bench_land.py --problems 2 --bulk-moduli inf --lv-sizes 6 --lv-refinements 0,1,2,3 --lv-steps 20 --cutbacks 40 --volumetric taylor-hood --isochoric --solver pardiso --nested-start --json results/land-p2-L3.json  # level 3: out of memory in one process
    # the same in two processes: levels 0-2 save their states, level 3 starts from level 2's
    nice taskset -c 0,1 python bench/bench_land.py --problems 2 --bulk-moduli inf --lv-sizes 6 --lv-refinements 0,1,2 --lv-steps 20 --cutbacks 40 --volumetric taylor-hood --isochoric --solver pardiso --nested-start --save-states results/states --json results/land-p2-L012.json
    nice taskset -c 0,1 python bench/bench_land.py --problems 2 --bulk-moduli inf --lv-sizes 6 --lv-refinements 3 --lv-steps 20 --cutbacks 40 --volumetric taylor-hood --isochoric --solver pardiso --nested-start --coarse-state results/states/p2-h6-bulkinf-clamped-L2.npz --json results/land-p2-L3.json
    python bench/bench_land.py --render results/land-*.json                 # tables of saved runs

Seconds are wall time per solve, JIT compilation included.

Writes ``bench/results/bench_land.json`` (`bench/results.py`) for the docs; ``--results NAME`` writes
``bench/results/NAME.json`` instead, so that several studies can be kept side by side (for example
``--results bench_land_p2_taylor_hood``), and ``--results ""`` writes none.
"""  # noqa: E501  (the example command lines above stay whole, to be copied)

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
from pathlib import Path

from hyperoc.cardiac.land import (
    FORMULATIONS,
    PUBLISHED,
    Formulation,
    LoadStepping,
    VentricleMesh,
    beam_deflection,
    load_state,
    save_state,
    ventricle_apex,
)
from hyperoc.errors import SolverError
from hyperoc.solvers.linsolve import SparseSolver
from hyperoc.solvers.newton import NewtonLog

#: Problem 2 values: apex z (mm) and deformed cavity volume (mm^3; missing in rows that lack it).
LV_KEYS = ["z_endo", "z_epi", "V_cavity"]


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split(",") if v]


def _order(h, z) -> tuple[float, float]:
    """Observed order p and Richardson limit from three levels: ``z_k = z* + c h_k^p`` solved exactly
    (bisection on ``(h1^p - h2^p) / (h2^p - h3^p) = (z1 - z2) / (z2 - z3)``, any mesh ratios)."""
    (h1, h2, h3), (z1, z2, z3) = h, z
    ratio = (z1 - z2) / (z2 - z3)
    g = lambda p: (h1**p - h2**p) / (h2**p - h3**p) - ratio
    lo, hi = 0.05, 12.0
    if not ratio > 0 or g(lo) * g(hi) > 0:  # non-monotone or outside the bracket: no asymptotic regime
        return math.nan, math.nan
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(lo) * g(mid) > 0 else (lo, mid)
    p = 0.5 * (lo + hi)
    return p, z3 + (z3 - z2) * h3**p / (h2**p - h3**p)


def _table(title: str, rows: list[dict], level_key: str, value_keys: list[str]) -> str:
    """Markdown table: per value, the difference to the previous level, and from the last three
    levels the observed order and the Richardson-extrapolated limit (h -> 0 at this bulk modulus)."""
    unit = lambda k: "mm^3" if k.startswith("V_") else "mm"
    head = f"| {level_key} | h (mm) | dofs | " + " | ".join(f"{k} ({unit(k)}) | diff | order | extrap."
                                                           for k in value_keys)
    head += " | Newton its (total / max per step) | load steps | s |"
    lines = [f"**{title}**", "", head, "|" + "---|" * (head.count("|") - 1)]
    for i, r in enumerate(rows):
        cells = [str(r["params"][level_key]), f"{r['h']:.3g}", str(r["dofs"])]
        for key in value_keys:
            z = _values(rows[: i + 1], key)
            order = extrap = ""
            if i >= 2:
                p, lim = _richardson(rows[: i + 1], key)
                order, extrap = f"{p:.2f}", f"{lim:.4f}"
            cells += [f"{z[-1]:.5f}", f"{z[-1] - z[-2]:+.2e}" if i else "", order, extrap]
        its, rejected = r["newton_iterations"], r.get("rejected_iterations")  # absent in older runs' files
        work = f"{sum(its)} / {max(its)}" + (f" (+{rejected} rejected)" if rejected else "")
        cells += [work, str(len(its)), f"{r['seconds']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _table_dict(title: str, rows: list[dict], level_key: str, value_keys: list[str], notes: str) -> dict:
    """The same table as `_table`, as a `bench/results.py` table (numbers, not text)."""
    from results import table

    unit = lambda k: "mm^3" if k.startswith("V_") else "mm"
    columns = [level_key, "h (mm)", "dofs"]
    for k in value_keys:
        columns += [f"{k} ({unit(k)})", f"{k} diff ({unit(k)})", f"{k} order", f"{k} Richardson limit ({unit(k)})"]
    columns += ["Newton iterations", "max per load step", "rejected iterations", "load steps", "wall time (s)"]
    out = []
    for i, r in enumerate(rows):
        cells = [r["params"][level_key], float(f"{r['h']:.3g}"), r["dofs"]]
        for key in value_keys:
            z = _values(rows[: i + 1], key)
            order = limit = None
            if i >= 2:
                p, lim = _richardson(rows[: i + 1], key)
                order, limit = ((round(p, 2) if math.isfinite(p) else None),
                                (round(lim, 4) if math.isfinite(lim) else None))
            cells += [round(z[-1], 5), float(f"{z[-1] - z[-2]:.2e}") if i else None, order, limit]
        its = r["newton_iterations"]
        cells += [sum(its), max(its), r.get("rejected_iterations") or 0, len(its), round(r["seconds"], 1)]
        out.append(cells)
    return table(title, columns, out, notes)


def _published(problem: int, rows: list[dict], value_keys: list[str]) -> str:
    """The distance of the finest level and of the Richardson limit to the published value
    (`hyperoc.cardiac.land.PUBLISHED`), for the benchmark as posed only (base clamped, tension not
    tapered; a finite bulk modulus k adds its own O(1/k) distance); "" otherwise."""
    params = rows[-1]["params"]
    if params.get("base", "clamped") != "clamped" or params.get("taper"):
        return ""
    cells = []
    for key in value_keys:
        ref = PUBLISHED[problem][key]
        cell = f"{key} {ref:g}: finest level {_values(rows, key)[-1] - ref:+.4f}"
        if len(rows) >= 3:
            _, lim = _richardson(rows, key)
            cell += f", limit {lim - ref:+.4f}" if math.isfinite(lim) else ", no limit"
        cells.append(cell)
    return ("\n\nPublished (S. Pezzuto's FEniCS submission to Land et al. 2015; `hyperoc.cardiac.land.PUBLISHED`), "
            f"distance to it: {'; '.join(cells)}"
            + ("" if params["bulk_modulus"] == math.inf else
               f" (bulk modulus {params['bulk_modulus']:g} kPa, not incompressible)"))


def _values(rows: list[dict], key: str) -> list[float]:
    """One reported value per row (NaN where a row lacks it: older files)."""
    return [row["values"].get(key, math.nan) for row in rows]


def _richardson(rows: list[dict], key: str) -> tuple[float, float]:
    """Observed order and Richardson limit of ``key`` from the last three rows (`_order`)."""
    return _order([_scale(row) for row in rows[-3:]], _values(rows[-3:], key))


def _scale(row: dict) -> float:
    """The mesh size behind the order and the limit: ``h0 / 2^k`` on a nested sequence (every cell
    halved exactly: the ratio is 2 in any measure), else the largest edge (Gmsh meshes)."""
    params = row["params"]
    return params["mesh_size"] / 2 ** params["refinements"] if params.get("nested") else row["h"]


def _extrapolate(by_bulk_modulus: dict, key: str) -> str:
    """``z_inf ~ z(k2) + (z(k2) - z(k1)) k1 / (k2 - k1)`` (linear in 1/k) from the two largest bulk moduli k."""
    k1, k2 = sorted(by_bulk_modulus)[-2:]
    z1, z2 = by_bulk_modulus[k1], by_bulk_modulus[k2]
    return (f"{key}: bulk modulus {k1:g} -> {z1:.5f}, {k2:g} -> {z2:.5f}, linear in 1/k -> "
            f"{z2 + (z2 - z1) * k1 / (k2 - k1):.5f}")


def _formulation(params: dict) -> str:
    """How the penalty enters (`hyperoc.mechanics.model.StateModel` ``volumetric``) and whether Q uses the
    isochoric strain, and the Newton predictor; rows without those options: pointwise, full strain,
    previous equilibrium."""
    mixed = {"cell-mean": ", cell-mean J (P2-P0)", "taylor-hood": ", Taylor-Hood (P2-P1)"}.get(
        params.get("volumetric", "pointwise"), "")
    secant = ", secant predictor" if params.get("predictor") == "secant" else ""
    return mixed + (", isochoric Q" if params.get("isochoric", False) else "") + secant


def _variant(params: dict) -> str:
    """The problem 2 or 3 geometry, base and mesh sequence of a result row (rows without those options:
    faceted, clamped, Gmsh sizes)."""
    geometry = "curved" if params.get("curved", False) else "faceted"
    nested = f", nested: h0 = {params['mesh_size']:g} refined" if params.get("nested") else ""
    solver = f", solver {params['solver']}" if params.get("solver", "auto") not in ("auto", "lu") else ""
    taper = f", tension tapered within {params['taper']:g} mm of the axis" if params.get("taper") else ""
    return f"{geometry}, base {params.get('base', 'clamped')}{nested}{solver}{_formulation(params)}{taper}"


def _level_key(params: dict) -> str:
    """The column that tells the levels of a problem 2 or 3 sequence apart."""
    return "refinements" if params.get("nested") else "mesh_size"


def render(paths: list[str]):
    """Print the tables of saved results (``--json`` files, or stdout logs with one JSON row a line)."""
    rows = []
    for path in paths:
        with open(path) as fh:
            text = fh.read()
        try:
            data = json.loads(text)  # a --json file, or a log holding a single row
            rows += data["results"] if "results" in data else [data]
        except json.JSONDecodeError:  # a stdout log: one JSON row a line, then the tables
            rows += [json.loads(line) for line in text.splitlines() if line.startswith('{"values"')]
    for problem, name, level_key, keys in ((1, "Problem 1 (beam)", "n", ["z_tip"]),
                                           (2, "Problem 2 (ventricle)", "mesh_size", LV_KEYS),
                                           (3, "Problem 3 (contraction)", "mesh_size", LV_KEYS)):
        mine = [r for r in rows if r["params"]["problem"] == problem]
        label = (lambda r: _formulation(r["params"])) if problem == 1 else (lambda r: ", " + _variant(r["params"]))
        for bulk_modulus, variant in sorted({(r["params"]["bulk_modulus"], label(r)) for r in mine}):
            group = sorted((r for r in mine if (r["params"]["bulk_modulus"], label(r)) == (bulk_modulus, variant)),
                           key=lambda r: -r["h"])
            key = level_key if problem == 1 else _level_key(group[0]["params"])
            print(_table(f"{name}, P2{variant}, bulk modulus {bulk_modulus:g} kPa", group, key, keys)
                  + _published(problem, group, keys) + "\n")


def solved_or_reported(run, level, bulk_modulus: float, failures: list):
    """``run(level, bulk_modulus)``, or None after noting a `SolverError` (the solve's step and cause) in
    ``failures``: one failed level does not lose the others."""
    try:
        return run(level, bulk_modulus)
    except SolverError as exc:
        failures.append(f"level {level}, bulk modulus {bulk_modulus:g} kPa: {exc}")
        print(f"FAILED: {failures[-1]}", flush=True)
        return None


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", default="1,2", help="which benchmark problems to run")
    ap.add_argument("--beam-levels", default="1,2,3", help="beam refinement n (10n x n x n cubes)")
    ap.add_argument("--lv-sizes", default="4,3,2", help="ventricle target edge lengths (mm)")
    ap.add_argument("--lv-refinements", default=None,
                    help="uniform refinement levels of each ventricle size, e.g. 0,1,2: nested sequences")
    ap.add_argument("--bulk-moduli", default="1000,10000", help="bulk moduli of the penalty (kPa)")
    ap.add_argument("--beam-steps", type=int, default=10)
    ap.add_argument("--lv-steps", type=int, default=20)
    ap.add_argument("--cutbacks", type=int, default=8,
                    help="failed load increments that may be halved and retried, in total per solve")
    ap.add_argument("--faceted", action="store_true", help="problems 2, 3 on straight-sided P2 cells (default: curved)")
    ap.add_argument("--base", default="clamped", choices=["clamped", "sliding"], help="problems 2, 3 base condition")
    ap.add_argument("--volumetric", default="pointwise", choices=FORMULATIONS,
                    help="the penalty at every quadrature point, on each cell's mean J (mixed P2-P0, "
                         "hyperoc.mechanics.model.StateModel), or a continuous P1 pressure (Taylor-Hood, "
                         "hyperoc.mechanics.mixed.TaylorHoodModel; there the bulk modulus may be inf: incompressible)")
    ap.add_argument("--isochoric", action="store_true",
                    help="Guccione's Q on the isochoric strain (J^(-2/3) C - I) / 2 "
                         "(hyperoc.mechanics.materials.Guccione)")
    ap.add_argument("--solver", default="auto", choices=["auto", *SparseSolver.methods],
                    help="problems 2, 3 linear solver (hyperoc.solvers.linsolve; auto = sparse LU at these sizes)")
    ap.add_argument("--predictor", default="previous", choices=["previous", "secant"],
                    help="Newton start at each load increment (hyperoc.dynamics.statics.solve_static)")
    ap.add_argument("--taper", type=float, default=0.0, metavar="MM",
                    help="problem 3 variant: the active tension tapered to zero on the long axis within this "
                         "radius (hyperoc.mechanics.active.axis_taper; default 0: the benchmark)")
    ap.add_argument("--nested-start", action="store_true",
                    help="with --lv-refinements: each level after the first starts at the full load from the "
                         "previous level's prolonged solution (nested iteration, "
                         "hyperoc.dynamics.statics.solve_static's guess), stepping the load only if Newton fails "
                         "from there")
    ap.add_argument("--save-states", default=None, metavar="DIR",
                    help="write each ventricle level's solution to "
                         "DIR/p<problem>-h<h0>-bulk<bulk_modulus>-<base>-L<level>.npz "
                         "(hyperoc.cardiac.land.save_state)")
    ap.add_argument("--coarse-state", default=None, metavar="NPZ",
                    help="a --save-states file of the level below the first of --lv-refinements: that level starts "
                         "from it (with --nested-start), so a fine level can run in a process of its own")
    ap.add_argument("--newton-log", action="store_true",
                    help="print every Newton iteration to stderr as it ends (hyperoc.solvers.newton.NewtonLog)")
    ap.add_argument("--json", default=None, help="write all results here")
    ap.add_argument("--results", default="bench_land", metavar="NAME",
                    help="results file bench/results/NAME.json for the docs (bench/results.py); '' for none")
    ap.add_argument("--render", nargs="+", default=None, metavar="JSON",
                    help="only print the tables of earlier runs (their --json files or stdout logs)")
    args = ap.parse_args()
    if args.render:
        render(args.render)
        return
    bulk_moduli = _floats(args.bulk_moduli)
    if args.save_states:
        Path(args.save_states).mkdir(parents=True, exist_ok=True)
    results = []

    def record(res, **extra):
        res.params.update(extra)
        row = {"values": res.values, "h": res.h, "dofs": res.dofs, "newton_iterations": res.newton_iterations.tolist(),
               "rejected_iterations": res.rejected_iterations, "seconds": res.seconds, "min_det_F": res.min_det_F,
               "max_volume_change": res.max_volume_change, "mean_volume_change": res.mean_volume_change,
               "volume_change": res.volume_change, "params": res.params}
        results.append(row)
        print(json.dumps(row), flush=True)
        return row

    tables, structured, extrap, failures = [], [], [], []
    problems = {int(v) for v in _floats(args.problems)}
    lv_sequences = [[(h, 0)] for h in _floats(args.lv_sizes)] if args.lv_refinements is None else \
        [[(h, int(k)) for k in _floats(args.lv_refinements)] for h in _floats(args.lv_sizes)]
    monitor = NewtonLog(sys.stderr) if args.newton_log else None
    solved = {}  # (problem, h, bulk_modulus, refinements) -> the last level's BenchmarkResult, for --nested-start

    def lv_solve(problem, level, bulk_modulus):
        h, k = level
        coarse = solved.pop((problem, h, bulk_modulus, k - 1), None)
        if coarse is None and args.coarse_state and args.nested_start:
            coarse = load_state(args.coarse_state)
        res = ventricle_apex(VentricleMesh(h, curved=not args.faceted, base=args.base, refinements=k),
                             Formulation(bulk_modulus, volumetric=args.volumetric, isochoric=args.isochoric),
                             LoadStepping(args.lv_steps, args.cutbacks, args.solver, args.predictor, monitor),
                             problem=problem, taper=args.taper if problem == 3 else 0.0, coarse=coarse)
        if args.nested_start:
            solved[(problem, h, bulk_modulus, k)] = res
        if args.save_states:
            save_state(res, Path(args.save_states) / f"p{problem}-h{h:g}-bulk{bulk_modulus:g}-{args.base}-L{k}.npz")
        return record(res, nested=args.lv_refinements is not None, solver=args.solver)

    lv_run = lambda problem: functools.partial(lv_solve, problem)
    lv_levels = lv_sequences if args.lv_refinements is not None else [sum(lv_sequences, [])]
    for number, name, sequences, run, level_key, keys in (
        (1, "Problem 1 (beam)", [[int(v) for v in _floats(args.beam_levels)]],
         lambda lv, k: record(beam_deflection(lv, Formulation(k, volumetric=args.volumetric, isochoric=args.isochoric),
                                              LoadStepping(args.beam_steps, args.cutbacks, predictor=args.predictor,
                                                           monitor=monitor))), "n", ["z_tip"]),
        (2, "Problem 2 (ventricle)", lv_levels, lv_run(2), None, LV_KEYS),
        (3, "Problem 3 (contraction)", lv_levels, lv_run(3), None, LV_KEYS),
    ):
        if number not in problems:
            continue
        finest = {}
        for bulk_modulus in bulk_moduli:
            for levels in sequences:
                rows = [row for row in (solved_or_reported(run, lv, bulk_modulus, failures) for lv in levels) if row]
                if not rows:
                    continue
                variant = f", {_variant(rows[0]['params'])}" if number > 1 else _formulation(rows[0]["params"])
                key = level_key or _level_key(rows[0]["params"])
                title = f"{name}, P2{variant}, bulk modulus {bulk_modulus:g} kPa"
                tables.append(_table(title, rows, key, keys) + _published(number, rows, keys))
                structured.append(_table_dict(title, rows, key, keys, _published(number, rows, keys).strip()))
                finest[bulk_modulus] = rows[-1]["values"]
        if len(finest) >= 2:
            extrap += [f"{name}, finest level: " + _extrapolate({k: v[key] for k, v in finest.items()}, key)
                       for key in keys]

    print("\n" + "\n\n".join(tables) + "\n")
    print("\n".join(f"- {line}" for line in extrap + failures))
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump({"results": results, "tables": tables, "bulk_modulus_extrapolation": extrap,
                       "failures": failures}, fh, indent=1)
    if structured and args.results:
        from results import command_line, write_results

        if extrap or failures:
            structured[-1]["notes"] = " ".join([structured[-1]["notes"], *extrap, *failures]).strip()
        write_results(args.results, command_line(), structured)


if __name__ == "__main__":
    main()

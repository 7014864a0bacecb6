"""Convert the participating codes' curves of the cardiac elastodynamics benchmark into the package's JSON files.

Source: the repository Reidmen/cardiac_benchmark_toolkit (commit e8d4755, MIT licence, copyright Reidmen
Arostica 2023), files ``results/data/monoventricular_nonblinded_step_{0A,0B,1}_group_<code>.pickle``. Each is a
pickled dict ``{"time": (n,), "displacement": {"p0" | "p1": {"ux", "uy", "uz", "magnitude": (n,)}}, "volume":
(n,) (absent for some codes), "stress": ...}`` in SI units (s, m, m^3); some codes sample from t = 0.001 or up
to t = 0.999. ``simvascular`` repeats ``simvascular_p2`` value for value and is left out, so each step has the
ten curves of the paper: 4C, Ambit, CARPentry, CHeart, CHimeRA, COMSOL, lifex, Simula, SimVascular P1 (its
P1-P1 formulation) and SimVascular P2.

    python bench/reference/convert_cardiac_benchmark.py PATH/TO/cardiac_benchmark_toolkit

writes ``hyperoc/data/cardiac_benchmark/curves_step_{0A,0B,1}.json``: ``{"source", "units", "groups": {code:
{"t": [...], "p0": [[ux, uy, uz], ...], "p1": [...], "volume": [...] or null}}}``, numbers to 10 significant
digits (the curves differ between codes in the second or third). Loading a pickle runs code from the file:
run this on a checkout of that repository only. Read by `hyperoc.cardiac.benchmark_curves.reference_curves`.
"""

from __future__ import annotations

import argparse
import json
import pickle
from pathlib import Path

import numpy as np

from hyperoc.io import atomic_write_text

STEPS = ("0A", "0B", "1")
NAMES = {"4c": "4C", "ambit": "Ambit", "carpentry": "CARPentry", "cheart": "CHeart", "chimera": "CHimeRA",
         "comsol": "COMSOL", "lifex": "lifex", "simula": "Simula", "simvascular_p1p1": "SimVascular P1",
         "simvascular_p2": "SimVascular P2"}
DUPLICATE = ("simvascular", "simvascular_p2")  # the first repeats the second
SOURCE = ("Reidmen/cardiac_benchmark_toolkit, commit e8d4755, results/data/monoventricular_nonblinded_step_"
          "{step}_group_*.pickle; MIT licence, copyright (c) 2023 Reidmen Arostica")
OUT = Path(__file__).resolve().parents[2] / "hyperoc" / "data" / "cardiac_benchmark"


def read_group(path: Path) -> dict:
    """``{"t", "p0", "p1", "volume"}`` of one pickle as arrays, units checked."""
    with path.open("rb") as f:
        data = pickle.load(f)  # the benchmark's own files, from a checkout of its repository
    t = np.asarray(data["time"], dtype=np.float64)
    points = {p: np.stack([np.asarray(data["displacement"][p][c], dtype=np.float64) for c in ("ux", "uy", "uz")],
                          axis=1) for p in ("p0", "p1")}
    volume = data.get("volume")
    volume = None if volume is None else np.asarray(volume, dtype=np.float64)
    check_si(path.name, t, points, volume)
    return {"t": t, **points, "volume": volume}


def check_si(name: str, t, points: dict, volume) -> None:
    """The curves are in s, m and m^3: a beat of one second, displacements of centimetres, a cavity of about
    170 mL (a file in ms, mm or mL fails here)."""
    if not (np.all(np.diff(t) > 0) and 0 <= t[0] <= 0.01 and 0.99 <= t[-1] <= 1.0):
        raise SystemExit(f"{name}: time is not increasing over [0, 1] s")
    for p, u in points.items():
        if u.shape != (len(t), 3) or not (1e-3 < np.abs(u).max() < 0.1):
            raise SystemExit(f"{name}: displacement of {p} is not of centimetres in m")
    if volume is not None and (volume.shape != t.shape or not (1e-4 < volume.max() < 3e-4)):
        raise SystemExit(f"{name}: the cavity volume is not about 1.7e-4 m^3")


def rounded(array):
    return None if array is None else [float(f"{v:.10g}") for v in np.asarray(array).reshape(-1)]


def convert(toolkit: Path, step: str) -> Path:
    folder = toolkit / "results" / "data"
    groups = {}
    files = {path.name.split("_group_")[1].removesuffix(".pickle").lower(): path
             for path in folder.glob(f"monoventricular_nonblinded_step_{step}_group_*.pickle")}
    repeated, kept = (read_group(files[k]) for k in DUPLICATE)
    if any(not np.array_equal(repeated[q], kept[q]) for q in ("t", "p0", "p1")):
        raise SystemExit(f"step {step}: {DUPLICATE[0]} no longer repeats {DUPLICATE[1]}; review NAMES")
    if set(files) != set(NAMES) | {DUPLICATE[0]}:
        raise SystemExit(f"step {step}: codes {sorted(files)} differ from the expected {sorted(NAMES)}")
    for code, name in NAMES.items():
        group = read_group(files[code])
        groups[name] = {"t": rounded(group["t"]), "p0": [rounded(u) for u in group["p0"]],
                        "p1": [rounded(u) for u in group["p1"]], "volume": rounded(group["volume"])}
    document = {"source": SOURCE.format(step=step), "step": step,
                "units": {"t": "s", "p0": "m", "p1": "m", "volume": "m^3"}, "groups": groups}
    path = OUT / f"curves_step_{step}.json"
    atomic_write_text(path, json.dumps(document, separators=(",", ":")) + "\n")
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("toolkit", type=Path, help="a checkout of Reidmen/cardiac_benchmark_toolkit")
    args = parser.parse_args()
    for step in STEPS:
        print(convert(args.toolkit, step))


if __name__ == "__main__":
    main()

"""The files of a cardiac benchmark run (`hyperoc.app.cardiac_benchmark.run_benchmark`) and their figures.

``OUT/curves.npz``: the record's arrays at every time level (``t`` s; ``p0``, ``p1`` (L, 3) m; ``volume`` m^3;
``pressure``, ``tension`` Pa). ``OUT/benchmark.json``: the same curves at the codes' sampling times
(`hyperoc.cardiac.benchmark.SAMPLE_DT`) with the run's description, cost and comparison, the entry the bench
script (``bench/bench_cardiac_benchmark.py``) collects. ``OUT/displacements.png``: the components of the
displacements of p0 and p1 over time, hyperoc's curve over the ten codes' curves and the band they span;
``OUT/volume.png``: the cavity volume over the codes' likewise, and the prescribed pressure and active tension.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..cardiac.benchmark import resampled, sample_times
from ..cardiac.benchmark_curves import curve_band, reference_curves
from ..io import read_json, write_json, write_npz
from .plotting import axis_label, new_figure, save_figure

__all__ = ["CURVES", "write_benchmark_outputs", "read_benchmark_record", "sampled_record", "plot_displacements",
           "plot_volume_and_loads"]

#: The record's time series, as `hyperoc.cardiac.benchmark.benchmark_curves` makes them.
CURVES = ("t", "p0", "p1", "volume", "pressure", "tension")
_MM = 1e3  # the figures show displacements in mm and volumes in mL: the codes' curves are in m and m^3
_ML = 1e6
_OURS = dict(color="C3", lw=2.0, label="hyperoc", zorder=5)
_CODE = dict(color="0.55", lw=0.7, zorder=2)
_BAND = dict(color="0.85", zorder=1, label="codes' band")


def write_benchmark_outputs(out, record: dict) -> dict:
    """Write ``curves.npz``, ``benchmark.json`` and the two figures of ``record`` into ``out``; return the
    JSON's content (`sampled_record`)."""
    out = Path(out)
    write_npz(out / "curves.npz", **{name: np.asarray(record[name]) for name in CURVES})
    entry = sampled_record(record)
    write_json(out / "benchmark.json", entry)
    title = f"cardiac benchmark step {record['step']}, P{record['degree']} ({record['mesh']['variant']} mesh)"
    plot_displacements(out / "displacements.png", record, title=title)
    plot_volume_and_loads(out / "volume.png", record, title=title)
    return entry


def sampled_record(record: dict) -> dict:
    """``record`` with its curves at the codes' sampling times (`hyperoc.cardiac.benchmark.sample_times`):
    lists in s, m, m^3 and Pa, for JSON."""
    times = sample_times(record["t"][-1])
    entry = {k: v for k, v in record.items() if k not in CURVES}
    entry["t"] = times.tolist()
    entry.update({name: values.tolist() for name, values in resampled(record, times, CURVES[1:]).items()})
    return entry


def read_benchmark_record(path) -> dict:
    """A ``benchmark.json`` written by `write_benchmark_outputs`, its curves as float64 arrays."""
    entry = read_json(path)
    for name in CURVES:
        entry[name] = np.asarray(entry[name], dtype=np.float64)
    return entry


def plot_displacements(path, record: dict, *, title: str) -> Path:
    """A 2 x 3 grid: the x, y, z components (mm) of the displacements of p0 (top) and p1 (bottom) against
    t (s), hyperoc's over each code's and the band they span."""
    curves = reference_curves(record["step"])
    t = np.asarray(record["t"])
    fig = new_figure(12.0, 6.5)
    axes = fig.subplots(2, 3, sharex=True)
    times = np.linspace(0.0, t[-1], 201)
    for row, point in enumerate(("p0", "p1")):
        band = curve_band(curves, times, point)
        for c, name in enumerate("xyz"):
            ax = axes[row, c]
            ax.fill_between(times, _MM * band["lower"][:, c], _MM * band["upper"][:, c], **_BAND)
            for code in curves.values():
                ax.plot(code["t"], _MM * code[point][:, c], **_CODE)
            ax.plot(t, _MM * np.asarray(record[point])[:, c], **_OURS)
            ax.set_title(f"{point}: u_{name}")
            ax.set_ylabel(axis_label(f"u_{name}({point})", "mm"))
            ax.grid(alpha=0.3)
        axes[row, 0].legend(loc="best", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel(axis_label("t", "s"))
        ax.set_xlim(0.0, t[-1])
    fig.suptitle(f"{title}: displacements of p0 and p1 (grey: the ten participating codes)")
    return save_figure(fig, path)


def plot_volume_and_loads(path, record: dict, *, title: str) -> Path:
    """The cavity volume (mL) against t (s) over the codes' curves and band, and the prescribed endocardial
    pressure and active tension (kPa)."""
    curves = reference_curves(record["step"])
    t = np.asarray(record["t"])
    fig = new_figure(11.0, 4.2)
    left, right = fig.subplots(1, 2)
    times = np.linspace(0.0, t[-1], 201)
    band = curve_band(curves, times, "volume")
    left.fill_between(times, _ML * band["lower"], _ML * band["upper"], **_BAND)
    for code in curves.values():
        if code["volume"] is not None:
            left.plot(code["t"], _ML * code["volume"], **_CODE)
    left.plot(t, _ML * np.asarray(record["volume"]), **_OURS)
    left.set_ylabel(axis_label("cavity volume", "mL"))
    left.set_title("cavity volume")
    left.legend(loc="best", fontsize=8)
    right.plot(t, 1e-3 * np.asarray(record["pressure"]), color="C0", label="endocardial pressure p")
    right.plot(t, 1e-3 * np.asarray(record["tension"]), color="C1", label="active tension T_a")
    right.set_ylabel(axis_label("p, T_a", "kPa"))
    right.set_title("prescribed loads")
    right.legend(loc="best", fontsize=8)
    for ax in (left, right):
        ax.set_xlabel(axis_label("t", "s"))
        ax.set_xlim(0.0, t[-1])
        ax.grid(alpha=0.3)
    fig.suptitle(f"{title}: cavity volume and loads")
    return save_figure(fig, path)

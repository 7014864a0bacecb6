"""The participating codes' curves of the cardiac elastodynamics benchmark (Aróstica et al. 2025), and the band
they span.

The package ships, for steps ``"0A"``, ``"0B"`` and ``"1"`` of the monoventricular benchmark, the curves of the
ten codes of the paper (4C, Ambit, CARPentry, CHeart, CHimeRA, COMSOL, lifex, Simula, SimVascular P1 and P2):
time ``t`` (s), the displacements of the points p0 and p1 (`hyperoc.cardiac.benchmark_geometry.P0`, ``P1``; m)
and the cavity volume (m^3; absent for COMSOL and lifex). Source, licence and conversion:
``hyperoc/data/cardiac_benchmark/NOTICE.md`` and ``bench/reference/convert_cardiac_benchmark.py``.

`curve_band` interpolates each code's curve linearly onto given times and takes the minimum and maximum over the
codes whose sampling covers each time (some start at 1 ms or end at 999 ms), per component.
"""

from __future__ import annotations

import json
from importlib import resources

import numpy as np

from ..errors import InputError

__all__ = ["STEPS", "QUANTITIES", "reference_curves", "curve_band"]

STEPS = ("0A", "0B", "1")
#: What `curve_band` bands: the displacement vectors, their magnitudes, and the cavity volume.
QUANTITIES = ("p0", "p1", "|p0|", "|p1|", "volume")


def reference_curves(step: str) -> dict:
    """``{code: {"t": (n,), "p0": (n, 3), "p1": (n, 3), "volume": (n,) or None}}`` of benchmark step ``step``
    (``"0A"``, ``"0B"`` or ``"1"``), float64 arrays in s, m and m^3."""
    step = str(step).upper()
    if step not in STEPS:
        raise InputError(f"cardiac benchmark: unknown step {step!r} (steps: {', '.join(STEPS)})")
    text = resources.files("hyperoc").joinpath("data", "cardiac_benchmark", f"curves_step_{step}.json").read_text()
    groups = json.loads(text)["groups"]
    return {code: {key: None if value is None else np.asarray(value, dtype=np.float64) for key, value in g.items()}
            for code, g in groups.items()}


def _quantity(curve: dict, quantity: str):
    """The (n, k) samples of ``quantity`` of one code's curve, or None if the code did not report it."""
    if quantity.startswith("|"):
        return np.linalg.norm(curve[quantity.strip("|")], axis=1)[:, None]
    value = curve[quantity]
    return None if value is None else value.reshape(len(curve["t"]), -1)


def curve_band(curves: dict, times, quantity: str = "p0") -> dict:
    """The band the codes span at ``times`` (m,), s.

    ``curves``: `reference_curves` of a step (or a subset of its codes). ``quantity``: one of `QUANTITIES`.
    Returns ``{"t": (m,), "lower": (m[, 3]), "upper": (m[, 3]), "count": (m,)}``: per time and component the
    minimum and maximum over the codes whose curve covers that time (``t_first <= t <= t_last``), each curve
    linearly interpolated, and how many codes that was (0: NaN bounds)."""
    if quantity not in QUANTITIES:
        raise InputError(f"curve_band: unknown quantity {quantity!r} (one of {', '.join(QUANTITIES)})")
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    samples = []
    for curve in curves.values():
        values = _quantity(curve, quantity)
        if values is None:
            continue
        t = curve["t"]
        inside = (times >= t[0] - 1e-12) & (times <= t[-1] + 1e-12)
        on_times = np.stack([np.interp(times, t, column) for column in values.T], axis=1)
        samples.append(np.where(inside[:, None], on_times, np.nan))
    if not samples:
        raise InputError(f"curve_band: no code reports {quantity!r}")
    stacked = np.stack(samples)  # (codes, m, k)
    count = np.sum(~np.isnan(stacked[..., 0]), axis=0)
    covered = count > 0
    lower = np.full(stacked.shape[1:], np.nan)
    upper = np.full(stacked.shape[1:], np.nan)
    lower[covered] = np.nanmin(stacked[:, covered], axis=0)
    upper[covered] = np.nanmax(stacked[:, covered], axis=0)
    squeeze = (lambda a: a[:, 0]) if stacked.shape[2] == 1 else (lambda a: a)
    return {"t": times, "lower": squeeze(lower), "upper": squeeze(upper), "count": count}

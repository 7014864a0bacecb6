"""The cardiac elastodynamics benchmark (monoventricular problem 1 of Aróstica et al. 2025): its curves, compared.

R. Aróstica et al., "A software benchmark for cardiac elastodynamics", Comput. Methods Appl. Mech. Engrg. 435
(2025) 117485. The problem is the shipped configuration ``hyperoc/data/cardiac-benchmark.toml`` (step 1: the
endocardial pressure and the active tension of the benchmark's Bestel laws on its reference mesh); its steps

- ``"0A"``: the active tension alone (no endocardial pressure),
- ``"0B"``: the endocardial pressure alone (no active tension),
- ``"1"``: both,

are that configuration with a load left out (`hyperoc.app.cardiac_benchmark.benchmark_config`, which also runs
them: `hyperoc.app.cardiac_benchmark.run_benchmark`). `benchmark_curves` records of a solve the displacements of
the probe points p0 and p1 (`hyperoc.cardiac.benchmark_geometry.P0`, ``P1``; m), the cavity volume enclosed by
the endocardium and its deformed rim (m^3), the pressure and the active tension (Pa); `compare_with_codes`
compares them with the band the ten participating codes span (`hyperoc.cardiac.benchmark_curves`).
"""

from __future__ import annotations

import numpy as np

from .benchmark_curves import STEPS, curve_band, reference_curves
from .benchmark_geometry import P0, P1

__all__ = ["STEPS", "SAMPLE_DT", "benchmark_curves", "compare_with_codes", "sample_times", "resampled"]

#: The codes' sampling interval (s): the comparison and the results JSON use these times.
SAMPLE_DT = 0.01


def benchmark_curves(sol, stepper) -> dict:
    """What the benchmark reports of a solve ``sol`` (`hyperoc.dynamics.stepper.StateSolution`) by ``stepper``,
    at every level: ``t`` (N+1,) s; ``p0``, ``p1`` (N+1, 3) displacements of the probe points, m; ``volume``
    (N+1,) the cavity volume, m^3; ``pressure`` and ``tension`` (N+1,) the endocardial pressure and the active
    tension, Pa (zero for a load the step leaves out)."""
    from ..dynamics.terms import DynamicPressure, PrescribedTension
    from ..fem.probes import probe_matrix
    from ..mechanics.cavity import CavityVolume

    model = sol.model
    U = sol.displacement()  # (N+1, nodes, 3)
    probes = probe_matrix(model.space, np.array([P0, P1]))
    at_points = np.einsum("pn,lnc->lpc", probes.toarray(), U)
    volume = CavityVolume(model, "endocardium", apex="rim").volumes(sol.y0)
    return {"t": sol.t, "p0": at_points[:, 0], "p1": at_points[:, 1], "volume": volume,
            "pressure": _law_values(stepper, DynamicPressure, sol.t),
            "tension": _law_values(stepper, PrescribedTension, sol.t)}


def _law_values(stepper, kind: type, t: np.ndarray) -> np.ndarray:
    """The time law of ``stepper``'s term of class ``kind`` at ``t`` (zero without such a term)."""
    for term in stepper.terms:
        if isinstance(term, kind):
            return np.array([float(term.law(s)) for s in t])
    return np.zeros_like(t)


def compare_with_codes(record: dict) -> dict:
    """hyperoc's curves of ``record`` (`benchmark_curves` plus ``"step"``) against the band of the participating
    codes (`hyperoc.cardiac.benchmark_curves.curve_band`) at their sampling times (`SAMPLE_DT`) up to the
    record's end.

    Per quantity (``p0``, ``p1`` components; ``|p0|``, ``|p1|``, ``volume``): ``inside``, the fraction of
    samples (and components) inside the band; ``worst``, the largest distance outside it relative to the
    band's largest magnitude; ``peak``, hyperoc's peak magnitude and the codes' range of theirs (only when the
    record covers the whole beat)."""
    curves = reference_curves(record["step"])
    t = record["t"]
    times = sample_times(t[-1])
    ours = _sampled(record, times)
    result = {}
    for quantity, values in ours.items():
        band = curve_band(curves, times, quantity)
        covered = band["count"] > 0
        lower, upper, mine = band["lower"][covered], band["upper"][covered], values[covered]
        outside = np.maximum(lower - mine, mine - upper).clip(min=0.0)
        scale = np.nanmax(np.abs(np.concatenate([np.ravel(lower), np.ravel(upper)])))
        # inside up to the round-off of interpolating (a code's own curve is inside its band)
        entry = {"inside": float(np.mean(outside <= 1e-12 * scale)), "worst": float(np.max(outside) / scale)}
        if quantity.startswith("|") and t[-1] >= 1.0 - 1e-9:
            peaks = [np.max(np.linalg.norm(c[quantity.strip("|")], axis=1)) for c in curves.values()]
            entry["peak"] = {"hyperoc": float(np.max(values)), "codes": [float(min(peaks)), float(max(peaks))]}
        result[quantity] = entry
    return result


def sample_times(t_end: float) -> np.ndarray:
    """The codes' sampling times (s): every `SAMPLE_DT` from 0 to ``t_end``."""
    return np.round(np.arange(0.0, t_end + 1e-9, SAMPLE_DT), 12)


def resampled(record: dict, times: np.ndarray, names) -> dict:
    """The record's curves ``names`` interpolated linearly onto ``times`` (m,): (m,) or, for vectors, (m, 3)."""
    t = np.asarray(record["t"])

    def on(values):
        values = np.asarray(values)
        if values.ndim == 1:
            return np.interp(times, t, values)
        return np.stack([np.interp(times, t, column) for column in values.T], axis=1)

    return {name: on(record[name]) for name in names}


def _sampled(record: dict, times: np.ndarray) -> dict:
    """The compared quantities at ``times``: ``p0``, ``p1`` (m, 3), ``|p0|``, ``|p1|``, ``volume`` (m,)."""
    out = resampled(record, times, ("p0", "p1"))
    out.update({f"|{name}|": np.linalg.norm(out[name], axis=1) for name in ("p0", "p1")})
    out.update(resampled(record, times, ("volume",)))
    return out

"""The clinical indices of a beat: ejections, stroke volume, ejection fraction, valve events.

A run closed by the lumped circulation (`hyperoc.dynamics.constraint.Circulation`) carries after each step n the
phase in force for step n + 1: 0 isovolumic, 1 ejection (aortic valve open), 2 filling (mitral valve open). The
phase of level n (n >= 1) is the one carried after step n - 1, the phase of the step from level n to n + 1.
An ejection is a maximal run of ejecting levels n_s, ..., n_e - 1: the ventricle ejects over the steps n_s to
n_e - 1, so that

    EDV = V(t_{n_s}),  ESV = V(t_{n_e}),  SV = EDV - ESV,  EF = SV / EDV,

with V the cavity volume the constraint holds (length^3). The phase of level 0 is not carried; a run that starts
in ejection counts its first ejection from level 1.
"""

from __future__ import annotations

import numpy as np

from ..dynamics.constraint import Circulation

__all__ = ["PHASES", "beat_indices", "level_phases", "solution_beat"]

#: The phases by their carried number.
PHASES = Circulation.PHASES
_ISOVOLUMIC, _EJECTION = PHASES.index("isovolumic"), PHASES.index("ejection")


def level_phases(carried_phases: np.ndarray) -> np.ndarray:
    """The phase of each level (N+1,) from the phases carried after each step (N,): level 0 has none (-1)."""
    return np.concatenate([[-1], np.rint(np.asarray(carried_phases, dtype=np.float64)).astype(int)])


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """The maximal runs ``[start, end)`` of True in ``mask`` (L,)."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def beat_indices(t: np.ndarray, volume: np.ndarray, pressure: np.ndarray, carried_phases: np.ndarray) -> dict:
    """The indices of a run: ``t``, ``volume`` (length^3) and ``pressure`` at the levels (N+1,), the phases
    carried after each step (N,).

    Returns ``{"valve_events": [{"t", "phase"}...], "ejections": [{"start", "end", "end_diastolic_volume",
    "end_systolic_volume", "stroke_volume", "ejection_fraction", "peak_pressure"}...],
    "isovolumic_volume_change": max |V(t_{n+1}) - V(t_n)| / V(t_0) over the isovolumic steps}``: a valve event
    is the level from which a new phase is in force; an ejection that reaches the last level has
    ``"end": None`` and no end-systolic volume, stroke volume or ejection fraction.
    """
    t, V, p = (np.asarray(a, dtype=np.float64) for a in (t, volume, pressure))
    phase = level_phases(carried_phases)
    changes = np.flatnonzero(np.diff(phase[1:]) != 0) + 2
    events = [{"t": float(t[n]), "phase": PHASES[phase[n]]} for n in changes]
    ejections = []
    for start, end in _runs(phase == _EJECTION):
        closed = end < t.size
        entry = {"start": float(t[start]), "end": float(t[end]) if closed else None,
                 "end_diastolic_volume": float(V[start]),
                 "peak_pressure": float(np.max(p[start:end + 1]))}
        if closed:
            sv = float(V[start] - V[end])
            entry.update(end_systolic_volume=float(V[end]), stroke_volume=sv, ejection_fraction=sv / float(V[start]))
        ejections.append(entry)
    steps = np.flatnonzero(phase[:-1] == _ISOVOLUMIC)
    change = np.abs(V[steps + 1] - V[steps]) / abs(V[0]) if steps.size else np.zeros(1)
    return {"valve_events": events, "ejections": ejections, "isovolumic_volume_change": float(np.max(change))}


def solution_beat(sol) -> dict | None:
    """`beat_indices` of a `hyperoc.dynamics.stepper.StateSolution` closed by the circulation, on the volume its
    constraint holds; None for the other constraints."""
    if sol.multiplier_states is None or sol.constrained_volume is None:
        return None
    return beat_indices(sol.t, sol.constrained_volume, sol.pressure, sol.multiplier_states[:, 2])

"""`hyperoc.cardiac.hemodynamics.beat_indices`: the valve events, ejections and isovolumic volume change of a run
from the phases its circulation carries after each step.

- On a hand-made run of 10 steps (phases carried after each step: isovolumic, ejection, isovolumic, filling,
  isovolumic) the events are the levels from which a new phase holds, the ejection spans its levels, and the
  stroke volume is the volume at the ejection's first level minus the one at its end.
- An ejection still open at the last level has no end, stroke volume or ejection fraction.
- The isovolumic volume change is read on the isovolumic steps only.
"""

import numpy as np
import pytest

from hyperoc.cardiac.hemodynamics import beat_indices, level_phases

#: after steps 0..9: the phase in force from levels 1..10
CARRIED = np.array([0, 0, 1, 1, 1, 0, 0, 2, 2, 0], dtype=float)


def test_levels_take_the_phase_carried_after_the_step_before_them():
    np.testing.assert_array_equal(level_phases(CARRIED), [-1, 0, 0, 1, 1, 1, 0, 0, 2, 2, 0])


def test_events_ejection_and_stroke_volume_of_a_hand_made_beat():
    t = np.linspace(0.0, 1.0, 11)
    V = np.array([10.0, 10.0, 10.0, 10.0, 9.0, 8.0, 7.0, 7.0, 7.0, 8.0, 9.0])
    p = np.array([0.0, 1.0, 5.0, 8.0, 9.0, 8.5, 6.0, 2.0, 0.5, 0.2, 0.1])
    out = beat_indices(t, V, p, CARRIED)
    assert [(e["t"], e["phase"]) for e in out["valve_events"]] == [
        (pytest.approx(0.3), "ejection"), (pytest.approx(0.6), "isovolumic"), (pytest.approx(0.8), "filling"),
        (pytest.approx(1.0), "isovolumic")]
    (ej,) = out["ejections"]
    assert ej["start"] == pytest.approx(0.3) and ej["end"] == pytest.approx(0.6)
    assert ej["end_diastolic_volume"] == 10.0 and ej["end_systolic_volume"] == 7.0
    assert ej["stroke_volume"] == 3.0 and ej["ejection_fraction"] == pytest.approx(0.3, rel=1e-15)
    assert ej["peak_pressure"] == 9.0
    assert out["isovolumic_volume_change"] == 0.0  # steps 1, 2, 6, 7 hold the volume; steps 5 and 9 eject, fill


def test_an_ejection_open_at_the_end_has_no_stroke_volume():
    t = np.linspace(0.0, 0.4, 5)
    out = beat_indices(t, np.array([5.0, 5.0, 5.0, 5.0, 4.5]), np.arange(5.0), np.array([0, 0, 1, 1], float))
    (ej,) = out["ejections"]
    assert ej["end"] is None and "stroke_volume" not in ej and ej["end_diastolic_volume"] == 5.0


def test_the_isovolumic_change_reads_the_isovolumic_steps():
    t = np.linspace(0.0, 0.4, 5)
    V = np.array([4.0, 3.0, 3.0 + 4e-10, 3.0 + 4e-10, 2.0])
    out = beat_indices(t, V, np.zeros(5), np.array([0, 0, 1, 1], float))
    # steps 1 and 2 are isovolumic; step 0's phase is not carried, step 3 ejects
    assert out["isovolumic_volume_change"] == pytest.approx(1e-10, rel=1e-6)

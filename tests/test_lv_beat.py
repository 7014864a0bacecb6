"""``hyperoc reproduce lv-beat`` (`hyperoc.app.lv_beat`): the paper's hybrid problem on a beat of the benchmark
ventricle closed by a Windkessel (the LV pressure the cavity's multiplier), max dp/dt at tau by an apical active
tension.

- The rate of pressure rise of the job's figures and summary is the objective's finite difference.
- The exact gradient of the job's problem: Taylor rates 2.00 +- 0.05 in xi, tau and jointly, on its first 20 ms
  (slow: its terms' gradients are checked one by one in the fast tier, in test_cavity_constraint,
  test_circulation and test_controls).
- The job (slow): converges to a KKT point, raises dp/dt at tau* over the uncontrolled beat, keeps the control
  within its bounds; both beats eject once, after the objective's window, and hold the cavity volume to 1e-10
  over their isovolumic steps; the job writes its figures and folders.
- ``--quick`` / ``--workers`` belong to paper-1d: one line, exit 2, nothing written.
"""

import json

import numpy as np
import pytest

from hyperoc import ControlPoint, taylor_test
from hyperoc.app.cli import main
from hyperoc.app.lv_beat import beat_config, pressure_rise, reproduce_lv_beat
from hyperoc.app.workflows import build_reduced
from hyperoc.control.verification import random_directions


def test_pressure_rise_is_the_forward_difference_over_eps():
    t = np.linspace(0.0, 0.06, 61)
    p = 3e5 * t**2
    eps = 2e-3
    rise = pressure_rise(t, p, eps)
    assert rise.size == 59  # the last two levels have no t + eps inside the run
    np.testing.assert_allclose(rise, 3e5 * (2 * t[:59] + eps), rtol=1e-12)


@pytest.mark.slow
def test_exact_gradient_of_the_beat_problem():
    """The job's config on [0, 20 ms] at tau = 12 ms, from a control adding up to 30 % to the prescribed tension:
    Taylor rates of the exact gradient (the control scaled by T_a(t) at the levels tau moves). Full Newton: chord
    Newton leaves p's last correction out of the remainders."""
    cfg = beat_config({"dynamics.T": 0.02, "dynamics.newton": "full"})
    J = build_reduced(cfg, 0.012)
    base = random_directions(J, J.zero(0.012), seed=1)["xi"].xi
    m = ControlPoint(-0.3 * np.abs(base) / np.max(np.abs(base)), 0.012)
    for name, dm in random_directions(J, m, seed=2).items():
        r = taylor_test(J, m, dm)
        print(name, r.as_dict())
        assert r.remainder.size >= 3, (name, r.as_dict())
        assert abs(r.rate - 2.0) <= 0.05, (name, r.as_dict())


@pytest.mark.slow
def test_the_job_converges_and_raises_the_rate_of_pressure_rise(tmp_path):
    """The job as shipped: a KKT point (projected gradient 1e-6 of the start's) that raises dp/dt at tau*, the
    control within its bounds (a contraction between 0 and 2 T_a); each beat ejects once, its aortic valve opening
    after tau* + eps (the objective reads the isovolumic contraction) and closing before the end, and holds the
    cavity volume to Newton's tolerance (1e-10) over its isovolumic steps."""
    out = tmp_path / "beat"
    s = reproduce_lv_beat(out)
    print(json.dumps({k: v for k, v in s.items() if k != "objective_terms"}, indent=1))
    assert s["converged"] and s["relative_gradient"] <= 1e-6
    assert s["pressure_rise_gain"] > 0 and s["gain_over_uncontrolled_max"] > 0
    assert -1.0 <= s["control_min"] < 0 and s["control_max"] <= 1.0
    eps = beat_config()["objective"]["eps"]
    for name, beat in s["beat"].items():
        (ejection,) = beat["ejections"]
        assert s["tau"] + eps < ejection["start"] < ejection["end"], (name, ejection)
        assert 0 < ejection["stroke_volume"] < ejection["end_diastolic_volume"], (name, ejection)
        assert beat["isovolumic_volume_change"] <= 1e-10, name
    for name in ("summary.json", "pressure.png", "pv_loops.png", "optimized/summary.json",
                 "optimized/paraview/state.xdmf", "uncontrolled/summary.json"):
        assert (out / name).is_file(), name
    assert json.loads((out / "summary.json").read_text())["tau"] == s["tau"]


@pytest.mark.parametrize("option", [["--quick"], ["--workers", "1"]])
def test_paper_options_are_refused_for_the_beat(tmp_path, capsys, option):
    out = tmp_path / "out"
    code = main(["reproduce", "lv-beat", "--out", str(out), *option])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "apply to paper-1d" in err and "\n" not in err, err
    assert not out.exists()

"""The configuration of the cardiac terms (``[dynamics] constraint, robin, pressure, activation``,
``[material] viscosity``, ``[mesh] scale, clamped``): bad input is one line and exit 2 with nothing
written; a small problem with every term runs through ``hyperoc simulate`` and matches the same problem
built in Python step for step."""

import json
import tomllib

import numpy as np
import pytest

from hyperoc.app.cli import main
from hyperoc.app.config import parse_config, time_law
from hyperoc.dynamics.laws import Constant, ExpressionLaw, OdeLaw, Table
from hyperoc.dynamics.stepper import TimeStepper
from hyperoc.dynamics.terms import DynamicPressure, PrescribedTension, RobinBoundary, Viscosity

BOX = """
[mesh]
kind = "box"
nx = 2
ny = 1
nz = 1
clamped = false

[material]
law = "holzapfel-ogden"
isochoric = false
bulk_modulus = 50.0
viscosity = 0.5

[fibres]
kind = "rule_based"
long_axis = [0.0, 0.0, 1.0]
inner = "left"
outer = "right"

[dynamics]
T = 0.04
dt = 0.01
damping = 0.0
constraint = "none"
solver = "lu"

[[dynamics.robin]]
boundary = "left"
stiffness = 10.0
damping = 1.0

[[dynamics.robin]]
boundary = "right"
stiffness = 5.0
direction = "normal"

[dynamics.pressure]
boundary = "top"
law = { times = [0.0, 0.02, 0.04], values = [0.0, 1.0, 0.5] }

[dynamics.activation]
law = "2.0*t"
"""


def _write(tmp_path, text):
    path = tmp_path / "run.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("change, message", [
    ((BOX[BOX.index('law = "holzapfel'):BOX.index('[dynamics]')], 'law = "neo-hookean"\nmu = 1.0\nlambda = 1.0\n'),
     "activation needs fibres"),
    (('times = [0.0, 0.02, 0.04]', 'times = [0.0, 0.04, 0.02]'), "strictly increasing"),
    (('boundary = "left"', 'boundary = "nowhere"'), "no boundary tag 'nowhere'"),
    (('direction = "normal"', 'direction = "tangential"'), "direction"),
    (('law = "2.0*t"', 'law = "2.0*q"'), "q"),
    (('viscosity = 0.5', 'viscosity = -0.5'), "viscosity"),
    (('constraint = "none"', 'constraint = "cavity"'), "constraint"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, change, message):
    text = BOX.replace(*change)
    assert text != BOX
    out = tmp_path / "out"
    code = main(["simulate", str(_write(tmp_path, text)), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and "\n" not in err, err
    assert not out.exists()


def test_time_law_spellings():
    assert isinstance(time_law(3.0), Constant) and isinstance(time_law("sin(t)"), ExpressionLaw)
    assert isinstance(time_law({"times": [0, 1], "values": [1, 2]}), Table)
    law = time_law({"bestel": "activation", "t_end": 0.5, "parameters": {"sigma_0": 1.0}})
    assert isinstance(law, OdeLaw) and law.t1 == 0.5


def test_simulate_matches_the_python_model(tmp_path):
    """``hyperoc simulate`` of a box with every term equals the same stepper built from the terms."""
    text = BOX
    path = _write(tmp_path, text)
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 4 and summary["pressure_max"] == summary["pressure_min"] == 0.0

    cfg = parse_config(tomllib.loads(text), tmp_path)
    model = cfg.model()
    terms = cfg.step_terms(model)
    assert [type(t) for t in terms] == [RobinBoundary, RobinBoundary, DynamicPressure, PrescribedTension, Viscosity]
    stepper = TimeStepper(model, cfg.scheme(), "lu", terms=terms, constraint="none")
    sol = stepper.run(cfg.grid(), diagnose=False)
    np.testing.assert_array_equal(np.load(out / "results.npz")["displacement"], sol.displacement())
    assert np.max(np.abs(sol.y0[-1])) > 1e-4  # the loads moved the body

"""Every example configuration runs through ``hyperoc simulate`` at degree 1 and 2, on a few time
steps, to the end (outputs and the post-solve regime checks included)."""

import json
import math
import tomllib
from pathlib import Path

import pytest

from hyperoc.app.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
# Gmsh meshes, 2D/3D kernels to compile
SLOW = {"annulus-2d.toml", "shell-3d.toml", "ventricle-3d.toml", "cardiac-benchmark-coarse.toml",
        "cardiac-circulation.toml"}


def _short_run(path: Path) -> list:
    """Overrides for a run of a few steps: T the fewest steps dt that leave tau0 = dt inside
    (0, T - eps), with at least two steps."""
    cfg = tomllib.loads(path.read_text())
    dt, eps = cfg["dynamics"]["dt"], cfg.get("objective", {}).get("eps", 0.0)
    steps = math.ceil(eps / dt) + 2
    return [f"dynamics.T={steps * dt!r}", f"optimize.tau0={dt!r}"]


CASES = [pytest.param(name, degree, marks=[pytest.mark.slow] if name in SLOW else [], id=f"{name}-P{degree}")
         for name in sorted(p.name for p in EXAMPLES.glob("*.toml")) for degree in (1, 2)]


@pytest.mark.parametrize("name, degree", CASES)
def test_example_simulates(tmp_path, capsys, name, degree):
    sets = [*_short_run(EXAMPLES / name), f"mesh.degree={degree}"]
    out = tmp_path / "out"
    code = main(["simulate", str(EXAMPLES / name), "--out", str(out), "--no-progress",
                 *(a for s in sets for a in ("--set", s))])
    assert code == 0, capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert math.isfinite(summary["pressure_max"])
    constraint = tomllib.loads((EXAMPLES / name).read_text())["dynamics"].get("constraint", "tissue_volume")
    if constraint == "tissue_volume":
        assert summary["volume_drift"] < 1e-8
    elif constraint == "none":  # no multiplier: the pressure reported is 0
        assert summary["pressure_max"] == summary["pressure_min"] == 0.0
    else:  # a cavity: its pressure-volume loop
        assert (out / summary["files"]["pv_loop_plot"]).exists()


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.toml")))
def test_every_example_declares_its_units(name):
    """The figures of every example carry its units (``[output] units``, "-" where dimensionless)."""
    units = tomllib.loads((EXAMPLES / name).read_text()).get("output", {}).get("units", {})
    assert set(units) == {"time", "length", "pressure", "control"}

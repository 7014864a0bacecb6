"""The cardiac benchmark command (`hyperoc benchmark cardiac-elastodynamics`) on hyperoc's coarse mesh of the
benchmark domain: its files, its resume from checkpoints, and its refusals."""

import json

import numpy as np
import pytest

from hyperoc.app.cli import main
from hyperoc.cardiac.benchmark import benchmark_config, compare_with_codes
from hyperoc.cardiac.benchmark_curves import reference_curves


def test_the_steps_leave_out_the_loads_the_benchmark_leaves_out():
    """0A keeps only the activation, 0B only the pressure, 1 both."""
    loads = {step: {k for k in ("pressure", "activation") if benchmark_config(step, mesh="coarse")["dynamics"].get(k)}
             for step in ("0A", "0B", "1")}
    assert loads == {"0A": {"activation"}, "0B": {"pressure"}, "1": {"pressure", "activation"}}


def test_a_code_s_own_curve_lies_inside_the_band():
    """The comparison puts one participating code's curve inside the band at every sampling time."""
    code = reference_curves("1")["CHeart"]
    record = {"step": "1", "t": code["t"], "p0": code["p0"], "p1": code["p1"], "volume": code["volume"]}
    comparison = compare_with_codes(record)
    assert all(c["inside"] == 1.0 and c["worst"] < 1e-12 for c in comparison.values())
    assert comparison["|p0|"]["peak"]["codes"][0] <= comparison["|p0|"]["peak"]["hyperoc"]


def test_benchmark_command_writes_its_files_and_resumes_from_its_checkpoints(tmp_path, capsys):
    out = tmp_path / "beat"
    args = ["benchmark", "cardiac-elastodynamics", "--mesh", "coarse", "--end-time", "0.06", "--out", str(out),
            "--no-progress"]
    assert main(args) == 0
    for name in ("benchmark.json", "curves.npz", "displacements.png", "volume.png", "segments/segment_00001.npz"):
        assert (out / name).is_file(), name
    entry = json.loads((out / "benchmark.json").read_text())
    assert entry["step"] == "1" and entry["degree"] == 1 and entry["dt"] == 1e-3
    assert np.allclose(entry["t"], np.arange(0.0, 0.0601, 0.01))
    assert np.asarray(entry["p0"]).shape == (7, 3) and np.all(np.isfinite(entry["volume"]))
    assert main(args) == 2  # the folder holds a checkpointed run
    assert "--resume" in capsys.readouterr().err
    (out / "segments" / "segment_00001.npz").unlink()
    assert main([*args, "--resume"]) == 0
    assert json.loads((out / "benchmark.json").read_text())["p0"] == entry["p0"]


@pytest.mark.parametrize("extra", [["--end-time", "2"], ["--step", "2"], ["--degree", "3"]])
def test_benchmark_command_refuses_bad_options(tmp_path, extra, capsys):
    out = tmp_path / "bad"
    assert main(["benchmark", "cardiac-elastodynamics", "--mesh", "coarse", "--out", str(out), *extra]) == 2
    assert not out.exists()
    assert capsys.readouterr().err.startswith("hyperoc: error:")

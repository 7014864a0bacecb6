"""The README's main job, ``hyperoc reproduce paper-1d``, on a coarse grid with a few iterations.

The full run is measured by bench/bench_paper_job.py; here the same code path runs on h = 0.05, dt = 0.1,
3 iterations, so that the job's structure (studies, files, parallel workers) cannot rot.
"""

import json

import numpy as np
import pytest

from hyperoc.cli import main
from hyperoc.paper import SPG_WINDOW, XI_MAX, reproduce_paper_1d

SMALL = {"mesh__n": 20, "dynamics__dt": 0.1, "optimize__max_iter": 3}


@pytest.fixture(scope="module")
def parallel(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    return out, reproduce_paper_1d(out, progress=False, workers=2, overrides=SMALL)


@pytest.mark.slow
def test_every_study_writes_its_outputs(parallel):
    out, summary = parallel
    for name in ("summary.json", "ray.json", "resolution.json", "pressure.png", "control.png", "displacement.png",
                 "velocity.png", "results.npz"):
        assert (out / name).is_file(), name
    for folder in ("algorithm1", "bounded", "bounded_dt2", "bounded_h2"):
        assert (out / folder / "summary.json").is_file(), folder
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["tau"] == summary["tau"] and on_disk["workers"] == 2


@pytest.mark.slow
def test_studies_use_the_stated_variants(parallel):
    _, summary = parallel
    T = summary["config"]["dynamics"]["T"]
    runs = summary["runs"]
    assert runs["algorithm1"]["xi_bounds"] is None
    assert runs["bounded"]["xi_bounds"] == [-XI_MAX, XI_MAX]
    assert runs["bounded"]["max_abs_xi"] <= XI_MAX
    assert runs["algorithm1"]["nonmonotone"] == 0  # the paper's Algorithm 1; the bounded runs by SPG
    assert all(r["nonmonotone"] == SPG_WINDOW for r in [runs["bounded"], *summary["resolution"]])
    by_label = {r["label"]: r for r in summary["resolution"]}
    assert by_label["bounded, dt/2"]["dt"] == pytest.approx(runs["bounded"]["dt"] / 2)
    assert by_label["bounded, h/2"]["h"] == pytest.approx(runs["bounded"]["h"] / 2)
    for r in list(runs.values()) + summary["resolution"]:
        assert 0 < r["tau"] < T
        assert r["iterations"] <= SMALL["optimize__max_iter"]
    scales = [row["scale"] for row in summary["ray"]]
    assert scales == sorted(scales) and 1.0 in scales


@pytest.mark.slow
def test_parallel_and_serial_runs_agree(parallel, tmp_path):
    """The optimizers are deterministic: worker processes and the shared compiled problem change
    where and how often things are compiled, not what is computed."""
    _, summary = parallel
    serial = reproduce_paper_1d(tmp_path, quick=True, progress=False, workers=1, overrides=SMALL)
    assert serial["resolution"] == []
    for key in ("algorithm1", "bounded"):
        assert serial["runs"][key]["tau"] == summary["runs"][key]["tau"]
        assert serial["runs"][key]["objective"] == summary["runs"][key]["objective"]
    np.testing.assert_array_equal([r["J"] for r in serial["ray"]], [r["J"] for r in summary["ray"]])


def test_quick_serial_job_writes_its_outputs_and_uses_the_stated_variants(tmp_path):
    """The fast tier's run of the job: ``quick`` (no resolution study), one process, a coarser grid
    (h = 0.1, dt = 0.2) and 2 iterations; the outputs and study variants of the tests above."""
    small = {"mesh__n": 10, "dynamics__dt": 0.2, "optimize__max_iter": 2}
    summary = reproduce_paper_1d(tmp_path, quick=True, progress=False, workers=1, overrides=small)
    for name in ("summary.json", "ray.json", "pressure.png", "control.png", "displacement.png", "velocity.png",
                 "results.npz"):
        assert (tmp_path / name).is_file(), name
    for folder in ("algorithm1", "bounded"):
        assert (tmp_path / folder / "summary.json").is_file(), folder
    assert summary["resolution"] == [] and not (tmp_path / "resolution.json").exists()
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk["tau"] == summary["tau"] and on_disk["workers"] == 1
    T = summary["config"]["dynamics"]["T"]
    runs = summary["runs"]
    assert runs["algorithm1"]["xi_bounds"] is None and runs["algorithm1"]["nonmonotone"] == 0
    assert runs["bounded"]["xi_bounds"] == [-XI_MAX, XI_MAX] and runs["bounded"]["max_abs_xi"] <= XI_MAX
    assert runs["bounded"]["nonmonotone"] == SPG_WINDOW
    for r in runs.values():
        assert 0 < r["tau"] < T and r["iterations"] <= small["optimize__max_iter"]
    scales = [row["scale"] for row in summary["ray"]]
    assert scales == sorted(scales) and 1.0 in scales


def test_bad_worker_count_is_an_input_error(tmp_path, capsys):
    assert main(["reproduce", "paper-1d", "--out", str(tmp_path), "--workers", "0", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "workers" in err[0]

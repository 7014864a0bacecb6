"""The README's main job, ``hyperoc reproduce paper-1d``, on coarse grids.

The full run is measured by bench/bench_paper_job.py; here the same code path runs on coarse grids, so that
the job's structure (headline, diagnostics, files, parallel workers) cannot rot, and the headline's
Newton-CG run is checked to reach the KKT tolerance.
"""

import json

import numpy as np
import pytest

from hyperoc.app.cli import main
from hyperoc.app.paper import PAPER_REPORT, SPG_WINDOW, WELL_POSED, XI_MAX, reproduce_paper_1d, wellposed_config
from hyperoc.app.workflows import build_reduced
from hyperoc.control.optimize import lbfgsb

SMALL = {"mesh.n": 20, "dynamics.dt": 0.1, "optimize.max_iter": 3}
HEADLINE_KEYS = ("tau", "objective", "iterations", "converged", "grad_norm_history", "objective_history",
                 "tau_history", "alpha", "beta", "paper")
FIGURES = ("pressure.png", "control.png", "displacement.png", "velocity.png", "control_snapshots.png",
           "history.png")


@pytest.fixture(scope="module")
def parallel(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    return out, reproduce_paper_1d(out, progress=False, workers=2, overrides=SMALL)


@pytest.mark.slow
def test_every_study_writes_its_outputs(parallel):
    out, summary = parallel
    for name in ("summary.json", "ray.json", "results.npz", *FIGURES):
        assert (out / name).is_file(), name
    for folder in ("as_stated", "bounded"):
        assert (out / folder / "summary.json").is_file(), folder
        assert (out / folder / "pressure.png").is_file(), folder
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["tau"] == summary["tau"] and on_disk["workers"] == 2


@pytest.mark.slow
def test_diagnostics_use_the_stated_variants(parallel):
    _, summary = parallel
    T = summary["config"]["dynamics"]["T"]
    runs = summary["diagnostics"]
    assert set(runs) == {"as_stated", "bounded"}
    assert runs["as_stated"]["xi_bounds"] is None and runs["as_stated"]["beta"] == 0.0
    assert runs["as_stated"]["alpha"] == PAPER_REPORT["alpha"] and runs["as_stated"]["method"] == "bb"
    assert runs["as_stated"]["nonmonotone"] == 0  # the paper's Algorithm 1; the bounded run by SPG
    assert runs["bounded"]["xi_bounds"] == [-XI_MAX, XI_MAX] and runs["bounded"]["max_abs_xi"] <= XI_MAX
    assert runs["bounded"]["nonmonotone"] == SPG_WINDOW
    for r in runs.values():
        assert 0 < r["tau"] < T and r["iterations"] <= SMALL["optimize.max_iter"]
    scales = [row["scale"] for row in summary["ray"]]
    assert scales == sorted(scales) and 1.0 in scales


@pytest.mark.slow
def test_parallel_and_serial_headlines_agree(parallel, tmp_path):
    """The optimizers are deterministic: worker processes change where things are computed, not what."""
    _, summary = parallel
    serial = reproduce_paper_1d(tmp_path, quick=True, progress=False, workers=1, overrides=SMALL)
    assert serial["diagnostics"] == {} and serial["ray"] == []
    assert serial["tau"] == summary["tau"] and serial["objective"] == summary["objective"]
    np.testing.assert_array_equal(serial["grad_norm_history"], summary["grad_norm_history"])


def test_headline_converges_to_the_kkt_tolerance(tmp_path):
    """The fast tier's run of the job: ``quick`` (the headline only), one process, h = 0.05, dt = 0.1.
    The headline (Newton-CG) must end at a KKT point of the well-posed problem, relative gradient <= gtol,
    and L-BFGS-B from the same start at the same maximizer."""
    coarse = {"mesh.n": 20, "dynamics.dt": 0.1}
    summary = reproduce_paper_1d(tmp_path, quick=True, progress=False, workers=1, overrides=coarse)
    for name in ("summary.json", "results.npz", *FIGURES):
        assert (tmp_path / name).is_file(), name
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    for key in HEADLINE_KEYS:
        assert key in on_disk, key
    assert on_disk["converged"] is True and on_disk["iterations"] <= summary["config"]["optimize"]["max_iter"]
    g = on_disk["grad_norm_history"]
    assert g[-1] <= summary["config"]["optimize"]["gtol"] * g[0]
    assert on_disk["relative_gradient"] == pytest.approx(g[-1] / g[0])
    assert (on_disk["alpha"], on_disk["beta"]) == (WELL_POSED["objective.alpha"], WELL_POSED["objective.beta"])
    assert on_disk["paper"] == PAPER_REPORT and on_disk["diagnostics"] == {}
    T = summary["config"]["dynamics"]["T"]
    assert 0 < on_disk["tau"] < T and on_disk["objective"] > 0
    assert on_disk["min_det_F"] > 0.5  # the maximizer keeps every element well inside the elastic range

    J = build_reduced(wellposed_config(coarse), PAPER_REPORT["tau0"])
    res = lbfgsb(J, J.zero(PAPER_REPORT["tau0"]), gtol=1e-6, max_iter=100)
    assert res.converged
    # Two points with relative gradients <= 1e-6 (|G| <= 2e-7 here) on a ridge whose curvature along tau
    # is ~1e-3 (the well-posedness page): |d tau| <~ |G| / 1e-3 = 2e-4, |d J| <~ |G|^2 / 2e-3 = 2e-11.
    assert abs(res.point.tau - on_disk["tau"]) <= 2e-4
    assert abs(res.objective - on_disk["objective"]) <= 1e-10


def test_bad_worker_count_is_an_input_error(tmp_path, capsys):
    assert main(["reproduce", "paper-1d", "--out", str(tmp_path), "--workers", "0", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "workers" in err[0]


def test_the_job_process_imports_neither_jax_nor_scipy():
    """It only starts the workers: a process that loads OpenBLAS on two CPUs and is then bound to one keeps
    a spinning BLAS thread beside the job (hyperoc.app.paper._run_jobs)."""
    import subprocess
    import sys

    code = ("import sys, hyperoc.app.cli, hyperoc.app.paper, hyperoc._cache; "
            "print(sorted(m for m in ('jax', 'scipy', 'matplotlib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert out.strip() == "[]"

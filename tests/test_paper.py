"""The README's main job, ``hyperoc reproduce paper-1d``, on coarse grids.

The full run is measured by bench/bench_paper_job.py; here the same code path runs on coarse grids, so that
the job's structure (headline, the other formulations, the value profile, files, parallel workers) cannot
rot, and the headline's projected Newton-CG run is checked to reach the KKT tolerance.
"""

import json

import numpy as np
import pytest

from hyperoc.app.cli import main
from hyperoc.app.paper import (
    FORMULATIONS,
    HEADLINE,
    OMEGA_INTERIOR,
    PAPER_REPORT,
    PROFILE_TAUS,
    REFINED_MAXIMA,
    WELL_POSED,
    XI_MAX,
    cold_stationarity,
    formulation_config,
    profile_maxima,
    refined_maximum,
    reproduce_paper_1d,
)
from hyperoc.app.workflows import build_reduced, optimize_single
from hyperoc.control.optimize import BoxProblem, stationarity
from hyperoc.control.reduced import ControlPoint

SMALL = {"mesh.n": 20, "dynamics.dt": 0.1, "optimize.max_iter": 3}
COARSE = {"mesh.n": 20, "dynamics.dt": 0.1}  # h = 0.05: the paper's c dt / h
HEADLINE_KEYS = ("tau", "objective", "iterations", "converged", "relative_gradient", "grad_norm_history",
                 "objective_history", "tau_history", "alpha", "beta", "xi_bounds", "omega", "paper", "runs", "profile")
FIGURES = ("pressure.png", "control.png", "displacement.png", "velocity.png", "control_snapshots.png",
           "history.png")


@pytest.fixture(scope="module")
def parallel(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    return out, reproduce_paper_1d(out, progress=False, workers=2, overrides=SMALL)


@pytest.mark.slow
def test_every_study_writes_its_outputs(parallel):
    out, summary = parallel
    for name in ("summary.json", "ray.json", "results.npz", "profile.json", "profile.png", *FIGURES):
        assert (out / name).is_file(), name
    for key in FORMULATIONS:
        if key != HEADLINE:
            assert (out / key / "summary.json").is_file(), key
            assert (out / key / "pressure.png").is_file(), key
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["tau"] == summary["tau"] and on_disk["workers"] == 2


@pytest.mark.slow
def test_runs_name_each_formulation(parallel):
    _, summary = parallel
    T = summary["config"]["dynamics"]["T"]
    runs = {r["name"]: r for r in summary["runs"]}
    assert list(runs) == list(FORMULATIONS) and runs[HEADLINE]["folder"] == "."
    for key in ("bounded", "interior"):  # the paper's weights with the bound of its Remark rk-box
        assert (runs[key]["alpha"], runs[key]["beta"]) == (PAPER_REPORT["alpha"], 0.0)
        assert runs[key]["xi_bounds"] == [-XI_MAX, XI_MAX] and runs[key]["max_abs_xi"] <= XI_MAX
        assert runs[key]["method"] == "newton"
    assert runs["bounded"]["omega"] == [0.75, 1.0] and runs["interior"]["omega"] == OMEGA_INTERIOR
    assert (runs["smooth"]["alpha"], runs["smooth"]["beta"]) == (WELL_POSED["objective.alpha"],
                                                                 WELL_POSED["objective.beta"])
    assert runs["as_stated"]["xi_bounds"] is None and runs["as_stated"]["alpha"] == PAPER_REPORT["alpha"]
    assert runs["as_stated"]["method"] == "bb" and runs["as_stated"]["nonmonotone"] == 0  # Algorithm 1
    for r in runs.values():
        assert 0 < r["tau"] < T and r["iterations"] <= SMALL["optimize.max_iter"]
        assert set(r) >= {"converged", "relative_gradient", "objective", "tau"}
    scales = [row["scale"] for row in summary["ray"]]
    assert scales == sorted(scales) and 1.0 in scales


@pytest.mark.slow
def test_profile_covers_the_tau_grid(parallel):
    """One fixed-tau solve per point of PROFILE_TAUS, in increasing tau, of the headline's formulation, its maximum
    refined."""
    _, summary = parallel
    q = summary["profile"]
    assert q["tau"] == list(PROFILE_TAUS) and len(q["J"]) == len(q["converged"]) == len(PROFILE_TAUS)
    assert q["formulation"] == HEADLINE and all(np.isfinite(q["J"]))
    assert q["tau"][0] <= q["tau_refined"] <= q["tau"][-1] and q["J_refined"] >= max(q["J"]) - 1e-15


def test_refined_maximum_is_the_vertex_of_a_parabola():
    taus = np.arange(1.0, 8.0)
    assert refined_maximum(taus, -(taus - 3.3) ** 2 + 2.0) == pytest.approx((3.3, 2.0), abs=1e-12)
    assert refined_maximum(taus, taus) == (7.0, 7.0)  # at an end: the grid point


@pytest.mark.slow
def test_parallel_and_serial_headlines_agree(parallel, tmp_path):
    """The optimizers are deterministic: worker processes change where things are computed, not what."""
    _, summary = parallel
    serial = reproduce_paper_1d(tmp_path, quick=True, progress=False, workers=1, overrides=SMALL)
    assert [r["name"] for r in serial["runs"]] == [HEADLINE] and serial["ray"] == []
    assert serial["profile"]["J"] == summary["profile"]["J"]
    assert serial["tau"] == summary["tau"] and serial["objective"] == summary["objective"]
    np.testing.assert_array_equal(serial["grad_norm_history"], summary["grad_norm_history"])


def test_headline_converges_to_the_kkt_tolerance(tmp_path):
    """The fast tier's run of the job: ``quick`` (the value profile and the headline), one process, h = 0.05,
    dt = 0.1. The headline (Newton-CG, alpha = beta = 10) starts from the profile's largest maxima with tau
    free, keeps the best end, and must end at a KKT point: projected gradient <= gtol times the zero control's
    at its start."""
    summary = reproduce_paper_1d(tmp_path, quick=True, progress=False, workers=1, overrides=COARSE)
    for name in ("summary.json", "results.npz", "profile.json", "profile.png", *FIGURES):
        assert (tmp_path / name).is_file(), name
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    for key in HEADLINE_KEYS:
        assert key in on_disk, key
    assert on_disk["converged"] is True and on_disk["iterations"] <= summary["config"]["optimize"]["max_iter"]
    assert on_disk["relative_gradient"] <= summary["config"]["optimize"]["gtol"]
    assert (on_disk["alpha"], on_disk["beta"]) == (WELL_POSED["objective.alpha"], WELL_POSED["objective.beta"])
    assert on_disk["paper"] == PAPER_REPORT
    q = on_disk["profile"]
    maxima = [q["tau"][k] for k in profile_maxima(q["J"], REFINED_MAXIMA)]
    assert [end["tau0"] for end in q["maxima"]] == maxima
    assert on_disk["objective"] == max(end["objective"] for end in q["maxima"])
    T = summary["config"]["dynamics"]["T"]
    assert 0 < on_disk["tau"] < T and on_disk["objective"] > 0
    assert on_disk["min_det_F"] > 0.5  # the maximizer keeps every element well inside the elastic range

    # The KKT claim recomputed from the written control, on the headline's grid (built at its first start).
    cfg = formulation_config(HEADLINE, COARSE)
    J = build_reduced(cfg, q["maxima"][0]["tau0"])
    end = ControlPoint(np.load(tmp_path / "results.npz")["xi"][:, :, 0], on_disk["tau"])
    value, g = J.value_and_gradient(end)
    best = max(q["maxima"], key=lambda e: e["objective"])
    tau_range = BoxProblem.around(J, best["tau0"]).tau_range
    assert value == pytest.approx(on_disk["objective"], rel=1e-12)
    assert (stationarity(J, end, g, tau_range, (None, None))
            <= cfg["optimize"]["gtol"] * cold_stationarity(J, best["tau0"], tau_range, (None, None)))


def test_bounded_problem_reaches_a_kkt_point():
    """The paper's weights with the bound |xi| <= XI_MAX: projected Newton-CG ends at a KKT point, the
    projected gradient recomputed at its end point <= gtol times the zero control's, within the bound."""
    cfg = formulation_config("bounded", COARSE)
    J, res = optimize_single(cfg, PAPER_REPORT["tau0"])
    assert res.converged and np.abs(res.point.xi).max() <= XI_MAX
    bounds, tau_range = cfg.xi_bounds(), BoxProblem.around(J, PAPER_REPORT["tau0"]).tau_range
    zero = J.zero(PAPER_REPORT["tau0"])
    assert (stationarity(J, res.point, J.value_and_gradient(res.point)[1], tau_range, bounds)
            <= cfg["optimize"]["gtol"] * stationarity(J, zero, J.value_and_gradient(zero)[1], tau_range, bounds))


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


def test_profile_maxima_are_the_largest_local_maxima():
    values = [1.0, 3.0, 2.0, 2.5, 5.0, 4.0, 4.5]  # local maxima 3.0, 5.0 and the end 4.5
    assert profile_maxima(values, 2) == [4, 6] and profile_maxima(values, 5) == [4, 6, 1]
    assert profile_maxima([2.0, 1.0], 1) == [0]  # an end above its neighbour

"""The ventricle example end to end: [fibres] wiring, control regions (cap, band), bad regions,
exact-gradient Taylor rates on a very coarse ventricle, and the outputs of the example config.

One coarse reduced functional (the example config with h = 6 mm and a few time steps) is compiled
once (about 45 s of JAX compilation, most of this file's time) and shared by the Taylor tests and the
optimization run.
"""

import json
import math
import tomllib
from pathlib import Path

import meshio
import numpy as np
import pytest

from hyperoc import InputError, Region
from hyperoc.app.cli import main
from hyperoc.app.config import parse_config
from hyperoc.app.workflows import build_reduced, check_gradient, optimize_single, write_optimization_outputs
from hyperoc.fem import geometry
from hyperoc.io import read_npz
from hyperoc.mechanics.fibres import FibreFrames

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "ventricle-3d.toml"


def _example_data(**sections) -> dict:
    """The example's TOML as a dict, with sections updated key by key."""
    data = tomllib.loads(EXAMPLE.read_text())
    for name, values in sections.items():
        data.setdefault(name, {}).update(values)
    return data


# Very coarse: h = 6 mm (283 tetrahedra), T = 2 ms in 0.5 ms steps, eps = 0.5 ms, tau0 = 1 ms.
COARSE = dict(mesh={"h": 6.0}, dynamics={"T": 2.0, "dt": 0.5},
              objective={"eps": 0.5}, optimize={"tau0": 1.0, "max_iter": 2, "tau_margin": 0.25})


@pytest.fixture(scope="module")
def coarse():
    """(config, reduced functional at tau0)."""
    cfg = parse_config(_example_data(**COARSE), EXAMPLE.parent)
    return cfg, build_reduced(cfg, cfg.tau_starts()[0])


@pytest.fixture(scope="module")
def lv():
    return geometry.ventricle(2.5)


# ---- config wiring --------------------------------------------------------------------------------

def test_fibres_section_builds_the_frames_of_material_and_active_stress(coarse):
    """[fibres] rule_based gives FibreFrames with the configured helix angles; the active stress on the
    cap uses row 0 of those frames on the masked cells (the frames are evaluated per cell index)."""
    cfg, J = coarse
    model = J.model
    frames = cfg.fibres(model.mesh)
    assert isinstance(frames, FibreFrames)
    assert np.allclose(np.degrees(frames.helix), (60.0, -60.0))
    control = model.control
    assert 0 < control.cell_mask.sum() < model.mesh.num_cells
    expected = frames.cell_frames()[control.cell_mask, 0]
    np.testing.assert_allclose(control.fibres, expected, rtol=0, atol=1e-14)


def test_cardiac_law_without_fibres_is_an_input_error():
    cfg = parse_config(_example_data(mesh={"h": 6.0}, fibres={"kind": "none"}))
    with pytest.raises(InputError, match="needs fibres"):
        cfg.model()


# ---- regions ----------------------------------------------------------------------------------------

def _cap_volume(rs: float, rl: float, z: float) -> float:
    """Volume of the solid ellipsoid (rs, rs, rl) below the plane z: pi rs^2/rl^2 int (rl^2 - s^2) ds."""
    return math.pi * rs**2 / rl**2 * (rl**2 * (z + rl) - (z**3 + rl**3) / 3.0)


def test_cap_selects_the_wall_below_z_max(lv):
    """Cells with centroid z <= z_max; their volume is the analytic shell cap volume up to the cells cut
    by the plane (at most h/2 times the cut area, 154 mm^2 at z = -5)."""
    z_max = -5.0
    mask = Region("cap", z_max=z_max).cell_mask(lv)
    np.testing.assert_array_equal(mask, lv.cell_centroids()[:, 2] <= z_max)
    exact = _cap_volume(10.0, 20.0, z_max) - _cap_volume(7.0, 17.0, z_max)
    assert abs(lv.cell_volumes()[mask].sum() - exact) <= 0.5 * 2.5 * 154.0
    assert lv.points[np.unique(lv.cells[mask])][:, 2].min() == pytest.approx(-20.0, abs=0.1)  # holds the apex


def test_transmural_bands_split_the_wall(lv):
    """Bands [0, 1/2] and [1/2, 1] cover every cell; the inner one lies nearer the endocardium in the
    geometric sense: mean ellipsoidal level (semi-axes (7 + 3 t, 17 + 3 t)) of its centroids below that
    of the outer band."""
    inner = Region("band", transmural=(0.0, 0.5)).cell_mask(lv)
    outer = Region("band", transmural=(0.5, 1.0)).cell_mask(lv)
    assert np.all(inner | outer) and inner.any() and outer.any()
    assert np.all(Region("band", transmural=(0.0, 1.0)).cell_mask(lv))
    c = lv.cell_centroids()
    levels = np.linspace(0.0, 1.0, 301)
    g = (c[:, None, 0] ** 2 + c[:, None, 1] ** 2) / (7 + 3 * levels) ** 2 + c[:, None, 2] ** 2 / (17 + 3 * levels) ** 2
    t = levels[np.argmin(np.abs(g - 1.0), axis=1)]
    assert t[inner].mean() < 0.5 < t[outer].mean()


BAD_REGIONS = [
    ('{ kind = "band", transmural = [0.5, 1.5] }', "0 <= a < b <= 1"),
    ('{ kind = "band", transmural = [0.6, 0.2] }', "lower < upper"),
    ('{ kind = "cap", z_max = 10.0 }', "at or above the base"),
    ('{ kind = "cap", z_max = -30.0 }', "contains no cell"),
    ('{ kind = "cap", z_max = "low" }', "z_max must be a number"),
    ('{ kind = "slab" }', "region kind must be"),
]


@pytest.mark.parametrize("region, message", BAD_REGIONS)
def test_bad_region_exit_2_with_one_line(tmp_path, capsys, region, message):
    text = EXAMPLE.read_text().replace('region = { kind = "cap", z_max = -5.0 }', f"region = {region}")
    assert f"region = {region}" in text
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text.replace("h = 2.5", "h = 6.0"))
    assert main(["optimize", str(cfg), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hyperoc: error:") and message in lines[0], lines


# ---- exact gradient -------------------------------------------------------------------------------

@pytest.mark.slow
def test_taylor_rates_on_a_coarse_ventricle(coarse):
    """Remainders |J(m + h dm) - J(m) - h dJ.dm| = O(h^2) for xi, tau and joint directions: the rate is
    2 up to O(h^3) terms, so in [1.9, 2.1] on the asymptotic range (`taylor_test` finds it); a wrong
    gradient gives 1. The point and directions are those of `hyperoc check-gradient`."""
    cfg, J = coarse
    rates = check_gradient(cfg, J=J)
    assert set(rates) == {"xi", "tau", "joint"}
    for name, r in rates.items():
        assert len(r["remainder"]) >= 3 and 1.9 <= r["rate"] <= 2.1, (name, r)


# ---- the example config runs and writes what it promises --------------------------------------------

def last_time_series_level(path: Path) -> tuple:
    """(point_data, cell_data) of the last level of a time series: XDMF + HDF5 where h5py is installed
    (`hyperoc.io.time_series_format`), else the last VTU piece of the PVD collection."""
    if path.suffix == ".xdmf":
        with meshio.xdmf.TimeSeriesReader(path) as reader:
            reader.read_points_cells()
            _, point_data, cell_data = reader.read_data(reader.num_steps - 1)
        return point_data, cell_data
    piece = meshio.read(sorted(path.parent.glob("state_*.vtu"))[-1])
    return piece.point_data, piece.cell_data


@pytest.mark.slow
def test_example_optimizes_and_writes_the_paraview_fields(coarse, tmp_path):
    cfg, J = coarse
    model = J.model
    J, res = optimize_single(cfg, cfg.tau_starts()[0], J=J)
    summary = write_optimization_outputs(tmp_path, cfg, J, res)
    T, eps = cfg["dynamics"]["T"], cfg["objective"]["eps"]
    assert 0 < summary["tau"] < T - eps and summary["objective"] >= 0.0  # J(0, tau0) = 0 is a feasible start
    assert summary["volume_drift"] < 1e-12 and summary["min_det_F"] > 0
    for key in ("newton_iterations_mean", "newton_iterations_max", "cavity_volume_0", "cavity_volume_change_max"):
        assert key in summary
    # LV cavity below the base z = 5: prolate ellipsoid cap, h = 6 mm underestimates it by < 15 %
    assert summary["cavity_volume_0"] == pytest.approx(_cap_volume(7.0, 17.0, 5.0), rel=0.15)
    for png in ("pressure.png", "control.png", "history.png"):
        assert (tmp_path / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    point_data, cell_data = last_time_series_level(tmp_path / summary["files"]["time_series"])
    assert {"displacement", "velocity", "control"} <= set(point_data)
    assert {"det_F", "fibre", "sheet", "normal", "active_stress", "cauchy_stress", "E_ff"} <= set(cell_data)
    assert point_data["control"].shape == (model.space.num_nodes,)  # the scalar active stress as a scalar
    nc = model.mesh.num_cells
    assert cell_data["active_stress"][0].shape == (nc, 9) and cell_data["fibre"][0].shape == (nc, 3)
    assert np.all(cell_data["det_F"][0] > 0)
    stress = cell_data["active_stress"][0].reshape(nc, 3, 3)
    assert np.all(stress[~model.control.cell_mask] == 0)
    data = read_npz(tmp_path / "results.npz")
    assert data["cavity_volume"].shape == data["t"].shape
    assert json.loads((tmp_path / "summary.json").read_text())["tau"] == summary["tau"]

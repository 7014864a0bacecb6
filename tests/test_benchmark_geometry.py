"""The cardiac elastodynamics benchmark's geometry (reference mesh, hyperoc's generator), fibres, probe points,
and the participating codes' curves with the band they span."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from hyperoc.cardiac import benchmark_geometry as bg
from hyperoc.cardiac.benchmark_curves import STEPS, curve_band, reference_curves
from hyperoc.errors import InputError
from hyperoc.fem.spaces import VectorSpace

CODES = {"4C", "Ambit", "CARPentry", "CHeart", "CHimeRA", "COMSOL", "lifex", "Simula", "SimVascular P1",
         "SimVascular P2"}
#: Exact volumes of the domain, m^3 (bench/bench_benchmark_geometry.py: an integral over the meridian section).
EXACT_WALL = 1.77842449e-4


def exact_cavity() -> float:
    """pi r_s^2 int_{-r_l}^{x_rim} (1 - x^2 / r_l^2) dx of the endocardial ellipsoid below its rim plane."""
    rs, rl = bg.ENDO
    x = bg.BASE_X[0]
    return math.pi * rs**2 * ((x + rl) - (x**3 + rl**3) / (3 * rl**2))


@pytest.fixture(scope="module")
def reference():
    return bg.reference_mesh()


@pytest.fixture(scope="module")
def coarse():
    return bg.coarse_mesh()


def test_reference_mesh_volumes_against_the_exact_domain_and_the_codes(reference):
    """Straight tetrahedra of size 5 mm: wall and cavity volumes below the exact ones by O(h^2) (chords of the
    ellipses); the cavity volume lies in the band of the volumes the codes reported at t = 0 on this mesh."""
    wall, cavity = reference.volume(), bg.cavity_volume(reference)
    assert -2e-3 < wall / EXACT_WALL - 1 < 0
    assert -1e-2 < cavity / exact_cavity() - 1 < 0
    band = curve_band(reference_curves("1"), [0.0], "volume")
    assert band["lower"][0] <= cavity <= band["upper"][0], (cavity, band)


def test_probe_points_lie_in_the_wall(reference):
    """p0 just below the base and p1 at the equator, both between the walls."""
    for point in (bg.P0, bg.P1):
        x = np.asarray(point)
        level = lambda axes: (x[0] / axes[1]) ** 2 + (x[1] ** 2 + x[2] ** 2) / axes[0] ** 2
        assert level(bg.ENDO) > 1 > level(bg.EPI)
        assert bg._cone_distance(x[None])[0] < 0  # below the base
    x = reference.points[reference.cells]  # p0 and p1 fall into a cell of the reference mesh
    for point in (bg.P0, bg.P1):
        lam = np.linalg.solve(np.swapaxes(x[:, 1:] - x[:, :1], 1, 2), (np.asarray(point) - x[:, 0])[..., None])[..., 0]
        inside = (lam >= -1e-12).all(axis=1) & (lam.sum(axis=1) <= 1 + 1e-12)
        assert inside.any()


def test_generated_mesh_has_the_benchmark_walls_and_base(coarse):
    mesh = bg.benchmark_mesh(bg.COARSE_H)
    facets = mesh.boundary_facets()
    tagged = np.concatenate([mesh.boundary(n) for n in ("endocardium", "epicardium", "base")])
    assert len(tagged) == len(facets)
    for name, axes in (("endocardium", bg.ENDO), ("epicardium", bg.EPI)):
        x = mesh.points[np.unique(mesh.boundary(name))]
        level = (x[:, 0] / axes[1]) ** 2 + (x[:, 1] ** 2 + x[:, 2] ** 2) / axes[0] ** 2
        np.testing.assert_allclose(level, 1.0, atol=1e-6)
    base = mesh.points[np.unique(mesh.boundary("base"))]
    assert np.abs(bg._cone_distance(base)).max() < 1e-9
    # The rim circles: the base meets each ellipsoid at the benchmark's x.
    for k, name in enumerate(("endocardium", "epicardium")):
        rim = np.intersect1d(mesh.boundary(name), mesh.boundary("base"))
        np.testing.assert_allclose(mesh.points[rim, 0], bg.BASE_X[k], atol=1e-9)
    # Curved P2 cells see the walls to O(h^3): their wall volume error is far below the straight cells'.
    straight = abs(mesh.volume() / EXACT_WALL - 1)
    p2 = abs(VectorSpace(mesh, 2).quadrature(4).wdx.sum() / EXACT_WALL - 1)
    assert p2 < 0.1 * straight, (p2, straight)
    # The shipped coarse mesh is this generator's at COARSE_H, straight: O(h^2) volume errors of about 1 and 3 %.
    assert -0.02 < coarse.volume() / EXACT_WALL - 1 < 0 and -0.04 < bg.cavity_volume(coarse) / exact_cavity() - 1 < 0


def test_benchmark_frames_follow_the_definition():
    rng = np.random.default_rng(1)
    t = rng.uniform(0, 1, 50)
    u, v = rng.uniform(0.6, 3.0, 50), rng.uniform(-np.pi, np.pi, 50)
    rs = bg.ENDO[0] + (bg.EPI[0] - bg.ENDO[0]) * t
    rl = bg.ENDO[1] + (bg.EPI[1] - bg.ENDO[1]) * t
    x = np.stack([rl * np.cos(u), rs * np.sin(u) * np.cos(v), rs * np.sin(u) * np.sin(v)], axis=1)
    R = bg.benchmark_frames(x, t)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-13)
    # The sheet normal (-row 3) is the normal of the ellipsoid of the family through the point.
    normal = np.stack([x[:, 0] / rl**2, x[:, 1] / rs**2, x[:, 2] / rs**2], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    np.testing.assert_allclose(np.abs(np.sum(R[:, 2] * normal, axis=1)), 1.0, atol=1e-13)
    # The helix angle against the circumferential direction (0, -sin v, cos v): -60 at t = 0 to +60 at t = 1.
    circumferential = np.stack([0 * v, -np.sin(v), np.cos(v)], axis=1)
    alpha = np.deg2rad(-60 + 120 * t)
    np.testing.assert_allclose(np.sum(R[:, 0] * circumferential, axis=1), np.cos(alpha), atol=1e-13)
    meridian = np.cross(circumferential, R[:, 2])  # e_u up to sign: the fibre's other component
    np.testing.assert_allclose(np.abs(np.sum(R[:, 0] * meridian, axis=1)), np.abs(np.sin(alpha)), atol=1e-13)


def test_benchmark_fibres_on_the_mesh(coarse):
    frames = bg.benchmark_fibres(coarse)
    endo = np.unique(coarse.boundary("endocardium"))
    np.testing.assert_allclose(frames.transmural[endo], 0.0, atol=1e-14)
    R = bg.benchmark_frames(coarse.points, frames.transmural)
    np.testing.assert_allclose(frames.fibres, R[:, 0])
    np.testing.assert_allclose(frames(coarse.points[coarse.cells])[:, :, 0], R[coarse.cells, 0], atol=1e-12)


def test_reference_curves_of_the_ten_codes():
    for step in STEPS:
        curves = reference_curves(step)
        assert set(curves) == CODES
        for code, c in curves.items():
            assert c["p0"].shape == c["p1"].shape == (len(c["t"]), 3)
            assert 0 <= c["t"][0] <= 1e-3 and 0.999 <= c["t"][-1] <= 1.0 and np.all(np.diff(c["t"]) > 0)
            assert 0.02 < np.linalg.norm(c["p0"], axis=1).max() < 0.04  # metres: a few centimetres
            assert (c["volume"] is None) == (code in ("COMSOL", "lifex"))
    with pytest.raises(InputError, match="unknown step '2'"):
        reference_curves("2")


def test_curve_band_is_the_envelope_of_the_interpolated_curves():
    curves = reference_curves("1")
    times = np.array([0.0, 0.0005, 0.25, 0.3003, 1.0])
    band = curve_band(curves, times, "p1")
    # t = 0 and 0.0005 precede the first sample of Ambit and Simula (1 ms); t = 1 follows Simula's last.
    np.testing.assert_array_equal(band["count"], [8, 8, 10, 10, 9])
    cheart = curves["CHeart"]
    own = np.stack([np.interp(times, cheart["t"], cheart["p1"][:, k]) for k in range(3)], axis=1)
    assert np.all((band["lower"] <= own + 1e-15) & (own <= band["upper"] + 1e-15))
    values = np.stack([c["p1"][np.isclose(c["t"], 0.25)][0] for c in curves.values()])
    np.testing.assert_allclose(band["lower"][2], values.min(axis=0))
    np.testing.assert_allclose(band["upper"][2], values.max(axis=0))
    magnitude = curve_band(curves, [0.3], "|p0|")
    assert magnitude["lower"].shape == (1,) and 0.03 < magnitude["lower"][0] <= magnitude["upper"][0] < 0.04
    with pytest.raises(InputError, match="unknown quantity"):
        curve_band(curves, times, "p2")


def test_docs_band_snippet_runs():
    """The band example of docs/cardiac.md runs as printed."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "cardiac.md").read_text()
    start = text.index("`hyperoc.cardiac.benchmark_curves` ships")
    code = re.search(r"```python\n(.*?)```", text[start:], re.S).group(1)
    names = {}
    exec(compile(code, "docs/cardiac.md", "exec"), names)
    band = names["band"]
    assert band["lower"].shape == (101,) and np.all(band["lower"][1:] <= band["upper"][1:])
    assert 0.034 < band["upper"].max() < 0.037  # the peak |p0| of step 1, m


def test_cavity_volume_of_deformed_configurations(reference):
    """The closed cavity's volume is invariant under rigid motions (the rim's cap turns with it) and scales by
    det A under a linear map x -> A x."""
    v0 = bg.cavity_volume(reference)
    x = reference.points
    angle = 0.7
    rotation = np.array([[1, 0, 0], [0, math.cos(angle), -math.sin(angle)], [0, math.sin(angle), math.cos(angle)]])
    rotation = rotation @ np.array([[math.cos(0.3), 0, math.sin(0.3)], [0, 1, 0], [-math.sin(0.3), 0, math.cos(0.3)]])
    rigid = x @ rotation.T + [0.01, -0.02, 0.03] - x
    assert bg.cavity_volume(reference, rigid) == pytest.approx(v0, rel=1e-12)
    A = np.array([[0.9, 0.05, 0.0], [0.0, 1.1, 0.02], [0.01, 0.0, 1.05]])
    assert bg.cavity_volume(reference, x @ A.T - x) == pytest.approx(np.linalg.det(A) * v0, rel=1e-12)


@pytest.mark.parametrize("degree", [1, 2])
def test_probes_at_p0_p1_reproduce_polynomials(reference, degree):
    """The probe matrix at p0 and p1 reproduces the fields its space reproduces: polynomials of the degree on
    the straight reference mesh, linear fields on the curved (isoparametric) coarse mesh; it refuses a point
    outside the wall."""
    from hyperoc.fem.probes import probe_matrix

    linear = lambda x: np.stack([x[:, 0], 2 * x[:, 1] - x[:, 2], 0.5 + x[:, 0] * 0], 1)
    quadratic = lambda x: np.stack([x[:, 0] * x[:, 1], x[:, 2] ** 2, x[:, 0] - x[:, 1] * x[:, 2]], 1)
    points = np.array([bg.P0, bg.P1])
    curved = bg.benchmark_mesh(bg.COARSE_H)
    for mesh, field in ((reference, linear if degree == 1 else quadratic), (curved, linear)):
        space = VectorSpace(mesh, degree)
        assert space.isoparametric == (mesh is curved and degree == 2)
        P = probe_matrix(space, points)
        np.testing.assert_allclose(P @ field(space.nodes), field(points), atol=1e-15)
    with pytest.raises(InputError, match="lies outside the mesh"):
        probe_matrix(VectorSpace(reference, degree), [[0.0, 0.0, 0.0]])  # in the cavity


def test_the_medium_mesh_converges_from_the_coarse_one(coarse):
    """The shipped medium mesh is the generator's at MEDIUM_H, straight: its wall and cavity volume errors are the
    coarse mesh's O(h^2) ones shrunk by about (MEDIUM_H / COARSE_H)^2 = 0.34 (at most 0.6 of them), all below the
    exact volumes (straight cells inside convex walls)."""
    medium = bg.read_mesh("medium")
    assert medium.num_cells > 2 * coarse.num_cells
    for volume, exact in ((lambda m: m.volume(), EXACT_WALL), (bg.cavity_volume, exact_cavity())):
        e_coarse, e_medium = volume(coarse) / exact - 1, volume(medium) / exact - 1
        assert e_coarse < e_medium < 0 and abs(e_medium) < 0.6 * abs(e_coarse), (e_coarse, e_medium)

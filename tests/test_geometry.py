"""Geometry generators (annulus, thick shell, idealized ventricle) and mesh file I/O."""

import math

import meshio
import numpy as np
import pytest

from hyperoc.errors import InputError
from hyperoc.fem import geometry
from hyperoc.fem.mesh import box, interval, rectangle


def facet_set(facets):
    return {tuple(sorted(f)) for f in np.asarray(facets).tolist()}


def assert_tags_partition_boundary(mesh, names):
    """The named facet sets are disjoint and together are exactly the boundary of the mesh."""
    sets = [facet_set(mesh.boundaries[name]) for name in names]
    assert sum(len(s) for s in sets) == len(set().union(*sets))
    assert set().union(*sets) == facet_set(mesh.boundary_facets())


# ---- annulus ---------------------------------------------------------------------------------


def test_structured_annulus_area_converges_at_second_order():
    r, R = 0.5, 1.0
    exact = math.pi * (R**2 - r**2)
    areas = [geometry.annulus(r, R, structured=True, n_radial=3, n_theta=n).volume() for n in (16, 32, 64)]
    errors = np.abs(np.array(areas) - exact)
    rates = np.log2(errors[:-1] / errors[1:])
    assert np.all((1.8 <= rates) & (rates <= 2.2)), rates


@pytest.mark.parametrize("structured", [True, False])
def test_annulus_tags_split_boundary_into_circles(structured):
    r, R, h = 0.4, 1.2, 0.15
    mesh = geometry.annulus(r, R, h, structured=structured)
    assert mesh.dim == 2
    assert_tags_partition_boundary(mesh, ["gamma_d", "gamma_n"])
    radius = np.linalg.norm(mesh.points, axis=1)
    np.testing.assert_allclose(radius[mesh.boundary("gamma_d")], R, rtol=1e-12)
    np.testing.assert_allclose(radius[mesh.boundary("gamma_n")], r, rtol=1e-12)
    assert facet_set(mesh.boundary("outer")) == facet_set(mesh.boundary("gamma_d"))
    assert facet_set(mesh.boundary("inner")) == facet_set(mesh.boundary("gamma_n"))


def test_gmsh_annulus_area_within_polygon_error():
    r, R, h = 0.5, 1.0, 0.1
    mesh = geometry.annulus(r, R, h)
    assert mesh.h() < 1.5 * h
    # A chord of length h cuts a segment of area h^3 / (12 rho); N = 2 pi rho / h of them per circle.
    bound = 2 * math.pi * mesh.h() ** 2 / 6
    assert abs(mesh.volume() - math.pi * (R**2 - r**2)) < bound


def test_annulus_rejects_bad_sizes():
    with pytest.raises(InputError):
        geometry.annulus(1.0, 0.5)
    with pytest.raises(InputError):
        geometry.annulus(h=0.0)
    with pytest.raises(InputError):
        geometry.annulus(n_theta=8)


# ---- thick shell -----------------------------------------------------------------------------


def test_thick_shell_volume_and_tags():
    r, R, h = 0.5, 1.0, 0.25
    mesh = geometry.thick_shell(r, R, h)
    assert mesh.dim == 3
    exact = 4 / 3 * math.pi * (R**3 - r**3)
    assert abs(mesh.volume() - exact) / exact < 2 * (h / r) ** 2
    # Polyhedral deficit: triangles of size h on a sphere of radius rho lose about h^2 / (6 rho)
    # of thickness, i.e. 2 pi rho h^2 / 3 of volume; the inner sphere's deficit adds volume.
    assert exact - 2 * math.pi * R * h**2 / 3 < mesh.volume() < exact + 2 * math.pi * r * h**2 / 3
    assert_tags_partition_boundary(mesh, ["gamma_d", "gamma_n"])
    radius = np.linalg.norm(mesh.points, axis=1)
    np.testing.assert_allclose(radius[mesh.boundary("gamma_d")], R, rtol=1e-9)
    np.testing.assert_allclose(radius[mesh.boundary("gamma_n")], r, rtol=1e-9)


# ---- ventricle -------------------------------------------------------------------------------

ENDO, EPI, BASE_Z = (7.0, 17.0), (10.0, 20.0), 5.0  # mm, Land et al. (2015)
H_LV = 3.5  # mm


@pytest.fixture(scope="module")
def lv():
    return geometry.ventricle(H_LV)


def ellipsoid_residual(x, rs, rl):
    return (x[:, 0] ** 2 + x[:, 1] ** 2) / rs**2 + x[:, 2] ** 2 / rl**2 - 1.0


def test_ventricle_surfaces_lie_on_their_analytic_surfaces(lv):
    x = lv.points
    assert lv.dim == 3
    assert_tags_partition_boundary(lv, ["base", "endocardium", "epicardium"])
    np.testing.assert_allclose(x[lv.boundary("base"), 2], BASE_Z, rtol=0, atol=1e-9)
    assert np.abs(ellipsoid_residual(x[lv.boundary_vertices("endocardium")], *ENDO)).max() < 1e-6
    assert np.abs(ellipsoid_residual(x[lv.boundary_vertices("epicardium")], *EPI)).max() < 1e-6
    assert x[:, 2].max() == pytest.approx(BASE_Z, abs=1e-9)
    assert x[:, 2].min() == pytest.approx(-EPI[1], abs=1e-9)
    assert facet_set(lv.boundary("gamma_n")) == facet_set(lv.boundary("endocardium"))
    assert facet_set(lv.boundary("gamma_d")) == facet_set(lv.boundary("base"))


def rim_edges(triangles):
    """Edges used by exactly one triangle of a surface, (ne, 2)."""
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [0, 2]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    return uniq[counts == 1]


def test_ventricle_cavity_is_closed_apart_from_base(lv):
    x = lv.points
    rim = rim_edges(lv.boundary("endocardium"))
    np.testing.assert_allclose(x[rim, 2], BASE_Z, atol=1e-9)
    _, degree = np.unique(rim, return_counts=True)
    assert np.all(degree == 2)  # the rim is closed ...
    angle = np.arctan2(x[:, 1], x[:, 0])[rim]
    swept = np.abs(np.angle(np.exp(1j * (angle[:, 1] - angle[:, 0])))).sum()
    assert swept == pytest.approx(2 * math.pi)  # ... and goes once around the long axis
    rim_radius = ENDO[0] * math.sqrt(1 - (BASE_Z / ENDO[1]) ** 2)
    np.testing.assert_allclose(np.linalg.norm(x[rim, :2], axis=2), rim_radius, rtol=1e-6)
    # Cavity volume: cones from the origin (inside the convex cavity) over the endocardium and
    # over the base disk, fanned from its centre.
    centre = np.array([0.0, 0.0, BASE_Z])
    cones = np.abs(np.linalg.det(x[lv.boundary("endocardium")])).sum() / 6
    cap = np.abs(np.linalg.det(np.stack([x[rim[:, 0]], x[rim[:, 1]], np.broadcast_to(centre, (len(rim), 3))], 1)))
    volume = cones + cap.sum() / 6
    rs, rl = ENDO
    exact = math.pi * rs**2 * ((BASE_Z + rl) - (BASE_Z**3 + rl**3) / (3 * rl**2))
    assert volume < exact  # the cavity is inscribed: all its vertices lie on the ellipsoid
    assert (exact - volume) / exact < 2 * (H_LV / ENDO[1]) ** 2


def test_ventricle_rejects_base_above_cavity():
    with pytest.raises(InputError):
        geometry.ventricle(4.0, base_z=18.0)


# ---- files -----------------------------------------------------------------------------------


def round_trip_cases():
    mask = np.zeros(2 * 4 * 3, dtype=bool)
    mask[::3] = True
    return [
        pytest.param(interval(6), id="interval"),
        pytest.param(
            rectangle(4, 3).with_subdomain("omega", mask).with_subdomain("empty", np.zeros_like(mask)), id="rectangle"
        ),
        pytest.param(box(2).with_subdomain("omega", box(2).cell_centroids()[:, 0] < 0.5), id="box"),
        pytest.param(geometry.annulus(structured=True, n_radial=2, n_theta=12), id="annulus"),
    ]


@pytest.mark.parametrize("mesh", round_trip_cases())
def test_msh_round_trip_keeps_points_cells_and_names(tmp_path, mesh):
    back = geometry.from_file(geometry.to_file(mesh, tmp_path / "mesh.msh"))
    np.testing.assert_array_equal(back.points, mesh.points)
    np.testing.assert_array_equal(back.cells, mesh.cells)
    assert set(back.boundaries) == set(mesh.boundaries)
    for key, facets in mesh.boundaries.items():
        np.testing.assert_array_equal(back.boundaries[key], facets)
    assert set(back.subdomains) == set(mesh.subdomains)
    for key, mask in mesh.subdomains.items():
        np.testing.assert_array_equal(back.subdomains[key], mask)


def write_gmsh_square(path, version):
    """Unit square meshed by Gmsh itself: "clamp" = left edge (also in "edges"), "body" = surface."""
    import gmsh

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.occ.addRectangle(0, 0, 0, 1, 1)
        gmsh.model.occ.synchronize()
        left = [tag for _, tag in gmsh.model.getEntitiesInBoundingBox(-0.1, -0.1, -0.1, 0.1, 1.1, 0.1, dim=1)]
        every = [tag for _, tag in gmsh.model.getEntities(1)]
        gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, left), "clamp")
        gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, every), "edges")
        gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, [1]), "body")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.25)
        gmsh.model.mesh.generate(2)
        gmsh.option.setNumber("Mesh.MshFileVersion", version)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


@pytest.mark.parametrize("version", [2.2, 4.1])
def test_from_file_reads_gmsh_physical_groups(tmp_path, version):
    path = tmp_path / "square.msh"
    write_gmsh_square(path, version)
    mesh = geometry.from_file(path, dirichlet="clamp", control="body")
    assert mesh.dim == 2 and mesh.points.shape[1] == 2
    assert mesh.volume() == pytest.approx(1.0)
    assert np.all(mesh.subdomains["omega"]) and np.all(mesh.subdomains["body"])
    np.testing.assert_allclose(mesh.points[mesh.boundary("gamma_d"), 0], 0.0, atol=1e-12)
    assert facet_set(mesh.boundary("edges")) == facet_set(mesh.boundary_facets())
    assert "gamma_n" not in mesh.boundaries
    assert len(np.unique(mesh.cells)) == len(mesh.points)


def test_to_file_rejects_name_shared_by_boundary_and_subdomain(tmp_path):
    mesh = rectangle(2).with_subdomain("left", np.ones(8, dtype=bool))
    with pytest.raises(InputError, match="both a subdomain and a boundary"):
        geometry.to_file(mesh, tmp_path / "clash.msh")


def test_from_file_drops_unused_points_and_flat_z(tmp_path):
    points = np.array([[0, 0, 0], [9, 9, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    path = tmp_path / "tri.vtu"
    meshio.write(path, meshio.Mesh(points, [("triangle", np.array([[0, 2, 3]]))]))
    mesh = geometry.from_file(path)
    np.testing.assert_array_equal(mesh.points, [[0, 0], [1, 0], [0, 1]])
    np.testing.assert_array_equal(mesh.cells, [[0, 1, 2]])


def test_from_file_errors(tmp_path):
    with pytest.raises(InputError, match="mesh file not found"):
        geometry.from_file(tmp_path / "missing.msh")
    garbage = tmp_path / "garbage.msh"
    garbage.write_text("not a mesh\n")
    with pytest.raises(InputError, match="cannot read mesh file"):
        geometry.from_file(garbage)
    quads = tmp_path / "quads.vtu"
    meshio.write(quads, meshio.Mesh(np.eye(4, 3), [("quad", np.array([[0, 1, 2, 3]]))]))
    with pytest.raises(InputError, match="no line, triangle or tetra"):
        geometry.from_file(quads)
    tilted = tmp_path / "tilted.vtu"
    meshio.write(tilted, meshio.Mesh(np.eye(3), [("triangle", np.array([[0, 1, 2]]))]))
    with pytest.raises(InputError, match="not all zero"):
        geometry.from_file(tilted)
    square = geometry.to_file(rectangle(2), tmp_path / "square.msh")
    with pytest.raises(InputError, match=r"no boundary tag 'clamp' \(tags found: "):
        geometry.from_file(square, dirichlet="clamp")

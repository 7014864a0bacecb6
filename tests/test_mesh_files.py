"""Mesh files: DOLFINx-style XDMF with tag grids, Gmsh .msh v2/v4 of order 1 and 2, VTU, tag names and aliases,
and the one-line errors of bad files."""

import math
from pathlib import Path

import meshio
import numpy as np
import pytest

from hyperoc.errors import InputError
from hyperoc.fem.files import from_file, to_file
from hyperoc.fem.mesh import box
from hyperoc.fem.spaces import VectorSpace

h5py = pytest.importorskip("h5py")

REFERENCE = Path(__file__).parents[1] / "hyperoc" / "data" / "cardiac_benchmark" / "ellipsoid_0.005.xdmf"


def write_dolfinx_xdmf(path: Path, points, cells, facets, facet_values, cell_values=None, order: int = 1):
    """A mesh as DOLFINx writes it: a tetrahedron grid, then meshtag grids (facets, cells) referencing its
    geometry, all arrays in the sibling .h5 file (order 2: Tetrahedron_10 and Triangle_6, VTK node order)."""
    tetra, triangle = ("Tetrahedron", "Triangle") if order == 1 else ("Tetrahedron_10", "Triangle_6")
    h5 = path.with_suffix(".h5")
    with h5py.File(h5, "w") as f:
        f["/Mesh/mesh/geometry"] = points
        f["/Mesh/mesh/topology"] = cells
        f["/MeshTags/facets/topology"] = facets
        f["/MeshTags/facets/values"] = facet_values
        if cell_values is not None:
            f["/MeshTags/cells/topology"] = cells
            f["/MeshTags/cells/values"] = cell_values
    geometry = "xpointer(/Xdmf/Domain/Grid[@Name='mesh']/Geometry)"

    def tag_grid(name, kind, n, k):
        return f"""<Grid Name="{name}" GridType="Uniform">
      <xi:include xpointer="{geometry}" />
      <Topology TopologyType="{kind}" NumberOfElements="{n}" NodesPerElement="{k}">
        <DataItem Dimensions="{n} {k}" NumberType="Int" Format="HDF">{h5.name}:/MeshTags/{name}/topology</DataItem>
      </Topology>
      <Attribute Name="{name}" AttributeType="Scalar" Center="Cell">
        <DataItem Dimensions="{n}" NumberType="Int" Format="HDF">{h5.name}:/MeshTags/{name}/values</DataItem>
      </Attribute>
    </Grid>"""

    grids = [tag_grid("facets", triangle, len(facets), facets.shape[1])]
    if cell_values is not None:
        grids.append(tag_grid("cells", tetra, len(cells), cells.shape[1]))
    path.write_text(f"""<?xml version="1.0"?>
<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">
  <Domain>
    <Grid Name="mesh" GridType="Uniform">
      <Topology TopologyType="{tetra}" NumberOfElements="{len(cells)}" NodesPerElement="{cells.shape[1]}">
        <DataItem Dimensions="{len(cells)} {cells.shape[1]}" NumberType="Int"
                  Format="HDF">{h5.name}:/Mesh/mesh/topology</DataItem>
      </Topology>
      <Geometry GeometryType="XYZ">
        <DataItem Dimensions="{len(points)} 3" Format="HDF">{h5.name}:/Mesh/mesh/geometry</DataItem>
      </Geometry>
    </Grid>
    {"".join(grids)}
  </Domain>
</Xdmf>
""")
    return path


def facet_set(facets):
    return {tuple(sorted(f)) for f in np.asarray(facets).tolist()}


def test_dolfinx_xdmf_with_facet_and_cell_tags(tmp_path):
    mesh = box(2)
    sides = ["left", "right", "top"]
    facets = np.concatenate([mesh.boundaries[s] for s in sides])
    values = np.concatenate([np.full(len(mesh.boundaries[s]), k + 1) for k, s in enumerate(sides)])
    cell_values = (mesh.cell_centroids()[:, 0] < 0.5).astype(np.int64) + 7  # 8 on the left half, 7 elsewhere
    path = write_dolfinx_xdmf(tmp_path / "box.xdmf", mesh.points, mesh.cells, facets, values, cell_values)
    back = from_file(path, dirichlet="1", tags={"clamp": 1, "endocardium": 3}, control="8")
    np.testing.assert_array_equal(back.points, mesh.points)
    assert back.num_cells == mesh.num_cells and back.volume() == pytest.approx(1.0)
    for k, side in enumerate(sides):
        assert facet_set(back.boundaries[str(k + 1)]) == facet_set(mesh.boundaries[side])
    assert facet_set(back.boundary("gamma_d")) == facet_set(mesh.boundaries["left"])
    assert facet_set(back.boundary("clamp")) == facet_set(mesh.boundaries["left"])
    assert facet_set(back.boundary("ENDO")) == facet_set(mesh.boundaries["top"])  # alias of the tag named by `tags`
    np.testing.assert_array_equal(back.subdomains["omega"], cell_values == 8)


def test_reference_mesh_of_the_cardiac_benchmark():
    """The benchmark's DOLFIN XDMF: one tetrahedron grid, one grid of all facets (untagged ones marked by the
    largest uint64); 4,577 vertices, 17,625 cells, tags 1 (endocardium), 2 (epicardium), 3 (base)."""
    mesh = from_file(REFERENCE, tags={"endocardium": 1, "epicardium": 2, "base": 3})
    assert mesh.points.shape == (4577, 3) and mesh.cells.shape == (17625, 4)
    assert sorted(mesh.boundaries) == ["1", "2", "3", "base", "endocardium", "epicardium"]
    assert [len(mesh.boundary(n)) for n in ("endo", "EPI", "top")] == [2500, 3474, 256]
    assert facet_set(np.concatenate([mesh.boundary(n) for n in "123"])) == facet_set(mesh.boundary_facets())
    radius = np.hypot(mesh.points[:, 1], mesh.points[:, 2])
    endo = np.unique(mesh.boundary("endocardium"))
    np.testing.assert_allclose((mesh.points[endo, 0] / 0.09) ** 2 + (radius[endo] / 0.025) ** 2, 1.0, atol=1e-6)


def gmsh_shell(path: Path, order: int, version: float, h: float = 0.3):
    """A spherical shell 0.5 < r < 1 meshed by Gmsh at ``order``, physical groups "ENDO" (r = 0.5), "epi"
    (r = 1) and "wall" (the volume)."""
    import gmsh

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        occ = gmsh.model.occ
        occ.cut([(3, occ.addSphere(0, 0, 0, 1.0))], [(3, occ.addSphere(0, 0, 0, 0.5))])
        occ.synchronize()
        surfaces = sorted((gmsh.model.occ.getMass(2, t), t) for _, t in gmsh.model.getEntities(2))
        gmsh.model.addPhysicalGroup(2, [surfaces[0][1]], name="ENDO")
        gmsh.model.addPhysicalGroup(2, [surfaces[1][1]], name="epi")
        gmsh.model.addPhysicalGroup(3, [t for _, t in gmsh.model.getEntities(3)], name="wall")
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.model.mesh.generate(3)
        gmsh.model.mesh.setOrder(order)
        gmsh.option.setNumber("Mesh.MshFileVersion", version)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return path


@pytest.mark.parametrize("version", [2.2, 4.1])
def test_order_two_msh_gives_curved_cells(tmp_path, version):
    """An order-2 .msh reads as the straight tetrahedra plus curved P2 edge nodes: the isoparametric P2
    volume is far closer to the exact shell volume than the straight cells' (O(h^4) against O(h^2))."""
    linear = from_file(gmsh_shell(tmp_path / "p1.msh", 1, version), neumann="endo")
    curved = from_file(gmsh_shell(tmp_path / "p2.msh", 2, version), neumann="endo")
    np.testing.assert_array_equal(curved.cells, linear.cells)
    np.testing.assert_allclose(curved.points, linear.points)
    assert curved.is_curved and not linear.is_curved
    exact = 4 * math.pi / 3 * (1 - 0.5**3)
    straight_error = abs(linear.volume() - exact)
    p2_volume = VectorSpace(curved, 2).quadrature(4).wdx.sum()
    assert abs(p2_volume - exact) < 0.1 * straight_error, (p2_volume, linear.volume(), exact)
    np.testing.assert_allclose(np.linalg.norm(curved.curved_points, axis=1).max(), 1.0, atol=1e-9)
    assert facet_set(curved.boundary("endocardium")) == facet_set(curved.boundary("gamma_n"))
    assert curved.subdomains["wall"].all()


def test_order_two_dolfinx_xdmf_matches_the_msh(tmp_path):
    """The same quadratic mesh as DOLFINx XDMF (Tetrahedron_10 cells, Triangle_6 facet tags) and as .msh."""
    path = gmsh_shell(tmp_path / "p2.msh", 2, 4.1)
    raw = meshio.read(path)
    cells, facets = raw.get_cells_type("tetra10"), raw.get_cells_type("triangle6")
    tags = np.concatenate([t for b, t in zip(raw.cells, raw.cell_data["gmsh:physical"]) if b.type == "triangle6"])
    xdmf = write_dolfinx_xdmf(tmp_path / "p2.xdmf", raw.points, cells, facets, tags, order=2)
    from_msh, from_xdmf = from_file(path), from_file(xdmf, tags={"endocardium": raw.field_data["ENDO"][0]})
    np.testing.assert_array_equal(from_xdmf.cells, from_msh.cells)
    np.testing.assert_array_equal(from_xdmf.curved_edges, from_msh.curved_edges)
    np.testing.assert_allclose(from_xdmf.curved_points, from_msh.curved_points)
    assert facet_set(from_xdmf.boundary("endo")) == facet_set(from_msh.boundary("ENDO"))


def test_vtu_with_integer_cell_tags(tmp_path):
    mesh = box(2)
    facets = np.concatenate([mesh.boundaries["left"], mesh.boundaries["right"]])
    marker = np.repeat([1, 2], [len(mesh.boundaries["left"]), len(mesh.boundaries["right"])])
    path = tmp_path / "box.vtu"
    meshio.write(path, meshio.Mesh(mesh.points, [("tetra", mesh.cells), ("triangle", facets)],
                                   cell_data={"markers": [np.full(mesh.num_cells, -1), marker]}))
    back = from_file(path, dirichlet="2")
    assert facet_set(back.boundary("gamma_d")) == facet_set(mesh.boundaries["right"])
    assert sorted(back.boundaries) == ["1", "2", "gamma_d"]


def test_round_trip_names_resolve_through_aliases(tmp_path):
    mesh = box(2).with_boundary("Endocardium", box(2).boundaries["front"])
    back = from_file(to_file(mesh, tmp_path / "box.msh"), neumann="ENDO", dirichlet="base")  # base -> "top"
    assert facet_set(back.boundary("gamma_n")) == facet_set(mesh.boundaries["front"])
    assert facet_set(back.boundary("gamma_d")) == facet_set(mesh.boundaries["top"])


def test_bad_files_raise_one_line(tmp_path):
    mesh = box(1)
    path = to_file(mesh, tmp_path / "box.msh")
    with pytest.raises(InputError, match=r"no boundary tag 'endo' \(tags found: back, bottom, front, gamma_d, "):
        from_file(path, neumann="endo")
    flat = mesh.points.copy()
    flat[:, 2] = 0.0  # every tetrahedron flattened: zero volume
    squashed = tmp_path / "flat.vtu"
    meshio.write(squashed, meshio.Mesh(flat, [("tetra", mesh.cells)]))
    with pytest.raises(InputError, match=r"flat.vtu: 6 degenerate \(zero-volume\) cell"):
        from_file(squashed)
    unknown = tmp_path / "mesh.unknown"
    unknown.write_text("1 2 3\n")
    broken_xdmf = tmp_path / "broken.xdmf"
    broken_xdmf.write_text("<Xdmf><Domain><Grid")
    missing_h5 = tmp_path / "missing.xdmf"
    write_dolfinx_xdmf(missing_h5, mesh.points, mesh.cells, mesh.boundaries["left"], np.ones(2, int))
    missing_h5.with_suffix(".h5").unlink()
    for bad in (unknown, broken_xdmf, missing_h5):
        with pytest.raises(InputError, match="cannot read mesh file") as info:
            from_file(bad)
        assert "\n" not in str(info.value)

"""Fibre and sheet fields from data: per vertex or per cell, from NPZ, VTU and XDMF files, checked (finite, unit,
orthogonal, one per vertex or cell), through the config and the CLI (bad fields: one line, exit status 2)."""

import re
from pathlib import Path

import meshio
import numpy as np
import pytest

from hyperoc.app.cli import main
from hyperoc.app.config import load_config
from hyperoc.cardiac.benchmark_geometry import benchmark_fibres, coarse_mesh
from hyperoc.errors import InputError
from hyperoc.fem.files import to_file
from hyperoc.fem.mesh import box
from hyperoc.io import write_npz
from hyperoc.mechanics.fibres import field_frames, read_fibres, write_fibres


@pytest.fixture(scope="module")
def mesh():
    return coarse_mesh()


@pytest.fixture(scope="module")
def frames(mesh):
    return benchmark_fibres(mesh)


def rotation_field(points):
    """Unit, orthogonal f and s (n, 3) turning with z: f = (cos z, sin z, 0), s = (0, 0, 1)."""
    z = points[:, 2]
    f = np.stack([np.cos(z), np.sin(z), 0 * z], axis=1)
    return f, np.tile([0.0, 0.0, 1.0], (len(z), 1))


def assert_orthonormal_right_handed(R):
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


def test_vertex_field_is_interpolated_then_orthonormalised():
    mesh = box(3, size=(1.0, 1.0, 2.0))
    f, s = rotation_field(mesh.points)
    frames = field_frames(mesh, f, s)
    assert frames.location == "node"
    x = mesh.points[mesh.cells]  # at the vertices the given vectors come back exactly
    R = frames(x)
    np.testing.assert_allclose(R[..., 0, :], f[mesh.cells], atol=1e-12)
    np.testing.assert_allclose(R[..., 1, :], s[mesh.cells], atol=1e-12)
    centroids = mesh.cell_centroids()[:, None, :]
    R = frames(centroids)
    assert_orthonormal_right_handed(R)
    # Between the vertices: the normalised linear interpolant of cos z, sin z, within O(h^2) of the exact turn.
    exact, _ = rotation_field(centroids[:, 0])
    assert np.abs(R[:, 0, 0] - exact).max() < (2.0 / 3) ** 2 / 8 * 1.01


def test_cell_field_is_constant_per_cell():
    mesh = box(2)
    f, s = rotation_field(mesh.cell_centroids())
    frames = field_frames(mesh, f, s, location="cell")
    x = mesh.points[mesh.cells]
    R = frames(x)
    np.testing.assert_allclose(R[..., 0, :], np.broadcast_to(f[:, None], (mesh.num_cells, 4, 3)), atol=1e-15)
    np.testing.assert_allclose(frames.fibre(x[:5, :1], cells=np.arange(5))[:, 0], f[:5], atol=1e-15)


def test_vtu_round_trip_per_cell(tmp_path, mesh, frames):
    back = read_fibres(write_fibres(tmp_path / "fibres.vtu", mesh, frames), mesh)
    assert back.location == "cell"
    np.testing.assert_allclose(back.cell_frames(), frames.cell_frames(), atol=1e-12)


def test_vtu_vertex_field_in_another_order_with_more_points(tmp_path, mesh, frames):
    """A file numbering the vertices differently and holding extra points (e.g. the edge nodes of a P2 field)
    is matched to the mesh by position."""
    rng = np.random.default_rng(0)
    order = rng.permutation(len(mesh.points))
    extra = mesh.cell_centroids()[:7]
    points = np.concatenate([mesh.points[order], extra])
    inverse = np.argsort(order)
    f = np.concatenate([frames.fibres[order], np.tile([1.0, 0, 0], (7, 1))])
    s = np.concatenate([frames.sheets[order], np.tile([0, 1.0, 0], (7, 1))])
    path = tmp_path / "nodal.vtu"
    meshio.write(path, meshio.Mesh(points, [("tetra", inverse[mesh.cells])], point_data={"fiber": f, "sheet": s}))
    back = read_fibres(path, mesh)
    assert back.location == "node"
    np.testing.assert_allclose(back.fibres, frames.fibres, atol=1e-15)
    np.testing.assert_allclose(back.cell_frames(), frames.cell_frames(), atol=1e-12)


def test_dolfinx_style_xdmf_vertex_field(tmp_path, mesh, frames):
    h5py = pytest.importorskip("h5py")
    with h5py.File(tmp_path / "f.h5", "w") as h5:
        h5["geometry"], h5["topology"] = mesh.points, mesh.cells
        h5["f0"], h5["s0"] = frames.fibres, frames.sheets
    nv, nc = len(mesh.points), mesh.num_cells
    attribute = """<Attribute Name="{0}" AttributeType="Vector" Center="Node">
        <DataItem Dimensions="{1} 3" Format="HDF">f.h5:/{0}</DataItem></Attribute>"""
    (tmp_path / "f.xdmf").write_text(f"""<?xml version="1.0"?>
<Xdmf Version="3.0"><Domain><Grid Name="mesh" GridType="Uniform">
  <Topology TopologyType="Tetrahedron" NumberOfElements="{nc}" NodesPerElement="4">
    <DataItem Dimensions="{nc} 4" NumberType="Int" Format="HDF">f.h5:/topology</DataItem></Topology>
  <Geometry GeometryType="XYZ"><DataItem Dimensions="{nv} 3" Format="HDF">f.h5:/geometry</DataItem></Geometry>
  {attribute.format("f0", nv)}{attribute.format("s0", nv)}
</Grid></Domain></Xdmf>""")
    back = read_fibres(tmp_path / "f.xdmf", mesh)
    np.testing.assert_allclose(back.cell_frames(), frames.cell_frames(), atol=1e-12)


def test_npz_per_node_and_per_cell(tmp_path, mesh, frames):
    write_npz(tmp_path / "nodes.npz", fibre=frames.fibres, sheet=frames.sheets)
    np.testing.assert_allclose(read_fibres(tmp_path / "nodes.npz", mesh).cell_frames(), frames.cell_frames())
    R = frames.cell_frames()
    write_npz(tmp_path / "cells.npz", f0=R[:, 0], s0=R[:, 1])
    back = read_fibres(tmp_path / "cells.npz", mesh)
    assert back.location == "cell"
    np.testing.assert_allclose(back.cell_frames(), R, atol=1e-15)


def bad_fields(frames):
    f, s = frames.fibres.copy(), frames.sheets.copy()
    nan = f.copy()
    nan[3, 1] = np.nan
    long = f.copy()
    long[5] *= 1.01
    tilted = s + 0.01 * f
    tilted /= np.linalg.norm(tilted, axis=1, keepdims=True)
    return {
        "nan": ({"fibre": nan, "sheet": s}, r"1 fibre vector\(s\) are not finite"),
        "non-unit": ({"fibre": long, "sheet": s}, r"1 fibre vector\(s\) are not unit \(largest \| \|v\| - 1 \| = 0.01"),
        "not orthogonal": ({"fibre": f, "sheet": tilted}, "fibre and sheet are not orthogonal at"),
        "wrong count": ({"fibre": f[:-1], "sheet": s[:-1]}, "fibre vectors, but the mesh has 466 vertices and 1402"),
        "no sheet": ({"fibre": f}, "no array named sheet or s0 or s"),
    }


@pytest.mark.parametrize("case", ["nan", "non-unit", "not orthogonal", "wrong count", "no sheet"])
def test_bad_fields_raise_one_line(tmp_path, mesh, frames, case):
    arrays, message = bad_fields(frames)[case]
    path = write_npz(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputError, match=message) as info:
        read_fibres(path, mesh)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_unreadable_files(tmp_path, mesh):
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file")
    with pytest.raises(InputError, match="cannot read it"):
        read_fibres(garbage, mesh)
    with pytest.raises(InputError, match="not found"):
        read_fibres(tmp_path / "missing.vtu", mesh)
    other = tmp_path / "other.vtu"  # a field on another mesh: its points do not match
    meshio.write(other, meshio.Mesh(box(2).points, [("tetra", box(2).cells)],
                                    point_data={"fibre": np.tile([1.0, 0, 0], (27, 1)),
                                                "sheet": np.tile([0, 1.0, 0], (27, 1))}))
    with pytest.raises(InputError, match="its points do not match the mesh's vertices"):
        read_fibres(other, mesh)


CONFIG = """
[mesh]
kind = "file"
file = "mesh.msh"
neumann_tag = "ENDO"
dirichlet_tag = "top"
degree = 1

[material]
law = "holzapfel-ogden"
a = 0.059
b = 8.023
af = 18.472
bf = 16.026
as = 2.481
bs = 11.12
afs = 0.216
bfs = 11.436
bulk_modulus = 100.0

[fibres]
kind = "file"
file = "fibres.npz"

[dynamics]
T = 0.2
dt = 0.1
damping = 1.0

[control]
kind = "active_stress"
region = { kind = "all" }

[objective]
phi1 = "pressure"
"""


def write_case(tmp_path: Path, mesh, fibres: dict) -> Path:
    to_file(mesh, tmp_path / "mesh.msh")
    write_npz(tmp_path / "fibres.npz", **fibres)
    cfg = tmp_path / "case.toml"
    cfg.write_text(CONFIG)
    return cfg


def test_config_builds_the_model_with_file_fibres(tmp_path, mesh, frames):
    cfg = load_config(write_case(tmp_path, mesh, {"fibre": frames.fibres, "sheet": frames.sheets}))
    read = cfg.fibres(cfg.mesh())
    np.testing.assert_allclose(read.cell_frames(), frames.cell_frames())
    model = cfg.model()
    np.testing.assert_allclose(model.control.fibres, frames.cell_frames()[:, 0], atol=1e-12)


@pytest.mark.parametrize("case", ["nan", "non-unit", "wrong count"])
def test_cli_bad_fibres_exit_2_nothing_written(tmp_path, capsys, mesh, frames, case):
    arrays, message = bad_fields(frames)[case]
    cfg = write_case(tmp_path, mesh, arrays)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hyperoc: error:"), lines
    assert re.search(message, lines[0]), lines
    assert not (tmp_path / "o").exists()


def test_cli_missing_tag_exit_2(tmp_path, capsys, mesh, frames):
    cfg = write_case(tmp_path, mesh, {"fibre": frames.fibres, "sheet": frames.sheets})
    cfg.write_text(CONFIG.replace('neumann_tag = "ENDO"', 'neumann_tag = "lv_endo"'))
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "no boundary tag 'lv_endo' (tags found: base, endocardium, epicardium" in lines[0]
    assert not (tmp_path / "o").exists()


def test_config_benchmark_mesh_and_fibres(tmp_path, mesh, frames):
    text = CONFIG.replace('kind = "file"\nfile = "mesh.msh"\nneumann_tag = "ENDO"\ndirichlet_tag = "top"',
                          'kind = "cardiac_benchmark"\nvariant = "coarse"\ndirichlet_tag = "base"')
    text = text.replace('kind = "file"\nfile = "fibres.npz"', 'kind = "benchmark"')
    (tmp_path / "bench.toml").write_text(text)
    cfg = load_config(tmp_path / "bench.toml")
    model = cfg.model()
    assert len(model.mesh.boundary("gamma_d")) == len(mesh.boundary("base"))
    assert len(model.mesh.boundary("gamma_n")) == len(mesh.boundary("endocardium"))
    np.testing.assert_allclose(model.control.fibres, frames.cell_frames()[:, 0], atol=1e-12)


def zero_volume_mesh(tmp_path: Path, mesh) -> None:
    flat = mesh.points.copy()
    flat[mesh.cells[0, 3]] = flat[mesh.cells[0, :3]].mean(axis=0)  # cell 0 flattened onto its first face
    meshio.write(tmp_path / "mesh.vtu", meshio.Mesh(flat, [("tetra", mesh.cells)]))


@pytest.mark.parametrize("case, message", [
    ("zero-volume cell", r"mesh.vtu: \d+ degenerate \(zero-volume\) cell"),
    ("unreadable mesh", "cannot read mesh file"),
    ("unreadable fibres", "fibres.npz: cannot read it"),
])
def test_cli_bad_files_exit_2_nothing_written(tmp_path, capsys, mesh, frames, case, message):
    cfg = write_case(tmp_path, mesh, {"fibre": frames.fibres, "sheet": frames.sheets})
    if case == "zero-volume cell":
        zero_volume_mesh(tmp_path, mesh)
        cfg.write_text(CONFIG.replace('file = "mesh.msh"\nneumann_tag = "ENDO"\ndirichlet_tag = "top"',
                                      'file = "mesh.vtu"'))
    elif case == "unreadable mesh":
        (tmp_path / "mesh.msh").write_text("$MeshFormat\n9 9 9\n")
    else:
        (tmp_path / "fibres.npz").write_bytes(b"PK\x03\x04 truncated")
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and re.search(message, lines[0]), lines
    assert not (tmp_path / "o").exists()

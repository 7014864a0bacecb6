"""The ParaView series read back with meshio: a scalar control as a scalar, the active stress with the sign
it acts with, the Cauchy stress and the fibre strain E_ff against their formulas; fibre frames given as any
callable (as `StateModel` takes them)."""

import sys
import xml.etree.ElementTree as ET

import meshio
import numpy as np

import hyperoc as ho
from hyperoc.app.report import write_state_outputs

MU, LAM, TENSION = 1.0, 1.0, 0.2  # SVK moduli; the fibre tension T_a of the contraction xi = -T_a
FRAME = np.array([[1.0, 1.0, 0.0], [-1.0, 1.0, 0.0], [0.0, 0.0, np.sqrt(2.0)]]) / np.sqrt(2.0)  # rows f, s, n


def _frames(x):
    """The constant frame at points x (..., 3): (..., 3, 3)."""
    return np.broadcast_to(FRAME, (*np.shape(x)[:-1], 3, 3))


def _contraction(tmp_path, monkeypatch):
    """A clamped SVK box contracting along the fibre f of `FRAME` (xi = -T_a on the whole body), its
    series written as VTU + PVD with ``frames`` a plain function; the last level read back."""
    monkeypatch.setitem(sys.modules, "h5py", None)  # the PVD writer
    fibre = lambda x, cells: np.broadcast_to(FRAME[0], x.shape)
    model = ho.StateModel(ho.box(2), ho.SaintVenantKirchhoff(MU, LAM), damping=0.1,
                          control=ho.ActiveStress(ho.Region("all"), fibres=fibre), frames=_frames)
    grid = ho.uniform_grid(0.4, 0.1)
    xi = np.full((grid.t.size, model.control.size), -TENSION)
    sol = ho.TimeStepper(model, ho.Scheme()).run(grid, xi)
    summary = write_state_outputs(tmp_path, sol, frames=_frames, series_every=1)
    pvd = tmp_path / summary["files"]["time_series"]
    last = [d.get("file") for d in ET.parse(pvd).getroot().iter("DataSet")][-1]
    return model, sol, meshio.read(pvd.parent / last), summary


def test_paraview_fields_read_back(tmp_path, monkeypatch):
    model, sol, mesh, _ = _contraction(tmp_path, monkeypatch)
    nc = model.mesh.num_cells
    assert mesh.point_data["control"].shape == (model.space.num_nodes,)  # a scalar, not (xi, 0, 0)
    np.testing.assert_array_equal(mesh.point_data["control"], -TENSION)

    ff = np.outer(FRAME[0], FRAME[0])
    active = mesh.cell_data["active_stress"][0].reshape(nc, 3, 3)
    np.testing.assert_allclose(active, np.broadcast_to(TENSION * ff, (nc, 3, 3)), rtol=0, atol=1e-15)
    np.testing.assert_allclose(mesh.cell_data["fibre"][0], np.broadcast_to(FRAME[0], (nc, 3)), rtol=0, atol=1e-15)

    # P1 tetrahedra: F is constant on each cell; SVK S = lambda tr(E) I + 2 mu E, P = F S, P_a = T_a f (x) f
    F = np.asarray(model.deformation_gradient(sol.y0[-1]))[:, 0]
    E = 0.5 * (np.einsum("cki,ckj->cij", F, F) - np.eye(3))
    S = LAM * np.trace(E, axis1=1, axis2=2)[:, None, None] * np.eye(3) + 2 * MU * E
    P = F @ S + TENSION * ff
    sigma = np.einsum("cij,ckj->cik", P, F) / np.linalg.det(F)[:, None, None]
    assert np.max(np.abs(E)) > 1e-3  # the body deformed
    written = mesh.cell_data["cauchy_stress"][0].reshape(nc, 3, 3)
    np.testing.assert_allclose(written, sigma, rtol=0, atol=1e-12 * np.max(np.abs(sigma)))
    E_ff = np.einsum("i,cij,j->c", FRAME[0], E, FRAME[0])
    np.testing.assert_allclose(mesh.cell_data["E_ff"][0], E_ff, rtol=0, atol=1e-14)
    assert np.mean(E_ff) < 0  # the fibres shorten under the contraction


def test_a_3d_mesh_without_the_cavity_wall_says_so(tmp_path, monkeypatch):
    """No ``cavity_volume`` without the wall named by ``cavity`` (default "endocardium"), and a warning
    naming the mesh's boundaries; the wall is ``[fibres] inner`` when the config has fibres."""
    from hyperoc.app.config import parse_config

    *_, summary = _contraction(tmp_path, monkeypatch)
    assert "cavity_volume_0" not in summary
    assert [w for w in summary["warnings"] if w.startswith("no cavity_volume: the mesh has no boundary 'endocardium' "
                                                           "(its boundaries: ")]
    fibres = {"kind": "rule_based", "inner": "endo"}
    assert parse_config({"mesh": {"kind": "ventricle"}, "fibres": fibres}).cavity_wall() == "endo"
    assert parse_config({"mesh": {"kind": "ventricle"}}).cavity_wall() == "endocardium"
    assert parse_config({"mesh": {"kind": "box"}}).cavity_wall() is None

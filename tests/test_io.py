import os
import struct
import sys
import types
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import meshio
import numpy as np
import pytest

import hyperoc.app.plotting
import hyperoc.io as hio
from hyperoc.app.plotting import (
    Units,
    plot_control_spacetime,
    plot_history,
    plot_pressure,
    plot_pressure_comparison,
    plot_snapshots,
)
from hyperoc.fem.mesh import interval, rectangle

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _hidden(directory: Path) -> list:
    """Temporary files/directories left behind (all start with a dot)."""
    return [p.name for p in directory.iterdir() if p.name.startswith(".")]


# ----------------------------------------------------------------------------- atomic files


def test_text_bytes_round_trip_without_temp_files(tmp_path):
    hio.atomic_write_text(tmp_path / "a.txt", "héllo\n")
    hio.atomic_write_bytes(tmp_path / "b.bin", b"\x00\x01")
    hio.atomic_write_text(tmp_path / "a.txt", "second")
    assert (tmp_path / "a.txt").read_text(encoding="utf-8") == "second"
    assert (tmp_path / "b.bin").read_bytes() == b"\x00\x01"
    assert _hidden(tmp_path) == []


def test_writer_failing_midway_keeps_old_file(tmp_path, monkeypatch):
    target = tmp_path / "out.txt"
    target.write_text("old content")
    real_fdopen = os.fdopen

    class HalfWriter:
        """A file that writes half of the data, then fails like a full disk."""

        def __init__(self, fd, mode):
            self.file = real_fdopen(fd, mode)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.file.close()

        def write(self, data):
            self.file.write(data[: len(data) // 2])
            self.file.flush()
            raise OSError("disk full")

    monkeypatch.setattr(hio.os, "fdopen", HalfWriter)
    with pytest.raises(OSError, match="disk full"):
        hio.atomic_write_text(target, "new content that never lands")
    assert target.read_text() == "old content"
    assert _hidden(tmp_path) == []


def test_failed_replace_keeps_old_npz(tmp_path, monkeypatch):
    path = tmp_path / "data.npz"
    hio.write_npz(path, a=np.arange(3))

    def failing_replace(src, dst):
        raise OSError("replace failed")

    monkeypatch.setattr(hio.os, "replace", failing_replace)
    with pytest.raises(OSError, match="replace failed"):
        hio.write_npz(path, a=np.zeros(5))
    np.testing.assert_array_equal(hio.read_npz(path)["a"], np.arange(3))
    assert _hidden(tmp_path) == []


def test_npz_round_trip(tmp_path):
    arrays = {"u": np.random.default_rng(0).normal(size=(4, 3)), "n": np.int64(7), "flags": np.array([True, False])}
    hio.write_npz(tmp_path / "s.npz", **arrays)
    back = hio.read_npz(tmp_path / "s.npz")
    assert set(back) == set(arrays)
    for key, value in arrays.items():
        np.testing.assert_array_equal(back[key], value)
        assert back[key].dtype == np.asarray(value).dtype
    with pytest.raises(TypeError, match="object"):
        hio.write_npz(tmp_path / "o.npz", bad=np.array([{}], dtype=object))
    assert not (tmp_path / "o.npz").exists()


def test_cache_npz_is_stored_uncompressed_atomically_and_without_fsync(tmp_path, monkeypatch):
    """A cache entry reads back bitwise, is stored (not deflated), leaves no temporary file, and is not
    synced to disk: its reader recomputes a lost entry, so durability is not worth its cost."""
    synced = []
    monkeypatch.setattr(hio.os, "fsync", lambda fd: synced.append(fd))
    g = np.random.default_rng(1).normal(size=(5, 2))
    path = hio.write_cache_npz(tmp_path / "e.npz", J=np.float64(0.5), gxi=g)
    back = hio.read_npz(path)
    np.testing.assert_array_equal(back["gxi"], g)
    assert back["J"] == 0.5 and _hidden(tmp_path) == [] and synced == []
    with zipfile.ZipFile(path) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}
    hio.write_npz(tmp_path / "d.npz", gxi=g)  # a result file: durable
    assert len(synced) == 2  # the file and its folder


def test_json_converts_numpy_and_writes_non_finite_as_null(tmp_path):
    obj = {"b": np.float64(1.5), "a": np.arange(3), "c": (np.int32(2), float("nan")), "d": {"inf": np.inf, "ok": True}}
    path = hio.write_json(tmp_path / "r.json", obj)
    assert hio.read_json(path) == {"a": [0, 1, 2], "b": 1.5, "c": [2, None], "d": {"inf": None, "ok": True}}
    text = path.read_text()
    assert text.index('"a"') < text.index('"b"') and text.startswith("{\n  ")
    with pytest.raises(TypeError, match="object"):
        hio.write_json(tmp_path / "bad.json", {"x": object()})
    assert not (tmp_path / "bad.json").exists()
    assert _hidden(tmp_path) == []


# ----------------------------------------------------------------------------- time series


def _fake_h5py():
    """Enough of h5py for meshio's XDMF writer/reader, storing datasets in an npz file."""

    class File:
        def __init__(self, path, mode):
            self.path, self.mode = Path(path), mode
            self.datasets = {}
            if mode == "r":
                with np.load(self.path) as f:
                    self.datasets = {k: f[k] for k in f.files}

        def create_dataset(self, name, data):
            self.datasets[name] = np.asarray(data)

        def __getitem__(self, key):
            return self.datasets[key]

        def close(self):
            if self.mode == "w":
                with open(self.path, "wb") as f:
                    np.savez(f, **self.datasets)

    return types.SimpleNamespace(File=File)


def _series_2d():
    mesh = rectangle(2, 3)
    nv, nc = len(mesh.points), len(mesh.cells)
    times = np.array([0.0, 0.25, 0.5])
    rng = np.random.default_rng(1)
    return {
        "mesh_points": mesh.points,
        "cells": ("triangle", mesh.cells),
        "times": times,
        "point_data": {"u": rng.normal(size=(3, nv, 2)), "p": rng.normal(size=(3, nv))},
        "cell_data": {"J": rng.normal(size=(3, nc))},
        "static_point_data": {"marker": np.arange(nv, dtype=float)},
    }


def _check_xdmf(path: Path, series: dict):
    assert path.suffix == ".xdmf" and path.with_suffix(".h5").is_file()
    with meshio.xdmf.TimeSeriesReader(path) as reader:
        points, cells = reader.read_points_cells()
        np.testing.assert_array_equal(points[:, :2], series["mesh_points"])
        np.testing.assert_array_equal(points[:, 2], 0.0)
        np.testing.assert_array_equal(cells[0].data, series["cells"][1])
        for n, t in enumerate(series["times"]):
            time, point_data, cell_data = reader.read_data(n)
            assert time == t
            np.testing.assert_array_equal(point_data["u"][:, :2], series["point_data"]["u"][n])
            np.testing.assert_array_equal(point_data["u"][:, 2], 0.0)
            np.testing.assert_array_equal(point_data["p"], series["point_data"]["p"][n])
            np.testing.assert_array_equal(point_data["marker"], series["static_point_data"]["marker"])
            np.testing.assert_array_equal(cell_data["J"][0], series["cell_data"]["J"][n])


def test_xdmf_series_read_back_with_meshio(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "h5py", _fake_h5py())
    monkeypatch.chdir(tmp_path)  # meshio 5.3 alone would put the .h5 file here
    series = _series_2d()
    assert hio.time_series_format() == "xdmf"
    path = hio.write_time_series(tmp_path / "out", "state", **series)
    assert path == tmp_path / "out" / "state.xdmf"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert sorted(p.name for p in path.parent.iterdir()) == ["state.h5", "state.xdmf"]
    _check_xdmf(path, series)


def test_xdmf_series_with_real_h5py(tmp_path):
    pytest.importorskip("h5py")
    series = _series_2d()
    _check_xdmf(hio.write_time_series(tmp_path, "state", **series, fmt="xdmf"), series)


def _pvd_entries(path: Path) -> list:
    root = ET.parse(path).getroot()
    assert root.tag == "VTKFile" and root.get("type") == "Collection"
    return [(float(d.get("timestep")), d.get("file")) for d in root.iter("DataSet")]


def test_pvd_series_read_back_with_meshio(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "h5py", None)  # import h5py -> ImportError
    assert hio.time_series_format() == "pvd"
    series = _series_2d()
    path = hio.write_time_series(tmp_path, "state", **series)
    assert path == tmp_path / "state.pvd"
    entries = _pvd_entries(path)
    assert [t for t, _ in entries] == list(series["times"])
    assert all((tmp_path / f).is_file() for _, f in entries)
    mesh = meshio.read(tmp_path / entries[1][1])
    np.testing.assert_array_equal(mesh.points[:, :2], series["mesh_points"])
    np.testing.assert_array_equal(mesh.cells_dict["triangle"], series["cells"][1])
    np.testing.assert_array_equal(mesh.point_data["u"], np.pad(series["point_data"]["u"][1], [(0, 0), (0, 1)]))
    np.testing.assert_array_equal(mesh.point_data["p"], series["point_data"]["p"][1])
    np.testing.assert_array_equal(mesh.point_data["marker"], series["static_point_data"]["marker"])
    np.testing.assert_array_equal(mesh.cell_data["J"][0], series["cell_data"]["J"][1])
    assert _hidden(tmp_path) == []


def test_pvd_1d_series_pads_points_and_vectors(tmp_path):
    mesh = interval(4)
    u = np.linspace(0, 1, 2 * 5).reshape(2, 5, 1)
    path = hio.write_time_series(tmp_path, "bar", mesh.points, ("line", mesh.cells), [0.0, 1.0], {"u": u}, fmt="pvd")
    piece = meshio.read(tmp_path / _pvd_entries(path)[1][1])
    assert piece.points.shape == (5, 3) and piece.point_data["u"].shape == (5, 3)
    np.testing.assert_array_equal(piece.point_data["u"][:, 0], u[1, :, 0])
    np.testing.assert_array_equal(piece.points[:, 1:], 0.0)


def test_pvd_rewrite_is_atomic_and_removes_stale_pieces(tmp_path, monkeypatch):
    series = _series_2d()
    path = hio.write_time_series(tmp_path, "state", **series, fmt="pvd")
    original = path.read_bytes()
    real_write = meshio.write
    calls = []

    def failing_write(*args, **kwargs):
        calls.append(args[0])
        if len(calls) == 2:
            raise RuntimeError("crash while writing")
        return real_write(*args, **kwargs)

    monkeypatch.setattr(meshio, "write", failing_write)
    with pytest.raises(RuntimeError, match="crash"):
        hio.write_time_series(tmp_path, "state", **{**series, "times": series["times"] + 1.0}, fmt="pvd")
    assert path.read_bytes() == original and _hidden(tmp_path) == []
    monkeypatch.setattr(meshio, "write", real_write)
    shorter = {**series, "times": series["times"][:2], "point_data": {"p": series["point_data"]["p"][:2]},
               "cell_data": None}
    hio.write_time_series(tmp_path, "state", **shorter, fmt="pvd")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.pvd", "state_000000.vtu", "state_000001.vtu"]


def test_time_series_rejects_bad_shapes(tmp_path):
    series = _series_2d()
    with pytest.raises(ValueError, match="'p'"):
        hio.write_time_series(tmp_path, "s", **{**series, "point_data": {"p": np.zeros((2, 3))}}, fmt="pvd")
    with pytest.raises(ValueError, match="cell type"):
        hio.write_time_series(tmp_path, "s", **{**series, "cells": ("quad", series["cells"][1])}, fmt="pvd")
    with pytest.raises(ValueError, match="name"):
        hio.write_time_series(tmp_path, "../s", **series, fmt="pvd")
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- plots


def _png_size(path: Path) -> tuple:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    return struct.unpack(">II", data[16:24])


def test_plot_pressure(tmp_path):
    t = np.linspace(0, 1, 50)
    path = plot_pressure(tmp_path / "p.png", t, np.sin(4 * t), volume=1 + 1e-6 * t, marks=TimeMarks(0.4, 0.1),
                         title="pressure")
    assert path == tmp_path / "p.png" and _png_size(path) == (960, 960)
    assert _png_size(plot_pressure(tmp_path / "p1.png", t, np.cos(t))) == (960, 480)
    with pytest.raises(ValueError, match="p must have shape"):
        plot_pressure(tmp_path / "bad.png", t, np.zeros(3))
    assert _hidden(tmp_path) == []


MM_MS = Units(time="ms", length="mm", pressure="kPa", control="kPa/mm")
TimeMarks = hyperoc.app.plotting.TimeMarks  # the pressure figure's tau, window and events


def _figures(monkeypatch) -> list:
    """The Figures the plotting functions save, in order (nothing is written)."""
    saved = []
    monkeypatch.setattr(hyperoc.app.plotting, "save_figure", lambda fig, path: saved.append(fig) or Path(path))
    return saved


def test_plot_pressure_with_marks_and_units(tmp_path):
    t = np.linspace(0, 8, 81)
    marks = [(2.0, "filling ends"), (7.46, "snapshot"), (7.48, "snapshot")]
    path = plot_pressure(tmp_path / "p.png", t, np.sin(t), volume=1 + 1e-6 * t, cavity=50 + np.sin(t),
                         marks=TimeMarks(5.0, 0.5, marks), title="run: pressure", units=MM_MS)
    assert _png_size(path) == (960, 1440) and _hidden(tmp_path) == []


def test_plot_pressure_labels(monkeypatch):
    figures = _figures(monkeypatch)
    t = np.linspace(0, 8, 81)
    marks = [(2.0, "filling ends"), (7.46, "snapshot"), (7.48, "snapshot")]
    plot_pressure("p.png", t, np.sin(t), volume=1 + 1e-6 * t, cavity=50 + np.sin(t), marks=TimeMarks(5.0, events=marks),
                  title="run: pressure", units=MM_MS)
    plot_pressure("q.png", t, np.sin(t), cavity=np.ones_like(t))
    fig, plain = figures
    assert fig._suptitle.get_text() == "run: pressure"
    assert [ax.get_ylabel() for ax in fig.axes] == ["pressure p [kPa]", "V(t)/V(0) - 1 [-]", "cavity volume [mm^3]"]
    assert fig.axes[-1].get_xlabel() == "time t [ms]"
    assert [len([ln for ln in ax.lines if ln.get_gid() == "mark"]) for ax in fig.axes] == [3, 0, 0]
    legend = [text.get_text() for text in fig.axes[0].get_legend().get_texts()]
    assert legend == ["p(t)", r"$\tau$", "filling ends", "snapshot"]
    assert plain._suptitle is None and plain.axes[-1].get_xlabel() == "time t [-]"
    assert [ax.get_ylabel() for ax in plain.axes] == ["pressure p [-]", "cavity volume [-]"]


def test_the_pressure_comparison_zooms_on_tau(monkeypatch):
    """With ``zoom`` a third panel shows the rates of rise on [tau - zoom, tau + eps + zoom], its vertical range that
    of the rates there (where a control acting near tau shows), not of the whole run."""
    figures = _figures(monkeypatch)
    t = np.linspace(0.0, 0.5, 501)
    bump = np.exp(-((t - 0.03) / 0.01) ** 2)
    runs = {"uncontrolled": 1e5 * bump, "optimized": 1.02e5 * bump}
    rises = {name: (t, r - 5e5 * (t > 0.3)) for name, r in runs.items()}
    plot_pressure_comparison("p.png", {name: (t, np.cumsum(r)) for name, r in runs.items()}, rises, tau=0.03,
                             eps=0.002, zoom=0.01, title="run: pressure", units=Units(time="s", pressure="Pa"))
    plot_pressure_comparison("q.png", {"a": (t, t)}, {"a": (t, t)}, tau=0.03)
    zoomed, plain = figures
    assert len(zoomed.axes) == 3 and len(plain.axes) == 2
    ax = zoomed.axes[2]
    assert ax.get_xlim() == pytest.approx((0.02, 0.042))
    lo, hi = ax.get_ylim()
    inside = (t >= 0.02) & (t <= 0.042)
    assert lo <= 0.99 * rises["uncontrolled"][1][inside].min() and hi >= rises["optimized"][1][inside].max()
    assert lo > 0 and hi < 1.1e5  # the whole run's rates reach -5e5
    assert ax.get_ylabel() == "(p(t + $\\varepsilon$) - p(t)) / $\\varepsilon$ [Pa/s]"
    assert zoomed.axes[-1].get_xlabel() == "time t [s]"


def test_plot_labels_carry_units(monkeypatch):
    figures = _figures(monkeypatch)
    t, x = np.linspace(0, 1, 11), np.linspace(0, 1, 30)
    xi = np.outer(np.sin(np.pi * t), x - 0.5)
    plot_control_spacetime("c.png", t, x, xi, title="run: control xi", units=MM_MS)
    plot_snapshots("s.png", x, t, xi, [0.5, 1.0], ylabel="u(x, t) [mm]",
                   title="run: displacement u", units=MM_MS)
    plot_snapshots("s0.png", x, t, xi, [0.5], ylabel="u")
    plot_history("h.png", {"objective": [3.0, 2.0], "tau": [0.5, 0.4]}, title="run: optimizer history")
    control, snapshots, plain, history = figures
    ax, bar = control.axes
    assert (ax.get_title(), ax.get_xlabel(), ax.get_ylabel()) == ("run: control xi", "x [mm]", "time t [ms]")
    assert bar.get_ylabel() == "control xi [kPa/mm]"
    assert ax.collections[0].norm.vmin == -ax.collections[0].norm.vmax  # centred on 0
    assert snapshots._suptitle.get_text() == "run: displacement u"
    assert [a.get_title() for a in snapshots.axes] == ["t = 0.5 ms", "t = 1 ms"]
    assert (snapshots.axes[0].get_ylabel(), snapshots.axes[0].get_xlabel()) == ("u(x, t) [mm]", "x [mm]")
    assert (plain.axes[0].get_title(), plain.axes[0].get_ylabel(), plain.axes[0].get_xlabel()) == (
        "t = 0.5", "u", "x [-]")
    assert history._suptitle.get_text() == "run: optimizer history"


def test_long_titles_are_wrapped_inside_the_figure(monkeypatch):
    """A run's name can be longer than a figure is wide: every title is broken into lines that stay inside."""
    figures = _figures(monkeypatch)
    t, x = np.linspace(0, 1, 11), np.linspace(0, 1, 30)
    title = "paper-1d, " + "a formulation with a long descriptive name " * 3
    plot_pressure("p.png", t, np.sin(t), title=title)
    plot_snapshots("s.png", x, t, np.outer(t, x), [0.5, 1.0], ylabel="u", title=title)
    plot_control_spacetime("c.png", t, x, np.outer(t, x), title=title)
    for fig in figures:
        text = fig._suptitle or fig.axes[0].title
        renderer = fig.canvas.get_renderer()
        fig.draw(renderer)
        box, page = text.get_window_extent(renderer), fig.bbox
        assert text.get_text().count("\n") >= 1 and page.x0 <= box.x0 and box.x1 <= page.x1, text.get_text()
        assert " ".join(text.get_text().split()) == " ".join(title.split())


def test_units_derived():
    assert (MM_MS.velocity, MM_MS.volume) == ("mm/ms", "mm^3")
    assert (Units().velocity, Units().volume) == ("-", "-")
    assert Units(time="s").velocity == "1/s" and Units(length="m").velocity == "m"
    assert hyperoc.app.plotting.axis_label("x", "mm") == "x [mm]"


def test_plot_control_spacetime(tmp_path):
    t, x = np.linspace(0, 1, 20), np.linspace(0, 1, 30)
    xi = np.outer(np.sin(np.pi * t), x - 0.5)
    assert _png_size(plot_control_spacetime(tmp_path / "xi.png", t, x, xi, title="control")) == (960, 720)
    assert _png_size(plot_control_spacetime(tmp_path / "zero.png", t, x, np.zeros_like(xi))) == (960, 720)
    with pytest.raises(ValueError, match="xi must have shape"):
        plot_control_spacetime(tmp_path / "bad.png", t, x, xi.T)


def test_plot_snapshots_grid(tmp_path):
    x, t = np.linspace(0, 1, 30), np.linspace(0, 1, 11)
    values = np.sin(np.pi * x)[None, :] * t[:, None]
    path = plot_snapshots(tmp_path / "s.png", x, t, values, [0, 0.2, 0.4, 0.6, 0.8, 1.0], ylabel="u", title="u(t)")
    assert _png_size(path) == (1560, 660)  # 4 columns x 2 rows
    assert _png_size(plot_snapshots(tmp_path / "s2.png", x, t, values, [0.5, 0.55], ylabel="u")) == (780, 330)


def test_plot_history(tmp_path):
    histories = {"objective": [3.0, 2.0, 1.5], "grad_norm": [1.0, 1e-2, 1e-4], "tau": [0.5, 0.45, 0.44]}
    assert _png_size(plot_history(tmp_path / "h.png", histories)) == (960, 990)
    assert _png_size(plot_history(tmp_path / "h0.png", {"grad_norm": [1.0, 0.0, np.nan]})) == (960, 330)
    with pytest.raises(ValueError):
        plot_history(tmp_path / "none.png", {})

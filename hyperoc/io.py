"""Output files that are never half-written.

Every file is written to a temporary file in its own directory, flushed to disk, and moved
over its final name with `os.replace` (atomic on POSIX and Windows): a reader sees either the
old content or the new one, and a crash or an exception leaves the old file untouched and no
temporary file behind.

Multi-file outputs (a time series) are written into a temporary sibling directory and then
moved into place file by file, the main file (``.xdmf`` or ``.pvd``) last.

JSON
----
`write_json` writes pretty-printed, key-sorted JSON and converts numpy scalars and arrays to
Python types. Non-finite floats (NaN, +-inf) are written as ``null``: strict JSON has no such
values, and a NaN objective in a history must not make the whole file unwritable.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import secrets
import shutil
import tempfile
import xml.etree.ElementTree as ET
from contextlib import contextmanager
from pathlib import Path

import meshio
import numpy as np

__all__ = [
    "atomic_write_bytes",
    "atomic_write_text",
    "write_json",
    "read_json",
    "write_npz",
    "write_cache_npz",
    "npz_bytes",
    "read_npz",
    "write_time_series",
    "time_series_format",
]

NODES_PER_CELL = {"line": 2, "triangle": 3, "tetra": 4, "line3": 3, "triangle6": 6, "tetra10": 10}


# ----------------------------------------------------------------------------- single files


@contextmanager
def _atomic_file(path, durable: bool = True):
    """Yield a binary file that replaces ``path`` when the block exits without an exception; ``durable``:
    the file and the rename reach the disk before it returns (fsync), so a power loss keeps them too."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            if durable:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        _fsync_directory(path.parent)


def _fsync_directory(directory: Path) -> None:
    """Make a rename durable; a no-op where directories cannot be opened (Windows)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path, data: bytes, *, durable: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically (durably unless ``durable`` is False: see `_atomic_file`); return
    the path."""
    with _atomic_file(path, durable) as f:
        f.write(data)
    return Path(path)


def atomic_write_text(path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically; return the path."""
    return atomic_write_bytes(path, text.encode(encoding))


def _jsonable(obj):
    """Recursively convert numpy values, tuples and paths to JSON types; non-finite floats -> None."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"write_json: cannot serialize {type(obj).__name__}")


def write_json(path, obj) -> Path:
    """Write ``obj`` as pretty, key-sorted JSON, atomically.

    numpy scalars and arrays become numbers and (nested) lists; NaN and +-inf become ``null``.
    """
    text = json.dumps(_jsonable(obj), indent=2, sort_keys=True, allow_nan=False)
    return atomic_write_text(path, text + "\n")


def read_json(path):
    """The parsed content of a JSON file."""
    return json.loads(Path(path).read_text(encoding="utf-8"))


def npz_bytes(arrays: dict, compress: bool = True) -> bytes:
    """npz content of ``arrays``, compressed unless ``compress`` is False (no object arrays: they would need
    pickle)."""
    converted = {name: np.asarray(value) for name, value in arrays.items()}
    for name, value in converted.items():
        if value.dtype.hasobject:
            raise TypeError(f"npz: array {name!r} has dtype object")
    buffer = io.BytesIO()
    (np.savez_compressed if compress else np.savez)(buffer, **converted)
    return buffer.getvalue()


def write_npz(path, **arrays) -> Path:
    """Write arrays to a compressed ``.npz`` file atomically; return the path."""
    return atomic_write_bytes(path, npz_bytes(arrays))


def write_cache_npz(path, **arrays) -> Path:
    """Write arrays to an uncompressed ``.npz`` file atomically but not durably; return the path. For caches
    whose reader detects a damaged entry and recomputes it: compression and fsync cost more than the
    computation they would save after a power loss."""
    return atomic_write_bytes(path, npz_bytes(arrays, compress=False), durable=False)


def read_npz(path) -> dict:
    """All arrays of an ``.npz`` file (path or binary file object), loaded into memory (pickle disabled)."""
    if hasattr(path, "read"):
        with np.load(path, allow_pickle=False) as f:
            return {name: f[name] for name in f.files}
    with open(path, "rb") as fh:  # closed also when a damaged file makes np.load raise
        return read_npz(fh)


# ----------------------------------------------------------------------------- time series


def time_series_format() -> str:
    """``"xdmf"`` (XDMF + HDF5) if h5py is importable, else ``"pvd"`` (VTU files + collection)."""
    try:
        import h5py  # noqa: F401
    except ImportError:
        return "pvd"
    return "xdmf"


def write_time_series(
    directory,
    name: str,
    mesh_points,
    cells: tuple,
    times,
    point_data: dict,
    cell_data: dict | None = None,
    static_point_data: dict | None = None,
    *,
    fmt: str = "auto",
) -> Path:
    """Write a ParaView-readable time series of fields on a fixed mesh.

    Parameters
    ----------
    directory : path
        Output directory (created if needed).
    name : str
        Base file name, without directory or suffix.
    mesh_points : (nv, dim) array_like, dim <= 3
        Reference coordinates; padded with zeros to 3D.
    cells : (str, (nc, nodes) array_like of int)
        ``(cell_type, connectivity)``, as a meshio cell block: the meshio cell type (``line, triangle,
        tetra, line3, triangle6, tetra10``) and the connectivity, ``nodes = NODES_PER_CELL[cell_type]``.
    times : (nt,) array_like
        Time levels.
    point_data : dict of str -> (nt, nv) or (nt, nv, k) array_like
        Fields at the vertices per time level; vectors with ``k < 3`` are padded with zeros to
        3 components (so that ParaView's "Warp by vector" applies to a 1D/2D displacement).
    cell_data : dict of str -> (nt, nc) or (nt, nc, k) array_like, optional
        Fields per cell and time level, padded like ``point_data``.
    static_point_data : dict of str -> (nv,) or (nv, k) array_like, optional
        Time-independent vertex fields, repeated at every time level.
    fmt : {"auto", "xdmf", "pvd"}
        ``"auto"`` uses `time_series_format`: XDMF needs h5py.

    Returns
    -------
    Path
        The main file: ``directory/name.xdmf`` (with ``name.h5``) or ``directory/name.pvd``
        (with ``name_000000.vtu``, ...).
    """
    fmt = time_series_format() if fmt == "auto" else fmt
    if fmt not in ("xdmf", "pvd"):
        raise ValueError(f"write_time_series: unknown format {fmt!r}")
    if not name or Path(name).name != name or name.startswith("."):
        raise ValueError(f"write_time_series: invalid series name {name!r}")
    series = _prepare_series(mesh_points, cells, times, point_data, cell_data, static_point_data)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".tmp", dir=directory))
    try:
        writer = _write_xdmf if fmt == "xdmf" else _write_pvd
        files = writer(staging, name, **series)
        for file in files:
            os.replace(staging / file, directory / file)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    _fsync_directory(directory)
    if fmt == "pvd":
        _remove_stale_pieces(directory, name, set(files))
    return directory / files[-1]


def _prepare_series(points, cells: tuple, times, point_data, cell_data, static_point_data) -> dict:
    """Validate shapes and pad points and vectors to 3 components; ``cells = (cell_type, connectivity)``."""
    cell_type, cells = cells
    if cell_type not in NODES_PER_CELL:
        raise ValueError(f"write_time_series: unknown cell type {cell_type!r} (use one of {sorted(NODES_PER_CELL)})")
    points = np.asarray(points, dtype=np.float64)
    points = points[:, None] if points.ndim == 1 else points
    cells = np.asarray(cells, dtype=np.int64)
    if cells.ndim != 2 or cells.shape[1] != NODES_PER_CELL[cell_type]:
        raise ValueError(f"write_time_series: {cell_type} cells need shape (nc, {NODES_PER_CELL[cell_type]}), "
                         f"got {cells.shape}")
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    nt, nv, nc = len(times), len(points), len(cells)
    return {
        "points": _pad_components(points, "points"),
        "cells": cells,
        "cell_type": cell_type,
        "times": times,
        "point_data": {k: _series_field(k, v, nt, nv) for k, v in point_data.items()},
        "cell_data": {k: _series_field(k, v, nt, nc) for k, v in (cell_data or {}).items()},
        "static": {k: _static_field(k, v, nv) for k, v in (static_point_data or {}).items()},
    }


def _pad_components(array: np.ndarray, name: str) -> np.ndarray:
    """Pad the last axis of a (..., k) array with zeros to k = 3 when k < 3."""
    k = array.shape[-1]
    if k >= 3:
        return array
    if k < 1:
        raise ValueError(f"write_time_series: {name!r} has no components")
    pad = [(0, 0)] * (array.ndim - 1) + [(0, 3 - k)]
    return np.pad(array, pad)


def _series_field(name: str, value, nt: int, n: int) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim not in (2, 3) or array.shape[:2] != (nt, n):
        raise ValueError(f"write_time_series: field {name!r} must have shape ({nt}, {n}[, k]), got {array.shape}")
    return _pad_components(array, name) if array.ndim == 3 else array


def _static_field(name: str, value, nv: int) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim not in (1, 2) or array.shape[0] != nv:
        raise ValueError(f"write_time_series: static field {name!r} must have shape ({nv}[, k]), got {array.shape}")
    return _pad_components(array, name) if array.ndim == 2 else array


def _fields_at(series_fields: dict, n: int, static: dict | None = None) -> dict:
    return {**{k: v[n] for k, v in series_fields.items()}, **(static or {})}


class _SiblingH5Writer(meshio.xdmf.TimeSeriesWriter):
    """meshio 5.3 opens ``<stem>.h5`` in the working directory; open it beside the .xdmf file."""

    def __enter__(self):
        import h5py

        self.h5_filename = str(self.filename.with_suffix(".h5"))
        self.h5_file = h5py.File(self.h5_filename, "w")
        return self


def _write_xdmf(staging: Path, name: str, points, cells, cell_type, times, point_data, cell_data, static) -> list:
    with _SiblingH5Writer(staging / f"{name}.xdmf") as writer:
        writer.write_points_cells(points, [(cell_type, cells)])
        for n, t in enumerate(times):
            blocks = {k: [v] for k, v in _fields_at(cell_data, n).items()}
            writer.write_data(float(t), point_data=_fields_at(point_data, n, static), cell_data=blocks)
    return [f"{name}.h5", f"{name}.xdmf"]


def _piece_name(name: str, n: int) -> str:
    return f"{name}_{n:06d}.vtu"


def _write_pvd(staging: Path, name: str, points, cells, cell_type, times, point_data, cell_data, static) -> list:
    pieces = []
    for n in range(len(times)):
        mesh = meshio.Mesh(
            points,
            [(cell_type, cells)],
            point_data=_fields_at(point_data, n, static),
            cell_data={k: [v] for k, v in _fields_at(cell_data, n).items()},
        )
        pieces.append(_piece_name(name, n))
        meshio.write(staging / pieces[-1], mesh, file_format="vtu")
    (staging / f"{name}.pvd").write_text(_pvd_xml(times, pieces), encoding="utf-8")
    return [*pieces, f"{name}.pvd"]


def _pvd_xml(times, pieces: list) -> str:
    """ParaView collection file listing one VTU file per time level."""
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    collection = ET.SubElement(root, "Collection")
    for t, piece in zip(times, pieces):
        ET.SubElement(collection, "DataSet", timestep=repr(float(t)), group="", part="0", file=piece)
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _remove_stale_pieces(directory: Path, name: str, keep: set) -> None:
    """Delete VTU files of an earlier, longer series with the same name."""
    pattern = re.compile(re.escape(name) + r"_\d{6}\.vtu")
    for path in directory.iterdir():
        if pattern.fullmatch(path.name) and path.name not in keep:
            path.unlink(missing_ok=True)

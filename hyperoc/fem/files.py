"""Mesh files: reading (Gmsh ``.msh`` v2 and v4 of order 1 and 2, VTU, XDMF) and writing (Gmsh MSH 2.2).

Reading
-------
`from_file` reads any file meshio reads and the XDMF files that DOLFINx (and legacy DOLFIN) write: one
``Uniform`` grid of cells plus further grids of tagged facets or cells sharing its geometry
(`read_xdmf_grids`), the layout of the cardiac benchmark's reference mesh.

- Cells are the simplices of the highest dimension present. Quadratic simplices (``line3``,
  ``triangle6``, ``tetra10``; meshio's VTK node order: the ``d + 1`` vertices, then one node per edge in
  the order of `_EDGES`) become straight simplices on their vertices, and every edge node that lies off
  its edge's midpoint becomes a curved P2 node (`hyperoc.fem.mesh.Mesh.curved_edges`): degree-2 spaces
  then see the file's curved geometry, degree-1 spaces its straight cells.
- Named groups: Gmsh physical groups (named by ``$PhysicalNames``, else by their number), meshio cell
  sets, and every integer cell array (XDMF attributes, VTU ``CellData``) as one group per value, named
  by the value (``"1"``, ``"2"``, ...; the "unset" marker of DOLFIN, the largest value of an unsigned
  type, and negative values are no tag). Facet groups become boundaries, cell groups subdomains.
- Tag names: ``tags`` names a file's tags (``{"endocardium": 1}``: the facets tagged 1 are also the
  boundary ``"endocardium"``); every look-up by name also accepts the aliases of
  `hyperoc.fem.mesh.ALIASES` (``ENDO``, ``endo`` for ``endocardium``, ``top`` for ``base``, ...).

Every problem (missing file, unreadable content, no simplices, a missing tag, degenerate cells) raises
`InputError` with one line that names the file.
"""

from __future__ import annotations

import contextlib
import io
import xml.etree.ElementTree as ET
from pathlib import Path

import meshio
import numpy as np

from ..errors import InputError
from .mesh import Mesh, find_group

__all__ = ["from_file", "to_file", "read_raw", "read_xdmf_grids"]

_SIMPLEX_DIM = {"line": 1, "triangle": 2, "tetra": 3}
_SIMPLEX_TYPE = {d: t for t, d in _SIMPLEX_DIM.items()}
_FACET_TYPE = {1: "vertex", 2: "line", 3: "triangle"}
_LINEAR = {"line3": "line", "triangle6": "triangle", "tetra10": "tetra"}
#: Vertex pairs of the edge nodes of the quadratic simplices, in meshio's (VTK's) node order.
_EDGES = {1: [(0, 1)], 2: [(0, 1), (1, 2), (2, 0)], 3: [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]}
#: An edge node this far off the midpoint (relative to the edge length) counts as curved.
_CURVED_TOL = 1e-8

_XDMF_TYPES = {"polyline": "line", "edge_3": "line3", "triangle": "triangle", "triangle_6": "triangle6",
               "tetrahedron": "tetra", "tetrahedron_10": "tetra10", "tet_10": "tetra10"}


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def from_file(path, *, dirichlet: str = "gamma_d", neumann: str = "gamma_n", control: str = "omega",
              tags: dict | None = None) -> Mesh:
    """Read a mesh file (module docstring): Gmsh ``.msh`` v2/v4 of order 1 or 2, ``.vtu``, ``.xdmf``, ...

    The dimension of the points follows the cells (``z``, or ``y`` and ``z``, must then be zero and are
    dropped). Vertices used by no cell (and the edge nodes of quadratic cells) are dropped and the rest
    renumbered; duplicate elements (Gmsh MSH 2 repeats an element once per physical group) are merged.
    Coordinates are taken in model length units as they are.

    Parameters
    ----------
    path : str or Path
        Mesh file.
    dirichlet, neumann : str
        Boundary groups that become ``"gamma_d"`` and ``"gamma_n"`` (names, numbers or aliases).
    control : str
        Cell group that becomes the control region ``"omega"``. A group named other than its default
        (``"gamma_d"``, ``"gamma_n"``, ``"omega"``) must exist; the defaults are simply absent if the file
        lacks them.
    tags : dict, optional
        ``{name: tag}``: the group ``tag`` (a name or number of the file) is also called ``name``.

    Raises
    ------
    InputError
        Missing or unreadable file, no simplices, non-flat coordinates, degenerate cells, edge nodes of a
        quadratic cell far off their edges, or a requested group that the file does not have.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"mesh file not found: {path}")
    raw = read_raw(path)
    blocks, edge_nodes = _linear_blocks(raw.cells)
    dims = [_SIMPLEX_DIM[b.type] for b in blocks if b.type in _SIMPLEX_DIM and len(b.data)]
    if not dims:
        found = sorted({b.type for b in raw.cells}) or ["nothing"]
        raise InputError(f"mesh file {path}: no line, triangle or tetra cells (of order 1 or 2); found {found}")
    dim = max(dims)
    cells, cell_rows = _merged_elements(blocks, _SIMPLEX_TYPE[dim])
    facets, facet_rows = _merged_elements(blocks, _FACET_TYPE[dim])
    groups = _named_groups(raw, blocks)
    boundaries = _boundary_groups(groups, facets, facet_rows, dim)
    subdomains = _subdomain_groups(groups, len(cells), cell_rows, dim)
    new_index = _renumbering(cells, len(raw.points))
    points, cells, boundaries = _drop_unused_points(raw.points, cells, boundaries)
    if np.any(points[:, dim:] != 0):
        raise InputError(f"mesh file {path}: {dim}D cells but coordinates beyond the first {dim} are not all zero")
    edges, positions = _curved_edges(raw.points[:, :dim], edge_nodes.get(dim), new_index, path)
    _name_tags(boundaries, subdomains, tags or {}, path)
    _alias(boundaries, "gamma_d", dirichlet, path, "boundary")
    _alias(boundaries, "gamma_n", neumann, path, "boundary")
    _alias(subdomains, "omega", control, path, "subdomain")
    try:
        return Mesh(points[:, :dim], cells, boundaries, subdomains, edges, positions)
    except InputError as exc:
        raise InputError(f"mesh file {path}: {str(exc).removeprefix('mesh: ')}") from exc


def _name_tags(boundaries: dict, subdomains: dict, tags: dict, path: Path) -> None:
    """``tags`` ``{name: tag}``: the boundary (or, failing that, subdomain) ``tag`` also called ``name``."""
    for name, tag in tags.items():
        named = boundaries if str(tag) in boundaries or str(tag) not in subdomains else subdomains
        named[name] = named[find_group(named, tag, source=f"mesh file {path}")]


def _alias(named: dict, canonical: str, source: str, path: Path, kind: str) -> None:
    """Make ``named[canonical]`` the group ``source``; a non-default ``source`` must exist."""
    if source == canonical and source not in named:
        return
    named[canonical] = named[find_group(named, source, kind, f"mesh file {path}")]


def read_raw(path) -> meshio.Mesh:
    """The file as a meshio mesh, with its point and cell data: DOLFIN(x)-style XDMF by `read_xdmf_grids`,
    anything else by meshio; a failure is a one-line `InputError`."""
    path = Path(path)
    if path.suffix.lower() == ".xdmf":
        grids = read_xdmf_grids(path)
        if grids is not None:
            return grids
    return _read_meshio(path)


def _read_meshio(path: Path) -> meshio.Mesh:
    """``meshio.read``, silenced, with every failure turned into a one-line `InputError`.

    ``.msh`` is read as Gmsh (meshio would try ANSYS first). meshio prints its readers' errors
    and calls ``sys.exit`` when none accepts the file, hence the captured output and the
    ``SystemExit`` handler.
    """
    file_format = "gmsh" if path.suffix == ".msh" else None
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            return meshio.read(path, file_format=file_format)
    except SystemExit as exc:
        raise InputError(f"cannot read mesh file {path}: not a valid {file_format or path.suffix} mesh") from exc
    except Exception as exc:  # meshio raises ReadError, KeyError, ValueError, ... on bad input
        lines = str(exc).strip().splitlines() or [type(exc).__name__]
        raise InputError(f"cannot read mesh file {path}: {lines[0]}") from exc


def read_xdmf_grids(path) -> meshio.Mesh | None:
    """An XDMF file of ``Uniform`` grids sharing one geometry (DOLFINx ``write_mesh`` +
    ``write_meshtags``, legacy DOLFIN ``write(mesh)`` + ``write(mesh_function)``) as one meshio mesh.

    Each grid's topology becomes a cell block; its integer cell attributes become cell data (named by
    the attribute, ``-1`` where a block has none), its node attributes point data. Data items may be
    inline (``Format="XML"``) or in HDF5 (``file.h5:/dataset``, read with h5py). Returns None for an XDMF
    file of another layout (a single grid, e.g. of mixed cells, or a time series), left to meshio.
    """
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise InputError(f"cannot read mesh file {path}: {exc}") from exc
    domain = root.find("Domain")
    grids = [] if domain is None else [g for g in domain.findall("Grid") if g.get("GridType", "Uniform") == "Uniform"]
    if len(grids) < 2:
        return None
    try:
        return _grids_mesh(path, grids)
    except InputError:
        raise
    except Exception as exc:  # h5py, numpy and XML errors on damaged files
        lines = str(exc).strip().splitlines() or [type(exc).__name__]
        raise InputError(f"cannot read mesh file {path}: {lines[0]}") from exc


def _grids_mesh(path: Path, grids: list) -> meshio.Mesh:
    geometry = next((g.find("Geometry/DataItem") for g in grids if g.find("Geometry/DataItem") is not None), None)
    if geometry is None:
        raise InputError(f"cannot read mesh file {path}: no grid has a geometry")
    points = _data_item(path, geometry).astype(np.float64).reshape(-1, 3 if "Z" in grids[0].find(
        "Geometry").get("GeometryType", "XYZ") else 2)
    blocks, cell_values, point_data = [], {}, {}
    for grid in grids:
        topology = grid.find("Topology")
        if topology is None:
            continue
        name = topology.get("TopologyType", topology.get("Type", "")).lower()
        if name not in _XDMF_TYPES:
            raise InputError(f"cannot read mesh file {path}: unsupported XDMF topology {name!r}")
        cell_type = _XDMF_TYPES[name]
        data = _data_item(path, topology.find("DataItem")).astype(np.int64)
        blocks.append(meshio.CellBlock(cell_type, data.reshape(len(data), -1)))
        for attribute in grid.findall("Attribute"):
            values = _data_item(path, attribute.find("DataItem"))
            if attribute.get("Center") == "Node":
                point_data[attribute.get("Name")] = values.reshape(len(points), -1).squeeze()
            elif values.dtype.kind in "iu":
                cell_values.setdefault(attribute.get("Name"), {})[len(blocks) - 1] = values.reshape(-1)
    cell_data = {name: [per.get(b, np.full(len(blk.data), -1)) for b, blk in enumerate(blocks)]
                 for name, per in cell_values.items()}
    return meshio.Mesh(points, blocks, point_data=point_data, cell_data=cell_data)


def _data_item(path: Path, item) -> np.ndarray:
    """The array of an XDMF ``DataItem``: inline text or an HDF5 dataset ``file.h5:/name``."""
    if item is None:
        raise InputError(f"cannot read mesh file {path}: a grid has no DataItem")
    text = (item.text or "").strip()
    if item.get("Format", "XML").upper() == "HDF":
        import h5py

        file, _, dataset = text.partition(":")
        with h5py.File(path.parent / file, "r") as h5:
            return np.asarray(h5[dataset][()])
    number = item.get("NumberType", item.get("DataType", "Float")).lower()
    dtype = np.float64 if number == "float" else np.int64
    return np.array(text.split(), dtype=dtype)


def _linear_blocks(blocks) -> tuple[list, dict]:
    """The blocks with quadratic simplices cut to their vertices, and per dimension the edge nodes of
    the quadratic cells: ``{dim: (vertex pairs (n, 2), node indices (n,))}``."""
    linear, edge_nodes = [], {}
    for block in blocks:
        if block.type not in _LINEAR:
            linear.append(block)
            continue
        data = np.asarray(block.data, dtype=np.int64)
        dim = _SIMPLEX_DIM[_LINEAR[block.type]]
        linear.append(meshio.CellBlock(_LINEAR[block.type], data[:, : dim + 1]))
        pairs = np.concatenate([data[:, [a, b]] for a, b in _EDGES[dim]])
        nodes = np.concatenate([data[:, dim + 1 + k] for k in range(len(_EDGES[dim]))])
        old_pairs, old_nodes = edge_nodes.get(dim, (np.zeros((0, 2), np.int64), np.zeros(0, np.int64)))
        edge_nodes[dim] = (np.concatenate([old_pairs, pairs]), np.concatenate([old_nodes, nodes]))
    return linear, edge_nodes


def _curved_edges(points: np.ndarray, edge_nodes, new_index: np.ndarray, path: Path) -> tuple:
    """Curved P2 edges ``(edges (ne, 2) in the renumbered vertices, positions (ne, dim))``: the edge nodes
    of quadratic cells off their edge's midpoint by more than `_CURVED_TOL` times the edge length."""
    dim = points.shape[1]
    if edge_nodes is None:
        return np.zeros((0, 2), np.int64), np.zeros((0, dim))
    pairs, nodes = edge_nodes
    pairs, first = np.unique(np.sort(pairs, axis=1), axis=0, return_index=True)
    position = points[nodes[first]]
    offset = np.linalg.norm(position - 0.5 * (points[pairs[:, 0]] + points[pairs[:, 1]]), axis=1)
    length = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    if np.any(offset > 0.5 * length):
        raise InputError(f"mesh file {path}: {int(np.sum(offset > 0.5 * length))} edge node(s) of quadratic cells "
                         "lie farther from their edge's midpoint than half its length (unknown node order?)")
    curved = offset > _CURVED_TOL * length
    return new_index[pairs[curved]], position[curved]


def _merged_elements(blocks, cell_type: str) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Distinct elements of one type over all blocks, in order of first appearance.

    Returns ``(elements (n, k), rows)`` where ``rows[b][i]`` is the row of element ``i`` of
    block ``b`` in ``elements``.
    """
    data = {b: np.asarray(block.data, dtype=np.int64) for b, block in enumerate(blocks) if block.type == cell_type}
    if not data:
        return np.empty((0, _element_dim(cell_type) + 1), dtype=np.int64), {}
    stacked = np.concatenate(list(data.values()))
    _, first, inverse = np.unique(np.sort(stacked, axis=1), axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    rows_all = rank[inverse.reshape(-1)]
    bounds = np.cumsum([0] + [len(d) for d in data.values()])
    rows = {b: rows_all[bounds[k] : bounds[k + 1]] for k, b in enumerate(data)}
    return stacked[first[order]], rows


def _named_groups(raw: meshio.Mesh, blocks: list) -> dict[tuple[str, int], dict[int, np.ndarray]]:
    """Named element groups: ``(name, dimension) -> {block: element indices}`` (``blocks``: the file's
    blocks, quadratic ones made linear, in the same order).

    Sources: ``gmsh:physical`` tags (names and dimensions from ``field_data``, where named groups
    without elements are kept, empty, so that they survive a round trip; unnamed tags are named by
    their number), meshio ``cell_sets`` (except Gmsh's internal ones) and the other integer cell
    arrays (one group per tag value, named by the value).
    """
    groups: dict[tuple[str, int], dict[int, np.ndarray]] = {}

    def add(key, block, idx):
        members = groups.setdefault(key, {})
        members[block] = np.union1d(members.get(block, np.empty(0, np.int64)), idx).astype(np.int64)

    physical = raw.cell_data.get("gmsh:physical")
    names = _physical_names(raw.field_data) if physical is not None else {}
    for tag, dim in names:
        groups.setdefault((names[tag, dim], dim), {})
    for b, tags in enumerate(physical or []):
        dim = _element_dim(blocks[b].type)
        tags = np.asarray(tags).reshape(-1)
        for tag in np.unique(tags[tags > 0]):
            add((names.get((int(tag), dim), str(int(tag))), dim), b, np.flatnonzero(tags == tag))
    for array_name, per_block in raw.cell_data.items():
        if array_name.startswith("gmsh:"):
            continue
        for b, values in enumerate(per_block):
            values = np.asarray(values).reshape(-1)
            if values.dtype.kind not in "iu" or len(values) != len(blocks[b].data):
                continue
            tagged = _is_tag(values)
            for tag in np.unique(values[tagged]):
                add((str(int(tag)), _element_dim(blocks[b].type)), b, np.flatnonzero(tagged & (values == tag)))
    for name, per_block in raw.cell_sets.items():
        if name.startswith("gmsh:"):
            continue
        for b, idx in enumerate(per_block):
            if idx is not None and len(idx):
                add((name, _element_dim(blocks[b].type)), b, np.asarray(idx))
    return groups


def _is_tag(values: np.ndarray) -> np.ndarray:
    """Which integer values are tags: not negative, not the largest value of an unsigned type (DOLFIN's
    "unset" marker of a mesh function)."""
    if values.dtype.kind == "u":
        return values != np.iinfo(values.dtype).max
    return values >= 0


def _physical_names(field_data: dict) -> dict[tuple[int, int], str]:
    """Gmsh ``$PhysicalNames`` as meshio stores them (``name -> [tag, dim]``): ``(tag, dim) -> name``."""
    names = {}
    for name, value in field_data.items():
        value = np.asarray(value).reshape(-1)
        if len(value) == 2 and 0 <= value[1] <= 3:
            names[int(value[0]), int(value[1])] = name
    return names


def _element_dim(cell_type: str) -> int:
    return 0 if cell_type == "vertex" else _SIMPLEX_DIM.get(cell_type, -1)


def _boundary_groups(groups: dict, facets: np.ndarray, facet_rows: dict, dim: int) -> dict[str, np.ndarray]:
    """Facet groups (dimension ``dim - 1``) as ``name -> (nf, dim)`` vertex indices, in file order."""
    out = {}
    for (name, gdim), members in groups.items():
        if gdim == dim - 1:
            rows = np.concatenate([facet_rows[b][idx] for b, idx in members.items() if b in facet_rows] or [[]])
            _, first = np.unique(rows, return_index=True)
            out[name] = facets[rows[np.sort(first)].astype(np.int64)]
    return out


def _subdomain_groups(groups: dict, num_cells: int, cell_rows: dict, dim: int) -> dict[str, np.ndarray]:
    """Cell groups (dimension ``dim``) as ``name -> (nc,) bool`` masks."""
    out = {}
    for (name, gdim), members in groups.items():
        if gdim == dim:
            mask = np.zeros(num_cells, dtype=bool)
            for b, idx in members.items():
                if b in cell_rows:
                    mask[cell_rows[b][idx]] = True
            out[name] = mask
    return out


def _renumbering(cells: np.ndarray, num_points: int) -> np.ndarray:
    """New index (num_points,) of each vertex when only those of ``cells`` are kept, in their order; -1
    for the others."""
    used = np.unique(cells)
    new_index = np.full(num_points, -1, dtype=np.int64)
    new_index[used] = np.arange(len(used))
    return new_index


def _drop_unused_points(points: np.ndarray, cells: np.ndarray, facet_sets: dict) -> tuple:
    """Keep the vertices of ``cells`` (in their original order) and renumber everything.

    Returns ``(points, cells, facet_sets)``; raises `InputError` if a facet uses a dropped vertex.
    """
    new_index = _renumbering(cells, len(points))
    renumbered = {}
    for name, facets in facet_sets.items():
        renumbered[name] = new_index[facets]
        if np.any(renumbered[name] < 0):
            raise InputError(f"mesh: boundary {name!r} has vertices that belong to no cell")
    return points[new_index >= 0], new_index[cells], renumbered


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


def to_file(mesh: Mesh, path) -> Path:
    """Write ``mesh`` with its named boundaries and subdomains; returns the path.

    Every name becomes a Gmsh physical group (``gmsh:physical`` tag + ``field_data`` name), its
    elements written as one extra cell block: all cells first, then each subdomain's cells, then
    each boundary's facets. A ``.msh`` path is written as Gmsh MSH 2.2 (ASCII), which Gmsh reads
    and from which `from_file` recovers every name, including empty groups. Other formats are
    written by meshio as they are; in ``.vtu``/``.vtk`` the names are lost (only the integer
    ``gmsh:physical`` tags remain, which `from_file` then reads as names ``"1"``, ``"2"``, ...).
    Points are padded to 3 coordinates. Only the straight-sided mesh is written: curved P2 edge nodes
    (``mesh.curved_edges``) are not, so the file reads back as ``mesh.faceted()``.
    """
    path = Path(path)
    shared = sorted(set(mesh.subdomains) & set(mesh.boundaries))
    if shared:
        raise InputError(f"to_file: {shared} name both a subdomain and a boundary; Gmsh names must be unique")
    blocks = [(_SIMPLEX_TYPE[mesh.dim], mesh.cells, 0)]
    field_data = {}
    groups = [(name, _SIMPLEX_TYPE[mesh.dim], mesh.cells[mask]) for name, mask in mesh.subdomains.items()]
    groups += [(name, _FACET_TYPE[mesh.dim], facets) for name, facets in mesh.boundaries.items()]
    for tag, (name, cell_type, data) in enumerate(groups, start=1):
        field_data[name] = np.array([tag, _element_dim(cell_type)])
        if len(data):
            blocks.append((cell_type, data, tag))
    cells = [meshio.CellBlock(cell_type, data) for cell_type, data, _ in blocks]
    physical = [np.full(len(data), tag, dtype=np.int32) for _, data, tag in blocks]
    geometrical = [np.full(len(data), k + 1, dtype=np.int32) for k, (_, data, _) in enumerate(blocks)]
    points = np.zeros((len(mesh.points), 3))
    points[:, : mesh.dim] = mesh.points
    out = meshio.Mesh(
        points, cells, cell_data={"gmsh:physical": physical, "gmsh:geometrical": geometrical}, field_data=field_data
    )
    if path.suffix == ".msh":
        out.write(path, file_format="gmsh22", binary=False)
    else:
        out.write(path)
    return path

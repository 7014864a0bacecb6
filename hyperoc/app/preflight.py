"""Checks made before a run writes anything or starts a solve, without importing JAX.

- `check_output_dir`: the output folder can be created and written (not a file, not under a file,
  not in a read-only place).
- `estimate_resources` and `check_resources`: the size of the problem (cells, dofs, time levels,
  states kept for the adjoint) and a lower bound of its memory, computed from the configuration
  alone, before any mesh or array of that size exists; above the memory available the run is
  refused (`InputError`) unless forced.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError

__all__ = ["check_inputs", "check_output_dir", "Estimate", "estimate_resources", "check_resources", "available_memory"]

FLOAT_BYTES = 8
# Mean cells per vertex of simplicial meshes (1D: 1; triangles: 2; tetrahedra: between 5 and 6,
# Kuhn's 6 per cube of a box): vertices ~ cells / this.
CELLS_PER_VERTEX = {1: 1.0, 2: 2.0, 3: 5.0}
# Volume of the equilateral simplex of edge h, over h^d: what a Gmsh mesh of size h fills per cell.
SIMPLEX_VOLUME = {2: math.sqrt(3) / 4, 3: 1 / (6 * math.sqrt(2))}
# Local nodes of a simplex of degree 1 and 2 in dimension d.
LOCAL_NODES = {(1, 1): 2, (1, 2): 3, (2, 1): 3, (2, 2): 6, (3, 1): 4, (3, 2): 10}


def check_inputs(cfg, command: str, force: bool = False):
    """The checks of a run that need no solver: the files ``cfg`` names, the problem's size
    (`check_resources`), the material's parameters, the mesh and control region, the time grid and, for
    ``simulate``, the prescribed control on the actual space-time grid, else the starts of tau. Returns the
    mesh, for the model to reuse."""
    from .config import read_control_file

    mesh_file, control_file = cfg.mesh_path(), cfg.control_path()
    if mesh_file is not None and not mesh_file.is_file():
        raise InputError(cfg.missing_file("mesh", "mesh"))
    if control_file is not None:
        if not control_file.is_file():
            raise InputError(cfg.missing_file("control", "control"))
        read_control_file(control_file)
    check_resources(cfg, command, force)
    cfg.material()
    mesh = cfg.mesh()
    grid = cfg.grid()
    control, space = cfg.control_data(mesh)
    if command == "simulate":
        cfg.control_values(control, space, grid.t)
    else:
        cfg.tau_starts()
    return mesh


def check_output_dir(out, option: str = "--out") -> Path:
    """``out`` as a Path if it is, or can be created as, a writable folder; else `InputError` with
    the path and the reason. Nothing is created."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{option} {out}: is a file, not a folder")
    existing = out
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if existing != out and not existing.is_dir():
        raise InputError(f"{option} {out}: {existing} is a file, so no folder can be made under it")
    if not _writable(existing):
        raise InputError(f"{option} {out}: {existing} is not writable")
    return out


def _writable(directory: Path) -> bool:
    """Whether a folder can be made in ``directory``, tried (and removed): `os.access` says yes to
    root on folders where nobody can create anything (``/proc``)."""
    try:
        probe = tempfile.mkdtemp(prefix=".hyperoc-probe-", dir=directory)
    except OSError:
        return False
    os.rmdir(probe)
    return True


@dataclass(frozen=True)
class Estimate:
    """Size of a run, from the configuration.

    cells, nodes : of the refined mesh (nodes of the displacement's degree); dofs = nodes * dim;
    levels : time levels N + 1 = T / dt + 1; stored_states : levels whose state (u, v) is kept at
    once (all for ``simulate`` and a full-storage adjoint; fewer with checkpointing); bytes : lower
    bound of the memory (see `estimate_resources`).
    """

    dim: int
    cells: int
    nodes: int
    dofs: int
    levels: int
    stored_states: int
    bytes: int

    def describe(self) -> str:
        return (f"{self.cells:.3g} cells, {self.dofs:.3g} dofs, {self.levels:.3g} time levels, "
                f"{self.stored_states:.3g} stored states: about {self.bytes / 2**30:.3g} GiB")


def estimate_resources(cfg, command: str) -> Estimate:
    """The `Estimate` of a ``simulate`` or ``optimize`` run of ``cfg`` (a `hyperoc.app.config.Config`).

    Memory (bytes) >= 8 * (3 * dofs * stored_states + 2 * dofs * levels + cells * (k d)^2): each
    stored level holds u, v and the adjoint's state of that level; the control and its gradient
    have at most dofs entries per level; the element tangents have (k d)^2 entries per cell (k
    local nodes). The sparse factorizations and the compiled kernels come on top.
    """
    m = cfg["mesh"]
    dim, cells = _mesh_cells(cfg)
    cells *= 2 ** (dim * m["refinements"])
    degree = m["degree"]
    vertices = cells / CELLS_PER_VERTEX[dim] + 1
    nodes = vertices if degree == 1 else (2 * cells + 1 if dim == 1 else 2 * vertices + cells)
    dofs = int(nodes) * dim
    d = cfg["dynamics"]
    levels = int(round(d["T"] / d["dt"])) + 1
    stored = levels if command == "simulate" else _stored_states(cfg["optimize"], levels)
    k = LOCAL_NODES[(dim, degree)]
    floats = 3 * dofs * stored + 2 * dofs * levels + int(cells) * (k * dim) ** 2
    return Estimate(dim, int(cells), int(nodes), dofs, levels, stored, FLOAT_BYTES * floats)


def _mesh_cells(cfg) -> tuple[int, float]:
    """``(dim, cells)`` of the unrefined mesh of ``[mesh]``: exact for the structured generators,
    the domain's volume over a size-h simplex's for the Gmsh ones; a mesh file is read."""
    m = cfg["mesh"]
    kind = m["kind"]
    if kind == "interval":
        return 1, m["n"]
    if kind == "rectangle":
        return 2, 2 * m["nx"] * m.get("ny", m["nx"])
    if kind == "box":
        return 3, 6 * m["nx"] * m.get("ny", m["nx"]) * m.get("nz", m["nx"])
    if kind == "annulus":
        if m["structured"] and "n_radial" in m and "n_theta" in m:
            return 2, 2 * m["n_radial"] * m["n_theta"]
        area = math.pi * (m["r_outer"] ** 2 - m["r_inner"] ** 2)
        return 2, area / (SIMPLEX_VOLUME[2] * m["h"] ** 2)
    if kind == "shell":
        volume = 4 / 3 * math.pi * (m["r_outer"] ** 3 - m["r_inner"] ** 3)
        return 3, volume / (SIMPLEX_VOLUME[3] * m["h"] ** 3)
    if kind == "ventricle":  # `hyperoc.fem.geometry.ventricle`'s default wall: endo (7, 17), epi (10, 20), base z = 5
        volume = _cut_spheroid_volume(10.0, 20.0, 5.0) - _cut_spheroid_volume(7.0, 17.0, 5.0)
        return 3, volume / (SIMPLEX_VOLUME[3] * m["h"] ** 3)
    mesh = cfg.file_mesh()  # its size is the size of what is on disk
    return mesh.dim, mesh.num_cells


def _cut_spheroid_volume(a: float, c: float, z0: float) -> float:
    """Volume of ``(x^2 + y^2) / a^2 + z^2 / c^2 <= 1`` below ``z = z0``:
    ``pi a^2 int_{-c}^{z0} (1 - z^2 / c^2) dz``."""
    return math.pi * a**2 * ((z0 + c) - (z0**3 + c**3) / (3 * c**2))


def _stored_states(o: dict, levels: int) -> int:
    """Levels kept at once by the adjoint: all, or every k-th plus one recomputed segment of k, or
    the s snapshots of a binomial schedule plus the level being recomputed."""
    if o.get("checkpoint_every"):
        k = o["checkpoint_every"]
        return min(levels, -(-(levels - 1) // k) + 1 + k)
    if o.get("checkpoint_snapshots"):
        return min(levels, o["checkpoint_snapshots"] + 1)
    return levels


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``), or None if unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_resources(cfg, command: str, force: bool = False) -> Estimate:
    """`estimate_resources`; `InputError` (with the estimate and the ways out) if it exceeds the
    available memory and ``force`` is false."""
    est = estimate_resources(cfg, command)
    available = available_memory()
    if force or available is None or est.bytes <= available:
        return est
    remedy = "coarser [mesh], fewer refinements, a larger dt or a shorter T"
    if command == "optimize" and est.stored_states == est.levels:
        remedy += ", [optimize] checkpoint_every or checkpoint_snapshots"
    raise InputError(f"resources: {est.describe()}, more than the {available / 2**30:.3g} GiB available; "
                     f"use {remedy}, or --force to run anyway")

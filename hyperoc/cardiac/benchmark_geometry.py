"""Geometry, fibres and probe points of the cardiac elastodynamics benchmark (monoventricular problem).

R. Aróstica et al., "A software benchmark for cardiac elastodynamics", Comput. Methods Appl. Mech. Engrg. 435
(2025) 117485. Units: m.

The domain is a truncated ellipsoidal shell with the long axis along ``x`` and the apex at ``x < 0``: the wall
between the ellipsoids of revolution

    x^2 / r_l^2 + (y^2 + z^2) / r_s^2 = 1,   (r_s, r_l) = (0.025, 0.09) endocardium, (0.035, 0.097) epicardium,

cut at the base by the cone through the two rim circles ``mu = -arccos(5/17)`` on the endocardium (``x =
0.09 * 5/17``) and ``mu = -arccos(5/20)`` on the epicardium (``x = 0.097 / 4``), where ``(r_l cos mu, r_s sin mu
cos theta, r_s sin mu sin theta)`` parametrizes each ellipsoid: the benchmark's base is the surface swept by
the straight segment between the two rim points of a meridian, not a plane. Boundary tags of the reference
mesh: 1 endocardium, 2 epicardium, 3 base (`TAGS`).

- `reference_mesh`: the benchmark's own mesh (shipped in ``hyperoc/data/cardiac_benchmark``, 4,577 vertices,
  17,625 tetrahedra, size 5 mm), the one the participating codes used;
- `benchmark_mesh`: hyperoc's Gmsh mesh of the same domain at any size, its wall vertices on the exact
  ellipsoids, with curved P2 edge nodes (`hyperoc.fem.geometry`); `coarse_mesh`: the shipped coarse one;
- `benchmark_frames` / `benchmark_fibres`: the benchmark's analytic fibre and sheet fields;
- `P0`, `P1`: the material points whose displacements the benchmark reports;
- `cavity_volume`: the volume enclosed by the endocardium and its rim, in the reference or a deformed
  configuration.
"""

from __future__ import annotations

import math
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..fem import geometry
from ..fem.files import from_file
from ..fem.mesh import Mesh
from ..mechanics.cavity import CavityVolume
from ..mechanics.fibres import FieldFrames, field_frames, transmural_coordinate
from ..mechanics.materials import NeoHookean
from ..mechanics.model import StateModel

__all__ = ["ENDO", "EPI", "BASE_X", "HELIX", "P0", "P1", "TAGS", "mesh_file", "read_mesh", "reference_mesh",
           "coarse_mesh", "benchmark_mesh", "benchmark_frames", "benchmark_fibres", "cavity_volume"]

#: Short and long semi-axes ``(r_s, r_l)`` of the endocardial and epicardial ellipsoids, m.
ENDO = (0.025, 0.09)
EPI = (0.035, 0.097)
#: ``x`` of the endocardial and epicardial rim circles (``r_l cos mu_base``), m.
BASE_X = (ENDO[1] * 5 / 17, EPI[1] * 5 / 20)
#: Helix angles at the endocardium and the epicardium, degrees (the benchmark's convention, `benchmark_frames`).
HELIX = (-60.0, 60.0)
#: The probe points p0 (on the base, mid-wall) and p1 (at the equator x = 0, mid-wall), m.
P0 = (0.025, 0.03, 0.0)
P1 = (0.0, 0.03, 0.0)
#: Facet tags of the reference mesh.
TAGS = {"endocardium": 1, "epicardium": 2, "base": 3}
#: Target cell sizes of the shipped coarse and medium meshes (`coarse_mesh`, `read_mesh("medium")`), m.
COARSE_H = 0.012
MEDIUM_H = 0.007

_DATA = "data/cardiac_benchmark"


#: The shipped meshes of the domain, by variant (`read_mesh`).
MESH_FILES = {"reference": "ellipsoid_0.005.xdmf", "coarse": "ellipsoid_coarse.msh", "medium": "ellipsoid_medium.msh"}


def mesh_file(variant: str = "reference") -> Path:
    """Path of a shipped mesh of the domain inside the installed package: ``"reference"``, the benchmark's own
    (XDMF + HDF5, 17,625 cells), or hyperoc's generator with straight cells (Gmsh MSH 2.2): ``"coarse"`` at
    `COARSE_H` (1,402 cells), ``"medium"`` at `MEDIUM_H` (3,494 cells, for mesh-independence studies)."""
    if variant not in MESH_FILES:
        raise InputError(f"cardiac benchmark: unknown mesh {variant!r} (one of {', '.join(MESH_FILES)})")
    return Path(str(resources.files("hyperoc").joinpath(_DATA, MESH_FILES[variant])))


def read_mesh(variant: str = "reference", *, dirichlet: str = "gamma_d") -> Mesh:
    """A shipped mesh (`mesh_file`) with the boundaries ``endocardium`` (= ``gamma_n``), ``epicardium`` and
    ``base``, and ``gamma_d`` = the boundary ``dirichlet`` if given (the benchmark itself clamps nothing)."""
    tags = TAGS if variant == "reference" else None
    return from_file(mesh_file(variant), tags=tags, neumann="endocardium", dirichlet=dirichlet)


def reference_mesh() -> Mesh:
    """The benchmark's reference mesh (4,577 vertices, 17,625 straight P1 tetrahedra, as the participating codes
    used it), boundaries as `read_mesh` plus their numbers ``"1"``, ``"2"``, ``"3"``."""
    return read_mesh("reference")


def coarse_mesh() -> Mesh:
    """The shipped coarse mesh of the benchmark domain (`benchmark_mesh` at `COARSE_H`, straight cells), for
    fast runs; boundaries as `read_mesh`."""
    return read_mesh("coarse")


def benchmark_mesh(h: float = 0.005, *, curved: bool = True, refinements: int = 0) -> Mesh:
    """Gmsh mesh of the benchmark domain (module docstring), target cell size ``h`` (m).

    Built with Gmsh OCC: the epicardial ellipsoid (a unit sphere dilated to the semi-axes) intersected with the
    solid cone below the base surface, minus the endocardial ellipsoid. Boundaries ``endocardium``
    (``gamma_n``), ``epicardium``, ``base`` (``gamma_d``), each facet named after the nearest surface; with
    ``curved`` the P2 edge nodes of the wall facets lie on the ellipsoids (the rim's within the base cone's
    tangent plane), see `hyperoc.fem.geometry`; ``refinements`` uniform refinements keep the walls exact."""
    if not (h > 0 and math.isfinite(h)):
        raise InputError(f"benchmark_mesh: need a finite h > 0 (m), got {h}")
    with geometry.gmsh_model("benchmark-ventricle") as gmsh:
        occ = gmsh.model.occ
        apex, slope, length = _base_cone()
        cone = occ.addCone(apex - length, 0, 0, length, 0, 0, slope * length, 0.0)
        wall, _ = occ.intersect([(3, _occ_ellipsoid(occ, *EPI))], [(3, cone)])
        occ.cut(wall, [(3, _occ_ellipsoid(occ, *ENDO))])
        occ.synchronize()
        mesh = geometry.gmsh_generate(gmsh, 3, h)
    walls = {"endocardium": geometry.Quadric(_semi_axes(ENDO)), "epicardium": geometry.Quadric(_semi_axes(EPI))}
    tag = lambda mesh, curved: geometry.tagged(mesh, walls, {"base": _cone_distance}, dirichlet="base",
                                               neumann="endocardium", curved=curved, planes={"base": _cone_normal})
    return geometry.refined(mesh, tag, curved, refinements)


def _semi_axes(axes: tuple) -> tuple:
    rs, rl = axes
    return (rl, rs, rs)


def _occ_ellipsoid(occ, rs: float, rl: float) -> int:
    """OCC volume tag of the ellipsoid of revolution about ``x`` with semi-axes ``(rl, rs, rs)``."""
    tag = occ.addSphere(0, 0, 0, 1.0)
    occ.dilate([(3, tag)], 0, 0, 0, rl, rs, rs)
    return tag


def _rim(axes: tuple, x: float) -> float:
    """Radius ``sqrt(y^2 + z^2)`` of the ellipsoid of semi-axes ``axes`` at ``x``."""
    rs, rl = axes
    return rs * math.sqrt(1.0 - (x / rl) ** 2)


def _base_cone() -> tuple[float, float, float]:
    """``(x_apex, slope, length)`` of the cone holding the base: radius ``slope * (x_apex - x)`` through both rim
    circles, and a length that reaches past the apex of the ventricle."""
    (x0, x1), (r0, r1) = BASE_X, (_rim(ENDO, BASE_X[0]), _rim(EPI, BASE_X[1]))
    slope = (r1 - r0) / (x0 - x1)
    return x0 + r0 / slope, slope, 2 * EPI[1] + x0 + r0 / slope


def _cone_distance(x: np.ndarray) -> np.ndarray:
    """Signed distance (n,) of points (n, 3) to the base cone in the meridian plane, positive above the base."""
    apex, slope, _ = _base_cone()
    r = np.hypot(x[:, 1], x[:, 2])
    return ((x[:, 0] - apex) + r / slope) * slope / math.hypot(1.0, slope)


def _cone_normal(x: np.ndarray) -> np.ndarray:
    """Unit normal (n, 3) of the base cone at points (n, 3) off the axis (the gradient of `_cone_distance`)."""
    _, slope, _ = _base_cone()
    r = np.hypot(x[:, 1], x[:, 2])
    normal = np.stack([np.full_like(r, slope), x[:, 1] / r, x[:, 2] / r], axis=1)
    return normal / math.hypot(1.0, slope)


def benchmark_frames(x, t) -> np.ndarray:
    """The benchmark's fibre frames (n, 3, 3), rows ``(f, s, n)``, at points x (n, 3) of transmural coordinate
    t (n,) (0 on the endocardium, 1 on the epicardium).

    On the ellipsoid of the family through the point, ``r_s(t) = r_s^endo + (r_s^epi - r_s^endo) t`` and
    likewise ``r_l(t)``, with ``x = r_l cos u``, ``(y, z) = r_s sin u (cos v, sin v)``, ``u`` in [0, pi]:

        e_u = dX/du / |dX/du| = (-r_l sin u, r_s cos u cos v, r_s cos u sin v) / |...|   (apex to base)
        e_v = dX/dv / |dX/dv| = (0, -sin v, cos v)                                           (circumferential)
        alpha = alpha_endo + (alpha_epi - alpha_endo) t,   `HELIX` = (-60, 60) degrees
        f = sin(alpha) e_u + cos(alpha) e_v,   n_w = e_u x e_v (wall normal),   s = f x n_w

    and the third row ``f x s = -n_w``: an orthonormal, right-handed frame."""
    x, t = np.asarray(x, dtype=np.float64), np.asarray(t, dtype=np.float64)
    (rs0, rl0), (rs1, rl1) = ENDO, EPI
    rs, rl = rs0 + (rs1 - rs0) * t, rl0 + (rl1 - rl0) * t
    radius = np.hypot(x[:, 1], x[:, 2])
    u = np.arctan2(radius / rs, x[:, 0] / rl)
    v = np.arctan2(x[:, 2], x[:, 1])
    e_u = np.stack([-rl * np.sin(u), rs * np.cos(u) * np.cos(v), rs * np.cos(u) * np.sin(v)], axis=1)
    e_u /= np.linalg.norm(e_u, axis=1, keepdims=True)
    e_v = np.stack([np.zeros_like(v), -np.sin(v), np.cos(v)], axis=1)
    alpha = np.deg2rad(HELIX[0] + (HELIX[1] - HELIX[0]) * t)[:, None]
    f = np.sin(alpha) * e_u + np.cos(alpha) * e_v
    s = np.cross(f, np.cross(e_u, e_v))
    return np.stack([f, s, np.cross(f, s)], axis=1)


def benchmark_fibres(mesh: Mesh, *, inner: str = "endocardium", outer: str = "epicardium") -> FieldFrames:
    """`benchmark_frames` at the vertices of ``mesh`` with t the P1 Laplace transmural coordinate
    (`hyperoc.mechanics.fibres.transmural_coordinate`, 0 on ``inner``, 1 on ``outer``), as a vertex field
    (`hyperoc.mechanics.fibres.FieldFrames`: P1 interpolation between the vertices, orthonormalised)."""
    t = transmural_coordinate(mesh, inner, outer)
    frames = benchmark_frames(mesh.points, t)
    return field_frames(mesh, frames[:, 0], frames[:, 1], location="node", source="benchmark fibres", transmural=t)


def cavity_volume(mesh: Mesh, displacement=None, endo: str = "endocardium") -> float:
    """Volume (m^3) of the cavity bounded by the straight endocardial facets, at the vertex positions
    ``X + u`` (``displacement`` u (nv, 3), m; default 0: the reference configuration), closed at the rim by the
    cone from the deformed rim's centroid (the cap of a flat rim is its plane): `CavityVolume` with
    ``apex="rim"`` on the P1 space of ``mesh``. The benchmark's codes report this volume (the reference mesh:
    167.52 mL)."""
    model = StateModel(mesh, NeoHookean(1.0, 1.0), dirichlet=None, pin_rigid=False)  # the law is not used
    u = np.zeros(model.n) if displacement is None else model.restrict(np.asarray(displacement, dtype=np.float64))
    return float(CavityVolume(model, endo, apex="rim").volume(u))

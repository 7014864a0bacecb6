"""Land et al. (2015) cardiac mechanics benchmarks, problems 1 to 3, as quasi-static solves.

S. Land et al., "Verification of cardiac mechanics software: benchmark problems and solutions for
testing active and passive material behaviour", Proc. R. Soc. A 471: 20150641 (2015),
doi:10.1098/rspa.2015.0641. Units: mm, kPa (forces in mN).

Problem 1 (beam). ``[0, 10] x [0, 1] x [0, 1]`` mm, clamped (u = 0) at x = 0, transversely
isotropic Guccione law with fibres along x, ``C = 2`` kPa, ``bf = 8``, ``bt = 2``, ``bfs = 4``;
a pressure of 0.004 kPa on the deformed bottom face z = 0 (a follower load). Reported: the
z-coordinate of the deformed position of the material point (10, 0.5, 1).

Problem 2 (ventricle). The idealized LV of `hyperoc.fem.geometry.ventricle` (endocardial semi-axes
7 / 17 mm, epicardial 10 / 20 mm, base plane z = 5 mm; by default with curved P2 edge nodes on the
two ellipsoids, i.e. isoparametric P2 cells), base fixed (or sliding in its plane), isotropic Guccione law
``C = 10`` kPa, ``bf = bt = bfs = 1`` (``Q = tr(E^2)``), endocardial pressure 10 kPa (follower).
Reported: the z-coordinates of the deformed endocardial apex (0, 0, -17) and epicardial apex
(0, 0, -20).

Problem 3 (contraction). The same ventricle and base conditions, the transversely isotropic Guccione
law of problem 1 (``C = 2`` kPa, ``bf = 8``, ``bt = 2``, ``bfs = 4``) with the analytic fibre field
`hyperoc.mechanics.fibres.prolate_fibres` (helix angle +90 degrees at the endocardium to -90 at the
epicardium), endocardial pressure 15 kPa and an active tension ``T = 60`` kPa along the fibres
(second Piola-Kirchhoff ``T f0 (x) f0``, `hyperoc.mechanics.active.FibreTension`), both ramped together.
Reported: the same apex positions.

What is solved and what it converges to. The benchmark material is incompressible; here it is
the compressible Guccione law of `hyperoc.mechanics.materials.Guccione` with the volumetric penalty
``bulk_modulus/4 (J^2 - 1 - 2 ln J)`` (``bulk_modulus`` = small-strain bulk modulus k, kPa) and *no*
global volume constraint (``solve_static(..., constraint="none")``). For a fixed k the P2 solutions
converge as h -> 0 to the solution ``u_k`` of that compressible problem; ``u_k`` tends to the
incompressible solution as ``k -> infinity``, at first order in ``1 / k`` (the volume change is
``O(p / k)``). Pure-displacement elements lock as ``k / C`` grows (P1 severely, P2 mildly), so a
study must vary both h and k; ``bench/bench_land.py`` does. With ``volumetric="taylor-hood"``
(`hyperoc.mechanics.mixed.TaylorHoodModel`: a continuous P1 pressure, inf-sup stable, no locking) k may
be ``math.inf``, and the values converge to the incompressible benchmark
itself; problem 2 then needs ``isochoric=True`` (on the full strain the law folds between the vertices).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..dynamics.statics import StaticOptions, solve_static
from ..errors import InputError
from ..fem.geometry import ventricle
from ..fem.mesh import Mesh, box
from ..io import read_npz, write_npz
from ..mechanics.active import FibreTension, axis_taper
from ..mechanics.cavity import CavityVolume
from ..mechanics.fibres import prolate_fibres
from ..mechanics.follower import FollowerPressure
from ..mechanics.materials import Guccione, det
from ..mechanics.mixed import TaylorHoodModel
from ..mechanics.model import VOLUMETRIC, StateModel

__all__ = ["BEAM", "VENTRICLE", "CONTRACTION", "PUBLISHED", "BASE_CONDITIONS", "FORMULATIONS", "BenchmarkResult",
           "beam_mesh", "beam_problem", "ventricle_problem", "contraction_problem", "node_position", "beam_deflection",
           "ventricle_apex", "save_state", "load_state", "Formulation", "VentricleMesh", "LoadStepping"]

#: Problem 1 parameters (Land et al. 2015): Guccione moduli (kPa, dimensionless) and pressure (kPa).
BEAM = {"C": 2.0, "bf": 8.0, "bt": 2.0, "bfs": 4.0, "pressure": 0.004, "point": (10.0, 0.5, 1.0)}
#: Problem 2 parameters: Guccione moduli, endocardial pressure (kPa), apex points (mm).
VENTRICLE = {"C": 10.0, "bf": 1.0, "bt": 1.0, "bfs": 1.0, "pressure": 10.0,
             "endo_apex": (0.0, 0.0, -17.0), "epi_apex": (0.0, 0.0, -20.0)}
#: Problem 3 parameters: Guccione moduli, endocardial pressure and active fibre tension (kPa), helix angles
#: at the endocardium and epicardium (degrees).
CONTRACTION = {"C": 2.0, "bf": 8.0, "bt": 2.0, "bfs": 4.0, "pressure": 15.0, "tension": 60.0, "helix": (90.0, -90.0)}
#: Published converged values of the benchmark as posed (incompressible, base clamped), by problem: z of the
#: deformed points (mm) and the deformed cavity volume (mm^3). One participant's submission to Land et al.
#: (2015): S. Pezzuto (Simula Research Laboratory, FEniCS), Taylor-Hood P2-P5 under uniform refinement, a 3D
#: beam and an axisymmetric ventricle; ``summary_results.txt`` of bitbucket.org/peppu/mechbench, mirrored at
#: github.com/finsberg/mechbench. Problem 1: its finest P2 rows (4.1689-4.1695; P3-P5 4.1678-4.1705, so
#: +-0.001); problems 2 and 3: the digits on which P2-P5 agree from 8x refinement on. Not the paper's
#: consensus of the 11 groups (whose tables were not retrievable here).
PUBLISHED = {1: {"z_tip": 4.169},
             2: {"z_endo": -26.612, "z_epi": -28.279, "V_cavity": 10734.3},
             3: {"z_endo": -12.347, "z_epi": -15.452, "V_cavity": 1795.9}}


@dataclass
class BenchmarkResult:
    """One benchmark solve.

    values : reported quantities (mm), by name.
    h : largest edge length of the mesh (mm).
    dofs : unknowns (free displacement dofs; with Taylor-Hood also the vertex pressures).
    newton_iterations : per accepted load increment (`solve_static` with ``cutbacks``).
    rejected_iterations : Newton iterations of rejected attempts (a failed guess, halved increments).
    seconds : wall time of the solve (JIT compilation included).
    min_det_F, max_volume_change : ``min det F`` and ``max |det F - 1|`` over quadrature points.
    mean_volume_change : ``int |det F - 1| dX / |Omega|`` (how far the penalty is from incompressible).
    volume_change : ``vol(u) / |Omega| - 1``, the change of the body's total volume.
    model, u : the model and its solution (reduced), e.g. for the next level's ``coarse`` start.
    """

    values: dict
    h: float
    dofs: int
    newton_iterations: np.ndarray
    seconds: float
    min_det_F: float
    max_volume_change: float
    mean_volume_change: float
    volume_change: float
    params: dict = field(default_factory=dict)
    rejected_iterations: int = 0
    model: StateModel | None = field(default=None, repr=False)
    u: np.ndarray | None = field(default=None, repr=False)


#: how the bulk term enters: `StateModel` ``volumetric`` or ``"taylor-hood"`` (`TaylorHoodModel`, P2-P1).
FORMULATIONS = VOLUMETRIC + ("taylor-hood",)


@dataclass(frozen=True)
class Formulation:
    """How a benchmark's Guccione law is discretized: ``bulk_modulus`` the bulk modulus (kPa; with
    ``"taylor-hood"`` also ``math.inf``: incompressible), ``degree`` of the displacement space,
    ``volumetric`` one of `FORMULATIONS`, ``isochoric``: `Guccione` on the isochoric strain."""

    bulk_modulus: float
    degree: int = 2
    volumetric: str = "pointwise"
    isochoric: bool = False

    def model(self, mesh: Mesh, params: dict, frames=None, **conditions) -> StateModel:
        """The Guccione model on ``mesh``: ``params`` the moduli, ``frames`` the fibre field (default: fibres
        along x), ``conditions`` the `StateModel` boundary conditions."""
        if self.volumetric not in FORMULATIONS:
            raise InputError(f"volumetric must be one of {list(FORMULATIONS)}, got {self.volumetric!r}")
        mixed = self.volumetric == "taylor-hood"
        if mixed and self.degree != 2:
            raise InputError(f"the Taylor-Hood formulation is P2-P1: degree must be 2, got {self.degree}")
        bulk = 0.0 if mixed and math.isinf(self.bulk_modulus) else self.bulk_modulus
        material = Guccione(C=params["C"], bf=params["bf"], bt=params["bt"], bfs=params["bfs"], bulk_modulus=bulk,
                            isochoric=self.isochoric)
        frames = _fibres_along_x if frames is None else frames
        if mixed:
            return TaylorHoodModel(mesh, material, bulk_modulus=self.bulk_modulus, frames=frames, **conditions)
        return StateModel(mesh, material, degree=self.degree, frames=frames, volumetric=self.volumetric,
                          **conditions)

    def params(self) -> dict:
        """The formulation's entries of a result's ``params`` (`BenchmarkResult`, `save_state`)."""
        return {"bulk_modulus": self.bulk_modulus, "degree": self.degree, "volumetric": self.volumetric,
                "isochoric": self.isochoric}


@dataclass(frozen=True)
class VentricleMesh:
    """The mesh of problems 2 and 3: `hyperoc.fem.geometry.ventricle` of size ``h`` (mm), ``curved``
    (isoparametric P2 on the exact ellipsoids, else straight-sided cells), after ``refinements`` uniform
    refinements, with the base condition ``base`` (`BASE_CONDITIONS`)."""

    h: float
    curved: bool = True
    base: str = "clamped"
    refinements: int = 0

    def model(self, formulation: Formulation, params: dict, frames=None) -> StateModel:
        """``formulation``'s model with the moduli ``params`` and the fibre field ``frames`` on this mesh."""
        if self.base not in BASE_CONDITIONS:
            raise InputError(f"ventricle base must be one of {sorted(BASE_CONDITIONS)}, got {self.base!r}")
        mesh = ventricle(self.h, curved=self.curved, refinements=self.refinements)
        return formulation.model(mesh, params, frames, **BASE_CONDITIONS[self.base])


@dataclass(frozen=True)
class LoadStepping:
    """How a benchmark's static solve steps the load (`hyperoc.dynamics.statics.solve_static`): ``steps``
    nominal increments, at most ``cutbacks`` halvings of a failed one, the linear ``solver``, the
    ``predictor`` of each increment and the Newton ``monitor``."""

    steps: int = 10
    cutbacks: int = 8
    solver: object = "auto"
    predictor: str = "previous"
    monitor: object = None

    def options(self) -> StaticOptions:
        """The `StaticOptions` of the benchmark's solves: this stepping with full Newton steps (the penalty's
        merit grows after the first step although Newton then converges: `hyperoc.dynamics.statics`)."""
        return StaticOptions(self.steps, self.cutbacks, self.predictor, line_search=False, solver=self.solver,
                             monitor=self.monitor)

    def params(self) -> dict:
        """The stepping's entries of a result's ``params``."""
        return {"steps": self.steps, "cutbacks": self.cutbacks, "predictor": self.predictor}


def _fibres_along_x(x):
    """Constant frame ``(f, s, n) = (e_x, e_y, e_z)`` at points x (..., 3) -> (..., 3, 3)."""
    return np.broadcast_to(np.eye(3), x.shape[:-1] + (3, 3))


def beam_mesh(n: int) -> Mesh:
    """The 10 x 1 x 1 mm beam with ``10 n x n x n`` cubes (six tetrahedra each).

    Boundaries: ``gamma_d`` = the face x = 0 (clamped) and ``z_bottom`` = the face z = 0 (loaded);
    `hyperoc.fem.mesh.box` names the z = 0 face ``front``.
    """
    if n < 1:
        raise InputError(f"beam_mesh: need n >= 1, got {n}")
    mesh = box(10 * n, n, n, size=(10.0, 1.0, 1.0), dirichlet="left")
    return mesh.with_boundary("z_bottom", mesh.boundary("front"))


def beam_problem(n: int, *, bulk_modulus: float, degree: int = 2, volumetric: str = "pointwise",
                 isochoric: bool = False) -> tuple[StateModel, FollowerPressure]:
    """Problem 1 on `beam_mesh` (n): the model and its follower pressure on the bottom face
    (``volumetric``: how the penalty enters, `StateModel`; ``isochoric``: `Guccione` on the isochoric
    strain; ``"taylor-hood"``: `hyperoc.mechanics.mixed.TaylorHoodModel`, bulk_modulus may then be ``math.inf``)."""
    return _beam_setup(n, Formulation(bulk_modulus, degree, volumetric, isochoric))


def _beam_setup(n: int, formulation: Formulation) -> tuple[StateModel, FollowerPressure]:
    """`beam_problem` (n) in ``formulation``: the model and its follower pressure."""
    model = formulation.model(beam_mesh(n), BEAM)
    return model, FollowerPressure(model, "z_bottom", BEAM["pressure"])


#: Problem 2 base conditions: `StateModel` keyword arguments.
BASE_CONDITIONS = {
    "clamped": {"dirichlet": "base"},  # u = 0 on the base
    "sliding": {"dirichlet": None, "dirichlet_components": {"base": (2,)}, "pin_rigid": True},  # u_z = 0
}


def ventricle_problem(h: float, *, bulk_modulus: float, degree: int = 2, curved: bool = True,
                      base: str = "clamped", refinements: int = 0, volumetric: str = "pointwise",
                      isochoric: bool = False) -> tuple[StateModel, FollowerPressure]:
    """Problem 2 on `hyperoc.fem.geometry.ventricle` (h, mm; ``curved``: isoparametric P2 on the exact
    ellipsoids, else straight-sided cells; ``refinements``: uniform refinements of the Gmsh mesh of
    size h, a nested sequence): the model and the endocardial pressure.

    ``base``: ``"clamped"`` (u = 0) or ``"sliding"`` (u_z = 0; the three in-plane rigid motions
    pinned by an isostatic support, `StateModel` ``pin_rigid``, which carries no reaction since the
    pressure on the cavity has no net in-plane force or moment about z). With ``bf = bt = bfs = 1``
    the Guccione law is isotropic (``Q = tr(E^2)``): the constant frame it is given does not matter.
    ``volumetric``, ``isochoric``: as in `beam_problem`."""
    return _ventricle_setup(2, VentricleMesh(h, curved, base, refinements),
                            Formulation(bulk_modulus, degree, volumetric, isochoric))


def contraction_problem(h: float, *, bulk_modulus: float, degree: int = 2, curved: bool = True,
                        base: str = "clamped", refinements: int = 0, volumetric: str = "pointwise",
                        isochoric: bool = False,
                        taper: float = 0.0) -> tuple[StateModel, tuple[FollowerPressure, FibreTension]]:
    """Problem 3 on the mesh of `ventricle_problem` (same arguments): the model (`CONTRACTION` moduli,
    `hyperoc.mechanics.fibres.prolate_fibres` with its helix angles) and its two loads, the endocardial pressure
    and the active fibre tension, for ``solve_static(..., follower=loads)``. ``taper > 0`` (mm): not the
    benchmark but a variant, the tension tapered to zero on the long axis (`hyperoc.mechanics.active.axis_taper`),
    where the fibres are singular."""
    return _ventricle_setup(3, VentricleMesh(h, curved, base, refinements),
                            Formulation(bulk_modulus, degree, volumetric, isochoric), taper)


def node_position(model: StateModel, u, point, tol: float = 1e-9) -> np.ndarray:
    """Deformed position ``X + u(X)`` (dim,) of the material point ``X = point``, which must be a node
    of the model's space (a mesh vertex or, for P2, an edge midpoint) within ``tol`` (mm)."""
    X = np.asarray(point, dtype=np.float64)
    dist = np.linalg.norm(model.space.nodes - X, axis=1)
    a = int(np.argmin(dist))
    if dist[a] > tol:
        raise InputError(f"the point {tuple(X)} is not a node of the mesh (nearest at {dist[a]:.3g})")
    return X + model.expand(u)[a]


def _solve(model, follower, stepping: LoadStepping, points: dict, params: dict, extra=None,
           coarse: BenchmarkResult | None = None) -> BenchmarkResult:
    """Solve; ``values`` are the z of the deformed ``points`` (name -> X) and ``extra(model, u)`` (a dict).
    ``coarse``: the same problem solved on the mesh this one refines, whose prolonged solution is
    Newton's first try at the full load (`solve_static`'s ``guess``)."""
    t0 = time.perf_counter()
    guess = None if coarse is None else model.prolong(coarse.model, coarse.u)
    sol = solve_static(model, follower=follower, constraint="none", guess=guess, options=stepping.options())
    seconds = time.perf_counter() - t0
    if coarse is not None:
        params["start"] = "prolonged" if sol.from_guess else f"prolonged, failed ({sol.guess_failure}): load stepping"
    J = np.asarray(det(model.deformation_gradient(jnp.asarray(sol.u))))  # (nc, nq)
    volume = float(np.sum(model.quad.wdx))  # |Omega|
    values = {name: float(node_position(model, sol.u, X)[2]) for name, X in points.items()}
    values.update(extra(model, sol.u) if extra is not None else {})
    model.release_kernels()  # the result keeps the model for prolongation only
    return BenchmarkResult(values, model.mesh.h(), model.n, sol.newton_iterations, seconds,
                           float(J.min()), float(np.abs(J - 1).max()),
                           float(np.sum(model.quad.wdx * np.abs(J - 1))) / volume, sol.volume / volume - 1.0, params,
                           sol.rejected_iterations, model, sol.u)


def beam_deflection(n: int, formulation: Formulation = Formulation(1000.0),
                    stepping: LoadStepping = LoadStepping()) -> BenchmarkResult:
    """Problem 1 on `beam_mesh` (n) in ``formulation``, its load stepped by ``stepping``: ``values["z_tip"]`` = z
    of the deformed point (10, 0.5, 1) (mm; 1 at rest). ``stepping.monitor``: `solve_static`'s (e.g.
    ``hyperoc.solvers.newton.NewtonLog(sys.stderr)``)."""
    model, load = _beam_setup(n, formulation)
    params = {"problem": 1, "n": n, **formulation.params(), **stepping.params()}
    return _solve(model, load, stepping, {"z_tip": BEAM["point"]}, params)


def ventricle_apex(mesh: VentricleMesh, formulation: Formulation = Formulation(1000.0),
                   stepping: LoadStepping = LoadStepping(), *, problem: int = 2, taper: float = 0.0,
                   coarse: BenchmarkResult | None = None) -> BenchmarkResult:
    """Problem 2 (`ventricle_problem`) or 3 (``problem=3``, `contraction_problem`) on ``mesh`` in ``formulation``,
    its load stepped by ``stepping``: ``values["z_endo"]``,
    ``values["z_epi"]`` = z of the deformed endocardial and epicardial apex (mm; -17 and -20 at rest),
    ``values["V_cavity"]`` the deformed cavity volume (mm^3, `hyperoc.mechanics.cavity.CavityVolume` with
    ``apex="rim"``: the endocardium closed by the base plane). ``taper``: problem 3 only, `contraction_problem`.
    ``coarse``: this problem's result on the mesh of ``refinements - 1`` (nested iteration: Newton
    starts at the full load from its prolonged solution, and steps the load only if that fails;
    ``params["start"]`` says which). ``stepping.monitor``: `solve_static`'s, e.g.
    ``hyperoc.solvers.newton.NewtonLog(sys.stderr)`` to follow a long solve. Raises `InputError` if
    this mesh does not refine its mesh."""

    if problem not in (2, 3):
        raise InputError(f"ventricle_apex: the ventricle problems are 2 and 3, got {problem!r}")
    if taper and problem != 3:
        raise InputError("ventricle_apex: taper (of the active tension) applies to problem 3 only")
    model, load = _ventricle_setup(problem, mesh, formulation, taper)
    cavity = lambda model, u: {"V_cavity": float(CavityVolume(model, "endocardium", apex="rim").volume(u))}
    params = {"problem": problem, "mesh_size": mesh.h, **formulation.params(), **stepping.params(),
              "curved": mesh.curved, "base": mesh.base, "refinements": mesh.refinements,
              **({"taper": taper} if taper else {})}
    return _solve(model, load, stepping, {"z_endo": VENTRICLE["endo_apex"], "z_epi": VENTRICLE["epi_apex"]}, params,
                  cavity, coarse)


def _ventricle_setup(problem: int, mesh: VentricleMesh, formulation: Formulation, taper: float = 0.0):
    """`ventricle_problem` (problem 2) or `contraction_problem` (3, with ``taper``) on ``mesh`` in ``formulation``:
    the model and its loads."""
    if problem == 2:
        model = mesh.model(formulation, VENTRICLE)
        return model, FollowerPressure(model, "endocardium", VENTRICLE["pressure"])
    fibres = prolate_fibres(helix_endo=CONTRACTION["helix"][0], helix_epi=CONTRACTION["helix"][1])
    model = mesh.model(formulation, CONTRACTION, fibres)
    profile = axis_taper(taper) if taper else None
    return model, (FollowerPressure(model, "endocardium", CONTRACTION["pressure"]),
                   FibreTension(model, CONTRACTION["tension"], profile))


def save_state(result: BenchmarkResult, path) -> Path:
    """Write a `ventricle_apex` result's solution ``u`` (n,), its ``values`` and ``params`` to ``path``
    (``.npz``, atomically), for `load_state`: the next level of a nested sequence can then start
    from it in another process, which holds only its own level's memory."""
    if result.u is None or result.params.get("problem") not in (2, 3):
        raise InputError("save_state: needs a ventricle_apex result (problem 2 or 3) with its solution")
    return write_npz(path, u=np.asarray(result.u), values=np.array(json.dumps(result.values)),
                     params=np.array(json.dumps(result.params)))


def load_state(path) -> BenchmarkResult:
    """The result `save_state` wrote, with its model rebuilt from the saved parameters (the same mesh:
    gmsh and the refinement are deterministic), usable as `ventricle_apex`'s ``coarse``. Only
    ``values``, ``params``, ``model``, ``u``, ``h`` and ``dofs`` are set (the diagnostics are NaN).
    A missing or foreign file, one without the parameters `ventricle_apex` now takes (e.g. ``kappa``
    for ``bulk_modulus``), or a rebuilt model of another size, is an `InputError`."""
    try:
        data = read_npz(path)
        u, values, params = data["u"], json.loads(str(data["values"])), json.loads(str(data["params"]))
    except (OSError, KeyError, ValueError) as err:
        raise InputError(f"load_state: {path} is not a state written by save_state ({err})") from err
    keys = ("bulk_modulus", "degree", "curved", "base", "refinements", "volumetric", "isochoric")
    missing = [k for k in ("problem", "mesh_size", *keys) if k not in params]
    if missing:
        raise InputError(f"load_state: {path} lacks the parameter(s) {', '.join(missing)} of ventricle_apex "
                         f"(it has {', '.join(params)})")
    mesh = VentricleMesh(params["mesh_size"], params["curved"], params["base"], params["refinements"])
    formulation = Formulation(params["bulk_modulus"], params["degree"], params["volumetric"], params["isochoric"])
    model, _ = _ventricle_setup(params["problem"], mesh, formulation, params.get("taper", 0.0))
    if model.n != u.size:
        raise InputError(f"load_state: {path} holds {u.size} unknowns, its rebuilt model has {model.n}")
    nan = float("nan")
    return BenchmarkResult(values, model.mesh.h(), model.n, np.zeros(0, int), nan, nan, nan, nan, nan, params,
                           model=model, u=u)

"""TOML configuration: validation against the schema (`hyperoc.app.schema`), with one clear message,
and the builders of the objects a run needs.

A configuration has the sections ``[mesh] [material] [fibres] [dynamics] [control] [objective]
[optimize] [output]`` (see ``examples/*.toml`` and ``docs/configuration.md``, printed by
``python -m hyperoc.app.config --reference``). Every entry is checked for its type and range before any
computation starts; a problem raises `InputError` naming the section and key, which the CLI turns
into one line on stderr and exit status 2.

Importing this module is cheap (no JAX, no solver): the builders import what they build.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import sys
import tomllib
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .schema import reference_markdown, validate_sections

__all__ = ["Config", "load_config", "parse_config", "apply_overrides", "reference_markdown", "BUDGET_KEYS"]

#: the name of every key that holds a path (``[mesh] file``, ``[control] file``)
PATH_KEY = "file"

#: the ``[optimize]`` entries that bound the optimizer's run (its budget and stopping test) without
#: changing any iterate before it stops: the only ones ``optimize --resume`` may change
BUDGET_KEYS = ("max_iter", "gtol")


@dataclass(frozen=True)
class Config:
    """Validated configuration (sections as dicts with defaults filled in), its folder, and its
    name (the config file's name without suffix, when read from a file: it names the run in the
    figures' titles)."""

    sections: dict
    base: Path
    name: str | None = None

    def __getitem__(self, name: str) -> dict:
        return self.sections[name]

    def to_toml(self) -> str:
        """The configuration as TOML, every default written out and file paths made absolute, so
        that `load_config` of the text, from any folder, gives the same `Config` sections."""
        lines = []
        for name, section in self.sections.items():
            lines.append(f"[{name}]")
            for key, value in section.items():
                if key == PATH_KEY:
                    value = str(self.path(name))
                lines.append(f"{key} = {_toml_value(value)}")
            lines.append("")
        return "\n".join(lines)

    # --- builders ---------------------------------------------------------------------------------
    def mesh(self):
        """The `hyperoc.fem.mesh.Mesh` of ``[mesh]``, refined ``refinements`` times."""
        from ..fem.mesh import refine

        c = self["mesh"]
        kind, k = c["kind"], c["refinements"]
        if kind in ("annulus", "shell", "ventricle"):
            return _scaled(self._curved_mesh(kind, k), c["scale"])
        mesh = self._straight_mesh(kind)
        for _ in range(k):
            mesh = refine(mesh)
        return _scaled(mesh, c["scale"])

    def file_mesh(self):
        """The mesh read from ``[mesh] file`` (or the shipped benchmark mesh), before refinements."""
        from ..fem import geometry

        c = self["mesh"]
        if c["kind"] == "cardiac_benchmark":
            from ..cardiac.benchmark_geometry import read_mesh

            return read_mesh(c["variant"], dirichlet=c["dirichlet_tag"])
        return geometry.from_file(self.mesh_path(), dirichlet=c["dirichlet_tag"], neumann=c["neumann_tag"],
                                  control=c["control_tag"], tags=c.get("tags"))

    def path(self, section: str) -> Path:
        """The ``file`` of ``[section]`` as an absolute path: a relative one is taken from the config's
        folder (`apply_overrides` has made those given with ``--set`` absolute, from the working directory)."""
        return (self.base / Path(self[section][PATH_KEY]).expanduser()).resolve()

    def missing_file(self, section: str, what: str) -> str:
        """The message for a ``[section] file`` that is not a file: the resolved path and the rule."""
        path = self.path(section)
        found = "not found" if not path.exists() else "is not a file"
        return (f"{what} file {found}: {path} ([{section}] file = {self[section][PATH_KEY]!r}; a relative path "
                f"is taken from the config's folder {self.base.resolve()}, one given with --set from the working "
                "directory)")

    def mesh_path(self) -> Path | None:
        """``[mesh] file`` as an absolute path (`path`), the shipped file of ``kind = "cardiac_benchmark"``, or
        None for a generated mesh."""
        c = self["mesh"]
        if c["kind"] == "cardiac_benchmark":
            from ..cardiac.benchmark_geometry import mesh_file

            return mesh_file(c["variant"])
        return self.path("mesh") if c["kind"] == "file" else None

    def fibres_path(self) -> Path | None:
        """``[fibres] file`` resolved against the config's folder (None without one)."""
        return self.path("fibres") if PATH_KEY in self["fibres"] else None

    def control_path(self) -> Path | None:
        """``[control] file`` as an absolute path (`path`; None without one)."""
        return self.path("control") if PATH_KEY in self["control"] else None

    def _straight_mesh(self, kind: str):
        from ..fem.mesh import box, interval, rectangle

        c = self["mesh"]
        if kind == "interval":
            return interval(c["n"], c["length"])
        if kind == "rectangle":
            return rectangle(c["nx"], c.get("ny"), tuple(c.get("size", (1.0, 1.0))), c["dirichlet"])
        if kind == "box":
            return box(c["nx"], c.get("ny"), c.get("nz"), tuple(c.get("size", (1.0, 1.0, 1.0))), c["dirichlet"])
        if kind in ("file", "cardiac_benchmark"):
            return self.file_mesh()
        raise InputError(f"config: [mesh] kind {kind!r} unknown "
                         "(interval, rectangle, box, annulus, shell, ventricle, file, cardiac_benchmark)")

    def _curved_mesh(self, kind: str, refinements: int):
        """The generators that put refined boundary vertices on their exact surfaces."""
        from ..fem import geometry

        c = self["mesh"]
        if kind == "annulus":
            return geometry.annulus(c["r_inner"], c["r_outer"], c["h"], structured=c["structured"],
                                    n_radial=c.get("n_radial"), n_theta=c.get("n_theta"), refinements=refinements)
        if kind == "shell":
            return geometry.thick_shell(c["r_inner"], c["r_outer"], c["h"], refinements=refinements)
        return geometry.ventricle(c["h"], refinements=refinements)

    def fibres(self, mesh):
        """Fibre frames of ``[fibres]`` on ``mesh``: `hyperoc.mechanics.fibres.FibreFrames` (kind "rule_based"),
        `hyperoc.mechanics.fibres.FieldFrames` (kinds "file" and "benchmark"), or None (kind "none")."""
        from ..mechanics.fibres import read_fibres, rule_based_fibres

        c = self["fibres"]
        if c["kind"] == "none":
            return None
        if mesh.dim != 3:
            raise InputError(f"config: [fibres] {c['kind']} needs a 3D mesh, got dimension {mesh.dim}")
        if c["kind"] == "file":
            return read_fibres(self.fibres_path(), mesh, location=c["location"], tolerance=float(c["tolerance"]))
        if c["kind"] == "benchmark":
            from ..cardiac.benchmark_geometry import benchmark_fibres

            return benchmark_fibres(mesh, inner=c["inner"], outer=c["outer"])
        axis = c["long_axis"]
        return rule_based_fibres(mesh, helix_endo=float(c["helix_endo"]), helix_epi=float(c["helix_epi"]),
                                 long_axis=tuple(float(v) for v in axis), inner=c["inner"], outer=c["outer"])

    def cavity_wall(self) -> str | None:
        """The boundary enclosing the cavity whose volume a run reports: ``[fibres] inner`` with
        rule-based fibres, else ``"endocardium"`` on a ventricle or a mesh file; None for the other
        generated meshes (no cavity)."""
        if self["fibres"]["kind"] == "rule_based":
            return self["fibres"]["inner"]
        return "endocardium" if self["mesh"]["kind"] in ("ventricle", "file", "cardiac_benchmark") else None

    def control_operator(self, frames=None):
        """The control of ``[control]``; active stress follows ``frames``' fibres when given."""
        from ..mechanics.controls import ActiveStress, BodyForce

        c = self["control"]
        region, profile = _region(c.get("region")), self.control_profile()
        if c["kind"] == "body_force":
            return BodyForce(region, profile)
        if c["kind"] == "active_stress":
            return ActiveStress(region, fibres=None if frames is None else frames.fibre, profile=profile)
        raise InputError(f"config: [control] kind {c['kind']!r} unknown (body_force, active_stress)")

    def control_profile(self):
        """The time law of ``[control] profile`` (``"activation"``: the law of ``[dynamics.activation]``), or None."""
        profile = self["control"].get("profile")
        if profile != "activation":
            return None if profile is None else time_law(profile)
        activation = self.sections.get("dynamics", {}).get("activation")
        if activation is None:
            raise InputError("config: [control] profile = 'activation' needs [dynamics.activation]")
        return time_law(activation["law"])

    def material(self):
        """The `hyperoc.mechanics.materials.Material` of ``[material]``, its parameters checked (no JAX needed)."""
        from ..mechanics.materials import material_from_config

        with _in_section("material"):
            return material_from_config({k: v for k, v in self["material"].items()
                                         if k not in ("volumetric", "viscosity")})

    def model(self, mesh=None):
        """The `hyperoc.mechanics.model.StateModel` of the config (on ``mesh`` if already built); the frames of
        ``[fibres]`` serve both a fibre-dependent material and the active stress (its fibre = row 0
        of the frame)."""
        from ..mechanics.materials import Guccione, HolzapfelOgden
        from ..mechanics.model import StateModel

        d = self["dynamics"]
        mesh = mesh if mesh is not None else self.mesh()
        traction = d.get("traction")
        if traction is not None and len(traction) != mesh.dim:
            raise InputError(f"config: [dynamics] traction must be a list of {mesh.dim} numbers, got {len(traction)}")
        material = self.material()
        frames = self.fibres(mesh)
        if frames is None and isinstance(material, (Guccione, HolzapfelOgden)):
            raise InputError(f"config: [material] law {self['material']['law']!r} needs fibres: "
                             "add [fibres] kind = 'rule_based', 'file' or 'benchmark'")
        return StateModel(mesh, material, degree=self["mesh"]["degree"], damping=float(d["damping"]),
                          density=float(d["density"]), control=self.control_operator(frames), traction=traction,
                          neumann="gamma_n", frames=frames, volumetric=self["material"]["volumetric"],
                          **self._dirichlet(mesh.dim))

    def _dirichlet(self, dim: int) -> dict:
        """StateModel keywords for gamma_d: clamped, or only ``[mesh] fixed_components`` fixed, or none
        (``[mesh] clamped = false``)."""
        if not self["mesh"]["clamped"]:
            return {"dirichlet": None}
        comps = self["mesh"].get("fixed_components")
        if comps is None:
            return {"dirichlet": "gamma_d"}
        if not all(c < dim for c in comps):
            raise InputError(f"config: [mesh] fixed_components must be integers in [0, {dim}) on this mesh, "
                             f"got {comps}")
        return {"dirichlet": None, "dirichlet_components": {"gamma_d": tuple(comps)}}

    def step_terms(self, model) -> tuple:
        """The terms of the step (`hyperoc.dynamics.terms`) of ``[dynamics] robin, pressure, activation`` and
        ``[material] viscosity`` on ``model``; `InputError` for a boundary the mesh does not have."""
        from ..dynamics.terms import DynamicPressure, PrescribedTension, Viscosity

        d, terms = self["dynamics"], list(self.robin(model))
        with _in_section("dynamics"):
            if d.get("pressure") is not None:
                terms.append(DynamicPressure(model, d["pressure"]["boundary"], time_law(d["pressure"]["law"])))
            if d.get("activation") is not None:
                if model.material_frames is None:
                    raise InputError("activation needs fibres: add [fibres] kind = 'rule_based'")
                terms.append(PrescribedTension(model, time_law(d["activation"]["law"])))
        if self["material"]["viscosity"] > 0:
            terms.append(Viscosity(model, float(self["material"]["viscosity"])))
        return tuple(terms)

    def robin(self, model) -> tuple:
        """The `hyperoc.dynamics.terms.RobinBoundary` terms of ``[[dynamics.robin]]`` on ``model``: in the step
        (`step_terms`) and, their springs, in a static solve (`hyperoc.dynamics.statics.solve_static`'s ``robin``);
        `InputError` for a boundary the mesh does not have."""
        from ..dynamics.terms import RobinBoundary

        with _in_section("dynamics"):
            return tuple(RobinBoundary(model, r["boundary"], float(r["stiffness"]), float(r["damping"]), r["direction"])
                         for r in self["dynamics"].get("robin") or [])

    def stepper(self, model):
        """The `hyperoc.dynamics.stepper.TimeStepper` of the config on ``model``: scheme, solver, step terms and
        constraint."""
        from ..dynamics.stepper import TimeStepper

        return TimeStepper(model, self.scheme(), self["dynamics"]["solver"], terms=self.step_terms(model),
                           constraint=self.constraint(model))

    def constraint(self, model, t=None):
        """The constraint of ``[dynamics] constraint`` on ``model`` (`hyperoc.dynamics.constraint`), the cavity's
        of ``[dynamics.cavity]``, the circulation of ``[dynamics.circulation]``; `InputError` for a wall the mesh
        lacks, one that encloses no volume, a circulation parameter out of range, or (given
        the levels ``t``) a volume change not finite on them."""
        from ..dynamics.constraint import CavityVolumeConstraint, Circulation, make_constraint

        d = self["dynamics"]
        if d["constraint"] == "circulation":
            with _in_section("dynamics.circulation"):
                c = dict(d["circulation"])
                return Circulation(model, c.pop("boundary", "endocardium"), **c)
        if d["constraint"] != "cavity_volume":
            return make_constraint(model, d["constraint"])
        cavity = d.get("cavity") or {}
        change = cavity.get("volume_change")
        with _in_section("dynamics.cavity"):
            constraint = CavityVolumeConstraint(model, cavity.get("boundary", "endocardium"),
                                                None if change is None else time_law(change),
                                                apex=cavity.get("apex", "fixed"))
            if t is not None:
                constraint.check_targets(t)
        return constraint

    def scheme(self):
        from ..dynamics.stepper import Scheme

        d = self["dynamics"]
        return Scheme(theta=float(d["theta"]), multiplier=d["multiplier"], rtol=float(d["newton_rtol"]),
                      max_iter=int(d["newton_max_iter"]), newton=d["newton"])

    def grid(self):
        """The time levels of a run: uniform (``[dynamics] T, dt``), or those of the ``[control] file``
        when it holds an array ``t`` (the levels of the run that wrote it: an optimization's grid
        depends on its tau), which must be T / dt + 1 increasing levels from 0 to T."""
        from ..dynamics.timegrid import TimeGrid, uniform_grid

        d = self["dynamics"]
        grid = uniform_grid(float(d["T"]), float(d["dt"]))
        path = self.control_path()
        t = None if path is None else read_control_times(path)
        if t is None:
            return grid
        if t.shape != grid.t.shape or t[0] != 0.0 or not np.isclose(t[-1], grid.t[-1], rtol=1e-12, atol=0.0):
            raise InputError(f"control file {path}: 't' must hold the {grid.t.size} levels from 0 to T = "
                             f"{grid.t[-1]:g} (T / dt + 1), got {t.size} from {t[0]:g} to {t[-1]:g}")
        with _in_section("control"):
            return TimeGrid(t)

    def objective(self):
        from ..control.objectives import objective_from_config

        return objective_from_config(self["objective"])

    def transform(self, tau: float):
        from ..dynamics.timegrid import TimeTransform

        d = self["dynamics"]
        eps = float(self["objective"].get("eps", 0.0))
        T = float(d["T"])
        if not 0 < tau < T - eps:
            raise InputError(f"config: tau = {tau} must lie in (0, T - eps) = (0, {T - eps})")
        return TimeTransform.for_step(T, float(d["dt"]), tau, eps)

    def tau_starts(self) -> list:
        """The starts of tau of ``[optimize]`` (``tau_starts``, else ``[tau0]``, else ``[T / 2]``);
        `InputError` naming the key of one outside (0, T - eps). Only the commands that optimize read them."""
        o, T = self["optimize"], float(self["dynamics"]["T"])
        eps = float(self["objective"].get("eps", 0.0))
        key, starts = ("tau_starts", o["tau_starts"]) if o.get("tau_starts") else ("tau0", [o.get("tau0", T / 2)])
        for k, t in enumerate(starts):
            if not 0 < t < T - eps:
                where = f"{key}[{k}]" if key == "tau_starts" else key
                raise InputError(f"config: [optimize] {where} = {t:g} must lie in (0, T - eps) = (0, {T - eps:g})")
        return [float(t) for t in starts]

    def budget(self) -> dict:
        """``{key: value}`` of the `BUDGET_KEYS` of ``[optimize]``."""
        return {k: self["optimize"][k] for k in BUDGET_KEYS}

    def xi_bounds(self):
        b = self["optimize"].get("xi_bounds")
        return (None, None) if b is None else (float(b[0]), float(b[1]))

    def control_data(self, mesh):
        """``(control, space)``: the `hyperoc.mechanics.controls.ControlData` of ``[control]`` on ``mesh`` and
        the displacement's `hyperoc.fem.spaces.VectorSpace`, built without the state model (its load
        matrix numbers every dof), so that the prescribed control can be checked before JAX starts."""
        from ..fem.spaces import VectorSpace

        space = VectorSpace(mesh, self["mesh"]["degree"])
        operator = self.control_operator(self.fibres(mesh))
        with _in_section("control"):
            return operator.build(space, np.arange(space.num_dofs)), space

    def prescribed_control(self, model, t: np.ndarray) -> np.ndarray | None:
        """Control values (N+1, n_ctrl) from ``[control] value`` (expression(s)) or ``file`` (NPZ)
        for ``model`` (anything with the ``control`` and ``space`` of a `hyperoc.mechanics.model.StateModel`);
        `InputError` if a value is not finite (e.g. an expression dividing by zero on the grid)."""
        return self.control_values(model.control, model.space, t)

    def control_values(self, control, space, t: np.ndarray) -> np.ndarray | None:
        """`prescribed_control` for a `hyperoc.mechanics.controls.ControlData` on ``space``."""
        from ..expr import expression_field, parse_expression

        c = self["control"]
        if "file" in c:
            return _control_from_npz(self.control_path(), control.size, t.size)
        if "value" not in c:
            return None
        comps = control.components
        values = c["value"] if isinstance(c["value"], list) else [c["value"]] * comps
        if len(values) != comps:
            raise InputError(f"config: [control] value needs {comps} expression(s) (one per component)")
        exprs = [parse_expression(str(v)) for v in values]
        x = control.coordinates(space)
        with np.errstate(all="ignore"):  # a non-finite value is reported below, with where it occurs
            out = np.stack([np.stack([expression_field(e, x, float(tk)) for e in exprs], axis=-1) for tk in t])
        _require_finite(out, t, x, exprs)
        return out.reshape(t.size, -1)


def time_law(value):
    """The `hyperoc.dynamics.laws.TimeLaw` of a validated ``law`` value (`hyperoc.app.schema`)."""
    from ..dynamics import laws

    if isinstance(value, str):
        return laws.ExpressionLaw(value)
    if not isinstance(value, dict):
        return laws.Constant(float(value))
    if "bestel" in value:
        make = laws.bestel_pressure if value["bestel"] == "pressure" else laws.bestel_activation
        if "period" in value:
            return laws.Periodic(make(float(value["period"]), value.get("parameters")), float(value["period"]))
        return make(float(value.get("t_end", 1.0)), value.get("parameters"))
    return laws.Table(value["times"], value["values"])


def _scaled(mesh, factor: float):
    """``mesh`` with its coordinates (and curved P2 nodes) times ``factor``."""
    if factor == 1.0:
        return mesh
    points = None if mesh.curved_points is None else mesh.curved_points * factor
    return dataclasses.replace(mesh, points=mesh.points * factor, curved_points=points)


@contextmanager
def _in_section(name: str):
    """An `InputError` raised inside the block, prefixed with the config section it concerns."""
    try:
        yield
    except InputError as err:
        raise InputError(f"config: [{name}] {err}") from None


def _require_finite(values: np.ndarray, t: np.ndarray, x: np.ndarray, exprs) -> None:
    """`InputError` naming the first (time, point, expression) where ``values`` (levels, nodes,
    components) is NaN or infinite."""
    bad = np.argwhere(~np.isfinite(values))
    if bad.size:
        k, i, c = bad[0]
        raise InputError(f"config: [control] value {exprs[c].source[:60]!r} is {values[k, i, c]} at t = {t[k]:g}, "
                         f"x = {np.round(x[i], 6).tolist()} (it must be finite on the whole grid)")


def _region(cfg):
    """`hyperoc.mechanics.controls.Region` of a validated ``[control] region`` table (None: the whole body)."""
    from ..mechanics.controls import Region

    if cfg is None:
        return Region()
    cfg = dict(cfg)
    kind = cfg.pop("kind", "box")
    return Region(kind=kind, **{k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()})


def _control_from_npz(path: Path, size: int, levels: int) -> np.ndarray:
    xi = read_control_file(path)
    if xi.shape != (levels, size):
        raise InputError(f"control file {path}: 'xi' must have shape (levels, n_ctrl) = {(levels, size)}, "
                         f"got {xi.shape} (after flattening nodal values)")
    return xi


def read_control_times(path: Path) -> np.ndarray | None:
    """The time levels ``t`` (levels,) of an NPZ control file as float64, or None if it has none
    (`read_control_file` checks the file itself)."""
    read_control_file(path)
    with np.load(path, allow_pickle=False) as data:
        if "t" not in data.files:
            return None
        t = data["t"]
    if t.ndim != 1 or not np.issubdtype(t.dtype, np.number) or np.iscomplexobj(t) or not np.all(np.isfinite(t)):
        raise InputError(f"control file {path}: 't' must be a 1D array of finite times, got {t.dtype} {t.shape}")
    return t.astype(np.float64)


def read_control_file(path: Path) -> np.ndarray:
    """The array ``xi`` of an NPZ control file as float64 (levels, n_ctrl); `InputError` if the file is
    missing, is not an NPZ archive, has no finite real array ``xi``.

    ``xi`` is either the control vectors (levels, n_ctrl) or their nodal values (levels, n_nodes,
    components), the layout ``results.npz`` holds (`hyperoc.mechanics.controls.ControlData.nodal`):
    n_ctrl = n_nodes * components, node-major, so the nodal values flatten to the control vectors and
    a run's ``results.npz`` replays as written."""
    import zipfile

    if not path.is_file():
        raise InputError(f"control file not found: {path}" if not path.exists()
                         else f"control file {path} is not a file")
    try:
        data = np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as err:
        raise InputError(f"control file {path} is not a readable NPZ archive ({type(err).__name__})") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise InputError(f"control file {path} is not an NPZ archive (a single .npy array?)")
    with data:
        if "xi" not in data.files:
            raise InputError(f"control file {path} has no array 'xi' (found: {', '.join(data.files) or 'none'})")
        try:
            xi = data["xi"]
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as err:
            raise InputError(f"control file {path}: array 'xi' is unreadable ({type(err).__name__})") from None
    if xi.ndim not in (2, 3) or not np.issubdtype(xi.dtype, np.number) or np.iscomplexobj(xi):
        raise InputError(f"control file {path}: 'xi' must be a real array (levels, n_ctrl) or "
                         f"(levels, n_nodes, components), got {xi.dtype} {xi.shape}")
    xi = xi.astype(np.float64).reshape(xi.shape[0], -1)
    if not np.all(np.isfinite(xi)):
        k, j = np.argwhere(~np.isfinite(xi))[0]
        raise InputError(f"control file {path}: 'xi' has a non-finite value ({xi[k, j]}) at level {k}, entry {j}")
    return xi


def parse_config(data: dict, base: Path = Path("."), name: str | None = None) -> Config:
    """Validate a config dict (as read from TOML) into a `Config` (`hyperoc.app.schema.validate_sections`)."""
    return Config(validate_sections(data), Path(base), name)


def load_config(path, overrides=()) -> Config:
    """Read and validate a TOML file, with ``overrides`` (`apply_overrides`) applied first; every
    problem raises `InputError` with a one-line message."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"config file not found: {path}")
    if not path.is_file():
        raise InputError(f"config {path} is not a file (a directory?)")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"config {path}: invalid TOML: {str(exc).splitlines()[0][:120]}") from None
    except OSError as exc:
        raise InputError(f"config {path} cannot be read: {exc.strerror}") from None
    return parse_config(apply_overrides(data, overrides), path.parent, path.stem)


def apply_overrides(data: dict, overrides) -> dict:
    """``data`` (a config as read from TOML) with each ``"SECTION.KEY=VALUE"`` of ``overrides`` set,
    e.g. ``optimize.xi_bounds=[-0.05, 0.05]`` or ``control.region.kind=box`` (a key path of any
    depth). VALUE is read as a TOML value (``0.05``, ``[1, 2]``, ``"svk"``, ``true``, ``{ a = 1 }``)
    or, when it is none, taken as a string (``material.law=svk``). A relative path (a key named
    ``file``) given here is taken from the working directory, where the command is typed; one in the
    config file from the config's folder (`Config.path`). The result is validated like the file by
    `parse_config`."""
    entries = {}
    for item in overrides:
        path, sep, text = item.partition("=")
        if not sep:
            raise InputError(f"override {item!r}: expected SECTION.KEY=VALUE, e.g. dynamics.dt=0.01")
        value = _read_value(text.strip())
        if path.strip().split(".")[-1] == PATH_KEY and isinstance(value, str):
            value = str(Path.cwd() / Path(value).expanduser())  # typed on the command line: from where it is typed
        entries[path.strip()] = value
    return set_entries(data, entries)


def set_entries(data: dict, entries) -> dict:
    """A copy of ``data`` (a config as read from TOML) with each ``"SECTION.KEY": value`` of the
    mapping ``entries`` set (a key path of any depth, as in ``--set``), e.g.
    ``{"mesh.n": 50, "optimize.xi_bounds": [-0.05, 0.05]}``: the one way configurations are changed,
    from the command line (`apply_overrides`) or from Python."""
    data = copy.deepcopy(data)  # the caller's dict stays as read
    for path, value in entries.items():
        keys = path.strip().split(".")
        if len(keys) < 2 or not all(keys):
            raise InputError(f"override {path!r}: expected SECTION.KEY (--set SECTION.KEY=VALUE), e.g. dynamics.dt")
        table = data
        for key in keys[:-1]:
            table = table.setdefault(key, {})
            if not isinstance(table, dict):
                raise InputError(f"override {path[:80]!r}: {key} is not a table")
        table[keys[-1]] = value
    return data


def _read_value(text: str):
    """A TOML value, or the text itself if it is not one."""
    try:
        return tomllib.loads(f"value = {text}")["value"]
    except tomllib.TOMLDecodeError:
        return text


def _toml_value(value) -> str:
    """One value of a validated config (bool, number, string, list, table) as TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string: JSON's escapes are TOML's
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items() if v is not None) + " }"
    raise TypeError(f"no TOML form for {value!r}")


def _main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m hyperoc.app.config", description="the configuration schema")
    parser.add_argument("--reference", action="store_true", help="print the configuration reference (Markdown)")
    args = parser.parse_args(argv)
    if not args.reference:
        parser.print_help()
        return 2
    sys.stdout.write(reference_markdown())
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(_main())

"""TOML configuration: schema, validation with one clear message, and builders.

A configuration has the sections ``[mesh] [material] [fibres] [dynamics] [control] [objective]
[optimize] [output]`` (see ``examples/*.toml``). Every entry is checked for its type and range before any
computation starts; a problem raises `InputError` naming the section and key, which the CLI turns
into one line on stderr and exit status 2.
"""

from __future__ import annotations

import copy
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .controls import ActiveStress, BodyForce, Region
from .dynamics import Scheme
from .errors import InputError
from .expr import expression_field, parse_expression
from .fibres import FibreFrames, rule_based_fibres
from .materials import Guccione, HolzapfelOgden, material_from_config
from .mesh import Mesh, box, interval, rectangle, refine
from .model import StateModel
from .objectives import objective_from_config
from .reduced import checkpoint_options
from .timegrid import TimeTransform, uniform_grid

__all__ = ["Config", "load_config", "parse_config", "apply_overrides"]

NUMBER = (int, float)

# section -> key -> (accepted types, default); None default = required, ... = optional
SCHEMA = {
    "mesh": {
        "kind": (str, "interval"), "n": (int, 100), "length": (NUMBER, 1.0), "nx": (int, 8), "ny": (int, ...),
        "nz": (int, ...), "size": (list, ...), "dirichlet": (str, "left"), "r_inner": (NUMBER, 0.5),
        "r_outer": (NUMBER, 1.0), "h": (NUMBER, 0.1), "structured": (bool, False), "n_radial": (int, ...),
        "n_theta": (int, ...), "file": (str, ...), "degree": (int, 1),
        # uniform refinements of the mesh built (hyperoc.mesh.refine; curved geometries stay exact)
        "refinements": (int, 0),
        "dirichlet_tag": (str, "gamma_d"), "neumann_tag": (str, "gamma_n"), "control_tag": (str, "omega"),
        # components fixed on gamma_d (default: all); e.g. [2] = a base sliding in its plane, with the
        # rigid in-plane motions this leaves removed by three pinned dofs (StateModel.pinned_dofs)
        "fixed_components": (list, ...),
    },
    "material": {"law": (str, "svk"), "mu": (NUMBER, ...), "lambda": (NUMBER, ...), "beta": (NUMBER, ...),
                 "gamma": (NUMBER, ...), "W0": (NUMBER, ...), "coefficients": (list, ...), "exponents": (list, ...),
                 # cardiac laws (kPa): Guccione C, bf, bt, bfs; Holzapfel-Ogden a, b, af, bf, as, bs, afs, bfs
                 "C": (NUMBER, ...), "bf": (NUMBER, ...), "bt": (NUMBER, ...), "bfs": (NUMBER, ...),
                 "a": (NUMBER, ...), "b": (NUMBER, ...), "af": (NUMBER, ...), "as": (NUMBER, ...),
                 "bs": (NUMBER, ...), "afs": (NUMBER, ...), "kappa": (NUMBER, ...),
                 # Guccione's Q on the isochoric strain (J^(-2/3) C - I)/2; needed with "cell-mean"
                 "isochoric": (bool, ...),
                 # the bulk term per quadrature point, or on each cell's mean J (mixed u-p with a
                 # piecewise-constant pressure, condensed; StateModel volumetric): "pointwise", "cell-mean"
                 "volumetric": (str, "pointwise")},
    # rule-based fibres (hyperoc.fibres.rule_based_fibres): helix angles in degrees, long axis apex -> base
    "fibres": {"kind": (str, "none"), "helix_endo": (NUMBER, 60.0), "helix_epi": (NUMBER, -60.0),
               "long_axis": (list, [0.0, 0.0, 1.0]), "inner": (str, "endocardium"), "outer": (str, "epicardium")},
    "dynamics": {"T": (NUMBER, 15.0), "dt": (NUMBER, 0.02), "kappa": (NUMBER, 2e-4), "density": (NUMBER, 1.0),
                 "theta": (NUMBER, 0.5), "multiplier": (str, "step"), "solver": (str, "auto"),
                 "newton_rtol": (NUMBER, 1e-11), "newton_max_iter": (int, 30), "traction": (list, ...)},
    "control": {"kind": (str, "body_force"), "region": (dict, ...), "value": ((str, list, NUMBER), ...),
                "file": (str, ...)},
    "objective": {"phi1": (str, "pressure"), "alpha": (NUMBER, 2e-3), "beta": (NUMBER, 0.0), "eps": (NUMBER, 0.0)},
    "optimize": {"method": (str, "bb"), "tau0": (NUMBER, ...), "tau_starts": (list, ...), "max_iter": (int, 100),
                 "gtol": (NUMBER, 1e-6), "xi_bounds": (list, ...), "tau_margin": (NUMBER, ...),
                 "gradient": (str, "exact"), "steps": (str, "joint"), "bb_step": (str, "bb1"),
                 "nonmonotone": (int, 0),  # bb: 0 = the paper's Algorithm 1, M > 0 = SPG's window
                 "tau_scale": ((str, NUMBER), "range"),  # L-BFGS-B's scaling of tau (`hyperoc.optimize.tau_scaling`)
                 "max_cg": (int, 20),  # newton: Hessian-vector products per iteration (`hyperoc.optimize.newton_cg`)
                 # checkpointed adjoint: every k-th level state, or a binomial schedule with s snapshots
                 "checkpoint_every": (int, ...), "checkpoint_snapshots": (int, ...)},
    "output": {"snapshot_times": (list, ...), "series_every": (int, ...)},
}


def _type_name(types) -> str:
    types = types if isinstance(types, tuple) else (types,)
    if float in types:  # an int is accepted wherever a float is
        types = tuple(t for t in types if t is not int)
    names = {int: "an integer", float: "a number", str: "a string", list: "a list", dict: "a table", bool: "true/false"}
    return " or ".join(dict.fromkeys(names[t] for t in types))


def _check_section(name: str, given: dict) -> dict:
    schema = SCHEMA[name]
    if not isinstance(given, dict):
        raise InputError(f"config: [{name}] must be a table")
    unknown = set(given) - set(schema)
    if unknown:
        raise InputError(f"config: [{name}] has unknown key(s) {sorted(unknown)}; allowed: {sorted(schema)}")
    out = {}
    for key, (types, default) in schema.items():
        if key not in given:
            if default is not ...:
                out[key] = default
            continue
        value = given[key]
        tt = types if isinstance(types, tuple) else (types,)
        ok = isinstance(value, tt) and not (isinstance(value, bool) and bool not in tt)
        if not ok:
            raise InputError(f"config: [{name}] {key} must be {_type_name(types)}, got {type(value).__name__} {value!r}")
        out[key] = value
    return out


@dataclass(frozen=True)
class Config:
    """Validated configuration (sections as dicts with defaults filled in) and its folder."""

    sections: dict
    base: Path

    def __getitem__(self, name: str) -> dict:
        return self.sections[name]

    def to_toml(self) -> str:
        """The configuration as TOML, every default written out and file paths made absolute, so
        that `load_config` of the text, from any folder, gives the same `Config` sections."""
        lines = []
        for name, section in self.sections.items():
            lines.append(f"[{name}]")
            for key, value in section.items():
                if key == "file":
                    value = str((self.base / value).resolve())
                lines.append(f"{key} = {_toml_value(value)}")
            lines.append("")
        return "\n".join(lines)

    # --- builders ---------------------------------------------------------------------------------
    def mesh(self) -> Mesh:
        c = self["mesh"]
        kind, k = c["kind"], c["refinements"]
        if k < 0:
            raise InputError(f"config: [mesh] refinements must be >= 0, got {k}")
        if kind in ("annulus", "shell", "ventricle"):
            return self._curved_mesh(kind, k)
        mesh = self._straight_mesh(kind)
        for _ in range(k):
            mesh = refine(mesh)
        return mesh

    def _straight_mesh(self, kind: str) -> Mesh:
        c = self["mesh"]
        if kind == "interval":
            return interval(c["n"], c["length"])
        if kind == "rectangle":
            return rectangle(c["nx"], c.get("ny"), tuple(c.get("size", (1.0, 1.0))), c["dirichlet"])
        if kind == "box":
            return box(c["nx"], c.get("ny"), c.get("nz"), tuple(c.get("size", (1.0, 1.0, 1.0))), c["dirichlet"])
        if kind == "file":
            from . import geometry

            if "file" not in c:
                raise InputError("config: [mesh] kind = 'file' needs file = 'path/to/mesh.msh'")
            path = (self.base / c["file"]).resolve()
            return geometry.from_file(path, dirichlet=c["dirichlet_tag"], neumann=c["neumann_tag"], control=c["control_tag"])
        raise InputError(f"config: [mesh] kind {kind!r} unknown (interval, rectangle, box, annulus, shell, ventricle, file)")

    def _curved_mesh(self, kind: str, refinements: int) -> Mesh:
        """The generators that put refined boundary vertices on their exact surfaces."""
        from . import geometry

        c = self["mesh"]
        if kind == "annulus":
            return geometry.annulus(c["r_inner"], c["r_outer"], c["h"], structured=c["structured"],
                                    n_radial=c.get("n_radial"), n_theta=c.get("n_theta"), refinements=refinements)
        if kind == "shell":
            return geometry.thick_shell(c["r_inner"], c["r_outer"], c["h"], refinements=refinements)
        return geometry.ventricle(c["h"], refinements=refinements)

    def fibres(self, mesh: Mesh) -> FibreFrames | None:
        """Fibre frames of ``[fibres]`` on ``mesh`` (kind "rule_based"), or None (kind "none")."""
        c = self["fibres"]
        if c["kind"] == "none":
            return None
        if c["kind"] != "rule_based":
            raise InputError(f"config: [fibres] kind {c['kind']!r} unknown (none, rule_based)")
        axis = c["long_axis"]
        if len(axis) != 3 or not all(isinstance(v, NUMBER) and not isinstance(v, bool) for v in axis):
            raise InputError(f"config: [fibres] long_axis must be a list of 3 numbers, got {axis!r}")
        if mesh.dim != 3:
            raise InputError(f"config: [fibres] rule_based needs a 3D mesh, got dimension {mesh.dim}")
        return rule_based_fibres(mesh, helix_endo=float(c["helix_endo"]), helix_epi=float(c["helix_epi"]),
                                 long_axis=tuple(float(v) for v in axis), inner=c["inner"], outer=c["outer"])

    def control_operator(self, frames: FibreFrames | None = None):
        """The control of ``[control]``; active stress follows ``frames``' fibres when given."""
        c = self["control"]
        region = _region(c.get("region"))
        if c["kind"] == "body_force":
            return BodyForce(region)
        if c["kind"] == "active_stress":
            return ActiveStress(region, fibres=None if frames is None else frames.fibre)
        raise InputError(f"config: [control] kind {c['kind']!r} unknown (body_force, active_stress)")

    def model(self) -> StateModel:
        """The `StateModel` of the config; the frames of ``[fibres]`` serve both a fibre-dependent
        material and the active stress (its fibre = row 0 of the frame)."""
        d = self["dynamics"]
        mesh = self.mesh()
        traction = d.get("traction")
        if traction is not None and (len(traction) != mesh.dim or not all(isinstance(v, NUMBER) for v in traction)):
            raise InputError(f"config: [dynamics] traction must be a list of {mesh.dim} numbers")
        if self["mesh"]["degree"] not in (1, 2):
            raise InputError(f"config: [mesh] degree must be 1 or 2, got {self['mesh']['degree']}")
        material = material_from_config({k: v for k, v in self["material"].items() if k != "volumetric"})
        frames = self.fibres(mesh)
        if frames is None and isinstance(material, (Guccione, HolzapfelOgden)):
            raise InputError(f"config: [material] law {self['material']['law']!r} needs fibres: add [fibres] kind = 'rule_based'")
        return StateModel(mesh, material, degree=self["mesh"]["degree"], kappa=float(d["kappa"]),
                          density=float(d["density"]), control=self.control_operator(frames), traction=traction,
                          neumann="gamma_n", frames=frames, volumetric=self["material"]["volumetric"],
                          **self._dirichlet(mesh.dim))

    def _dirichlet(self, dim: int) -> dict:
        """StateModel keywords for gamma_d: clamped, or only ``[mesh] fixed_components`` fixed."""
        comps = self["mesh"].get("fixed_components")
        if comps is None:
            return {"dirichlet": "gamma_d"}
        if not comps or not all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c < dim for c in comps):
            raise InputError(f"config: [mesh] fixed_components must be a non-empty list of integers in [0, {dim})")
        return {"dirichlet": None, "dirichlet_components": {"gamma_d": tuple(comps)}}

    def scheme(self) -> Scheme:
        d = self["dynamics"]
        return Scheme(theta=float(d["theta"]), multiplier=d["multiplier"], rtol=float(d["newton_rtol"]),
                      max_iter=int(d["newton_max_iter"]))

    def grid(self):
        d = self["dynamics"]
        return uniform_grid(float(d["T"]), float(d["dt"]))

    def objective(self):
        return objective_from_config(self["objective"])

    def transform(self, tau: float) -> TimeTransform:
        d = self["dynamics"]
        eps = float(self["objective"]["eps"])
        T = float(d["T"])
        if not 0 < tau < T - eps:
            raise InputError(f"config: tau = {tau} must lie in (0, T - eps) = (0, {T - eps})")
        return TimeTransform.for_step(T, float(d["dt"]), tau, eps)

    def tau_starts(self) -> list:
        o, T = self["optimize"], float(self["dynamics"]["T"])
        starts = o.get("tau_starts") or [o.get("tau0", T / 2)]
        if not all(isinstance(t, NUMBER) and not isinstance(t, bool) for t in starts):
            raise InputError("config: [optimize] tau_starts must be a list of numbers")
        for t in starts:
            self.transform(float(t))
        return [float(t) for t in starts]

    def xi_bounds(self):
        b = self["optimize"].get("xi_bounds")
        if b is None:
            return (None, None)
        if len(b) != 2 or not all(isinstance(v, NUMBER) for v in b) or not b[0] < b[1]:
            raise InputError("config: [optimize] xi_bounds must be [lower, upper] with lower < upper")
        return (float(b[0]), float(b[1]))

    def prescribed_control(self, model: StateModel, t: np.ndarray) -> np.ndarray | None:
        """Control values (N+1, n_ctrl) from ``[control] value`` (expression(s)) or ``file`` (NPZ)."""
        c = self["control"]
        if "file" in c:
            return _control_from_npz(self.base / c["file"], model, t.size)
        if "value" not in c:
            return None
        comps = model.control.components
        values = c["value"] if isinstance(c["value"], list) else [c["value"]] * comps
        if len(values) != comps:
            raise InputError(f"config: [control] value needs {comps} expression(s) (one per component)")
        exprs = [parse_expression(str(v)) for v in values]
        x = model.control.coordinates(model.space)
        out = np.stack([np.stack([expression_field(e, x, float(tk)) for e in exprs], axis=-1) for tk in t])
        return out.reshape(t.size, -1)


# [control.region] key -> accepted value ("numbers" = a list of numbers)
_REGION_KEYS = {"tag": str, "inner": str, "outer": str, "z_max": "number", "lower": "numbers", "upper": "numbers",
                "r_range": "numbers", "theta_range": "numbers", "transmural": "numbers"}


def _region(cfg) -> Region:
    if cfg is None:
        return Region()
    cfg = dict(cfg)
    kind = cfg.pop("kind", "box")
    if not isinstance(kind, str):
        raise InputError("config: [control.region] kind must be a string")
    if set(cfg) - set(_REGION_KEYS):
        raise InputError(f"config: [control.region] unknown key(s) {sorted(set(cfg) - set(_REGION_KEYS))}; "
                         f"allowed: {sorted(_REGION_KEYS)}")
    is_number = lambda v: isinstance(v, NUMBER) and not isinstance(v, bool)
    conv = {}
    for key, value in cfg.items():
        expected = _REGION_KEYS[key]
        if expected is str and not isinstance(value, str):
            raise InputError(f"config: [control.region] {key} must be a string")
        if expected == "number" and not is_number(value):
            raise InputError(f"config: [control.region] {key} must be a number")
        if expected == "numbers" and not (isinstance(value, list) and all(is_number(v) for v in value)):
            raise InputError(f"config: [control.region] {key} must be a list of numbers")
        conv[key] = tuple(float(v) for v in value) if expected == "numbers" else (float(value) if expected == "number" else value)
    return Region(kind=kind, **conv)


def _control_from_npz(path: Path, model: StateModel, levels: int) -> np.ndarray:
    if not path.exists():
        raise InputError(f"control file not found: {path}")
    with np.load(path) as data:
        if "xi" not in data:
            raise InputError(f"control file {path} has no array 'xi'")
        xi = np.asarray(data["xi"], dtype=np.float64)
    if xi.shape != (levels, model.control.size):
        raise InputError(f"control file {path}: 'xi' must have shape (levels, n_ctrl) = {(levels, model.control.size)}, got {xi.shape}")
    return xi


def parse_config(data: dict, base: Path = Path(".")) -> Config:
    """Validate a config dict (as read from TOML) into a `Config`."""
    unknown = set(data) - set(SCHEMA)
    if unknown:
        raise InputError(f"config: unknown section(s) {sorted(unknown)}; allowed: {sorted(SCHEMA)}")
    sections = {name: _check_section(name, data.get(name, {})) for name in SCHEMA}
    d = sections["dynamics"]
    if not d["dt"] > 0 or not d["T"] > 0:
        raise InputError(f"config: [dynamics] needs dt > 0 and T > 0, got dt = {d['dt']}, T = {d['T']}")
    if d["kappa"] < 0:
        raise InputError(f"config: [dynamics] kappa must be >= 0, got {d['kappa']}")
    if d["density"] <= 0:
        raise InputError(f"config: [dynamics] density must be > 0, got {d['density']}")
    o = sections["optimize"]
    try:
        checkpoint_options(o.get("checkpoint_every"), o.get("checkpoint_snapshots"))
    except InputError as err:
        raise InputError(f"config: [optimize] {err}") from None
    return Config(sections, Path(base))


def load_config(path, overrides=()) -> Config:
    """Read and validate a TOML file, with ``overrides`` (`apply_overrides`) applied first; every
    problem raises `InputError` with a one-line message."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"config file not found: {path}")
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"config {path}: invalid TOML: {exc}") from None
    return parse_config(apply_overrides(data, overrides), path.parent)


def apply_overrides(data: dict, overrides) -> dict:
    """``data`` (a config as read from TOML) with each ``"SECTION.KEY=VALUE"`` of ``overrides`` set,
    e.g. ``optimize.xi_bounds=[-0.05, 0.05]`` or ``control.region.kind=box`` (a key path of any
    depth). VALUE is read as a TOML value (``0.05``, ``[1, 2]``, ``"svk"``, ``true``, ``{ a = 1 }``)
    or, when it is none, taken as a string (``material.law=svk``). The result is validated like the
    file by `parse_config`."""
    data = copy.deepcopy(data)  # the caller's dict stays as read
    for item in overrides:
        path, sep, text = item.partition("=")
        keys = path.strip().split(".")
        if not sep or len(keys) < 2 or not all(keys):
            raise InputError(f"override {item!r}: expected SECTION.KEY=VALUE, e.g. dynamics.dt=0.01")
        table = data
        for key in keys[:-1]:
            table = table.setdefault(key, {})
            if not isinstance(table, dict):
                raise InputError(f"override {item!r}: {key} is not a table")
        table[keys[-1]] = _read_value(text.strip())
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
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"no TOML form for {value!r}")

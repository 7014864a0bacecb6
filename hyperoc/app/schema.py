"""The configuration schema: every key of every section, its type, default, constraint and meaning.

One pydantic model per TOML section (``[mesh] [material] [fibres] [dynamics] [control] [objective]
[optimize] [output]``) checks types (strictly: an integer is accepted for a number, nothing else is
converted), ranges, finiteness (no NaN or inf anywhere) and the rules that tie keys together
(bounds ordered, tau inside ``(0, T - eps)``, a key given only for the kind it applies to). The
checks that need the mesh or the material law (a control region that holds no cell, a law's own
parameter ranges) are made when the model is built (`hyperoc.app.config.Config.model`).

`validate_sections` turns the first violation into an `InputError` naming the section and key;
`reference_markdown` renders the schema as the configuration reference (``docs/configuration.md``).
This module imports neither JAX nor the solvers, so that a bad input is reported at once.
"""

from __future__ import annotations

import json
import math
import typing
from typing import Annotated, Any, ClassVar, Literal, Optional, Union

import annotated_types as at
from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator

from ..control.tau_scale import is_tau_scale
from ..errors import InputError, quote
from ..expr import parse_expression

__all__ = ["SECTIONS", "ConfigSchema", "validate_sections", "reference_markdown", "quote"]

# --- field types ----------------------------------------------------------------------------------
Number = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(allow_inf_nan=False, gt=0)]
NonNegative = Annotated[float, Field(allow_inf_nan=False, ge=0)]
Count = Annotated[int, Field(ge=1)]
Numbers = Annotated[list[Number], Field(min_length=1)]


def _expressions(value):
    """A control value: an expression string, a number, or a non-empty list of them (one per
    component); every string is parsed here (`hyperoc.expr.parse_expression`), so a syntax error
    is reported with the other config errors."""
    items = value if isinstance(value, list) else [value]
    if not items or not all(_is_expression(v) for v in items):
        raise ValueError(f"must be an expression string, a finite number, or a list of them (one per component), "
                         f"got {quote(value)}")
    for v in items:
        if isinstance(v, str):
            parse_expression(v)
    return value


def _is_expression(v) -> bool:
    return isinstance(v, str) or (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v))


def _tau_scale(value):
    if is_tau_scale(value):
        return value
    raise ValueError(f"must be 'range', 'curvature' or a positive number, got {quote(value)}")


def _ordered_pair(value):
    if len(value) != 2 or not value[0] < value[1]:
        raise ValueError(f"must be [lower, upper] with lower < upper, got {quote(value)}")
    return value


def _time_law(value):
    """A time law (`hyperoc.dynamics.laws`): a finite number (constant), an expression string of t, a table
    ``{times = [...], values = [...]}`` (times strictly increasing) or a Bestel ODE ``{bestel = "pressure" |
    "activation", t_end = 1.0, parameters = {...}, period = ...}`` (unknown parameters are reported when the law
    is built; with a period the law of one beat, integrated on ``[0, period]``, repeats)."""
    if _is_expression(value):
        if isinstance(value, str):
            parse_expression(value, {"t"})
        return value
    if not isinstance(value, dict):
        raise ValueError(f"must be a number, an expression of t, a table {{times, values}} or a Bestel law "
                         f"{{bestel = 'pressure' | 'activation'}}, got {quote(value)}")
    if "bestel" in value:
        extra = sorted(set(value) - {"bestel", "t_end", "parameters", "period"})
        if extra or value["bestel"] not in ("pressure", "activation"):
            raise ValueError(f"a Bestel law takes bestel = 'pressure' | 'activation', t_end, parameters and period, "
                             f"got {quote(value)}")
        t_end, parameters = value.get("t_end", 1.0), value.get("parameters", {})
        for name, number in (("t_end", t_end), ("period", value.get("period", 1.0))):
            if not (_is_expression(number) and not isinstance(number, str) and number > 0):
                raise ValueError(f"Bestel {name} must be a positive number, got {quote(number)}")
        if not isinstance(parameters, dict) or not all(_is_expression(v) and not isinstance(v, str)
                                                       for v in parameters.values()):
            raise ValueError(f"Bestel parameters must be a table of finite numbers, got {quote(parameters)}")
        return value
    if set(value) != {"times", "values"}:
        raise ValueError(f"a table law has exactly the keys times and values, got {sorted(value)}")
    times, values = value["times"], value["values"]
    numbers = lambda v: isinstance(v, list) and all(_is_expression(x) and not isinstance(x, str) for x in v)
    if not (numbers(times) and numbers(values) and len(times) == len(values) >= 2):
        raise ValueError("a table law needs times and values: lists of as many finite numbers, at least 2")
    bad = [k for k in range(len(times) - 1) if not times[k] < times[k + 1]]
    if bad:
        k = bad[0]
        raise ValueError(f"table times must be strictly increasing: times[{k}] = {times[k]:g} >= "
                         f"times[{k + 1}] = {times[k + 1]:g}")
    return value


def _control_profile(value):
    """``"activation"`` (the law of ``[dynamics.activation]``) or a time law (`_time_law`)."""
    return value if value == "activation" else _time_law(value)


Expressions = Annotated[Any, BeforeValidator(_expressions)]
TimeLawValue = Annotated[Any, BeforeValidator(_time_law),
                         Field(json_schema_extra={"type": "number, expression of t, table or Bestel law"})]
ControlProfile = Annotated[Any, BeforeValidator(_control_profile),
                           Field(json_schema_extra={"type": "'activation', number, expression of t, table or "
                                                            "Bestel law"})]
TauScale = Annotated[Any, BeforeValidator(_tau_scale),
                     Field(json_schema_extra={"type": "'range', 'curvature' or number"})]
Bounds = Annotated[list[Number], AfterValidator(_ordered_pair)]


class Section(BaseModel):
    """A TOML table: unknown keys rejected, no type conversion, and optionally keys that apply only
    to some values of a selector key (``KIND_KEY``): ``KINDS[value]`` lists them; keys not listed
    anywhere apply to every kind. A key given for another kind is an error unless it holds its
    default."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)
    KIND_KEY: ClassVar[str | None] = None
    KINDS: ClassVar[dict] = {}

    @model_validator(mode="after")
    def _keys_apply_to_kind(self):
        if self.KIND_KEY is None:
            return self
        kind = getattr(self, self.KIND_KEY)
        # a key left at its default changes nothing (and configs written before this rule hold them all)
        stray = sorted(k for k in self.model_fields_set if k not in self.applicable_keys()
                       and getattr(self, k) != type(self).model_fields[k].default)
        if stray:
            raise ValueError(f"{stray[0]} does not apply to {self.KIND_KEY} = {kind!r} "
                             f"(its keys: {', '.join(sorted(self.applicable_keys()))})")
        return self

    @classmethod
    def kind_specific(cls) -> set:
        return set().union(*cls.KINDS.values()) if cls.KINDS else set()

    def applicable_keys(self) -> list:
        """The keys of this section that the chosen kind reads, in declaration order."""
        own = self.KINDS.get(getattr(self, self.KIND_KEY), set()) if self.KIND_KEY else set()
        specific = self.kind_specific()
        return [k for k in type(self).model_fields if k not in specific or k in own]

    def values(self) -> dict:
        """``{key: value}`` of the applicable keys that have a value (given or a default)."""
        dumped = self.model_dump()
        return {k: dumped[k] for k in self.applicable_keys() if dumped[k] is not None}


class Mesh(Section):
    """The body: a generated mesh or a mesh file."""

    KIND_KEY: ClassVar[str] = "kind"
    KINDS: ClassVar[dict] = {
        "interval": {"n", "length"},
        "rectangle": {"nx", "ny", "size", "dirichlet"},
        "box": {"nx", "ny", "nz", "size", "dirichlet"},
        "annulus": {"r_inner", "r_outer", "h", "structured", "n_radial", "n_theta"},
        "shell": {"r_inner", "r_outer", "h"},
        "ventricle": {"h"},
        "file": {"file", "dirichlet_tag", "neumann_tag", "control_tag", "tags"},
        "cardiac_benchmark": {"variant", "dirichlet_tag"},
    }

    kind: Literal["interval", "rectangle", "box", "annulus", "shell", "ventricle", "file", "cardiac_benchmark"] = Field(
        "interval", description="generator (interval: 1D, rectangle and annulus: 2D, box, shell and ventricle: 3D), "
                                "a mesh file, or a shipped mesh of the cardiac elastodynamics benchmark (m)")
    n: Count = Field(100, description="cells of the interval (0, length)")
    length: Positive = Field(1.0, description="length of the interval")
    nx: Count = Field(
        8, description="cells along x (rectangle: squares split in 2 triangles, box: cubes in 6 tetrahedra)")
    ny: Optional[Count] = Field(None, description="cells along y (default: nx)")
    nz: Optional[Count] = Field(None, description="cells along z (default: nx)")
    size: Optional[Annotated[list[Positive], Field(min_length=2, max_length=3)]] = Field(
        None, description="side lengths [a, b] or [a, b, c] (default: unit square or cube)")
    dirichlet: str = Field("left", description="the side clamped (gamma_d): left, right, bottom, top, front, back")
    r_inner: Positive = Field(0.5, description="inner radius (the free cavity wall)")
    r_outer: Positive = Field(1.0, description="outer radius (clamped)")
    h: Positive = Field(0.1, description="target cell size of the Gmsh generators (ventricle: mm)")
    structured: bool = Field(False, description="annulus: a structured (radial x angular) mesh instead of Gmsh's")
    n_radial: Optional[Count] = Field(None, description="structured annulus: cells across the wall")
    n_theta: Optional[Count] = Field(None, description="structured annulus: cells around")
    file: Optional[str] = Field(
        None, description="mesh file read by meshio (.msh, .vtu, .xdmf), relative to the config")
    degree: Literal[1, 2] = Field(1, description="polynomial degree of the displacement (P1 or P2)")
    refinements: Annotated[int, Field(ge=0)] = Field(
        0, description="uniform refinements of the mesh built (curved boundaries stay on their exact surfaces)")
    dirichlet_tag: str = Field("gamma_d", description="boundary tag (name or number) of the file's clamped part")
    neumann_tag: str = Field("gamma_n", description="boundary tag (name or number) of the file's free part")
    control_tag: str = Field("omega", description="subdomain tag of the file's control region")
    variant: Literal["reference", "coarse", "medium"] = Field(
        "reference", description="cardiac_benchmark: the benchmark's reference mesh (17,625 cells) or hyperoc's "
                                 "coarse (1,402) or medium (3,494) one; boundaries endocardium (gamma_n), "
                                 "epicardium, base")
    tags: Optional[dict[str, Union[Annotated[int, Field(ge=0)], str]]] = Field(
        None, description="names of the file's tags, e.g. {endocardium = 1, epicardium = 2, base = 3}; any look-up "
                          "also accepts the aliases endo/ENDO, epi/EPI, top for endocardium, epicardium, base")
    fixed_components: Optional[Annotated[list[Annotated[int, Field(ge=0, le=2)]], Field(min_length=1)]] = Field(
        None, description="components fixed on gamma_d (default: all), e.g. [2]: a base sliding in its plane")
    clamped: bool = Field(True, description="false: no Dirichlet boundary at all (a body held by Robin boundaries)")
    scale: Positive = Field(1.0, description="factor on the coordinates of the mesh built, e.g. 1e-3: the "
                                             "ventricle generator's mm in m")

    @model_validator(mode="after")
    def _radii_ordered(self):
        if self.kind in ("annulus", "shell") and not self.r_inner < self.r_outer:
            raise ValueError(f"r_inner = {self.r_inner:g} must be < r_outer = {self.r_outer:g}")
        if self.kind == "file" and self.file is None:
            raise ValueError("kind = 'file' needs file = 'path/to/mesh.msh'")
        if self.size is not None and len(self.size) != (2 if self.kind == "rectangle" else 3):
            raise ValueError(f"size must have {2 if self.kind == 'rectangle' else 3} entries for kind = {self.kind!r}")
        return self


class Material(Section):
    """The hyperelastic law; each law reads its own parameters (`hyperoc.mechanics.materials`), whose ranges it
    checks when the model is built."""

    law: str = Field("svk", description="svk, neo-hookean, fung, ogden, guccione, holzapfel-ogden")
    mu: Optional[Number] = Field(None, description="shear modulus (svk, neo-hookean)")
    lambda_: Optional[Number] = Field(None, alias="lambda", description="Lame's first parameter (svk, neo-hookean)")
    beta: Optional[Number] = Field(None, description="Fung: scale")
    gamma: Optional[Number] = Field(None, description="Fung: exponent")
    W0: Optional[Number] = Field(None, description="Fung: energy offset")
    coefficients: Optional[Numbers] = Field(None, description="Ogden: c_k")
    exponents: Optional[Numbers] = Field(None, description="Ogden: gamma_k")
    C: Optional[Number] = Field(None, description="Guccione: C (kPa)")
    bf: Optional[Number] = Field(None, description="Guccione, Holzapfel-Ogden: fibre exponent")
    bt: Optional[Number] = Field(None, description="Guccione: transverse exponent")
    bfs: Optional[Number] = Field(None, description="Guccione, Holzapfel-Ogden: fibre-sheet exponent")
    a: Optional[Number] = Field(None, description="Holzapfel-Ogden: isotropic modulus (kPa)")
    b: Optional[Number] = Field(None, description="Holzapfel-Ogden: isotropic exponent")
    af: Optional[Number] = Field(None, description="Holzapfel-Ogden: fibre modulus")
    as_: Optional[Number] = Field(None, alias="as", description="Holzapfel-Ogden: sheet modulus")
    bs: Optional[Number] = Field(None, description="Holzapfel-Ogden: sheet exponent")
    afs: Optional[Number] = Field(None, description="Holzapfel-Ogden: fibre-sheet modulus")
    bulk_modulus: Optional[Number] = Field(
        None, description="Guccione, Holzapfel-Ogden: small-strain bulk modulus of the volumetric penalty (kPa)")
    switch_width: Optional[NonNegative] = Field(
        None, description="Holzapfel-Ogden: width w (in I4 - 1) of a C^2 tension-only switch, so that objectives "
                          "of the state are smooth (default 0: the published <I4 - 1>^2)")
    switch_steepness: Optional[NonNegative] = Field(
        None, description="Holzapfel-Ogden: k of the smooth switch 1/(1 + exp(-k (I4 - 1))) several cardiac "
                          "benchmark codes use (k = 100) in place of <I4 - 1>^2 (default 0: the published switch)")
    isochoric: Optional[bool] = Field(
        None, description="Guccione: Q on the isochoric strain (needed with cell-mean); Holzapfel-Ogden: I1bar "
                          "(default) or, false, the full I1 of the cardiac elastodynamics benchmark")
    viscosity: NonNegative = Field(
        0.0, description="eta of the viscous pseudo-potential (eta/2) tr(dE/dt^2) (stress x time, e.g. Pa s)")
    volumetric: Literal["pointwise", "cell-mean"] = Field(
        "pointwise", description="bulk term per quadrature point, or on each cell's mean J (condensed mixed u-p)")

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True, populate_by_name=False)

    def values(self) -> dict:
        dumped = self.model_dump(by_alias=True)
        return {k: v for k, v in dumped.items() if v is not None}


class Robin(Section):
    """``[[dynamics.robin]]``: a spring-dashpot boundary, traction -(k u + c u_t) or its normal part."""

    boundary: str = Field(description="boundary name")
    stiffness: NonNegative = Field(description="spring k (stress / length, e.g. Pa/m)")
    damping: NonNegative = Field(0.0, description="dashpot c (stress x time / length, e.g. Pa s/m)")
    direction: Literal["full", "normal"] = Field("full", description="every component, or the reference normal's")


class BoundaryPressure(Section):
    """``[dynamics.pressure]``: a follower pressure (positive pushes into the body) on a boundary."""

    boundary: str = Field("endocardium", description="boundary name")
    law: TimeLawValue = Field(description="p(t): number, expression of t, {times, values} or {bestel = 'pressure'}")


class Activation(Section):
    """``[dynamics.activation]``: a prescribed active tension T_a(t) along the fibres, beside the control."""

    law: TimeLawValue = Field(description="T_a(t): number, expression of t, {times, values} or "
                                          "{bestel = 'activation'}")


class Cavity(Section):
    """``[dynamics.cavity]``: the cavity whose volume ``constraint = "cavity_volume"`` holds, its multiplier the
    cavity (left-ventricular) pressure acting on the wall."""

    boundary: str = Field("endocardium", description="the cavity's wall (a boundary of the mesh, closed or open on "
                                                     "one rim, which the lid from its centroid closes)")
    volume_change: Optional[TimeLawValue] = Field(
        None, description="dV(t): the cavity volume is held at V(0) + dV(t) (length^3, e.g. m^3); none: at V(0), "
                          "an isovolumic phase; a time law finite on the grid",
        json_schema_extra={"type": "number, expression of t, table or Bestel law"})
    apex: Literal["fixed", "rim"] = Field(
        "fixed", description="the lid's apex: the reference rim's centroid (fixed), or the deformed rim's centroid "
                             "(rim: the volume the benchmark codes and clinicians report; serial path only)")


class CirculationSection(Section):
    """``[dynamics.circulation]``: the lumped circulation closing the cavity of ``constraint = "circulation"``
    (`hyperoc.dynamics.constraint.Circulation`): a Windkessel behind the aortic valve, a constant atrial pressure
    behind the mitral valve; the valves switch by their pressure and flow conditions. Units: the config's
    (SI: Pa, m^3, s)."""

    boundary: str = Field("endocardium", description="the cavity's wall (as in [dynamics.cavity])")
    resistance: Positive = Field(description="Windkessel peripheral resistance R (pressure time / volume, Pa s/m^3)")
    compliance: Positive = Field(description="Windkessel compliance C (volume / pressure, m^3/Pa)")
    characteristic_resistance: NonNegative = Field(
        0.0, description="R_c, the 3-element Windkessel's characteristic resistance (0: 2-element)")
    atrial_pressure: Number = Field(description="p_a, the constant atrial pressure behind the mitral valve")
    mitral_resistance: Positive = Field(description="R_m, the mitral valve's resistance to filling")
    aortic_pressure: Number = Field(description="Pa(0), the Windkessel's pressure at the first level")
    phase: Literal["isovolumic", "ejection", "filling"] = Field(
        "filling", description="the phase at the first level")
    apex: Literal["fixed", "rim"] = Field("fixed", description="the lid's apex (as in [dynamics.cavity])")


class Fibres(Section):
    """Fibre frames for fibre-dependent laws and active stress: the helix-angle rule
    (`hyperoc.mechanics.fibres.rule_based_fibres`), fields from a file (`hyperoc.mechanics.fibres.read_fibres`)
    or the cardiac elastodynamics benchmark's analytic fields
    (`hyperoc.cardiac.benchmark_geometry.benchmark_fibres`)."""

    KIND_KEY: ClassVar[str] = "kind"
    KINDS: ClassVar[dict] = {"none": set(),
                             "rule_based": {"helix_endo", "helix_epi", "long_axis", "inner", "outer"},
                             "file": {"file", "location", "tolerance"},
                             "benchmark": {"inner", "outer"}}

    kind: Literal["none", "rule_based", "file", "benchmark"] = Field(
        "none", description="no fibres, the helix-angle rule (3D), fields from a file, or the benchmark's fields")
    helix_endo: Number = Field(60.0, description="helix angle on the inner wall (degrees)")
    helix_epi: Number = Field(-60.0, description="helix angle on the outer wall (degrees)")
    long_axis: Annotated[list[Number], Field(min_length=3, max_length=3)] = Field(
        [0.0, 0.0, 1.0], description="long axis, apex to base")
    inner: str = Field("endocardium", description="boundary name of the inner wall")
    outer: str = Field("epicardium", description="boundary name of the outer wall")
    file: Optional[str] = Field(
        None, description="fibre and sheet fields (.xdmf, .vtu point or cell data; .npz arrays fibre, sheet), "
                          "relative to the config")
    location: Literal["auto", "node", "cell"] = Field(
        "auto", description="file: one vector per vertex or per cell (auto: from their number)")
    tolerance: Annotated[float, Field(allow_inf_nan=False, gt=0, lt=1)] = Field(
        1e-3, description="file: largest | |f| - 1 |, | |s| - 1 | and |f . s| accepted")

    @model_validator(mode="after")
    def _axis_nonzero(self):
        if self.kind == "rule_based" and not any(self.long_axis):
            raise ValueError("long_axis must not be zero")
        if self.kind == "file" and self.file is None:
            raise ValueError("kind = 'file' needs file = 'path/to/fibres.vtu'")
        return self


class Dynamics(Section):
    """Time interval, damping, density and the time stepping."""

    T: Positive = Field(15.0, description="final time; T / dt must be a whole number")
    dt: Positive = Field(0.02, description="time step")
    damping: NonNegative = Field(2e-4, description="viscous damping kappa (the paper's M y'' + kappa K y' + ...)")
    density: Positive = Field(1.0, description="mass density")
    theta: Annotated[float, Field(allow_inf_nan=False, ge=0.5, le=1.0)] = Field(
        0.5, description="theta scheme: 1/2 Crank-Nicolson, 1 implicit Euler")
    multiplier: Literal["step", "theta"] = Field(
        "step", description="volume multiplier per step, or theta-weighted (comparison with the paper)")
    solver: str = Field(
        "auto", description="linear solver: auto, tridiagonal, dense, lu, lu_reuse, pardiso, ..., minres")
    newton_rtol: Annotated[float, Field(allow_inf_nan=False, gt=0, lt=1)] = Field(
        1e-11, description="Newton's relative residual tolerance")
    newton_max_iter: Count = Field(30, description="Newton iterations per step")
    newton: Literal["auto", "full", "chord"] = Field(
        "auto", description="auto: chord Newton (a kept factorization) with the sparse solvers, full Newton otherwise")
    traction: Optional[Numbers] = Field(None, description="constant traction on gamma_n, one number per dimension")
    constraint: Literal["tissue_volume", "cavity_volume", "circulation", "none"] = Field(
        "tissue_volume", description="the tissue volume held by a multiplier (the paper's); the volume of the cavity "
                                     "of [dynamics.cavity] held by the cavity pressure (the reported pressure, "
                                     "positive pushing the wall out of the cavity); the cavity closed by the lumped "
                                     "circulation of [dynamics.circulation] (the phases of a beat); or none (only "
                                     "the material's bulk term; the reported pressure is then 0)")
    cavity: Optional[Cavity] = Field(None, description="constraint = 'cavity_volume': the cavity, [dynamics.cavity]")
    circulation: Optional[CirculationSection] = Field(
        None, description="constraint = 'circulation': the Windkessel and the valves, [dynamics.circulation]")
    robin: Optional[list[Robin]] = Field(None, description="spring-dashpot boundaries, [[dynamics.robin]] tables")
    pressure: Optional[BoundaryPressure] = Field(None, description="follower pressure p(t) on a boundary")
    activation: Optional[Activation] = Field(None, description="prescribed active tension T_a(t) along the fibres")

    @model_validator(mode="after")
    def _step_fits(self):
        if self.dt > self.T:
            raise ValueError(f"dt = {self.dt:g} must be <= T = {self.T:g}")
        if self.cavity is not None and self.constraint != "cavity_volume":
            raise ValueError(f"[dynamics.cavity] applies to constraint = 'cavity_volume', got {self.constraint!r}")
        if (self.circulation is not None) != (self.constraint == "circulation"):
            raise ValueError("constraint = 'circulation' goes with a [dynamics.circulation] table, and only it")
        return self


class Region(Section):
    """``[control] region``: the control's support (`hyperoc.mechanics.controls.Region`)."""

    kind: Literal["all", "tag", "box", "sector", "cap", "band"] = Field("box", description="region kind")
    tag: Optional[str] = Field(None, description="subdomain name (tag)")
    lower: Optional[Numbers] = Field(None, description="box corner, one number per dimension")
    upper: Optional[Numbers] = Field(None, description="box corner, one number per dimension")
    r_range: Optional[Bounds] = Field(None, description="sector radii")
    theta_range: Optional[Bounds] = Field(None, description="sector polar angles (radians)")
    z_max: Optional[Number] = Field(None, description="cap: cells below this height")
    transmural: Optional[Bounds] = Field(None, description="band: [a, b] in [0, 1] of the transmural coordinate")
    inner: Optional[str] = Field(None, description="band: inner wall")
    outer: Optional[str] = Field(None, description="band: outer wall")

    @model_validator(mode="after")
    def _box_corners(self):
        if self.kind == "box" and (self.lower is None or self.upper is None):
            raise ValueError("region kind 'box' needs lower and upper")
        if self.kind == "box" and (len(self.lower) != len(self.upper)
                                   or not all(a < b for a, b in zip(self.lower, self.upper))):
            raise ValueError(f"region box needs lower < upper in every coordinate, got {self.lower}, {self.upper}")
        return self


class Control(Section):
    """The control operator, and for ``simulate`` the prescribed control."""

    kind: Literal["body_force", "active_stress"] = Field(
        "body_force", description="a body force (one component per dimension) or a fibre active stress (one)")
    region: Optional[Region] = Field(None, description="support of the control (default: the whole body)")
    profile: Optional[ControlProfile] = Field(
        None, description="g(t): dynamics apply the control as g(t) xi(x, t); 'activation': the prescribed tension "
                          "T_a(t) of [dynamics.activation], so that an active-stress xi is dimensionless and the fibre "
                          "tension T_a (1 - xi) (a contraction cannot push: xi <= 1); none: g = 1")
    value: Optional[Expressions] = Field(
        None, description="simulate: xi(x, y, z, r, t) as an expression, or a list with one per component",
        json_schema_extra={"type": "expression(s)"})
    file: Optional[str] = Field(
        None, description="simulate: NPZ file with an array 'xi' (levels, n_ctrl) or (levels, n_nodes, components), "
                          "and optionally its time levels 't' (an optimization's results.npz)")

    @model_validator(mode="after")
    def _one_source(self):
        if self.value is not None and self.file is not None:
            raise ValueError("give value or file, not both")
        return self

    def values(self) -> dict:
        out = super().values()
        if self.region is not None:
            out["region"] = {k: v for k, v in self.region.model_dump().items()
                             if v is not None and k in self.region.model_fields_set | {"kind"}}
        return out


class Objective(Section):
    """J = phi1 - alpha/2 ||xi||^2 - beta/2 ||d xi/dt||^2 (maximized)."""

    KIND_KEY: ClassVar[str] = "phi1"
    KINDS: ClassVar[dict] = {"pressure": {"observation"}, "pressure_rise": {"eps"}, "pressure_mean": {"eps"}}

    phi1: Literal["pressure", "pressure_rise", "pressure_mean"] = Field(
        "pressure", description="p(tau), the rise (p(tau + eps) - p(tau)) / eps, or the mean (1/eps) "
                                "int_tau^{tau+eps} p dt")
    alpha: NonNegative = Field(2e-3, description="weight of the control cost alpha/2 ||xi||^2_{L2(0,T;L2(omega))}")
    beta: NonNegative = Field(
        0.0, description="weight of the cost beta/2 ||d xi/dt||^2_{L2(0,T;L2(omega))} (controls regular in time)")
    eps: NonNegative = Field(0.0, description="pressure_rise, pressure_mean: the length of the window after tau")
    observation: Literal["centred", "causal"] = Field(
        "centred", description="pressure: p(tau) from the step pressures on both sides of tau, or from those "
                               "before it only (causal)")

    @model_validator(mode="after")
    def _window_needs_eps(self):
        if self.phi1 != "pressure" and not self.eps > 0:
            raise ValueError(f"phi1 = '{self.phi1}' needs eps > 0")
        return self


class Optimize(Section):
    """The optimizer of (xi, tau) and its stopping test."""

    KIND_KEY: ClassVar[str] = "method"
    KINDS: ClassVar[dict] = {"bb": {"steps", "bb_step", "nonmonotone"}, "lbfgsb": {"tau_scale"},
                             "newton": {"max_cg", "tau_scale"}}

    method: Literal["bb", "lbfgsb", "newton"] = Field(
        "bb", description="the paper's Algorithm 1 (Barzilai-Borwein), L-BFGS-B, or projected Newton-CG")
    tau0: Optional[Number] = Field(None, description="start of tau (default: T / 2); in (0, T - eps)")
    tau_starts: Optional[Numbers] = Field(None, description="several starts of tau, run in parallel (multi-start)")
    max_iter: Count = Field(100, description="iterations")
    gtol: NonNegative = Field(1e-6, description="stop when ||G|| <= gtol ||G0||")
    xi_bounds: Optional[Bounds] = Field(None, description="pointwise bounds [lower, upper] of xi")
    tau_margin: Optional[Positive] = Field(None, description="tau stays in [margin, T - eps - margin] (default: 2 dt)")
    gradient: Literal["exact", "continuous"] = Field(
        "exact", description="gradient of the discrete J, or the paper's continuous adjoint")
    steps: Literal["joint", "blockwise"] = Field("joint", description="bb: one step for (xi, tau), or one per block")
    bb_step: Literal["bb1", "bb2", "abbmin"] = Field("bb1", description="bb: the step length rule")
    nonmonotone: Annotated[int, Field(ge=0)] = Field(
        0, description="bb: 0 = the paper's Algorithm 1, M > 0 = SPG's nonmonotone window")
    tau_scale: TauScale = Field(
        "range", description="lbfgsb, newton: the scaling c of tau, 'range' (c = 1 without finite bounds), a number, "
                             "or (newton) 'curvature': c^2 = |d^2J/dtau^2| at the start")
    max_cg: Count = Field(20, description="newton: Hessian-vector products per iteration")
    checkpoint_every: Optional[Count] = Field(
        None, description="adjoint memory: keep every k-th level state (recompute the others)")
    checkpoint_snapshots: Optional[Count] = Field(
        None, description="adjoint memory: a binomial schedule with s snapshots")
    horizon: Literal["objective", "full"] = Field(
        "objective", description="solve J up to the last step the objective reads (the same J and gradient), "
                                 "or over [0, T] (controls whose state fails after it are rejected)")

    @model_validator(mode="after")
    def _exclusive(self):
        if self.tau0 is not None and self.tau_starts is not None:
            raise ValueError("give tau0 or tau_starts, not both")
        if self.method == "lbfgsb" and self.tau_scale == "curvature":
            raise ValueError("tau_scale = 'curvature' applies to method newton ('range' or a number for lbfgsb)")
        if self.checkpoint_every is not None and self.checkpoint_snapshots is not None:
            raise ValueError("checkpoint_every and checkpoint_snapshots exclude each other (set one)")
        return self


class OutputUnits(Section):
    """``[output] units``: the units printed on the figures' axes (the computation has none of its
    own); ``"-"`` is dimensionless."""

    time: str = Field("-", description="time, e.g. \"ms\"")
    length: str = Field("-", description="length, e.g. \"mm\" (volumes in length^3)")
    pressure: str = Field("-", description="pressure, e.g. \"kPa\"")
    control: str = Field("-", description="control xi, e.g. \"kPa/mm\" for a body force, \"kPa\" for an active stress")


class Output(Section):
    """What the run writes besides ``summary.json`` and ``results.npz``."""

    snapshot_times: Optional[Annotated[list[NonNegative], Field(min_length=1)]] = Field(
        None, description="1D figures: times of the displacement snapshots, in [0, T]")
    series_every: Optional[Count] = Field(None, description="time series: every k-th level")
    checkpoint_every: Optional[Count] = Field(
        None, description="simulate: save the solve every k time steps in OUT/segments, so that `hyperoc simulate "
                          "--resume OUT` continues an interrupted run (bitwise the same result)")
    units: OutputUnits = Field(
        OutputUnits(), description="figure axes: units of time, length, pressure and control (a table, see "
                                   "[output.units]; each \"-\", dimensionless, unless given)")


class ConfigSchema(BaseModel):
    """A whole configuration, with the rules that tie sections together."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    mesh: Mesh = Mesh()
    material: Material = Material()
    fibres: Fibres = Fibres()
    dynamics: Dynamics = Dynamics()
    control: Control = Control()
    objective: Objective = Objective()
    optimize: Optimize = Optimize()
    output: Output = Output()

    @model_validator(mode="after")
    def _times_inside(self):
        # tau0 and tau_starts are checked by the commands that read them (`hyperoc.app.config.Config.tau_starts`)
        T, eps = self.dynamics.T, self.objective.eps
        if not T - eps > 0:
            raise ValueError(f"[objective] eps = {eps:g} must be < T = {T:g}")
        late = [t for t in self.output.snapshot_times or [] if t > T]
        if late:
            raise ValueError(f"[output] snapshot_times must lie in [0, T = {T:g}], got {late[0]:g}")
        return self


SECTIONS = {name: field.annotation for name, field in ConfigSchema.model_fields.items()}


def validate_sections(data: dict) -> dict:
    """``{section: {key: value}}`` of a config dict as read from TOML: the applicable keys of each
    section with their defaults; the first violation of the schema raises `InputError`."""
    if not isinstance(data, dict):
        raise InputError("config: expected a table of sections")
    _reject_renamed(data)
    try:
        schema = ConfigSchema.model_validate(data)
    except ValidationError as err:
        raise InputError(_message(err.errors()[0])) from None
    return {name: getattr(schema, name).values() for name in SECTIONS}


#: ``(section, old key) -> new key``: keys renamed since 0.1.0, reported by their new name
RENAMED = {("dynamics", "kappa"): "damping", ("material", "kappa"): "bulk_modulus"}


def _reject_renamed(data: dict) -> None:
    """`InputError` naming the new key if ``data`` uses a key of `RENAMED` (a config written for 0.1.0)."""
    for (section, old), new in RENAMED.items():
        table = data.get(section)
        if isinstance(table, dict) and old in table:
            raise InputError(f"config: [{section}] {old} is now called {new}")


_TYPE_WORDS = {"int": "an integer", "float": "a number", "bool": "true or false", "string": "a string",
               "list": "a list", "dict": "a table", "model": "a table"}


def _message(error: dict) -> str:
    """One line for pydantic's ``error`` (its first one): ``config: [section] key <what is wrong>``."""
    loc = [p for p in error["loc"] if not str(p).startswith("function-")]
    where = "config: " + (f"[{loc[0]}] " if loc else "") + _key_text(loc[1:])
    kind, ctx, value = error["type"], error.get("ctx", {}), error.get("input")
    if kind == "extra_forbidden":
        if len(loc) == 1:
            return f"config: unknown section [{loc[0]}]; allowed: {', '.join(SECTIONS)}"
        model = _model_at(loc[:-1])
        keys = ", ".join(f.alias or k for k, f in model.model_fields.items()) if model else ""
        table = f"[{loc[0]}] " + _key_text(loc[1:-1])
        return f"config: {table}unknown key {quote(loc[-1], 40)}" + (f" (keys: {keys})" if keys else "")
    if kind == "value_error":
        return f"{where}{str(ctx.get('error', error['msg']))}"
    return f"{where}{_requirement(kind, ctx)}, got {_value_text(value)}"


def _key_text(path: list) -> str:
    """``key``, ``key[0]`` or ``region lower[1]`` followed by a space ("" for no key)."""
    text = ""
    for p in path:
        text += f"[{p}]" if isinstance(p, int) else f"{' ' if text else ''}{p}"
    return text + " " if text else ""


def _model_at(path: list):
    """The section model (or sub-table model) at a location of the config, if any."""
    model = ConfigSchema
    for name in path:
        field = model.model_fields.get(name) if isinstance(name, str) else None
        inner = [a for a in (field.annotation, *typing.get_args(field.annotation)) if isinstance(a, type)
                 and issubclass(a, BaseModel)] if field else []
        if not inner:
            return None
        model = inner[0]
    return model


def _requirement(kind: str, ctx: dict) -> str:
    bounds = {"greater_than": ("gt", ">"), "greater_than_equal": ("ge", ">="), "less_than": ("lt", "<"),
              "less_than_equal": ("le", "<=")}
    if kind in bounds:
        name, sign = bounds[kind]
        return f"must be {sign} {ctx[name]:g}"
    if kind == "finite_number":
        return "must be a finite number"
    if kind == "literal_error":
        return f"must be {ctx['expected']}"
    if kind in ("too_short", "too_long"):
        count = "at least " + str(ctx["min_length"]) if kind == "too_short" else "at most " + str(ctx["max_length"])
        return f"must have {count} item(s)"
    if kind == "missing":
        return "is required"
    word = _TYPE_WORDS.get(kind.split("_")[0])
    return f"must be {word}" if word else "is invalid"


def _value_text(value) -> str:
    return f"{type(value).__name__} {quote(value)}" if isinstance(value, (str, bool, list, dict)) else quote(value)


# --- the reference ----------------------------------------------------------------------------------
def reference_markdown() -> str:
    """The configuration reference in Markdown: one table per section (key, type, default,
    constraint, description), generated from the schema."""
    parts = ["# Configuration reference", "",
             "A run is configured by a TOML file with the sections below (all optional; `examples/` has complete "
             "files). Numbers must be finite; an integer is accepted where a number is expected. A key that "
             "applies to some kinds only (the constraint column says which) is an error for the others, "
             "unless it holds its default value. "
             "`--set SECTION.KEY=VALUE` overrides an entry. This page is generated by "
             "`python -m hyperoc.app.config --reference`.", "",
             "**Paths.** A relative path (every key named `file`: `[mesh] file`, `[control] file`) is taken from "
             "the folder of the configuration file that holds it; one given with `--set` is taken from the working "
             "directory. A run records them as absolute paths in `OUT/config.toml`; a missing file is reported "
             "with the path it resolved to.", "",
             "**Replay, resume, extend.** `[control] file` replays a run's control: an optimization's "
             "`results.npz` is a control file as written (its `xi`, and its time levels `t`, on which the replay "
             "steps). `optimize --resume OUT` continues the run recorded in `OUT/config.toml`; with `--set` it "
             "may change only `optimize.max_iter` and `optimize.gtol` (extend a run that stopped at its budget), "
             "and refuses any other change, naming the key. See the getting-started page.", ""]
    for name, model in SECTIONS.items():
        parts += _section_table(name, model)
    parts += _section_table("control.region", Region)
    parts += _section_table("output.units", OutputUnits)
    parts += _section_table("dynamics.robin", Robin)
    parts += _section_table("dynamics.pressure", BoundaryPressure)
    parts += _section_table("dynamics.cavity", Cavity)
    parts += _section_table("dynamics.circulation", CirculationSection)
    parts += _section_table("dynamics.activation", Activation)
    parts += ["A time `law` is a number (constant), an expression of `t` (e.g. `\"1e3*sin(pi*t)\"`), a table "
              "`{ times = [...], values = [...] }` (piecewise linear, times strictly increasing, constant outside) or "
              "the benchmark's Bestel ODE `{ bestel = \"pressure\" }` / `{ bestel = \"activation\" }` with optional "
              "`t_end` (s, default 1) and `parameters` (a table overriding `hyperoc.dynamics.laws.BESTEL_PRESSURE` / "
              "`BESTEL_ACTIVATION`; SI units).", ""]
    return "\n".join(parts)


def _section_table(name: str, model) -> list:
    lines = [f"## [{name}]", "", " ".join((model.__doc__ or "").split()), "",
             "| key | type | default | constraint | description |", "|---|---|---|---|---|"]
    for key, field in model.model_fields.items():
        shown = field.alias or key
        row = [f"`{shown}`", _type_text(field), _default_text(field), _constraint_text(model, key, field),
               (field.description or "").replace("|", "\\|")]
        lines.append("| " + " | ".join(row) + " |")
    return lines + [""]


def _type_text(field) -> str:
    extra = field.json_schema_extra or {}
    if "type" in extra:
        return extra["type"]
    return _annotation_text(field.annotation)


def _annotation_text(annotation) -> str:
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Annotated:
        return _annotation_text(args[0])
    if origin is typing.Union:
        return " or ".join(_annotation_text(a) for a in args if a is not type(None))
    if origin is Literal:
        return "integer" if all(isinstance(a, int) for a in args) else "string"
    if origin is list:
        return f"list of {_annotation_text(args[0])}s"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "table"
    return {int: "integer", float: "number", str: "string", bool: "boolean"}.get(annotation, str(annotation))


def _default_text(field) -> str:
    if field.is_required():
        return "required"
    if field.default is None or isinstance(field.default, BaseModel):
        return "-"
    return f"`{json.dumps(field.default)}`"


def _constraint_text(model, key: str, field) -> str:
    parts = []
    for meta in _metadata(field.annotation) + list(field.metadata):
        for attr, sign in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            if isinstance(meta, getattr(at, attr.capitalize())):
                parts.append(f"{sign} {getattr(meta, attr):g}")
    choices = _literal_choices(field.annotation)
    if choices:
        parts.append("one of " + ", ".join(f"`{c}`" for c in choices))
    if model.KIND_KEY and key in model.kind_specific():
        kinds = [k for k, keys in model.KINDS.items() if key in keys]
        parts.append(f"{model.KIND_KEY} = " + " or ".join(f"`{k}`" for k in kinds))
    return "; ".join(parts) or "-"


def _metadata(annotation) -> list:
    out = []
    if typing.get_origin(annotation) is Annotated:
        args = typing.get_args(annotation)
        out += [m for m in args[1:]]
        for m in args[1:]:
            out += list(getattr(m, "metadata", []))
        out += _metadata(args[0])
    elif typing.get_origin(annotation) is typing.Union:
        for a in typing.get_args(annotation):
            out += _metadata(a)
    return out


def _literal_choices(annotation) -> tuple:
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Literal:
        return args
    if origin in (Annotated, typing.Union):
        for a in args if origin is typing.Union else args[:1]:
            found = _literal_choices(a)
            if found:
                return found
    return ()

"""Hyperelastic strain energies ``W(E)`` and their automatic derivatives.

A material is a frozen dataclass of parameters with one method, ``energy(E, frame)``: the strain
energy density per unit reference volume as a function of the Green-Lagrange strain
``E = (F^T F - I) / 2`` (a JAX-traceable function of one symmetric (d, d) matrix). ``frame`` is a
(k, d) array of unit material directions (fibre, sheet, ...) at the point, ignored by isotropic
laws. Stresses and tangents are never written by hand: ``P = dW/dF`` and ``dP/dF`` come from JAX.

Adding a law takes a few lines::

    @dataclass(frozen=True)
    class MooneyRivlinLike(Material):
        c1: float = 1.0
        def energy(self, E, frame=None):
            return self.c1 * jnp.trace(E @ E)

Units: moduli in the pressure unit of the model (the paper's 1D case is dimensionless; the
cardiac examples use kPa with lengths in mm).

Fibre-dependent laws (`Guccione`, `HolzapfelOgden`) read the rows of ``frame`` as the fibre ``f``,
sheet ``s`` and sheet-normal ``n`` directions (in 2D only ``f, s``), e.g. from
`hyperoc.mechanics.fibres.rule_based_fibres` passed as ``StateModel(frames=...)``. Their compressible forms
add the volumetric penalty ``U(J) = bulk_modulus/4 (J^2 - 1 - 2 ln J)`` (Simo-Taylor), ``J = sqrt(det C)``:
``U(1) = U'(1) = 0`` and ``U''(1) = bulk_modulus``, the small-strain bulk modulus.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from functools import partial

import numpy as np

from .._lazy import jax, jnp  # JAX on first use: checking a material's parameters does not start it
from ..errors import InputError

__all__ = [
    "Material",
    "SaintVenantKirchhoff",
    "Fung",
    "Ogden",
    "NeoHookean",
    "Guccione",
    "HolzapfelOgden",
    "first_piola",
    "tangent_modulus",
    "material_from_config",
    "MATERIALS",
]


class Material:
    """Base class: subclasses are frozen dataclasses that implement ``energy(E, frame)``."""

    def energy(self, E, frame=None):  # pragma: no cover - interface
        raise NotImplementedError

    def validate(self) -> "Material":
        """Raise `InputError` on unphysical parameters; return self."""
        return self

    def energy_of_F(self, F, frame=None):
        """``W(E(F))`` with ``E = (F^T F - I) / 2``."""
        E = 0.5 * (F.T @ F - jnp.eye(F.shape[0]))
        return self.energy(E, frame)

    def volumetric_split(self):
        """``(rest, U)`` with ``W(E) = rest.energy(E) + U(J)``, ``J = det F``, U a scalar function of J
        that carries the law's bulk stiffness; None for U when the law has no such term. Used by
        `hyperoc.mechanics.model.StateModel` ``volumetric="cell-mean"`` to average J over each cell."""
        return self, None


def det(F):
    """Determinant of a (..., d, d) array, d <= 3, by explicit formulas (cheap, smooth autodiff)."""
    d = F.shape[-1]
    if d == 1:
        return F[..., 0, 0]
    if d == 2:
        return F[..., 0, 0] * F[..., 1, 1] - F[..., 0, 1] * F[..., 1, 0]
    return (
        F[..., 0, 0] * (F[..., 1, 1] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 1])
        - F[..., 0, 1] * (F[..., 1, 0] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 0])
        + F[..., 0, 2] * (F[..., 1, 0] * F[..., 2, 1] - F[..., 1, 1] * F[..., 2, 0])
    )


def _require(cond: bool, msg: str) -> None:
    if not cond:
        raise InputError(msg)


@dataclass(frozen=True)
class SaintVenantKirchhoff(Material):
    """``W = mu tr(E^2) + lambda/2 tr(E)^2`` (paper eq. ``Lame-model``). Requires mu > 0, lambda >= 0.

    Loses rank-one convexity in strong compression (1D: at ``u_x = -1 + 1/sqrt(3)``).
    """

    mu: float = 0.05
    lam: float = 0.05

    def energy(self, E, frame=None):
        return self.mu * jnp.trace(E @ E) + 0.5 * self.lam * jnp.trace(E) ** 2

    def validate(self):
        _require(self.mu > 0, f"Saint Venant-Kirchhoff: mu must be > 0, got {self.mu}")
        _require(self.lam >= 0, f"Saint Venant-Kirchhoff: lambda must be >= 0, got {self.lam}")
        return self


@dataclass(frozen=True)
class Fung(Material):
    """``W = W0 + beta (exp(gamma tr(E^2)) - 1)``; beta > 0, gamma > 0, W0 >= 0."""

    beta: float = 0.05
    gamma: float = 1.0
    W0: float = 0.0

    def energy(self, E, frame=None):
        return self.W0 + self.beta * (jnp.exp(self.gamma * jnp.trace(E @ E)) - 1.0)

    def validate(self):
        _require(self.beta > 0, f"Fung: beta must be > 0, got {self.beta}")
        _require(self.gamma > 0, f"Fung: gamma must be > 0, got {self.gamma}")
        _require(self.W0 >= 0, f"Fung: W0 must be >= 0, got {self.W0}")
        return self


@dataclass(frozen=True)
class Ogden(Material):
    """``W = sum_k c_k tr(C^gamma_k - I)`` with ``C = 2E + I`` (paper appendix, sum of terms).

    Note: with this (paper's) form the reference configuration carries the isotropic stress
    ``Sigma(0) = sum_k 2 gamma_k c_k I``, which the volume multiplier balances at rest
    (``p = -sum_k 2 gamma_k c_k``). Coercive for c_k > 0 and gamma_k >= 1 (paper).
    """

    coefficients: tuple = (0.025,)
    exponents: tuple = (2.0,)

    def energy(self, E, frame=None):
        C = 2.0 * E + jnp.eye(E.shape[0])
        return sum(c * (_trace_power(C, g) - E.shape[0]) for c, g in zip(self.coefficients, self.exponents))

    def validate(self):
        _require(len(self.coefficients) == len(self.exponents) >= 1,
                 "Ogden: need as many coefficients as exponents (>= 1)")
        _require(all(c > 0 for c in self.coefficients), f"Ogden: coefficients must be > 0, got {self.coefficients}")
        _require(all(g >= 1 for g in self.exponents), f"Ogden: exponents must be >= 1, got {self.exponents}")
        return self


@dataclass(frozen=True)
class NeoHookean(Material):
    """Compressible neo-Hookean ``W = mu/2 (tr C - d) - mu ln J + lambda/2 (ln J)^2``, ``J = sqrt(det C)``."""

    mu: float = 0.05
    lam: float = 0.05

    def energy(self, E, frame=None):
        d = E.shape[0]
        C = 2.0 * E + jnp.eye(d)
        logJ = 0.5 * jnp.log(det(C))
        return 0.5 * self.mu * (jnp.trace(C) - d) - self.mu * logJ + 0.5 * self.lam * logJ**2

    def volumetric_split(self):
        """The ``lambda/2 (ln J)^2`` term as U; the rest keeps ``mu`` (and its ``-mu ln J``)."""
        return replace(self, lam=0.0), lambda J: 0.5 * self.lam * jnp.log(J) ** 2

    def validate(self):
        _require(self.mu > 0, f"neo-Hookean: mu must be > 0, got {self.mu}")
        _require(self.lam >= 0, f"neo-Hookean: lambda must be >= 0, got {self.lam}")
        return self


# --- fibre-dependent laws (cardiac tissue, kPa) ----------------------------------------------------

def penalty(bulk_modulus, J):
    """``U(J) = bulk_modulus/4 (J^2 - 1 - 2 ln J)``; U(1) = U'(1) = 0, U''(1) = bulk_modulus (Simo-Taylor)."""
    return _penalty_of_J2(bulk_modulus, J * J)


def _penalty_of_J2(bulk_modulus, J2):
    return 0.25 * bulk_modulus * (J2 - 1.0 - jnp.log(J2))


def _volumetric(bulk_modulus, C):
    """`penalty` from ``J^2 = det C``; exactly 0 (not traced) when bulk_modulus = 0, the split-off rest."""
    return _penalty_of_J2(bulk_modulus, det(C)) if bulk_modulus else 0.0


def _split_penalty(material):
    """``(material without its penalty, U)`` for the laws with a ``bulk_modulus`` field."""
    return replace(material, bulk_modulus=0.0), partial(penalty, material.bulk_modulus)


def _frame_rows(frame, k: int, law: str):
    """The first k rows of the material frame; `InputError` if there are fewer."""
    if frame is None or frame.shape[0] < k:
        got = "none" if frame is None else f"{frame.shape[0]} row(s)"
        raise InputError(f"{law} needs a material frame with >= {k} unit direction(s) (fibre, sheet, ...) "
                         "at every point, e.g. StateModel(frames=hyperoc.mechanics.fibres.rule_based_fibres(mesh)); "
                         f"got {got}")
    return frame[:k]


def _check_moduli(law: str, positive: dict, nonnegative: dict | None = None) -> None:
    """`InputError` unless every ``positive`` value is finite and > 0 and every ``nonnegative`` one >= 0."""
    for name, v in positive.items():
        _require(math.isfinite(v) and v > 0, f"{law}: {name} must be a finite number > 0, got {v}")
    for name, v in (nonnegative or {}).items():
        _require(math.isfinite(v) and v >= 0, f"{law}: {name} must be a finite number >= 0, got {v}")


@dataclass(frozen=True)
class Guccione(Material):
    """Transversely isotropic Guccione law (Guccione, McCulloch & Waldman 1991), compressible form.

    ``W = C/2 (exp(Q) - 1) + bulk_modulus/4 (J^2 - 1 - 2 ln J)``, ``J = sqrt(det(2E + I))``, with

    ``Q = bf E_ff^2 + bt (E_ss^2 + E_nn^2 + 2 E_sn^2) + bfs (2 E_fs^2 + 2 E_fn^2)``, ``E_ab = a . E b``,

    evaluated from the fibre ``f = frame[0]`` alone as ``Q = bf (f.Ef)^2 + bt |P E P|^2 + 2 bfs |P E f|^2``
    with ``P = I - f f^T`` (equal to the component form for any orthonormal ``(f, s, n)``: the law is
    transversely isotropic about f). Works in 1D-3D; stress free at E = 0.

    ``isochoric=True``: Q from the isochoric strain ``Ebar = (J^(-2/d) C - I) / 2`` instead of E (the
    Simo-Taylor-Pister split ``W = W_iso(Cbar) + U(J)``). The same law at J = 1, so the same
    incompressible limit, but a different compressible one: the bulk response is U alone, and at
    a given bulk modulus the body is more compressible (on Land problem 2, use bulk_modulus >= 1e4 kPa with it
    to stay close to the incompressible limit). Without U, the exponential part
    then grows without bound as a point is compressed to J -> 0, unless it keeps its shape (``Cbar``
    bounded, e.g. a pure dilatation): uniaxially (``F = diag(lambda, 1, 1)``) the transverse
    ``Ebar_22 = Ebar_33 ~ lambda^(-2/3) / 2``. On E it stays bounded (``|E_ij| <= 1/2`` as F -> 0)
    and loses ellipticity in uniaxial compression below the stretch where
    ``lambda^6 - 2 lambda^4 + 4 lambda^2 = 1`` (0.534 for bf = 1). Use it with
    `hyperoc.mechanics.model.StateModel` ``volumetric="cell-mean"``, which takes the bulk term off the points.

    Units: C and bulk_modulus in kPa, bf, bt, bfs dimensionless. Defaults: Land et al. (2015) problems 1
    and 3 (C = 2 kPa, bf = 8, bt = 2, bfs = 4); problem 2 is C = 10 kPa, bf = bt = bfs = 1. The
    benchmark is incompressible; here ``bulk_modulus`` (kPa, >= 0, default 1000 = 500 C; ``Q`` alone
    already penalizes every strain) approximates it, and P1 elements lock as bulk_modulus / C grows.
    """

    C: float = 2.0
    bf: float = 8.0
    bt: float = 2.0
    bfs: float = 4.0
    bulk_modulus: float = 1000.0
    isochoric: bool = False

    def energy(self, E, frame=None):
        f = _frame_rows(frame, 1, "Guccione")[0]
        C = 2.0 * E + jnp.eye(E.shape[0])
        volumetric = _volumetric(self.bulk_modulus, C)
        if self.isochoric:
            E = 0.5 * (det(C) ** (-1.0 / E.shape[0]) * C - jnp.eye(E.shape[0]))
        P = jnp.eye(E.shape[0]) - jnp.outer(f, f)
        Ef = E @ f
        PEf, PEP = P @ Ef, P @ E @ P
        Q = self.bf * (f @ Ef) ** 2 + self.bt * jnp.sum(PEP * PEP) + 2.0 * self.bfs * (PEf @ PEf)
        return 0.5 * self.C * jnp.expm1(Q) + volumetric

    volumetric_split = _split_penalty

    def validate(self):
        _check_moduli("Guccione", {"C": self.C, "bf": self.bf, "bt": self.bt, "bfs": self.bfs},
                      {"bulk_modulus": self.bulk_modulus})
        _require(isinstance(self.isochoric, bool), f"Guccione: isochoric must be True or False, got {self.isochoric!r}")
        return self


def tension_square(x, width: float = 0.0):
    """``<x>^2 = max(x, 0)^2`` (width 0), or its C^2 switch of width ``w > 0``: 0 for ``x <= 0``, ``x^2`` for
    ``x >= w`` and ``w^2 q(x / w)`` between, ``q(s) = 3 s^3 - 3 s^4 + s^5`` (the quintic with q, q', q'' equal
    to those of ``s^2`` at 1 and to 0 at 0: convex and increasing, below ``x^2`` by at most ``0.035 w^2``).
    Works on JAX and NumPy values; x dimensionless (``I4 - 1``)."""
    if width == 0.0:
        return jnp.where(x > 0.0, x, 0.0) ** 2
    r = jnp.clip(x / width, 0.0, 1.0)
    blend = width**2 * r**3 * (3.0 - 3.0 * r + r**2)
    return jnp.where(x >= width, x**2, blend)


@dataclass(frozen=True)
class HolzapfelOgden(Material):
    """Orthotropic Holzapfel-Ogden law (Holzapfel & Ogden 2009, Phil. Trans. R. Soc. A 367), with an
    isochoric ``I1`` (the common compressible form) or, with ``isochoric=False``, the full ``I1 = tr C``
    (the cardiac elastodynamics benchmark's form, Aróstica et al. 2025, CMAME 435:117485; it is not
    stress free: at E = 0 the second Piola stress is ``a I``, 59 Pa with the benchmark's parameters).

    ``W = a/(2b) (exp(b (I1bar - d)) - 1)
        + af/(2bf) (exp(bf <I4f - 1>^2) - 1) + as/(2bs) (exp(bs <I4s - 1>^2) - 1)
        + afs/(2bfs) (exp(bfs I8fs^2) - 1) + bulk_modulus/4 (J^2 - 1 - 2 ln J)``

    with ``C = 2E + I``, ``J^2 = det C``, ``I1bar = J^(-2/d) tr C``, ``I4f = f.Cf``, ``I4s = s.Cs``,
    ``I8fs = f.Cs`` (``f, s`` = rows 0, 1 of the frame; d = 2 or 3), and ``<x> = max(x, 0)``: fibres
    and sheets bear load only when stretched. Only the isotropic term is isochoric; the fibre terms
    use the full invariants, as is common (with isochoric I4bar a compressible anisotropic body
    answers a hydrostatic load by a pure dilatation, Sansour 2008). Stress free at E = 0 when isochoric.

    The frame must be orthonormal: the code evaluates ``I4 - 1 = 2 a.E a`` and ``I8fs = 2 f.E s``
    (equal for such frames), which vanish exactly at E = 0 whatever the round-off in ``|f|``.

    Smoothness: ``<x>^2`` is C^1 with a second derivative that jumps from 0 to 2 at ``x = 0``; the
    tangent exists everywhere (Newton and the adjoint only need it piecewise continuous) and at
    ``I4 = 1`` exactly it is the compression (left) limit 0, so the reference tangent (E = 0) has no
    fibre or sheet contribution. The stress then has a kink where a quadrature point crosses ``I4 = 1``,
    so a state, and an objective of it, is only piecewise differentiable in the loads: an optimizer's
    projected gradient jumps there. ``switch_width = w > 0`` replaces ``<x>^2`` by the C^2 switch
    (`tension_square`) equal to it outside ``(0, w)``: then the stress is C^1 and the objective's gradient
    continuous; ``w = 0`` (default) is the law as published.

    ``switch_steepness = k > 0`` takes instead the smooth switch several of the cardiac benchmark's participating
    codes use (Simula's, SimVascular's ``HolzapfelOgden-ModifiedAnisotropy``, k = 100): the fibre and sheet terms
    ``a_i/(2b_i) chi_k(I4_i) (exp(b_i (I4_i - 1)^2) - 1)``, ``chi_k(I4) = 1 / (1 + exp(-k (I4 - 1)))``. Unlike
    ``<I4 - 1>^2`` it resists shortening near ``I4 = 1`` (``chi = 1/2`` there) and softens the stretch just above
    it; with ``k = 0`` (default) the published switch. ``switch_width`` and ``switch_steepness`` exclude each
    other.

    Units: a, af, as, afs, bulk_modulus in stress units (kPa with mm; Pa with m: the benchmark's a = 59 Pa,
    af = 18472 Pa, as = 2481 Pa, afs = 216 Pa, bulk_modulus = 1e6 Pa); b, bf, bs, bfs dimensionless.
    Defaults: the 2009 fit to Dokos et al. shear data (a = 0.059, b = 8.023, af = 18.472, bf = 16.026,
    as = 2.481, bs = 11.120, afs = 0.216, bfs = 11.436, kPa); ``as_`` is spelled ``as`` in configs.
    """

    a: float = 0.059
    b: float = 8.023
    af: float = 18.472
    bf: float = 16.026
    as_: float = 2.481
    bs: float = 11.120
    afs: float = 0.216
    bfs: float = 11.436
    bulk_modulus: float = 1000.0
    isochoric: bool = True
    switch_width: float = 0.0
    switch_steepness: float = 0.0

    def _tension_term(self, a_i, b_i, x):
        """One fibre or sheet term of W for ``x = I4 - 1`` (class docstring: the published, C^2 or sigmoid switch)."""
        if self.switch_steepness > 0.0:
            return a_i / (2 * b_i) * jax.nn.sigmoid(self.switch_steepness * x) * jnp.expm1(b_i * x**2)
        return a_i / (2 * b_i) * jnp.expm1(b_i * tension_square(x, self.switch_width))

    def energy(self, E, frame=None):
        f, s = _frame_rows(frame, 2, "Holzapfel-Ogden")
        d = E.shape[0]
        C = 2.0 * E + jnp.eye(d)
        I1bar = det(C) ** (-1.0 / d) * jnp.trace(C) if self.isochoric else jnp.trace(C)
        # I4 - 1 = 2 a.E a and I8 = 2 f.E s for a unit, orthogonal frame: exactly 0 at E = 0.
        return (self.a / (2 * self.b) * jnp.expm1(self.b * (I1bar - d))
                + self._tension_term(self.af, self.bf, 2.0 * (f @ E @ f))
                + self._tension_term(self.as_, self.bs, 2.0 * (s @ E @ s))
                + self.afs / (2 * self.bfs) * jnp.expm1(self.bfs * (2.0 * (f @ E @ s)) ** 2)
                + _volumetric(self.bulk_modulus, C))

    volumetric_split = _split_penalty

    def validate(self):
        _check_moduli("Holzapfel-Ogden",
                      {"a": self.a, "b": self.b, "bf": self.bf, "bs": self.bs, "bfs": self.bfs,
                       "bulk_modulus": self.bulk_modulus},
                      {"af": self.af, "as": self.as_, "afs": self.afs, "switch_width": self.switch_width,
                       "switch_steepness": self.switch_steepness})
        _require(isinstance(self.isochoric, bool),
                 f"Holzapfel-Ogden: isochoric must be True or False, got {self.isochoric!r}")
        _require(self.switch_width == 0.0 or self.switch_steepness == 0.0,
                 "Holzapfel-Ogden: give switch_width or switch_steepness, not both")
        return self


# --- spectral functions with robust derivatives (Ogden) -----------------------------------------

def _power_divided_difference(li, lj, a):
    """``(li^a - lj^a) / (li - lj)``, computed without cancellation; ``a li^(a-1)`` when equal."""
    r = (li - lj) / lj
    safe_r = jnp.where(r == 0.0, 1.0, r)
    ratio = jnp.where(r == 0.0, a, jnp.expm1(a * jnp.log1p(safe_r)) / safe_r)
    return lj ** (a - 1.0) * ratio


def _trace_power(C, gamma):
    """``tr(C^gamma)`` for symmetric positive definite C, differentiable twice even at C = I."""

    @jax.custom_jvp
    def tr_pow(C):
        return jnp.sum(jnp.linalg.eigvalsh(C) ** gamma)

    @jax.custom_jvp
    def dtr_pow(C):  # d tr(C^g) / dC = g C^(g-1)
        lam, V = jnp.linalg.eigh(C)
        return (V * (gamma * lam ** (gamma - 1.0))) @ V.T

    @tr_pow.defjvp
    def _(primals, tangents):
        (C,), (dC,) = primals, tangents
        return tr_pow(C), jnp.sum(dtr_pow(C) * dC)

    @dtr_pow.defjvp
    def _(primals, tangents):
        # Daleckii-Krein: d f(C) = V (Gamma o (V^T dC V)) V^T with Gamma the divided differences of f.
        (C,), (dC,) = primals, tangents
        lam, V = jnp.linalg.eigh(C)
        gamma_ij = gamma * _power_divided_difference(lam[:, None], lam[None, :], gamma - 1.0)
        return dtr_pow(C), V @ (gamma_ij * (V.T @ dC @ V)) @ V.T

    return tr_pow(C)


# --- point-wise derivatives -----------------------------------------------------------------------

def first_piola(material: Material, F, frame=None):
    """First Piola-Kirchhoff stress ``P = dW/dF = F Sigma`` at one point, (d, d)."""
    return jax.grad(material.energy_of_F)(F, frame)


def tangent_modulus(material: Material, F, frame=None):
    """``dP/dF`` at one point, (d, d, d, d), indices ``[i, J, k, L] = d P_iJ / d F_kL``."""
    return jax.hessian(material.energy_of_F)(F, frame)


MATERIALS = {
    "svk": SaintVenantKirchhoff,
    "saint-venant-kirchhoff": SaintVenantKirchhoff,
    "fung": Fung,
    "ogden": Ogden,
    "neo-hookean": NeoHookean,
    "neohookean": NeoHookean,
    "guccione": Guccione,
    "holzapfel-ogden": HolzapfelOgden,
}

_ALIASES = {"lambda": "lam", "as": "as_"}  # config spellings of field names


def material_from_config(cfg: dict) -> Material:
    """Build a material from ``{"law": "svk", "mu": 0.05, "lambda": 0.05, ...}`` (``"as"`` for ``as_``;
    switches such as Guccione's ``isochoric`` take true or false)."""
    cfg = dict(cfg)
    law = str(cfg.pop("law", "svk")).lower()
    if law not in MATERIALS:
        raise InputError(f"unknown material law {law!r}; choose one of {sorted(set(MATERIALS))}")
    cls = MATERIALS[law]
    clashes = [k for k in cfg if k in _ALIASES and _ALIASES[k] in cfg]
    if clashes:
        raise InputError(f"material {law!r}: give {clashes[0]!r} or {_ALIASES[clashes[0]]!r}, not both")
    cfg = {_ALIASES.get(k, k): v for k, v in cfg.items()}
    names = {f.name for f in fields(cls)}
    unknown = set(cfg) - names
    if unknown:
        raise InputError(f"material {law!r}: unknown parameter(s) {sorted(unknown)}; expected {sorted(names)}")
    is_number = lambda x: isinstance(x, (int, float)) and not isinstance(x, bool) and bool(np.isfinite(x))
    defaults = {f.name: f.default for f in fields(cls)}
    kwargs = {}
    for k, v in cfg.items():
        if isinstance(defaults[k], bool):  # a switch (Guccione isochoric)
            if not isinstance(v, bool):
                raise InputError(f"material {law!r}: {k} must be true or false, got {type(v).__name__} {v!r}")
            kwargs[k] = v
        elif isinstance(defaults[k], tuple):  # a list parameter (Ogden terms)
            if not (isinstance(v, (list, tuple)) and v and all(is_number(x) for x in v)):
                raise InputError(f"material {law!r}: {k} must be a non-empty list of finite numbers, got {v!r}")
            kwargs[k] = tuple(float(x) for x in v)
        elif is_number(v):
            kwargs[k] = float(v)
        else:
            raise InputError(f"material {law!r}: {k} must be a finite number, got {type(v).__name__} {v!r}")
    return cls(**kwargs).validate()


def finite_difference_check(material: Material, F: np.ndarray, h: float = 1e-6, frame=None) -> tuple[float, float]:
    """Errors of autodiff ``P`` and ``dP/dF`` against central differences of ``W`` and ``P``,
    relative to ``max(|dP/dF|, |P|)``; ``frame`` (k, d) for fibre-dependent laws."""
    F = np.asarray(F, dtype=np.float64)
    d = F.shape[0]
    frame = None if frame is None else jnp.asarray(frame, dtype=jnp.float64)
    W = lambda G: float(material.energy_of_F(jnp.asarray(G), frame))
    P_at = lambda G: np.asarray(first_piola(material, jnp.asarray(G), frame))
    P = P_at(F)
    A = np.asarray(tangent_modulus(material, jnp.asarray(F), frame))
    P_fd, A_fd = np.zeros_like(P), np.zeros_like(A)
    for k in range(d):
        for L in range(d):
            dF = np.zeros_like(F)
            dF[k, L] = h
            P_fd[k, L] = (W(F + dF) - W(F - dF)) / (2 * h)
            A_fd[:, :, k, L] = (P_at(F + dF) - P_at(F - dF)) / (2 * h)
    # Relative to the tangent's size, which is not zero at a stress-free state (where P = 0).
    scale = max(np.linalg.norm(A), np.linalg.norm(P), 1e-300)
    return float(np.linalg.norm(P - P_fd) / scale), float(np.linalg.norm(A - A_fd) / scale)

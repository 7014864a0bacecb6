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
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import jax
import jax.numpy as jnp
import numpy as np

from . import _jax  # noqa: F401  (float64 everywhere)
from .errors import InputError

__all__ = [
    "Material",
    "SaintVenantKirchhoff",
    "Fung",
    "Ogden",
    "NeoHookean",
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
        _require(len(self.coefficients) == len(self.exponents) >= 1, "Ogden: need as many coefficients as exponents (>= 1)")
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
        logJ = 0.5 * jnp.log(jnp.linalg.det(C))
        return 0.5 * self.mu * (jnp.trace(C) - d) - self.mu * logJ + 0.5 * self.lam * logJ**2

    def validate(self):
        _require(self.mu > 0, f"neo-Hookean: mu must be > 0, got {self.mu}")
        _require(self.lam >= 0, f"neo-Hookean: lambda must be >= 0, got {self.lam}")
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
}


def material_from_config(cfg: dict) -> Material:
    """Build a material from ``{"law": "svk", "mu": 0.05, "lambda": 0.05, ...}``."""
    cfg = dict(cfg)
    law = str(cfg.pop("law", "svk")).lower()
    if law not in MATERIALS:
        raise InputError(f"unknown material law {law!r}; choose one of {sorted(set(MATERIALS))}")
    cls = MATERIALS[law]
    if "lambda" in cfg:
        cfg["lam"] = cfg.pop("lambda")
    names = {f.name for f in fields(cls)}
    unknown = set(cfg) - names
    if unknown:
        raise InputError(f"material {law!r}: unknown parameter(s) {sorted(unknown)}; expected {sorted(names)}")
    is_number = lambda x: isinstance(x, (int, float)) and not isinstance(x, bool)
    defaults = {f.name: f.default for f in fields(cls)}
    kwargs = {}
    for k, v in cfg.items():
        if isinstance(defaults[k], tuple):  # a list parameter (Ogden terms)
            if not (isinstance(v, (list, tuple)) and v and all(is_number(x) for x in v)):
                raise InputError(f"material {law!r}: {k} must be a non-empty list of numbers, got {v!r}")
            kwargs[k] = tuple(float(x) for x in v)
        elif is_number(v):
            kwargs[k] = float(v)
        else:
            raise InputError(f"material {law!r}: {k} must be a number, got {type(v).__name__} {v!r}")
    return cls(**kwargs).validate()


def finite_difference_check(material: Material, F: np.ndarray, h: float = 1e-6) -> tuple[float, float]:
    """Errors of autodiff ``P`` and ``dP/dF`` against central differences of ``W`` and ``P``,
    relative to ``max(|dP/dF|, |P|)``."""
    F = np.asarray(F, dtype=np.float64)
    d = F.shape[0]
    W = lambda G: float(material.energy_of_F(jnp.asarray(G)))
    P = np.asarray(first_piola(material, jnp.asarray(F)))
    A = np.asarray(tangent_modulus(material, jnp.asarray(F)))
    P_fd, A_fd = np.zeros_like(P), np.zeros_like(A)
    for k in range(d):
        for L in range(d):
            dF = np.zeros_like(F)
            dF[k, L] = h
            P_fd[k, L] = (W(F + dF) - W(F - dF)) / (2 * h)
            A_fd[:, :, k, L] = (np.asarray(first_piola(material, jnp.asarray(F + dF))) - np.asarray(first_piola(material, jnp.asarray(F - dF)))) / (2 * h)
    # Relative to the tangent's size, which is not zero at a stress-free state (where P = 0).
    scale = max(np.linalg.norm(A), np.linalg.norm(P), 1e-300)
    return float(np.linalg.norm(P - P_fd) / scale), float(np.linalg.norm(A - A_fd) / scale)

"""Time laws ``g(t)``: the scalar histories of the time-dependent loads and of the prescribed activation.

Every law is a JAX function of the time t (a traced scalar), differentiable in t: on the tau-dependent
t-grid of the optimal control problem (`hyperoc.dynamics.timegrid.TimeTransform`) the levels move with
tau, so the exact tau-gradient of the discrete state needs ``dg/dt`` (`jax.grad` of `TimeLaw.__call__`).

- `Constant`: ``g(t) = c``.
- `ExpressionLaw`: an expression of t (`hyperoc.expr`, evaluated with jax.numpy).
- `Table`: piecewise-linear interpolation of samples ``(t_k, g_k)`` (strictly increasing ``t_k``), held
  constant outside them; its derivative jumps at the samples (one-sided there).
- `OdeLaw`: the solution of a scalar ODE ``g' = h(t, g)``, ``g(t0) = g0``, integrated once by
  ``scipy.integrate.solve_ivp`` (Radau, rtol 1e-10, atol 1e-10 of the law's scale) at the nodes of a
  fine uniform grid and interpolated by the cubic Hermite polynomial whose slopes are the ODE's
  right-hand side at the nodes: C^1 in t, with interpolation error ``O(h^4 max|g''''|)`` (h the node
  spacing). `bestel_pressure` and `bestel_activation` are the Bestel-type laws of the cardiac
  elastodynamics benchmark (Aróstica et al. 2025, CMAME 435:117485; Bestel, Clément & Sorine 2001).

Bestel laws (SI units: t in s, the laws in Pa). With ``S+-(x) = (1 +- tanh(x / gamma)) / 2``:

    activation:  tau' = -|a(t)| tau + sigma_0 <a(t)>_+,
                 a(t) = a_max f(t) + a_min (1 - f(t)),   f(t) = S+(t - t_sys) S-(t - t_dias);
    pressure:    p' = -|b(t)| p + sigma_mid <b(t)>_+ + sigma_pre <g_pre(t)>_+,
                 b(t) = a_pre(t) + alpha_pre g_pre(t) + alpha_mid,
                 a_pre(t) = a_max f_pre(t) + a_min (1 - f_pre(t)),
                 f_pre(t) = S+(t - t_sys_pre) S-(t - t_dias_pre),   g_pre(t) = S-(t - t_dias_pre);

both from 0 at t = 0. Benchmark parameters (`BESTEL_ACTIVATION`, `BESTEL_PRESSURE`): t_sys = 0.16 s,
t_dias = 0.484 s, gamma = 0.005 s, a_max = 5 /s, a_min = -30 /s, sigma_0 = 150 kPa; t_sys_pre = 0.17 s,
t_dias_pre = 0.484 s, alpha_pre = 5 /s, alpha_mid = 1 /s, sigma_pre = 7 kPa, sigma_mid = 16 kPa.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from ..errors import InputError

__all__ = ["TimeLaw", "Constant", "ExpressionLaw", "Table", "Periodic", "OdeLaw", "bestel_activation",
           "bestel_pressure", "BESTEL_ACTIVATION", "BESTEL_PRESSURE"]

BESTEL_ACTIVATION = {"t_sys": 0.16, "t_dias": 0.484, "gamma": 0.005, "a_max": 5.0, "a_min": -30.0,
                     "sigma_0": 150e3}
BESTEL_PRESSURE = {"t_sys_pre": 0.17, "t_dias_pre": 0.484, "gamma": 0.005, "a_max": 5.0, "a_min": -30.0,
                   "alpha_pre": 5.0, "alpha_mid": 1.0, "sigma_pre": 7000.0, "sigma_mid": 16000.0}


class TimeLaw:
    """A scalar law ``g(t)``; ``law(t)`` works on floats and on traced JAX scalars."""

    def __call__(self, t):
        raise NotImplementedError

    def values(self, t) -> np.ndarray:
        """``g`` at the times ``t`` (k,), on the host, (k,)."""
        return np.asarray(jax.vmap(self.__call__)(jnp.asarray(t, dtype=jnp.float64)))

    def rate(self, t) -> np.ndarray:
        """``dg/dt`` at the times ``t`` (k,) by automatic differentiation, (k,)."""
        return np.asarray(jax.vmap(jax.grad(self.__call__))(jnp.asarray(t, dtype=jnp.float64)))


@dataclass(frozen=True)
class Constant(TimeLaw):
    """``g(t) = value``."""

    value: float

    def __post_init__(self):
        if not math.isfinite(self.value):
            raise InputError(f"time law: a constant must be finite, got {self.value}")

    def __call__(self, t):
        return self.value + 0.0 * t


@dataclass(frozen=True)
class ExpressionLaw(TimeLaw):
    """``g(t)`` given as an expression string of ``t`` (`hyperoc.expr` syntax, e.g. ``"1e3*sin(pi*t)"``)."""

    source: str

    def __post_init__(self):
        from ..expr import Expression

        object.__setattr__(self, "_expr", Expression(self.source, frozenset({"t"})))

    def __call__(self, t):
        return self._expr.traced(t=t)


@dataclass(frozen=True, eq=False)
class Table(TimeLaw):
    """Piecewise-linear interpolation of the samples ``(times[k], values[k])``, constant outside.
    ``times`` must be strictly increasing and every value finite (else `InputError`)."""

    times: np.ndarray
    values_: np.ndarray

    def __post_init__(self):
        t, g = np.asarray(self.times, np.float64), np.asarray(self.values_, np.float64)
        if t.ndim != 1 or t.shape != g.shape or t.size < 2:
            raise InputError(f"time law table: need two matching lists of at least 2 entries, got {t.shape}, "
                             f"{g.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(g))):
            raise InputError("time law table: times and values must be finite")
        if np.any(np.diff(t) <= 0):
            k = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise InputError(f"time law table: times must be strictly increasing (t[{k}] = {t[k]:g} >= "
                             f"t[{k + 1}] = {t[k + 1]:g})")
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "values_", g)

    def __call__(self, t):
        return jnp.interp(t, self.times, self.values_)


@dataclass(frozen=True, eq=False)
class Periodic(TimeLaw):
    """``g(t) = law(t mod period)``: a law of one beat repeated (``period`` > 0, else `InputError`)."""

    law: TimeLaw
    period: float

    def __post_init__(self):
        if not (math.isfinite(self.period) and self.period > 0):
            raise InputError(f"a periodic time law needs a finite period > 0, got {self.period}")

    def __call__(self, t):
        return self.law(jnp.mod(t, self.period))


@dataclass(frozen=True, eq=False)
class OdeLaw(TimeLaw):
    """The solution of ``g' = rhs(t, g, xp)`` (``rhs`` written for the array namespace ``xp``, numpy for the
    integration, jax.numpy for the slopes), ``g(t0) = g0``, on
    ``[t0, t1]``, integrated once (Radau, tight tolerances) at ``nodes`` uniform nodes and interpolated
    by cubic Hermite polynomials with the slopes ``rhs(t_k, g_k)`` (C^1). Constant outside ``[t0, t1]``
    (the end values; the slope there is the one-sided limit 0 outside).

    scale : the law's magnitude, for the absolute tolerance ``1e-10 scale`` of the integration.
    """

    rhs: object
    t0: float
    t1: float
    g0: float = 0.0
    nodes: int = 4001
    scale: float = 1.0
    _t: np.ndarray = field(init=False, repr=False)
    _g: np.ndarray = field(init=False, repr=False)
    _s: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        from scipy.integrate import solve_ivp

        if not (self.t1 > self.t0 and self.nodes >= 2):
            raise InputError(f"ODE time law: need t1 > t0 and nodes >= 2, got [{self.t0}, {self.t1}], {self.nodes}")
        t = np.linspace(self.t0, self.t1, self.nodes)
        sol = solve_ivp(lambda s, y: self.rhs(s, y, np), (self.t0, self.t1), [self.g0], method="Radau",
                        t_eval=t, rtol=1e-10, atol=1e-10 * self.scale)
        if not sol.success:
            raise InputError(f"ODE time law: integration failed ({sol.message})")
        g = sol.y[0]
        object.__setattr__(self, "_t", t)
        object.__setattr__(self, "_g", g)
        object.__setattr__(self, "_s", np.asarray(self.rhs(t, g, np), dtype=np.float64))

    def __call__(self, t):
        ts, g, s = (jnp.asarray(a) for a in (self._t, self._g, self._s))
        h = float(self._t[1] - self._t[0])
        tc = jnp.clip(t, ts[0], ts[-1])
        k = jnp.clip(jnp.floor((tc - ts[0]) / h).astype(int), 0, ts.size - 2)
        x = (tc - ts[k]) / h
        h00, h10 = (1 + 2 * x) * (1 - x) ** 2, x * (1 - x) ** 2
        h01, h11 = x ** 2 * (3 - 2 * x), x ** 2 * (x - 1)
        return h00 * g[k] + h10 * h * s[k] + h01 * g[k + 1] + h11 * h * s[k + 1]


def _switch(x, gamma, sign, xp):
    """``S+-(x) = (1 +- tanh(x / gamma)) / 2``."""
    return 0.5 * (1.0 + sign * xp.tanh(x / gamma))


def _bestel_activation_rhs(p):
    def rhs(t, tau, xp):
        f = _switch(t - p["t_sys"], p["gamma"], 1, xp) * _switch(t - p["t_dias"], p["gamma"], -1, xp)
        a = p["a_max"] * f + p["a_min"] * (1.0 - f)
        return -xp.abs(a) * tau + p["sigma_0"] * xp.maximum(a, 0.0)

    return rhs


def _bestel_pressure_rhs(p):
    def rhs(t, q, xp):
        g_pre = _switch(t - p["t_dias_pre"], p["gamma"], -1, xp)
        f_pre = _switch(t - p["t_sys_pre"], p["gamma"], 1, xp) * g_pre
        b = p["a_max"] * f_pre + p["a_min"] * (1.0 - f_pre) + p["alpha_pre"] * g_pre + p["alpha_mid"]
        return -xp.abs(b) * q + p["sigma_mid"] * xp.maximum(b, 0.0) + p["sigma_pre"] * xp.maximum(g_pre, 0.0)

    return rhs


def _parameters(defaults: dict, given: dict | None, what: str) -> dict:
    """``defaults`` updated by ``given``; `InputError` for an unknown name or a non-finite value."""
    given = dict(given or {})
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        raise InputError(f"{what}: unknown parameter(s) {unknown}; known: {sorted(defaults)}")
    out = {**defaults, **{k: float(v) for k, v in given.items()}}
    if not all(math.isfinite(v) for v in out.values()) or out["gamma"] <= 0:
        raise InputError(f"{what}: parameters must be finite and gamma > 0")
    return out


def bestel_activation(t_end: float = 1.0, parameters: dict | None = None, nodes: int = 4001) -> OdeLaw:
    """The benchmark's active tension T_a(t) (Pa) on ``[0, t_end]`` s (`BESTEL_ACTIVATION` updated by
    ``parameters``)."""
    p = _parameters(BESTEL_ACTIVATION, parameters, "Bestel activation")
    return OdeLaw(_bestel_activation_rhs(p), 0.0, float(t_end), 0.0, nodes, scale=abs(p["sigma_0"]) or 1.0)


def bestel_pressure(t_end: float = 1.0, parameters: dict | None = None, nodes: int = 4001) -> OdeLaw:
    """The benchmark's endocardial pressure p(t) (Pa) on ``[0, t_end]`` s (`BESTEL_PRESSURE` updated by
    ``parameters``)."""
    p = _parameters(BESTEL_PRESSURE, parameters, "Bestel pressure")
    return OdeLaw(_bestel_pressure_rhs(p), 0.0, float(t_end), 0.0, nodes,
                  scale=max(abs(p["sigma_mid"]), abs(p["sigma_pre"]), 1.0))

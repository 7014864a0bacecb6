"""Verification tools: Taylor tests of gradients and observed convergence rates.

`taylor_test` checks that ``r(h) = |J(m + h dm) - J(m) - h dJ(m).dm|`` falls like ``h^2``: a wrong
gradient leaves ``r = O(h)``. The step range is chosen automatically: it starts where the linear
term is a small fraction of the perturbation scale and stops before ``r`` reaches the round-off
floor of J (about ``1e-13 |J|`` with Newton converged to 1e-11).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .reduced import ControlPoint, ReducedFunctional

__all__ = ["TaylorResult", "taylor_test", "observed_rates", "random_directions"]


def observed_rates(sizes, errors) -> np.ndarray:
    """``log(e_k / e_{k+1}) / log(h_k / h_{k+1})`` for successive pairs."""
    s, e = np.asarray(sizes, float), np.asarray(errors, float)
    return np.log(e[:-1] / e[1:]) / np.log(s[:-1] / s[1:])


# The observed rate of a correct gradient: the second-order remainder's 2, within this (the
# pre-asymptotic range ends when the last two rates are inside it).
EXPECTED_RATE, RATE_TOLERANCE = 2.0, 0.1


@dataclass
class TaylorResult:
    """Steps h, remainders r(h), observed rates between successive steps, and their summary."""

    h: np.ndarray
    remainder: np.ndarray
    rates: np.ndarray
    derivative: float
    value: float

    @property
    def rate(self) -> float:
        """The rate on the two smallest steps above the noise floor (the asymptotic one)."""
        return float(self.rates[-1]) if self.rates.size else float("nan")

    @property
    def passed(self) -> bool:
        """The asymptotic rate is ``EXPECTED_RATE`` within ``RATE_TOLERANCE`` (a correct gradient)."""
        return bool(abs(self.rate - EXPECTED_RATE) <= RATE_TOLERANCE)

    def as_dict(self) -> dict:
        return {"h": self.h.tolist(), "remainder": self.remainder.tolist(), "rates": self.rates.tolist(),
                "rate": self.rate, "passed": self.passed, "dJ_dm": self.derivative, "J": self.value}


def taylor_test(J: ReducedFunctional, m: ControlPoint, dm: ControlPoint, *, steps: int = 5,
                h0: float | None = None, noise: float = 1e-13, max_halvings: int = 14) -> TaylorResult:
    """Second-order Taylor remainders of J at m along dm, with an automatic step range.

    ``h0`` defaults to a step that moves tau by two time steps (J varies in tau on the time scale
    of the dynamics, which the grid resolves) and the control by 10% of its scale. Steps are
    halved ``steps - 1`` times, and further (up to ``max_halvings``) while the last observed rates'
    pair is not yet within 0.1 of 2 (pre-asymptotic range). Remainders below ``1e3 * noise * |J|`` are
    round-off, not Taylor, and are dropped.
    """
    J0, d = J.value_and_derivative(m)
    dJdm = float(np.sum(d.xi * dm.xi) + d.tau * dm.tau)
    h = _default_h0(J, m, dm) if h0 is None else h0
    floor = 1e3 * noise * max(abs(J0), 1e-300)
    hs, rs = [], []
    for k in range(max_halvings):
        r = abs(J(m + dm * h) - J0 - h * dJdm)
        if r <= floor:
            break
        hs.append(h)
        rs.append(r)
        rates = observed_rates(hs, rs) if len(rs) > 1 else np.array([])
        if len(rs) >= steps and np.all(np.abs(rates[-2:] - EXPECTED_RATE) <= RATE_TOLERANCE):
            break
        h /= 2
    hs, rs = np.array(hs[-steps:]), np.array(rs[-steps:])
    return TaylorResult(hs, rs, observed_rates(hs, rs) if rs.size > 1 else np.array([]), dJdm, J0)


def _default_h0(J: ReducedFunctional, m: ControlPoint, dm: ControlPoint) -> float:
    room = min(m.tau, J.transform.T - J.transform.eps - m.tau)
    dt_max = float(np.max(J.transform.dt(m.tau)))
    h_tau = min(0.25 * room, 2 * dt_max) / abs(dm.tau) if dm.tau else np.inf
    xi_scale = max(np.max(np.abs(m.xi)), 1e-3)
    h_xi = 0.1 * xi_scale / np.max(np.abs(dm.xi)) if np.any(dm.xi) else np.inf
    return float(min(h_tau, h_xi))


def random_directions(J: ReducedFunctional, m: ControlPoint, seed: int = 0) -> dict:
    """Directions for the three checks: xi alone, tau alone, joint; smooth in time.

    The xi part is a random field made smooth in s (cumulative sums of noise, normalized), so that
    the test probes the gradient at resolved scales and not only at the grid scale.
    """
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(m.xi.shape)
    smooth = np.cumsum(noise, axis=0)
    smooth -= smooth.mean(axis=0)
    dxi = smooth / max(np.max(np.abs(smooth)), 1e-300)
    return {
        "xi": ControlPoint(dxi, 0.0),
        "tau": ControlPoint(np.zeros_like(m.xi), 1.0),
        "joint": ControlPoint(dxi, 1.0),
    }

"""Time grids, and the time transformation ``t = mu(s, tau)`` that decouples the free time tau.

``mu(., tau)`` maps ``s in [0, 2]`` piecewise linearly: ``[0, 1] -> [0, tau]``,
``[1, 1 + eps~] -> [tau, tau + eps]``, ``[1 + eps~, 2] -> [tau + eps, T]`` (paper,
``sec-transformation``; two pieces when eps = 0). A fixed s-grid with ``(N1, N2, N3)`` uniform
steps per piece gives a tau-dependent t-grid whose node ``N1`` is exactly tau and node
``N1 + N2`` exactly ``tau + eps``; tau enters the discrete state only through the step sizes
``dt_n = mu_dot(s_n, tau) ds_n``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["TimeGrid", "TimeTransform", "uniform_grid", "trapezoid_weights"]


def trapezoid_weights(steps) -> np.ndarray:
    """Weights (N+1,) of the trapezoid rule on levels separated by ``steps`` (N,)."""
    steps = np.asarray(steps, dtype=np.float64)
    w = np.zeros(steps.size + 1)
    w[:-1] += steps / 2
    w[1:] += steps / 2
    return w


@dataclass(frozen=True, eq=False)
class TimeGrid:
    """Time levels ``t_0 < ... < t_N`` (shape (N+1,)) and steps ``dt_n = t_{n+1} - t_n`` (N,)."""

    t: np.ndarray

    def __post_init__(self):
        t = np.asarray(self.t, dtype=np.float64)
        if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
            raise InputError("time grid: need at least two strictly increasing finite levels (dt > 0)")
        object.__setattr__(self, "t", t)

    @property
    def dt(self) -> np.ndarray:
        return np.diff(self.t)

    @property
    def num_steps(self) -> int:
        return self.t.size - 1

    def first(self, k: int) -> "TimeGrid":
        """The grid of the first k steps (levels 0 .. k); this grid itself when k is all of them."""
        return self if k == self.num_steps else TimeGrid(self.t[:k + 1])


def uniform_grid(T: float, dt: float) -> TimeGrid:
    """``round(T / dt)`` equal steps on ``[0, T]``; ``T / dt`` must be an integer up to 1e-9."""
    if not (dt > 0 and T > 0):
        raise InputError(f"time grid: need T > 0 and dt > 0, got T = {T}, dt = {dt}")
    n = int(round(T / dt))
    if n < 1 or abs(n * dt - T) > 1e-9 * T:
        raise InputError(f"time grid: T = {T} is not a whole number of steps dt = {dt}")
    return TimeGrid(np.linspace(0.0, T, n + 1))


@dataclass(frozen=True)
class TimeTransform:
    """The change of variables ``mu(s, tau)`` on a fixed s-grid.

    Parameters
    ----------
    T : final time.
    steps : (N1, N2, N3) uniform s-steps on ``[0, 1]``, ``[1, 1 + eps~]``, ``[1 + eps~, 2]``; N2 = 0 iff eps = 0.
    eps : the time offset of the objective ``(p(tau + eps) - p(tau)) / eps`` (0 for ``p(tau)``).
    eps_tilde : its image length in s (the paper's eps~ in (0, 1)); defaults to ``N2 / (N2 + N3)``,
        which makes the s-step uniform on ``[1, 2]``.
    """

    T: float
    steps: tuple
    eps: float = 0.0
    eps_tilde: float | None = None

    def __post_init__(self):
        n1, n2, n3 = (int(k) for k in self.steps)
        if self.T <= 0 or n1 < 1 or n3 < 1 or n2 < 0:
            raise InputError(f"time transform: need T > 0, N1 >= 1, N3 >= 1, N2 >= 0; "
                             f"got T={self.T}, steps={self.steps}")
        if (self.eps > 0) != (n2 > 0) or self.eps < 0:
            raise InputError("time transform: eps > 0 needs N2 > 0 steps on [tau, tau + eps] "
                             "(and eps = 0 needs N2 = 0)")
        et = self.eps_tilde if self.eps_tilde is not None else (n2 / (n2 + n3))
        if self.eps > 0 and not 0 < et < 1:
            raise InputError(f"time transform: eps_tilde must lie in (0, 1), got {et}")
        object.__setattr__(self, "steps", (n1, n2, n3))
        object.__setattr__(self, "eps_tilde", float(et))

    @classmethod
    def for_step(cls, T: float, dt: float, tau: float, eps: float = 0.0) -> "TimeTransform":
        """Step counts giving steps close to ``dt`` on every piece when evaluated at ``tau``."""
        if not 0 < tau < T - eps:
            raise InputError(f"tau must lie in (0, T - eps) = (0, {T - eps}), got {tau}")
        n1 = max(1, int(round(tau / dt)))
        n2 = int(round(eps / dt)) if eps > 0 else 0
        if eps > 0:
            n2 = max(1, n2)
        n3 = max(1, int(round((T - tau - eps) / dt)))
        return cls(T=T, steps=(n1, n2, n3), eps=eps)

    @property
    def num_steps(self) -> int:
        return sum(self.steps)

    @property
    def tau_index(self) -> int:
        """Level index of tau (and ``tau_index + N2`` is that of tau + eps)."""
        return self.steps[0]

    def check_tau(self, tau: float) -> None:
        if not 0 < tau < self.T - self.eps:
            raise InputError(f"tau must lie in (0, T - eps) = (0, {self.T - self.eps}), got {tau}")

    def s_levels(self) -> np.ndarray:
        """The fixed s-grid, shape (N+1,), in [0, 2]."""
        n1, n2, n3 = self.steps
        et = self.eps_tilde if n2 else 0.0
        parts = [np.linspace(0, 1, n1 + 1)]
        if n2:
            parts.append(np.linspace(1, 1 + et, n2 + 1)[1:])
        parts.append(np.linspace(1 + et, 2, n3 + 1)[1:])
        return np.concatenate(parts)

    def ds(self) -> np.ndarray:
        return np.diff(self.s_levels())

    def dt(self, tau: float) -> np.ndarray:
        """Step sizes ``dt_n = mu_dot(s_n, tau) ds_n``, shape (N,)."""
        n1, n2, n3 = self.steps
        return np.concatenate([np.full(n1, tau / n1), np.full(n2, self.eps / max(n2, 1)),
                               np.full(n3, (self.T - tau - self.eps) / n3)])

    def ddt_dtau(self) -> np.ndarray:
        """``d dt_n / d tau`` (independent of tau): 1/N1, 0, -1/N3 on the three pieces."""
        n1, n2, n3 = self.steps
        return np.concatenate([np.full(n1, 1.0 / n1), np.zeros(n2), np.full(n3, -1.0 / n3)])

    def grid(self, tau: float) -> TimeGrid:
        """The t-levels ``mu(s_n, tau)`` as a `TimeGrid`; level N1 is tau exactly."""
        self.check_tau(tau)
        t = np.concatenate([[0.0], np.cumsum(self.dt(tau))])
        t[self.steps[0]] = tau
        if self.steps[1]:
            t[self.steps[0] + self.steps[1]] = tau + self.eps
        t[-1] = self.T
        return TimeGrid(t)

    def mu(self, s, tau: float):
        """``mu(s, tau)`` for s in [0, 2] (vectorized)."""
        s = np.asarray(s, dtype=np.float64)
        et = self.eps_tilde if self.steps[1] else 0.0
        return np.where(
            s <= 1,
            tau * s,
            np.where(s <= 1 + et, tau + (self.eps / et if et else 0.0) * (s - 1),
                     self.T - (2 - s) * (self.T - tau - self.eps) / (1 - et)),
        )

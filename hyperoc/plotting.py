"""PNG figures of pressures, controls, snapshots and optimizer histories.

Figures are built with `matplotlib.figure.Figure` on an Agg canvas, never through pyplot: no
global state, no display needed, safe in worker processes. Each function renders to memory
and writes the PNG atomically (`hyperoc.io.atomic_write_bytes`), then returns its path.
"""

from __future__ import annotations

import math
from io import BytesIO
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .io import atomic_write_bytes

__all__ = ["plot_pressure", "plot_control_spacetime", "plot_snapshots", "plot_history"]

_DPI = 150


def _new_figure(width: float, height: float, layout: str | None = "constrained") -> Figure:
    fig = Figure(figsize=(width, height), layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path) -> Path:
    buffer = BytesIO()
    fig.savefig(buffer, format="png", dpi=_DPI)
    return atomic_write_bytes(path, buffer.getvalue())


def _as_1d(name: str, values, n: int | None = None) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 1 or (n is not None and len(array) != n):
        expected = f"({n},)" if n is not None else "1D"
        raise ValueError(f"{name} must have shape {expected}, got {array.shape}")
    return array


def _as_spacetime(name: str, values, nt: int, nx: int) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (nt, nx):
        raise ValueError(f"{name} must have shape (nt, nx) = ({nt}, {nx}), got {array.shape}")
    return array


def plot_pressure(path, t, p, *, tau=None, eps=None, volume=None, cavity=None, title=None) -> Path:
    """Plot the pressure p(t), with the free time tau marked, and optionally the volume drift and the
    cavity volume.

    Parameters
    ----------
    path : path
        Output PNG.
    t : (nt,) array_like
        Time levels.
    p : (nt,) array_like
        Pressure (Lagrange multiplier of the volume constraint) at each time level.
    tau : float, optional
        Free time; a dashed vertical line. With ``eps``, the window [tau, tau + eps] is shaded.
    eps : float, optional
        Width of the window after tau.
    volume : (nt,) array_like, optional
        Body volume ``int det F``; adds a panel with the relative drift ``volume / volume[0] - 1``.
    cavity : (nt,) array_like, optional
        Cavity volume (e.g. of a ventricle, `hyperoc.report.cavity_volume`); adds a panel with it.
    title : str, optional

    Returns
    -------
    Path
    """
    t = _as_1d("t", t)
    p = _as_1d("p", p, len(t))
    panels = 1 + (volume is not None) + (cavity is not None)
    fig = _new_figure(6.4, 3.2 * panels)
    axes = fig.subplots(panels, 1, sharex=True, squeeze=False)[:, 0]
    axes[0].plot(t, p, color="C0", label="p(t)")
    axes[0].set_ylabel("pressure p")
    if tau is not None:
        for ax in axes:
            ax.axvline(tau, color="k", linestyle="--", linewidth=1.0, label=r"$\tau$")
            if eps is not None:
                ax.axvspan(tau, tau + eps, color="0.85", label=r"$[\tau, \tau+\varepsilon]$")
    axes[0].legend(loc="best")
    if volume is not None:
        volume = _as_1d("volume", volume, len(t))
        axes[1].plot(t, volume / volume[0] - 1.0, color="C1")
        axes[1].set_ylabel(r"$V(t)/V(0) - 1$")
    if cavity is not None:
        axes[-1].plot(t, _as_1d("cavity", cavity, len(t)), color="C2")
        axes[-1].set_ylabel("cavity volume")
    axes[-1].set_xlabel("t")
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_control_spacetime(path, t, x, xi, *, xlabel="x", tau=None, title=None) -> Path:
    """Space-time map of a 1D control (or of slice means of a 2D/3D one), x horizontal and t
    vertical, colors centered at 0.

    Parameters
    ----------
    path : path
        Output PNG.
    t : (nt,) array_like
        Time levels.
    x : (nx,) array_like
        Spatial nodes.
    xi : (nt, nx) array_like
        Control values ``xi[n, i] = xi(t_n, x_i)``.
    xlabel : str
        Label of the space axis.
    tau : float, optional
        Free time; a dashed horizontal line.
    title : str, optional

    Returns
    -------
    Path
    """
    t, x = _as_1d("t", t), _as_1d("x", x)
    xi = _as_spacetime("xi", xi, len(t), len(x))
    bound = float(np.nanmax(np.abs(xi))) if np.isfinite(xi).any() else 0.0
    bound = bound if bound > 0 else 1.0
    fig = _new_figure(6.4, 4.8)
    ax = fig.subplots()
    mesh = ax.pcolormesh(x, t, xi, shading="nearest", cmap="RdBu_r", vmin=-bound, vmax=bound)
    fig.colorbar(mesh, ax=ax, label=r"$\xi$")
    if tau is not None:
        ax.axhline(tau, color="k", linestyle="--", linewidth=1.0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("t")
    if title:
        ax.set_title(title)
    return _save(fig, path)


def _nearest_levels(t: np.ndarray, times) -> np.ndarray:
    """Indices of the time levels nearest to each requested time."""
    requested = np.atleast_1d(np.asarray(times, dtype=np.float64))
    return np.abs(t[None, :] - requested[:, None]).argmin(axis=1)


def plot_snapshots(path, x, t, values, times, *, ylabel, title=None, ncols: int = 4) -> Path:
    """Small multiples of a 1D field at selected times, with shared axes.

    Parameters
    ----------
    path : path
        Output PNG.
    x : (nx,) array_like
        Spatial nodes.
    t : (nt,) array_like
        Time levels.
    values : (nt, nx) array_like
        Field values per time level.
    times : sequence of float
        Requested times; each panel shows the nearest time level (its actual time in the title).
    ylabel : str
        Label of the field axis.
    title : str, optional
    ncols : int
        Panels per row.

    Returns
    -------
    Path
    """
    x, t = _as_1d("x", x), _as_1d("t", t)
    values = _as_spacetime("values", values, len(t), len(x))
    levels = _nearest_levels(t, times)
    if not len(levels):
        raise ValueError("plot_snapshots: no times requested")
    ncols = min(ncols, len(levels))
    nrows = math.ceil(len(levels) / ncols)
    # A fixed layout: the constrained solver costs seconds on 16 panels and shared axes need none.
    fig = _new_figure(2.6 * ncols, 2.2 * nrows, layout=None)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.07, top=0.93, wspace=0.08, hspace=0.35)
    axes = fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False).ravel()
    for ax, n in zip(axes, levels):
        ax.plot(x, values[n], color="C0")
        ax.set_title(f"t = {t[n]:.4g}", fontsize="medium")
    for ax in axes[len(levels):]:
        ax.set_visible(False)
    for i, ax in enumerate(axes[: len(levels)]):
        if i % ncols == 0:
            ax.set_ylabel(ylabel)
        if i + ncols >= len(levels):  # lowest visible panel of its column
            ax.set_xlabel("x")
            ax.xaxis.set_tick_params(labelbottom=True)
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_history(path, histories: dict, *, logy_keys=("grad_norm",)) -> Path:
    """Optimizer histories (objective, gradient norm, tau, ...) vs iteration, one panel each.

    Parameters
    ----------
    path : path
        Output PNG.
    histories : dict of str -> sequence of float
        One sequence per quantity, indexed by iteration.
    logy_keys : iterable of str
        Quantities drawn on a log scale (when all their finite values are positive).

    Returns
    -------
    Path
    """
    if not histories:
        raise ValueError("plot_history: no histories given")
    fig = _new_figure(6.4, 2.2 * len(histories))
    axes = fig.subplots(len(histories), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (key, values) in zip(axes, histories.items()):
        values = _as_1d(key, values)
        ax.plot(np.arange(len(values)), values, marker="o", markersize=3)
        ax.set_ylabel(key)
        finite = values[np.isfinite(values)]
        if key in logy_keys and finite.size and np.all(finite > 0):
            ax.set_yscale("log")
    axes[-1].set_xlabel("iteration")
    return _save(fig, path)

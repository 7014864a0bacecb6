"""PNG figures of pressures, controls, snapshots and optimizer histories.

Figures are built with `matplotlib.figure.Figure` on an Agg canvas, never through pyplot: no
global state, no display needed, safe in worker processes. Each function renders to memory
and writes the PNG atomically (`hyperoc.io.atomic_write_bytes`), then returns its path.

Every axis is labelled ``name [unit]`` (`axis_label`) with the units of a `Units`; ``-`` marks a
dimensionless quantity (the default: the model's equations carry no units of their own).
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ..io import atomic_write_bytes

__all__ = ["Units", "TimeMarks", "axis_label", "plot_pressure", "plot_control_spacetime", "plot_snapshots",
           "plot_history", "plot_value_profile", "plot_pressure_comparison", "plot_pv_loops"]

_DPI = 150
_MARK_COLOR = "C3"  # the vertical markers of `plot_pressure`: dotted, apart from p (C0) and tau (black)


@dataclass(frozen=True)
class Units:
    """Units of the quantities on the figures' axes, as printed (e.g. ``"ms"``, ``"mm"``, ``"kPa"``);
    ``"-"`` is dimensionless.

    Attributes
    ----------
    time : str
        Time t.
    length : str
        Coordinates and displacements; volumes are in ``length^3``.
    pressure : str
        The pressure p (the multiplier of the volume constraint).
    control : str
        The control xi (a body force: force per volume; an active stress: a stress).
    """

    time: str = "-"
    length: str = "-"
    pressure: str = "-"
    control: str = "-"

    @property
    def velocity(self) -> str:
        """``length/time``; ``-`` when both are dimensionless."""
        if self.time == "-":
            return self.length
        return f"1/{self.time}" if self.length == "-" else f"{self.length}/{self.time}"

    @property
    def volume(self) -> str:
        """``length^3``; ``-`` when length is dimensionless."""
        return "-" if self.length == "-" else f"{self.length}^3"

    @property
    def pressure_rate(self) -> str:
        """``pressure/time``; ``-`` when both are dimensionless."""
        if self.time == "-":
            return self.pressure
        return f"1/{self.time}" if self.pressure == "-" else f"{self.pressure}/{self.time}"


@dataclass(frozen=True)
class TimeMarks:
    """What a figure marks on its time axis [units.time].

    Attributes
    ----------
    tau : float, optional
        The free time: a dashed vertical line.
    eps : float, optional
        With ``tau``, the window ``[tau, tau + eps]`` after it, shaded.
    events : sequence of (float, str)
        ``(time, label)`` pairs: dotted vertical lines, each distinct label once in the legend.
    """

    tau: float | None = None
    eps: float | None = None
    events: tuple = ()

    def draw(self, axes) -> None:
        """The tau line and its window on every axis of ``axes``, the events on the first."""
        if self.tau is not None:
            for ax in axes:
                ax.axvline(self.tau, color="k", linestyle="--", linewidth=1.0, label=r"$\tau$")
                if self.eps is not None:
                    ax.axvspan(self.tau, self.tau + self.eps, color="0.85", label=r"$[\tau, \tau+\varepsilon]$")
        _draw_events(axes[0], self.events)


def axis_label(name: str, unit: str = "-") -> str:
    """An axis label ``"name [unit]"``, e.g. ``axis_label("x", "mm") == "x [mm]"``."""
    return f"{name} [{unit}]"


def new_figure(width: float, height: float, layout: str | None = "constrained") -> Figure:
    """A Matplotlib figure of ``width`` x ``height`` inches on the Agg canvas (no GUI backend, thread-safe)."""
    fig = Figure(figsize=(width, height), layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _fitted(title: str, fig: Figure) -> str:
    """``title`` broken into lines that fit the figure's width (a character of the default 12 pt title font
    is about 6.8 pt wide)."""
    return textwrap.fill(title, width=max(20, int(fig.get_figwidth() * 72 / 6.8)))


def save_figure(fig: Figure, path) -> Path:
    """``fig`` as a PNG at ``path``, written atomically (a reader never sees half a file); returns the path."""
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


def plot_pressure(path, t, p, *, volume=None, cavity=None, marks: TimeMarks = TimeMarks(), title=None,
                  units=None) -> Path:
    """Plot the pressure p(t), with the free time tau marked, and optionally the volume drift and the
    cavity volume.

    Parameters
    ----------
    path : path
        Output PNG.
    t : (nt,) array_like
        Time levels [units.time].
    p : (nt,) array_like
        Pressure (Lagrange multiplier of the volume constraint) at each time level [units.pressure].
    volume : (nt,) array_like, optional
        Body volume ``int det F``; adds a panel with the relative drift ``volume / volume[0] - 1`` [-].
    cavity : (nt,) array_like, optional
        Cavity volume (e.g. of a ventricle, `hyperoc.mechanics.cavity.CavityVolume`) [units.length^3]; adds a
        panel with it.
    marks : TimeMarks, optional
        The free time tau and its window on every panel, the events on the pressure panel.
    title : str, optional
        Figure title (e.g. the run's name).
    units : Units, optional
        Units of the axes (default: all dimensionless).

    Returns
    -------
    Path
    """
    units = units or Units()
    t = _as_1d("t", t)
    p = _as_1d("p", p, len(t))
    panels = 1 + (volume is not None) + (cavity is not None)
    fig = new_figure(6.4, 3.2 * panels)
    axes = fig.subplots(panels, 1, sharex=True, squeeze=False)[:, 0]
    axes[0].plot(t, p, color="C0", label="p(t)")
    axes[0].set_ylabel(axis_label("pressure p", units.pressure))
    marks.draw(axes)
    axes[0].legend(loc="best")
    if volume is not None:
        volume = _as_1d("volume", volume, len(t))
        axes[1].plot(t, volume / volume[0] - 1.0, color="C1")
        axes[1].set_ylabel(axis_label("V(t)/V(0) - 1"))
    if cavity is not None:
        axes[-1].plot(t, _as_1d("cavity", cavity, len(t)), color="C2")
        axes[-1].set_ylabel(axis_label("cavity volume", units.volume))
    axes[-1].set_xlabel(axis_label("time t", units.time))
    if title:
        fig.suptitle(_fitted(title, fig))
    return save_figure(fig, path)


def _draw_events(ax, events) -> None:
    """Dotted vertical lines (gid ``"mark"``) at the times of ``events`` = [(t, label), ...]; a
    label already drawn is not repeated in the legend."""
    seen = set()
    for time, label in events or ():
        label = str(label) if label else ""
        shown = label if label and label not in seen else "_nolegend_"
        seen.add(label)
        ax.axvline(float(time), color=_MARK_COLOR, linestyle=":", linewidth=1.2, label=shown, gid="mark")


def plot_control_spacetime(path, t, x, xi, *, xlabel="x", tau=None, title=None, units=None) -> Path:
    """Space-time map of a 1D control (or of slice means of a 2D/3D one), x horizontal and t
    vertical, colors centered at 0.

    Parameters
    ----------
    path : path
        Output PNG.
    t : (nt,) array_like
        Time levels [units.time].
    x : (nx,) array_like
        Spatial nodes [units.length].
    xi : (nt, nx) array_like
        Control values ``xi[n, i] = xi(t_n, x_i)`` [units.control].
    xlabel : str
        Name of the space axis (its unit is appended).
    tau : float, optional
        Free time [units.time]; a dashed horizontal line.
    title : str, optional
        Axes title (e.g. the run's name).
    units : Units, optional
        Units of the axes and of the colour bar (default: all dimensionless).

    Returns
    -------
    Path
    """
    units = units or Units()
    t, x = _as_1d("t", t), _as_1d("x", x)
    xi = _as_spacetime("xi", xi, len(t), len(x))
    bound = float(np.nanmax(np.abs(xi))) if np.isfinite(xi).any() else 0.0
    bound = bound if bound > 0 else 1.0
    fig = new_figure(6.4, 4.8)
    ax = fig.subplots()
    mesh = ax.pcolormesh(x, t, xi, shading="nearest", cmap="RdBu_r", vmin=-bound, vmax=bound)
    fig.colorbar(mesh, ax=ax, label=axis_label("control xi", units.control))
    if tau is not None:
        ax.axhline(tau, color="k", linestyle="--", linewidth=1.0)
    ax.set_xlabel(axis_label(xlabel, units.length))
    ax.set_ylabel(axis_label("time t", units.time))
    if title:
        ax.set_title(_fitted(title, fig))
    return save_figure(fig, path)


def _nearest_levels(t: np.ndarray, times) -> np.ndarray:
    """Indices of the time levels nearest to each requested time."""
    requested = np.atleast_1d(np.asarray(times, dtype=np.float64))
    return np.abs(t[None, :] - requested[:, None]).argmin(axis=1)


def plot_snapshots(path, x, t, values, times, *, ylabel, title=None, ncols: int = 4, units=None) -> Path:
    """Small multiples of a 1D field at selected times, with shared axes.

    Parameters
    ----------
    path : path
        Output PNG.
    x : (nx,) array_like
        Spatial nodes [units.length].
    t : (nt,) array_like
        Time levels [units.time].
    values : (nt, nx) array_like
        Field values per time level.
    times : sequence of float
        Requested times; each panel shows the nearest time level (its actual time in the title).
    ylabel : str
        Label of the field axis, with its unit (e.g. ``axis_label("u(x, t)", units.length)``).
    title : str, optional
        Figure title (e.g. the run's name).
    ncols : int
        Panels per row.
    units : Units, optional
        Units of the space and time axes (default: all dimensionless).

    Returns
    -------
    Path
    """
    units = units or Units()
    x, t = _as_1d("x", x), _as_1d("t", t)
    values = _as_spacetime("values", values, len(t), len(x))
    levels = _nearest_levels(t, times)
    if not len(levels):
        raise ValueError("plot_snapshots: no times requested")
    ncols = min(ncols, len(levels))
    nrows = math.ceil(len(levels) / ncols)
    # A fixed layout: the constrained solver costs seconds on 16 panels and shared axes need none.
    # Margins in inches, so that labels and titles fit a single row as well as four.
    width, height = 2.6 * ncols, 2.2 * nrows
    fig = new_figure(width, height, layout=None)
    title = _fitted(title, fig) if title else ""
    lines = title.count("\n") + 1 if title else 0
    fig.subplots_adjust(left=0.8 / width, right=1 - 0.15 / width, bottom=0.5 / height,
                        top=1 - (0.3 + 0.25 * lines) / height, wspace=0.15, hspace=0.35)
    axes = fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False).ravel()
    time_unit = "" if units.time == "-" else f" {units.time}"
    for ax, n in zip(axes, levels):
        ax.plot(x, values[n], color="C0")
        # A fixed title height: matplotlib otherwise places each panel's title past its tick labels,
        # a layout pass over every tick that doubles the figure's drawing time (none are on top here).
        ax.set_title(f"t = {t[n]:.4g}{time_unit}", fontsize="medium", y=1.0)
    for ax in axes[len(levels):]:
        ax.set_visible(False)
    for i, ax in enumerate(axes[: len(levels)]):
        if i % ncols == 0:
            ax.set_ylabel(ylabel)
            ax.ticklabel_format(axis="y", scilimits=(-2, 3))  # short tick labels: the margin is fixed
        if i + ncols >= len(levels):  # lowest visible panel of its column
            ax.set_xlabel(axis_label("x", units.length))
            ax.xaxis.set_tick_params(labelbottom=True)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


def plot_history(path, histories: dict, *, logy_keys=("grad_norm",), title=None) -> Path:
    """Optimizer histories (objective, gradient norm, tau, ...) vs iteration, one panel each.

    Parameters
    ----------
    path : path
        Output PNG.
    histories : dict of str -> sequence of float
        One sequence per quantity, indexed by iteration.
    logy_keys : iterable of str
        Quantities drawn on a log scale (when all their finite values are positive).
    title : str, optional
        Figure title (e.g. the run's name).

    Returns
    -------
    Path
    """
    if not histories:
        raise ValueError("plot_history: no histories given")
    fig = new_figure(6.4, 2.2 * len(histories))
    axes = fig.subplots(len(histories), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (key, values) in zip(axes, histories.items()):
        values = _as_1d(key, values)
        ax.plot(np.arange(len(values)), values, marker="o", markersize=3)
        ax.set_ylabel(key)
        finite = values[np.isfinite(values)]
        if key in logy_keys and finite.size and np.all(finite > 0):
            ax.set_yscale("log")
    axes[-1].set_xlabel("iteration")
    axes[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    if title:
        fig.suptitle(_fitted(title, fig))
    return save_figure(fig, path)


def plot_value_profile(path, tau, value, converged, *, marks=(), title=None) -> Path:
    """The value profile ``J*(tau) = max_xi J(xi, tau)`` against tau: converged points filled, the others
    hollow; ``marks`` ``[(t, label), ...]`` as dotted vertical lines (e.g. the paper's tau and tau*)."""
    tau, value = _as_1d("tau", tau), _as_1d("J*", value, np.size(tau))
    ok = np.asarray(converged, dtype=bool)
    fig = new_figure(6.4, 3.6)
    ax = fig.subplots()
    ax.plot(tau, value, color="C0", lw=1)
    ax.plot(tau[ok], value[ok], "o", color="C0", ms=4, label="converged (KKT)")
    if np.any(~ok):
        ax.plot(tau[~ok], value[~ok], "o", mfc="none", color="C0", ms=4, label="not converged")
    for k, (t, label) in enumerate(marks):
        ax.axvline(t, ls=":", color=f"C{k + 1}", label=label)
    ax.set_xlabel(axis_label("tau"))
    ax.set_ylabel(axis_label("J*(tau) = max over xi of J(xi, tau)"))
    ax.legend(fontsize="small")
    if title:
        ax.set_title(_fitted(title, fig))
    return save_figure(fig, path)


def plot_pressure_comparison(path, pressures: dict, rises: dict, *, tau=None, eps=None, title=None,
                             units=None, zoom=None) -> Path:
    """Pressures of several runs (top) and their rates of rise (middle), tau marked; with ``zoom``, the rates
    around tau once more (bottom), where a control that acts near tau shows.

    Parameters
    ----------
    path : path
        Output PNG.
    pressures : dict of str -> ((L,), (L,)) array_like
        Each run's label mapped to its time levels [units.time] and pressure [units.pressure].
    rises : dict of str -> ((L',), (L',)) array_like
        Each run's label mapped to times and its rate of pressure rise ``(p(t + eps) - p(t)) / eps``
        [units.pressure / units.time].
    tau, eps : float, optional
        The free time (a dashed line) and the window ``[tau, tau + eps]`` (shaded) [units.time].
    title : str, optional
        Figure title.
    units : Units, optional
        Units of the axes.
    zoom : float, optional
        Half-width of the bottom panel's window ``[tau - zoom, tau + eps + zoom]`` [units.time]; needs tau.

    Returns
    -------
    Path
    """
    units = units or Units()
    zoomed = zoom is not None and tau is not None
    fig = new_figure(6.4, 8.8 if zoomed else 6.4)
    axes = fig.subplots(3 if zoomed else 2, 1)
    top, middle = axes[0], axes[1]
    middle.sharex(top)
    top.tick_params(labelbottom=False)
    for k, (label, (t, p)) in enumerate(pressures.items()):
        top.plot(_as_1d("t", t), _as_1d("p", p, np.size(t)), color=f"C{k}", label=label)
    rate_label = axis_label(r"(p(t + $\varepsilon$) - p(t)) / $\varepsilon$", units.pressure_rate)
    for ax in axes[1:]:
        for k, (label, (t, r)) in enumerate(rises.items()):
            ax.plot(_as_1d("t", t), _as_1d("rate", r, np.size(t)), color=f"C{k}", label=label)
        ax.set_ylabel(rate_label)
    for ax in axes:
        if tau is not None:
            ax.axvline(tau, color="k", linestyle="--", linewidth=1.0, label=r"$\tau^*$")
            if eps is not None:
                ax.axvspan(tau, tau + eps, color="0.85", label=r"$[\tau^*, \tau^*+\varepsilon]$")
    if zoomed:
        _zoom_to(axes[2], rises, tau - zoom, tau + (eps or 0.0) + zoom)
        axes[2].set_title(r"around $\tau^*$", fontsize="small")
    top.set_ylabel(axis_label("pressure p", units.pressure))
    axes[-1].set_xlabel(axis_label("time t", units.time))
    top.legend(loc="best", fontsize="small")
    if title:
        fig.suptitle(_fitted(title, fig))
    return save_figure(fig, path)


def _zoom_to(ax, curves: dict, lo: float, hi: float) -> None:
    """Limit ``ax`` to ``lo <= t <= hi`` and to the range the ``curves`` ({label: (t, y)}) take there."""
    inside = [np.asarray(y)[(np.asarray(t) >= lo) & (np.asarray(t) <= hi)] for t, y in curves.values()]
    values = np.concatenate(inside) if inside else np.zeros(0)
    ax.set_xlim(lo, hi)
    if values.size:
        pad = 0.05 * max(np.ptp(values), 1e-12 * np.max(np.abs(values)))
        ax.set_ylim(values.min() - pad, values.max() + pad)


def plot_pv_loops(path, loops: dict, *, title=None, units=None) -> Path:
    """Pressure-volume loops: each run's pressure against its cavity volume, its start marked.

    Parameters
    ----------
    path : path
        Output PNG.
    loops : dict of str -> ((L,), (L,)) array_like
        Each run's label (a legend entry) mapped to its cavity volume [units.length^3] and pressure
        [units.pressure] at the same levels; the first level is marked.
    title : str, optional
        Figure title.
    units : Units, optional
        Units of the axes.

    Returns
    -------
    Path
    """
    units = units or Units()
    fig = new_figure(6.4, 4.8)
    ax = fig.subplots()
    for k, (label, (v, p)) in enumerate(loops.items()):
        v = _as_1d("volume", v)
        ax.plot(v, _as_1d("p", p, v.size), color=f"C{k}", label=label)
        ax.plot(v[:1], np.asarray(p)[:1], "o", color=f"C{k}", ms=4)
    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3), useOffset=False)  # m^3 as 1e-4 m^3
    ax.set_xlabel(axis_label("cavity volume", units.volume))
    ax.set_ylabel(axis_label("pressure p", units.pressure))
    ax.legend(loc="best", fontsize="small")
    if title:
        fig.suptitle(_fitted(title, fig))
    return save_figure(fig, path)

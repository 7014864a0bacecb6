"""Files people can look at, written from solutions: NPZ arrays, JSON summary, PNG plots, ParaView series.

Every file goes through `hyperoc.io`'s atomic writers, so an interrupted run never leaves a
half-written result behind.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._jax import on_device
from ..dynamics.stepper import StateSolution
from ..fem.volumes import cavity_volume
from ..io import write_json, write_npz, write_time_series
from ..mechanics.fibres import FibreFrames
from ..mechanics.materials import det
from .plotting import Units, plot_control_spacetime, plot_history, plot_pressure, plot_snapshots

__all__ = ["write_state_outputs", "cell_det_F", "PAPER_STATE_TIMES", "PAPER_CONTROL_TIMES"]

# Times of the paper's Figures figDisp and figVelo (the state), and figControl (the control).
PAPER_STATE_TIMES = (0.02, 1.0, 2.5, 3.0, 4.0, 5.0, 6.0, 6.3, 7.0, 8.0, 9.0, 10.0, 12.0, 13.0, 14.0, 15.0)
PAPER_CONTROL_TIMES = (0.02, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0, 6.5, 7.0, 7.46, 7.48)

DEFAULT_TITLE = "hyperoc run"  # names the run in the figures' titles when no title is given

_CELL_TYPES = {(1, 1): "line", (1, 2): "line3", (2, 1): "triangle", (2, 2): "triangle6", (3, 1): "tetra",
               (3, 2): "tetra10"}


def _series_levels(n_levels: int, every: int | None, max_frames: int = 200) -> np.ndarray:
    every = every or max(1, int(np.ceil(n_levels / max_frames)))
    levels = np.arange(0, n_levels, every)
    return levels if levels[-1] == n_levels - 1 else np.append(levels, n_levels - 1)


def _vtk_cells(sol: StateSolution) -> tuple[np.ndarray, str]:
    space = sol.model.space
    cells = space.cell_nodes
    if space.degree == 2 and space.dim == 1:
        cells = cells[:, [0, 1, 2]]
    return cells, _CELL_TYPES[(space.dim, space.degree)]


def cell_det_F(sol: StateSolution, levels: np.ndarray) -> np.ndarray:
    """``min det F`` over the quadrature points of each cell at the given levels, (len(levels), nc)."""
    model = sol.model
    fn = jax.jit(lambda u: jnp.min(det(model.deformation_gradient(u)), axis=1))
    return np.stack([np.asarray(fn(on_device(sol.y0[n]))) for n in levels])


def _cell_series(sol: StateSolution, levels: np.ndarray, frames: FibreFrames | None) -> dict:
    """Cell fields of the ParaView series, each (len(levels), nc[, k]).

    ``det_F`` (min over the cell's quadrature points); with ``frames`` the unit vectors ``fibre``,
    ``sheet``, ``normal`` at the centroids (constant in time); with an active-stress control the tensor
    ``active_stress = xi_c fhat (x) fhat`` (9 components, a 2D tensor padded with zeros to 3 x 3 as
    ParaView and XDMF expect, stress units, zero outside omega; ``xi_c`` the mean of the cell's nodal
    control values, ``fhat`` the control's fibre at the centroid).
    """
    model, nc = sol.model, sol.model.mesh.num_cells
    fields = {"det_F": cell_det_F(sol, levels)}
    if frames is not None:
        R = frames.cell_frames()
        for k, name in enumerate(("fibre", "sheet", "normal")):
            fields[name] = np.broadcast_to(R[:, k], (levels.size, nc, 3))
    control = model.control
    if sol.xi is not None and control is not None and control.fibres is not None:
        f = control.fibres
        xi_c = control.cell_values(sol.xi[levels])[..., 0]  # (nl, nc_omega)
        d = model.dim
        stress = np.zeros((levels.size, nc, 3, 3))
        stress[:, control.cell_mask, :d, :d] = xi_c[..., None, None] * np.einsum("ci,cj->cij", f, f)
        fields["active_stress"] = stress.reshape(levels.size, nc, 9)
    return fields


def write_state_outputs(out: Path, sol: StateSolution, *, tau: float | None = None, eps: float | None = None,
                        snapshot_times=None, series_every: int | None = None, extra_summary: dict | None = None,
                        history: dict | None = None, frames: FibreFrames | None = None, title: str | None = None,
                        units: Units | None = None, pressure_marks=None) -> dict:
    """Write results.npz, summary.json, pressure.png, the ParaView series and figures.

    results.npz holds ``t, p, p_steps, volume, nodes, displacement, velocity`` (all levels), the
    per-step monitors ``newton_iterations, min_det_F``, the control ``xi`` with its node
    coordinates ``xi_nodes`` when there is a control, and in 3D with an ``endocardium`` boundary the
    `cavity_volume`. pressure.png shows p (tau marked), the body-volume drift and the cavity volume;
    control.png the control's space-time map (1D; 2D/3D scalar controls: means over slices of the
    last coordinate, the long axis of a ventricle); 1D adds snapshot figures. The series ``paraview/state``
    has the point fields ``displacement``, ``velocity``, ``control`` (the control's space-time field, zero
    outside omega) and the cell fields of `_cell_series` (``frames``: the fibre frames, for output only).

    Every figure is titled ``"{title}: {figure}"`` (``title``: the run's name, default
    `DEFAULT_TITLE`) and its axes carry ``units`` (`hyperoc.app.plotting.Units`, default dimensionless);
    ``pressure_marks``: ``[(t, label), ...]`` marked on the pressure panel. Returns the summary.
    """
    title, units = title or DEFAULT_TITLE, units or Units()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model = sol.model
    u, v = sol.displacement(), sol.velocity()
    arrays = dict(t=sol.t, p=sol.pressure, p_steps=sol.p_steps, volume=sol.volume, nodes=model.space.nodes,
                  displacement=u, velocity=v, newton_iterations=sol.newton_iterations, min_det_F=sol.min_det_F)
    xi_nodal = None
    if sol.xi is not None and model.control is not None:
        xi_nodal = model.control.nodal(sol.xi)
        arrays.update(xi=xi_nodal, xi_nodes=model.control.coordinates(model.space))

    files = {"results": "results.npz", "pressure_plot": "pressure.png"}
    cavity, cavity_summary = None, {}
    if model.dim == 3 and "endocardium" in model.mesh.boundaries:
        cavity = cavity_volume(model.space, u)
        arrays["cavity_volume"] = cavity
        cavity_summary = {"cavity_volume_0": float(cavity[0]),
                          "cavity_volume_change_max": float(np.max(np.abs(cavity / cavity[0] - 1.0)))}
    write_npz(out / "results.npz", **arrays)
    plot_pressure(out / "pressure.png", sol.t, sol.pressure, tau=tau, eps=eps, volume=sol.volume, cavity=cavity,
                  title=f"{title}: pressure", units=units, marks=pressure_marks)
    cells, cell_type = _vtk_cells(sol)
    levels = _series_levels(sol.t.size, series_every)
    point_data = {"displacement": u[levels], "velocity": v[levels]}
    if xi_nodal is not None:
        full = np.zeros((levels.size, model.space.num_nodes, xi_nodal.shape[-1]))
        full[:, model.control.nodes] = xi_nodal[levels]
        point_data["control"] = full
    series = write_time_series(out / "paraview", "state", model.space.nodes, cells, cell_type, sol.t[levels],
                               point_data, cell_data=_cell_series(sol, levels, frames))
    files["time_series"] = str(Path(series).relative_to(out))
    if model.dim == 1:
        files.update(_write_1d_figures(out, sol, u, v, xi_nodal, snapshot_times, title, units, tau))
    elif xi_nodal is not None and xi_nodal.shape[-1] == 1:
        z = model.control.coordinates(model.space)[:, -1]
        centers, means = _slice_means(z, xi_nodal[..., 0])
        plot_control_spacetime(out / "control.png", sol.t, centers, means, xlabel=f"{'yz'[model.dim - 2]} (slice mean)",
                               tau=tau, title=f"{title}: control xi", units=units)
        files["control_plot"] = "control.png"
    if history:
        plot_history(out / "history.png", history, title=f"{title}: optimizer history")
        files["history_plot"] = "history.png"
    summary = {**sol.summary(), "newton_iterations_mean": float(np.mean(sol.newton_iterations)), **cavity_summary,
               "files": files, **(extra_summary or {})}
    write_json(out / "summary.json", summary)
    return summary


def _slice_means(z: np.ndarray, values: np.ndarray, n_slices: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Means of nodal values (nt, n) over ``n_slices`` equal slices of the coordinate z (n,) that
    hold nodes: slice centers (k,) and means (nt, k)."""
    edges = np.linspace(z.min(), z.max(), n_slices + 1)
    which = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, n_slices - 1)
    count = np.bincount(which, minlength=n_slices)
    sums = np.stack([np.bincount(which, weights=row, minlength=n_slices) for row in values])
    used = count > 0
    return (0.5 * (edges[:-1] + edges[1:]))[used], sums[:, used] / count[used]


def _write_1d_figures(out: Path, sol: StateSolution, u, v, xi_nodal, times, title: str, units: Units,
                      tau: float | None = None) -> dict:
    """The 1D figures: displacement, velocity and control snapshots at ``times`` (default: the paper's,
    `PAPER_STATE_TIMES` and `PAPER_CONTROL_TIMES`) and the control's space-time map, titled
    ``"{title}: ..."``, with ``units``."""
    x = sol.model.space.nodes[:, 0]
    order = np.argsort(x)
    state_times = [t for t in times or PAPER_STATE_TIMES if sol.t[0] <= t <= sol.t[-1]]
    control_times = [t for t in times or PAPER_CONTROL_TIMES if sol.t[0] <= t <= sol.t[-1]]
    plot_snapshots(out / "displacement.png", x[order], sol.t, u[:, order, 0], state_times, ylabel="u(x, t)",
                   title=f"{title}: displacement u", units=units, field_unit=units.length)
    plot_snapshots(out / "velocity.png", x[order], sol.t, v[:, order, 0], state_times, ylabel="u_t(x, t)",
                   title=f"{title}: velocity u_t", units=units, field_unit=units.velocity)
    files = {"displacement_plot": "displacement.png", "velocity_plot": "velocity.png"}
    if xi_nodal is not None:
        xc = sol.model.control.coordinates(sol.model.space)[:, 0]
        o = np.argsort(xc)
        plot_control_spacetime(out / "control.png", sol.t, xc[o], xi_nodal[:, o, 0], tau=tau,
                               title=f"{title}: control xi", units=units)
        plot_snapshots(out / "control_snapshots.png", xc[o], sol.t, xi_nodal[:, o, 0], control_times,
                       ylabel="xi(x, t)",
                       title=f"{title}: control xi", units=units, field_unit=units.control)
        files.update(control_plot="control.png", control_snapshots_plot="control_snapshots.png")
    return files

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
from ..cardiac.hemodynamics import solution_beat
from ..dynamics.stepper import StateSolution
from ..errors import InputError
from ..io import write_json, write_npz, write_time_series
from ..mechanics.cavity import CavityVolume
from ..mechanics.materials import det
from .plotting import (
    TimeMarks,
    Units,
    axis_label,
    plot_control_spacetime,
    plot_history,
    plot_pressure,
    plot_pv_loops,
    plot_snapshots,
)

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


def _cell_series(sol: StateSolution, levels: np.ndarray, frames) -> dict:
    """Cell fields of the ParaView series, each (len(levels), nc[, k]); tensors have 9 components, a 1D or
    2D tensor padded with zeros to 3 x 3 as ParaView and XDMF expect.

    ``det_F`` (min over the cell's quadrature points); ``cauchy_stress`` (`_stress_and_fibre_strain`);
    with an active-stress control ``active_stress = -g(t) xi_c fhat (x) fhat``, the first Piola-Kirchhoff stress
    the control adds, with the sign it acts with (a contraction, fibre tension T_a = -xi_c > 0, is
    positive; stress units, zero outside omega; ``xi_c`` the mean of the cell's nodal control values,
    ``fhat`` the control's fibre at the centroid, g the control's time profile, 1 without one,
    `hyperoc.mechanics.controls.ActiveStress`). With
    ``frames`` (`hyperoc.mechanics.fibres.FibreFrames`, or any callable ``x (nc, nq, 3) -> (nc, nq, k,
    3)`` as `hyperoc.mechanics.model.StateModel` takes) the unit vectors ``fibre``, ``sheet``, ``normal``
    at the centroids (constant in time) and the fibre strain ``E_ff``.
    """
    model, nc, d = sol.model, sol.model.mesh.num_cells, sol.model.dim
    fields = {"det_F": cell_det_F(sol, levels)}
    fibre = None
    if frames is not None:
        R = np.asarray(frames(model.mesh.cell_centroids()[:, None, :]))[:, 0]  # (nc, k, 3)
        for k, name in enumerate(("fibre", "sheet", "normal")[:R.shape[1]]):
            fields[name] = np.broadcast_to(R[:, k], (levels.size, nc, 3))
        fibre = np.asarray(frames(model.quad.x))[..., 0, :]  # (nc, nq, d) at the quadrature points
    active = np.zeros((levels.size, nc, d, d))
    control = model.control
    if sol.xi is not None and control is not None and control.fibres is not None:
        f = control.fibres
        xi_c = control.cell_values(sol.xi[levels])[..., 0] * control.scale(sol.t[levels])[:, None]  # (nl, nc_omega)
        active[:, control.cell_mask] = -xi_c[..., None, None] * np.einsum("ci,cj->cij", f, f)
        fields["active_stress"] = _padded_tensor(active)
    sigma, E_ff = _stress_and_fibre_strain(sol, levels, active, fibre)
    fields["cauchy_stress"] = _padded_tensor(sigma)
    if E_ff is not None:
        fields["E_ff"] = E_ff
    return fields


def _padded_tensor(a: np.ndarray) -> np.ndarray:
    """Tensors (..., d, d) as (..., 9), zero-padded to 3 x 3."""
    d = a.shape[-1]
    out = np.zeros((*a.shape[:-2], 3, 3))
    out[..., :d, :d] = a
    return out.reshape(*a.shape[:-2], 9)


def _stress_and_fibre_strain(sol: StateSolution, levels: np.ndarray, active: np.ndarray, fibre):
    """Per cell and level, the means over the cell's quadrature points (weights ``w dx``) of

    - the Cauchy stress ``sigma = J^-1 (P(F) + P_a) F^T`` (nl, nc, d, d), stress units: P = dW/dF the
      material law's first Piola-Kirchhoff stress (its bulk term at each point, also for ``volumetric =
      "cell-mean"``), P_a the control's active stress (``active`` (nl, nc, d, d), zero without one); the
      volume multiplier p is not in it: it acts as the pressure ``-p cof(F) N`` on the free walls. The
      law's part is symmetric; the active part ``J^-1 P_a F^T = -xi J^-1 fhat (x) F fhat`` of the paper's
      control operator is not;
    - with ``fibre`` (nc, nq, d), the unit fibre at the quadrature points, the fibre strain
      ``E_ff = f . E f``, ``E = (F^T F - I) / 2`` (nl, nc), dimensionless; else None.
    """
    model = sol.model
    w = np.asarray(model.quad.wdx)
    law = model.material.energy_of_F
    first_piola = jax.grad(law)

    def fields(u, P_a):
        F = model.deformation_gradient(u)
        P = model.pointwise(first_piola, F) + P_a[:, None]  # the law at the model's own material frames
        sigma = jnp.einsum("cqij,cqkj->cqik", P, F) / det(F)[..., None, None]
        E = 0.5 * (jnp.einsum("cqki,cqkj->cqij", F, F) - jnp.eye(model.dim))
        E_ff = jnp.zeros(F.shape[:2]) if fibre is None else jnp.einsum("cqi,cqij,cqj->cq", fibre, E, fibre)
        return sigma, E_ff

    fn = jax.jit(fields)
    weights = w / w.sum(axis=1, keepdims=True)
    out = [fn(on_device(sol.y0[n]), on_device(P_a)) for n, P_a in zip(levels, active)]
    sigma = np.stack([np.einsum("cq,cqij->cij", weights, np.asarray(s)) for s, _ in out])
    E_ff = None if fibre is None else np.stack([np.einsum("cq,cq->c", weights, np.asarray(e)) for _, e in out])
    return sigma, E_ff


def write_state_outputs(out: Path, sol: StateSolution, *, tau: float | None = None, eps: float | None = None,
                        snapshot_times=None, series_every: int | None = None, extra_summary: dict | None = None,
                        history: dict | None = None, frames=None, title: str | None = None,
                        units: Units | None = None, pressure_marks=None, cavity: str | None = "endocardium") -> dict:
    """Write results.npz, summary.json, pressure.png, the ParaView series and figures.

    results.npz holds ``t, p, p_steps, volume, nodes, displacement, velocity`` (all levels), the
    per-step monitors ``newton_iterations, min_det_F``, the control ``xi`` (levels, n_nodes, components)
    with its time levels ``t`` and node coordinates ``xi_nodes`` when there is a control (a control file
    as written: ``[control] file`` replays it on its levels), in 3D the `cavity_volume` enclosed by the
    boundary ``cavity`` (default ``"endocardium"``, `_cavity_volumes`; a 3D mesh without it gets a warning
    saying so, unless ``cavity`` is None: a body with no cavity), with a cavity constraint the volume it holds
    ``constrained_cavity_volume`` (with the constraint's apex), and with the circulation constraint its
    ``aortic_pressure`` and ``phase`` after each step (N,) (the summary's ``beat``: its valve events and
    ejections, `hyperoc.cardiac.hemodynamics.solution_beat`). pressure.png shows p (tau marked), the body-volume
    drift and the cavity volume; pv_loop.png the pressure against the cavity volume (the constrained one if any,
    else the reported); control.png the control's space-time map (1D; 2D/3D scalar controls: means over slices
    along the mesh's longest extent, the long axis of a ventricle: `_long_axis`); 1D adds snapshot figures.
    The series ``paraview/state`` has the point fields ``displacement``, ``velocity``, ``control`` (the
    control's space-time field, zero outside omega; a scalar for an active stress) and the cell fields
    of `_cell_series` (``frames``: the fibre frames, for output only).

    Every figure is titled ``"{title}: {figure}"`` (``title``: the run's name, default
    `DEFAULT_TITLE`) and its axes carry ``units`` (`hyperoc.app.plotting.Units`, default dimensionless);
    ``pressure_marks``: ``[(t, label), ...]`` marked on the pressure panel. Returns the summary, whose
    pressure extrema leave out extrapolated levels (`_pressure_extrema`).
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
    cavity_values, cavity_summary = _cavity_volumes(sol, cavity), {}
    if cavity_values is not None:
        arrays["cavity_volume"] = cavity_values
        cavity_summary = {"cavity_volume_0": float(cavity_values[0]),
                          "cavity_volume_change_max": float(np.max(np.abs(cavity_values / cavity_values[0] - 1.0)))}
    if sol.multiplier_states is not None:  # the circulation's carried (p, Pa, phase) after each step
        arrays.update(aortic_pressure=sol.multiplier_states[:, 1], phase=sol.multiplier_states[:, 2])
    if sol.constrained_volume is not None:
        arrays["constrained_cavity_volume"] = sol.constrained_volume
    write_npz(out / "results.npz", **arrays)
    # the loop of the volume a cavity constraint holds (its isovolumic phases vertical), else of the reported one
    loop_volume = cavity_values if sol.constrained_volume is None else sol.constrained_volume
    if loop_volume is not None:
        plot_pv_loops(out / "pv_loop.png", {"p(V)": (loop_volume, sol.pressure)},
                      title=f"{title}: pressure-volume loop", units=units)
        files["pv_loop_plot"] = "pv_loop.png"
    plot_pressure(out / "pressure.png", sol.t, sol.pressure, volume=sol.volume, cavity=cavity_values,
                  marks=TimeMarks(tau, eps, tuple(pressure_marks or ())), title=f"{title}: pressure", units=units)
    cells, cell_type = _vtk_cells(sol)
    levels = _series_levels(sol.t.size, series_every)
    point_data = {"displacement": u[levels], "velocity": v[levels]}
    if xi_nodal is not None:  # a scalar control (active stress) as a scalar field: its sign is its meaning
        full = np.zeros((levels.size, model.space.num_nodes, xi_nodal.shape[-1]))
        full[:, model.control.nodes] = xi_nodal[levels]
        point_data["control"] = full[..., 0] if full.shape[-1] == 1 else full
    series = write_time_series(out / "paraview", "state", model.space.nodes, (cell_type, cells), sol.t[levels],
                               point_data, cell_data=_cell_series(sol, levels, frames))
    files["time_series"] = str(Path(series).relative_to(out))
    if model.dim == 1:
        files.update(_write_1d_figures(out, sol, u, v, xi_nodal, snapshot_times, title, units, tau))
    elif xi_nodal is not None and xi_nodal.shape[-1] == 1:
        axis = _long_axis(model.mesh.points)
        centers, means = _slice_means(model.control.coordinates(model.space)[:, axis], xi_nodal[..., 0])
        plot_control_spacetime(out / "control.png", sol.t, centers, means, xlabel=f"{'xyz'[axis]} (slice mean)",
                               tau=tau, title=f"{title}: control xi", units=units)
        files["control_plot"] = "control.png"
    if history:
        plot_history(out / "history.png", history, title=f"{title}: optimizer history")
        files["history_plot"] = "history.png"
    summary = {**sol.summary(), **_pressure_extrema(sol), **cavity_summary, **_beat(sol),
               "newton_iterations_mean": float(np.mean(sol.newton_iterations)), "files": files, **(extra_summary or {})}
    write_json(out / "summary.json", summary)
    return summary


def _beat(sol: StateSolution) -> dict:
    """``{"beat": ...}``, the indices of a run closed by the circulation (valve events, ejections, stroke volume,
    ejection fraction: `hyperoc.cardiac.hemodynamics.solution_beat`); empty for the other constraints."""
    beat = solution_beat(sol)
    return {} if beat is None else {"beat": beat}


def _cavity_volumes(sol: StateSolution, cavity: str | None) -> np.ndarray | None:
    """In 3D, the volume (L,) of the cavity bounded by the wall ``cavity`` at each level, closed at its rim by
    the lid from the deformed rim's centroid (`hyperoc.mechanics.cavity.CavityVolume` with ``apex="rim"``);
    None, with a warning added to ``sol.warnings``, for a mesh without that wall or a wall that encloses no
    cavity (a flat face, an outer wall); None without a warning in 2D or for ``cavity`` None."""
    model = sol.model
    if model.dim != 3 or cavity is None:
        return None
    if cavity not in model.mesh.boundaries:
        sol.warnings = [*sol.warnings, f"no cavity_volume: the mesh has no boundary {cavity!r} (its boundaries: "
                        f"{', '.join(sorted(model.mesh.boundaries))}); [fibres] inner names the cavity's wall"]
        return None
    try:
        return CavityVolume(model, cavity, apex="rim").volumes(sol.y0)
    except InputError:
        sol.warnings = [*sol.warnings, f"no cavity_volume: the boundary {cavity!r} encloses no cavity"]
        return None


def _pressure_extrema(sol: StateSolution) -> dict:
    """``pressure_max``, ``t_pressure_max``, ``pressure_min`` over the levels whose pressure comes from
    computed multipliers: every level when the multipliers are level values (``multiplier = "theta"``),
    else the interior ones, each between two computed mid-step values; the two end levels extrapolate
    them (`hyperoc.dynamics.stepper.level_pressure`) and are left out, unless there is no interior level."""
    computed = slice(None) if sol.p_steps.shape[0] == sol.t.size or sol.t.size < 3 else slice(1, -1)
    p, t = sol.pressure[computed], sol.t[computed]
    k = int(np.argmax(p))
    return {"pressure_max": float(p[k]), "t_pressure_max": float(t[k]), "pressure_min": float(np.min(p))}


def _long_axis(points: np.ndarray) -> int:
    """The coordinate (0, 1 or 2) along which the points (n, d) extend furthest, the last of equal ones: a
    ventricle's long axis (z for `hyperoc.fem.geometry`'s, x for the cardiac benchmark's)."""
    extent = np.ptp(points, axis=0)
    return int(extent.size - 1 - np.argmax(extent[::-1]))


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
    plot_snapshots(out / "displacement.png", x[order], sol.t, u[:, order, 0], state_times,
                   ylabel=axis_label("u(x, t)", units.length), title=f"{title}: displacement u", units=units)
    plot_snapshots(out / "velocity.png", x[order], sol.t, v[:, order, 0], state_times,
                   ylabel=axis_label("u_t(x, t)", units.velocity), title=f"{title}: velocity u_t", units=units)
    files = {"displacement_plot": "displacement.png", "velocity_plot": "velocity.png"}
    if xi_nodal is not None:
        xc = sol.model.control.coordinates(sol.model.space)[:, 0]
        o = np.argsort(xc)
        plot_control_spacetime(out / "control.png", sol.t, xc[o], xi_nodal[:, o, 0], tau=tau,
                               title=f"{title}: control xi", units=units)
        plot_snapshots(out / "control_snapshots.png", xc[o], sol.t, xi_nodal[:, o, 0], control_times,
                       ylabel=axis_label("xi(x, t)", units.control), title=f"{title}: control xi", units=units)
        files.update(control_plot="control.png", control_snapshots_plot="control_snapshots.png")
    return files

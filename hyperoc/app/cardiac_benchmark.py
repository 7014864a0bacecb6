"""The cardiac elastodynamics benchmark as a run of the configuration (``hyperoc benchmark
cardiac-elastodynamics``): the shipped configuration ``hyperoc/data/cardiac-benchmark.toml`` of each step
(`benchmark_config`) solved in checkpointed segments (`hyperoc.dynamics.resumable.run_resumable`: an
interrupted run resumes bitwise), recorded and compared by `hyperoc.cardiac.benchmark` (`run_benchmark`); its
files and figures are `hyperoc.app.cardiac_benchmark_report`'s.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from ..cardiac.benchmark import benchmark_curves, compare_with_codes
from ..cardiac.benchmark_curves import STEPS
from ..errors import InputError
from .config import parse_config

__all__ = ["STEP_LOADS", "benchmark_config", "run_benchmark"]

#: The loads each step keeps, of ``[dynamics] pressure`` and ``[dynamics] activation``.
STEP_LOADS = {"0A": ("activation",), "0B": ("pressure",), "1": ("pressure", "activation")}
#: Time steps per checkpoint segment.
CHECKPOINT_EVERY = 50


def benchmark_config(step: str = "1", *, degree: int = 1, mesh: str = "reference", T: float | None = None,
                     dt: float | None = None, solver: str | None = None):
    """The `hyperoc.app.config.Config` of benchmark step ``step`` (`STEP_LOADS`): Lagrange ``degree`` 1 or 2,
    ``mesh`` ``"reference"`` (the benchmark's) or ``"coarse"``, the end time ``T`` (s; default the beat, 1 s),
    the time step ``dt`` (s; default the benchmark's, 1 ms), the linear ``solver`` (``[dynamics] solver``;
    default the shipped config's)."""
    step = _step(step)
    if degree not in (1, 2):
        raise InputError(f"cardiac benchmark: degree must be 1 or 2, got {degree}")
    source = resources.files("hyperoc").joinpath("data", "cardiac-benchmark.toml")
    data = tomllib.loads(source.read_text(encoding="utf-8"))
    data["mesh"].update(degree=degree, variant=mesh)
    for load in ("pressure", "activation"):
        if load not in STEP_LOADS[step]:
            del data["dynamics"][load]
    if T is not None:
        data["dynamics"]["T"] = float(T)
    if dt is not None:
        data["dynamics"]["dt"] = float(dt)
    if solver is not None:
        data["dynamics"]["solver"] = solver
    return parse_config(data, Path("."), f"cardiac benchmark step {step} (P{degree}, {mesh} mesh)")


def _step(step) -> str:
    step = str(step).upper()
    if step not in STEPS:
        raise InputError(f"cardiac benchmark: unknown step {step!r} (steps: {', '.join(STEPS)})")
    return step


def run_benchmark(step: str, out, *, degree: int = 1, mesh: str = "reference", T: float | None = None,
                  dt: float | None = None, solver: str | None = None, progress: bool = False, on_segment=None,
                  model=None, stepper=None) -> dict:
    """Solve benchmark step ``step`` (`benchmark_config`) with checkpoints in ``out/segments`` and return the
    record `benchmark_curves` makes of it, with the comparison `compare_with_codes` under ``"comparison"``
    and the run's cost. A run started again on the same ``out`` resumes from its last segment. ``model``: the
    configuration's model if already built (`hyperoc.app.workflows.check_run`); ``stepper``: its stepper if
    built (on MPI ranks a `hyperoc.distributed.dynamics.DistributedStepper` of that model)."""
    from ..dynamics.resumable import SEGMENTS_DIR, Segments, run_resumable, segment_costs

    cfg = benchmark_config(step, degree=degree, mesh=mesh, T=T, dt=dt, solver=solver)
    model = stepper.model if stepper is not None else model or cfg.model()
    stepper, grid = stepper or cfg.stepper(model), cfg.grid()
    folder = Path(out) / SEGMENTS_DIR
    sol = run_resumable(stepper, grid, None, segments=Segments(folder, CHECKPOINT_EVERY, cfg.sections),
                        progress=progress, on_segment=on_segment)
    record = benchmark_curves(sol, stepper)
    record.update(step=_step(step), mesh={"variant": mesh, "vertices": int(len(model.mesh.points)),
                                          "cells": int(len(model.mesh.cells))},
                  degree=degree, dt=float(cfg["dynamics"]["dt"]), unknowns=int(model.n),
                  scheme={"theta": float(cfg["dynamics"]["theta"]), "newton": cfg["dynamics"]["newton"]},
                  solver=cfg["dynamics"]["solver"],
                  newton_iterations={"total": int(np.sum(sol.newton_iterations)),
                                     "mean": float(np.mean(sol.newton_iterations)),
                                     "max": int(np.max(sol.newton_iterations))},
                  **segment_costs(folder))
    record["comparison"] = compare_with_codes(record)
    return record

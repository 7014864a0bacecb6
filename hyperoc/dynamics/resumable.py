"""Forward solves that survive interruption: the time steps in segments, each segment's outputs saved
atomically as it ends, a run resumed from the last saved segment.

A long 3D solve (a heart beat on a benchmark mesh: hours on two cores) is a cluster job with a wall-time
limit. `run_resumable` cuts the grid into segments of ``every`` steps. Each segment starts from the state
the previous one ended in, with no factorization kept from it (`SparseSolver.forget_factorization`: chord
Newton refreshes at the first step of every segment), and writes its outputs to
``folder/segment_<k>.npz`` by a temporary file and a rename. A run started again on the same folder reads
the segments found there and solves the others: whether it was interrupted or not, every segment is
computed from the same state with the same solver history, so the result is bitwise the same.

The folder also holds ``problem.json``, a fingerprint of what was solved (model size, grid, controls and
loads, scheme, segment length); resuming a different problem is refused.
"""

from __future__ import annotations

import hashlib
import json
import resource
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..io import atomic_write_bytes, atomic_write_text, npz_bytes

if TYPE_CHECKING:  # annotations only: the CLI reads SEGMENTS_DIR before any JAX is imported
    from .stepper import StateSolution, TimeStepper
    from .timegrid import TimeGrid

__all__ = ["run_resumable", "Segments", "segment_costs", "SEGMENTS_DIR", "SEGMENT_OUTPUTS", "SEGMENT_COST"]

#: the per-step outputs of `TimeStepper.march_levels` a segment file holds, in its order
SEGMENT_OUTPUTS = ("y0", "y1", "p", "newton_iterations", "status", "min_det_F", "max_grad")
#: the folder of a run's output folder that holds its segments (what ``--resume`` continues)
SEGMENTS_DIR = "segments"
#: what a segment file records of its solve: seconds, and the solving process's peak resident memory (MiB)
SEGMENT_COST = ("wall_time", "peak_memory_mib")


@dataclass(frozen=True)
class Segments:
    """Where and how a resumable run is saved: segments of ``every`` steps in ``folder`` (created if needed);
    ``identity``: JSON data naming the problem beyond what the fingerprint digests (e.g. a configuration's
    sections), compared on resume."""

    folder: Path | str
    every: int
    identity: dict | None = None


def run_resumable(stepper: TimeStepper, grid: TimeGrid, xi=None, *, segments: Segments, u0=None, v0=None,
                  external=None, progress: bool = False, on_segment=None) -> StateSolution:
    """`TimeStepper.run` in the `Segments` ``segments``, resuming from the segments already saved. Same
    arguments and result as `TimeStepper.run` (multiplier "step" only: the "theta" weighting carries p across
    steps as a state the segments would have to agree on). `hyperoc.errors.SolverError` names the first failed
    step as `run` does; the segments before it stay saved.

    ``on_segment(index, count, segment, solved)``: called after each segment
    (``solved`` False for one read back), e.g. to log progress to a file. The result's ``wall_time`` is the
    sum over all segments, those solved by an earlier process included (`SEGMENT_COST`); `segment_costs`
    reads them back."""
    every = segments.every
    if every < 1:
        raise InputError(f"checkpoint segments need every >= 1 step, got {every}")
    if stepper.scheme.multiplier != "step":
        raise InputError("resumable solves need the scheme's multiplier 'step'")
    m, N = stepper.model, grid.num_steps
    y0 = np.zeros(m.n) if u0 is None else np.asarray(u0, dtype=np.float64)
    y1 = np.zeros(m.n) if v0 is None else np.asarray(v0, dtype=np.float64)
    xis, fs = stepper._controls(xi, N), stepper.external_loads(external, grid)
    stepper._check_initial_velocity(y0, y1, grid.t[0])
    folder = Path(segments.folder)
    _claim(folder, _fingerprint(stepper, grid, xis, fs, y0, y1, every) | {"identity": _as_json(segments.identity)})
    V0 = stepper.constraint_reference(y0, grid.t)
    state, outputs = (y0, y1, stepper.constraint.carried(0.0)), []
    starts = range(0, N, every)
    from tqdm.auto import tqdm

    for index, k in enumerate(tqdm(starts, disable=not progress, desc="segments", leave=False)):
        levels = slice(k, min(k + every, N) + 1)
        path = _segment_path(folder, index)
        solved = not path.exists()
        if solved:
            start = time.perf_counter()
            segment = _solve_segment(stepper, state, grid.t[levels], xis[levels], fs[levels], V0)
            segment.update(wall_time=time.perf_counter() - start, peak_memory_mib=_peak_memory_mib())
            _write_segment(path, segment)
        else:
            segment = _read_segment(path)
        outputs.append(segment)
        if on_segment is not None:
            on_segment(index, len(starts), segment, solved)
        stepper.raise_on_failure(*(np.concatenate([o[name] for o in outputs]) if name else grid
                                   for name in ("status", None, "newton_iterations", "min_det_F")))
        p = segment["p"][-1]  # the carried multiplier state: a number, or the circulation's (p, Pa, phase)
        state = (segment["y0"][-1], segment["y1"][-1], float(p) if np.ndim(p) == 0 else p)
    stacked = {name: np.concatenate([o[name] for o in outputs]) for name in SEGMENT_OUTPUTS}
    Y0 = np.concatenate([y0[None], stacked["y0"]])
    Y1 = np.concatenate([y1[None], stacked["y1"]])
    monitors = (stacked["newton_iterations"], stacked["min_det_F"], stacked["max_grad"])
    wall = float(sum(o["wall_time"] for o in outputs))
    return stepper.solution(grid, Y0, Y1, stacked["p"], monitors, xis, wall, diagnose=True)


def segment_costs(folder) -> dict:
    """``{"wall_time": s, "peak_memory_mib": MiB, "segments": k}`` of the segments saved in ``folder``: the
    total solve time and the largest peak memory of the processes that solved them."""
    paths = sorted(Path(folder).glob("segment_*.npz"))
    costs = [_read_cost(path) for path in paths]
    return {"wall_time": float(sum(c["wall_time"] for c in costs)),
            "peak_memory_mib": float(max((c["peak_memory_mib"] for c in costs), default=0.0)),
            "segments": len(costs)}


def _segment_path(folder: Path, index: int) -> Path:
    return folder / f"segment_{index:05d}.npz"


def _peak_memory_mib() -> float:
    """This process's peak resident memory so far, MiB (Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _solve_segment(stepper: TimeStepper, state, t, xis, fs, V0) -> dict:
    """The outputs (`SEGMENT_OUTPUTS`) of the steps over the levels ``t`` from ``state = (y0, y1, p)`` (p the
    carried multiplier state),
    with no factorization kept from before."""
    forget = getattr(stepper.solver, "forget_factorization", None)
    if forget is not None:
        forget()
    y0, y1, p = state
    out = stepper.march_levels(y0, y1, p, t, xis, fs, V0)
    return dict(zip(SEGMENT_OUTPUTS, (np.asarray(o) for o in out)))


def _write_segment(path: Path, segment: dict) -> None:
    """Write ``segment`` to ``path`` atomically (a uniquely named temporary file in the same folder, then a
    rename: the MPI ranks of a distributed solve write the same segment at once)."""
    atomic_write_bytes(path, npz_bytes(segment, compress=False))


def _read_segment(path: Path) -> dict:
    with np.load(path) as data:
        return {name: data[name] for name in SEGMENT_OUTPUTS} | _costs(data)


def _read_cost(path: Path) -> dict:
    """The `SEGMENT_COST` entries of a segment file, without loading its states."""
    with np.load(path) as data:
        return _costs(data)


def _costs(data) -> dict:
    return {name: float(data[name]) for name in SEGMENT_COST}


def _fingerprint(stepper: TimeStepper, grid: TimeGrid, xis, fs, y0, y1, every: int) -> dict:
    """What a resumed run must agree on: sizes, the quadrature points per cell, the scheme, the step's terms, the
    segment length and digests of the grid, the controls, the loads and the initial state."""
    digest = hashlib.sha256()
    for a in (grid.t, xis, fs, y0, y1):
        digest.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    scheme = stepper.scheme
    return {"unknowns": int(stepper.model.n), "quadrature_points": int(stepper.model._w.shape[-1]),
            "steps": int(grid.num_steps), "every": int(every),
            "scheme": [scheme.theta, scheme.multiplier, scheme.rtol, scheme.atol, scheme.max_iter, scheme.newton],
            "terms": [type(term).__name__ for term in stepper.terms],
            "data_sha256": digest.hexdigest()}


def _as_json(data):
    """``data`` as it reads back from JSON (tuples as lists, paths as strings), for comparing with a file's."""
    return json.loads(json.dumps(data, default=str))


def _claim(folder: Path, fingerprint: dict) -> None:
    """Create ``folder`` with ``problem.json``, or check that the one there describes the same solve."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "problem.json"
    if path.exists():
        found = json.loads(path.read_text())
        if found != fingerprint:
            changed = sorted(k for k in fingerprint if found.get(k) != fingerprint[k])
            raise InputError(f"{folder} holds the segments of another solve (differs in: {', '.join(changed)})")
        return
    atomic_write_text(path, json.dumps(fingerprint, indent=1))  # a unique temporary: MPI ranks claim together


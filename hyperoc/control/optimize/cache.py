"""The evaluation cache: ``(J, gradient)`` of every point an optimizer evaluates, on disk or in memory.

The optimizers are deterministic, so a resumed run starts again from the first iterate and replays
the cached evaluations (no PDE solve) up to where it stopped: it ends exactly where an uninterrupted
run ends.
"""

from __future__ import annotations

import hashlib
import warnings
import zipfile
from pathlib import Path

import numpy as np

from ...io import read_npz, write_cache_npz
from ..reduced import ControlPoint, ReducedFunctional

__all__ = ["EvaluationCache"]


class EvaluationCache:
    """``(J, Riesz gradient)`` of every evaluated point, on disk (one atomic NPZ per point:
    `hyperoc.io.write_cache_npz`) or in memory.

    An entry that cannot be read back (not an NPZ archive, arrays missing, non-finite, or a
    gradient of another shape than the point's) is reported (`RuntimeWarning`), deleted and
    recomputed: a damaged cache costs evaluations, never the run.
    """

    def __init__(self, J: ReducedFunctional, directory=None):
        self.J, self.dir = J, Path(directory) if directory is not None else None
        self.memory: dict = {}
        self.hits = 0
        if self.dir is not None:
            self.dir.mkdir(parents=True, exist_ok=True)

    @staticmethod
    def key(m: ControlPoint) -> str:
        h = hashlib.sha256(np.ascontiguousarray(m.xi, dtype=np.float64).tobytes())
        h.update(np.float64(m.tau).tobytes())
        return h.hexdigest()[:32]

    @staticmethod
    def read_entry(path: Path) -> tuple[float, ControlPoint]:
        """``(J, gradient)`` stored in ``path``; `ValueError` naming the damage if it is not a
        complete entry."""
        try:
            data = read_npz(path)
        except (OSError, EOFError, ValueError, zipfile.BadZipFile) as err:
            raise ValueError(f"unreadable: {type(err).__name__}") from None
        missing = {"J", "gxi", "gtau"} - set(data)
        if missing:
            raise ValueError(f"missing array(s) {sorted(missing)}")
        J, gxi, gtau = data["J"], data["gxi"], data["gtau"]
        if J.shape != () or gtau.shape != () or gxi.ndim != 2:
            raise ValueError("arrays of the wrong shape")
        if not (np.isfinite(J) and np.isfinite(gtau) and np.all(np.isfinite(gxi))):
            raise ValueError("non-finite values")
        return float(J), ControlPoint(gxi.astype(np.float64), float(gtau))

    @classmethod
    def scan(cls, directory) -> tuple[int, list]:
        """``(count, dropped)``: the readable entries of a cache folder, and ``(path, reason)`` for
        each damaged one, which is deleted (the run will recompute it)."""
        directory = Path(directory)
        if not directory.is_dir():
            return 0, []
        count, dropped = 0, []
        for path in sorted(directory.glob("*.npz")):
            try:
                cls.read_entry(path)
                count += 1
            except ValueError as err:
                path.unlink(missing_ok=True)
                dropped.append((path, str(err)))
        return count, dropped

    def __call__(self, m: ControlPoint) -> tuple[float, ControlPoint]:
        k = self.key(m)
        if k in self.memory:
            self.hits += 1
            return self.memory[k]
        path = self.dir / f"{k}.npz" if self.dir is not None else None
        out = self._cached(path, m) if path is not None and path.exists() else None
        if out is not None:
            self.hits += 1
        else:
            out = self.J.value_and_gradient(m)
            if path is not None:
                write_cache_npz(path, J=np.float64(out[0]), gxi=out[1].xi, gtau=np.float64(out[1].tau))
        self.memory[k] = out
        return out

    def _cached(self, path: Path, m: ControlPoint) -> tuple[float, ControlPoint] | None:
        """The entry of ``m`` in ``path``, or None (reported, deleted) if it is damaged."""
        try:
            value, g = self.read_entry(path)
            if g.xi.shape != np.shape(m.xi):
                raise ValueError(f"gradient of shape {g.xi.shape}, the point has {np.shape(m.xi)}")
        except ValueError as err:
            warnings.warn(f"damaged evaluation cache entry {path} ({err}): dropped, recomputed", RuntimeWarning,
                          stacklevel=3)
            path.unlink(missing_ok=True)
            return None
        return value, g

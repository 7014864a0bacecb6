"""Results files of the bench scripts: ``bench/results/<name>.json``, rendered to the docs by
``python bench/make_tables.py``.

A results file holds what one invocation of a bench script measured, and the command that did it::

    {"bench": name, "command": command,
     "tables": [{"title": str, "columns": [str, ...], "rows": [[...], ...], "notes": str}, ...]}

Column names carry their units ("factorization (s)", "peak RSS (MB)"); cells are numbers, strings,
booleans or None. Numbers are written as measured; the renderer rounds them for display.
"""

from __future__ import annotations

import json
import math
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def _plain(value):
    """A JSON-ready copy of ``value`` (NumPy scalars and arrays to Python numbers and lists)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist"):  # NumPy scalar or array
        return _plain(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def table(title: str, columns: list[str], rows: list[list], notes: str = "") -> dict:
    """One table of a results file; every row has one cell per column."""
    for row in rows:
        if len(row) != len(columns):
            raise ValueError(f"{title!r}: row {row!r} has {len(row)} cells for {len(columns)} columns")
    return {"title": title, "columns": list(columns), "rows": [list(r) for r in rows], "notes": notes}


def cell(value) -> str:
    """One Markdown table cell: floats to at most 8 significant digits, large integers with thousands
    separators, booleans as yes/no, None empty."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if hasattr(value, "item"):  # NumPy scalar
        value = value.item()
    if isinstance(value, float):
        return f"{value:.8g}"
    if isinstance(value, int):
        return f"{value:,}" if abs(value) >= 10000 else str(value)
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_row(cells) -> str:
    return "| " + " | ".join(cell(c) for c in cells) + " |"


def markdown_table(columns: list[str], rows: list[list]) -> str:
    return "\n".join([markdown_row(columns), "|" + "---|" * len(columns), *(markdown_row(r) for r in rows)])


class Table:
    """A table filled row by row, each row printed as a Markdown row when added (so a long run shows
    its progress), then passed to `write_results` with `as_dict`."""

    def __init__(self, title: str, columns: list[str], notes: str = "", echo: bool = True):
        self.title, self.columns, self.notes, self.echo, self.rows = title, list(columns), notes, echo, []

    def add(self, *cells) -> None:
        if len(cells) != len(self.columns):
            raise ValueError(f"{self.title!r}: {len(cells)} cells for {len(self.columns)} columns")
        if self.echo:
            if not self.rows:
                print(f"\n{self.title}\n\n{markdown_row(self.columns)}\n|" + "---|" * len(self.columns), flush=True)
            print(markdown_row(cells), flush=True)
        self.rows.append(list(cells))

    def as_dict(self) -> dict:
        return table(self.title, self.columns, self.rows, self.notes)


def command_line() -> str:
    """The command that runs this process, as a user would type it from the repository root, with the
    CPUs it was bound to (``taskset -c``) when it could not use all of them."""
    script = Path(sys.argv[0]).resolve()
    try:
        script = script.relative_to(Path(__file__).resolve().parents[1])
    except ValueError:
        pass
    words = ["python", str(script), *sys.argv[1:]]
    allowed, total = sorted(os.sched_getaffinity(0)), os.cpu_count() or 1
    if len(allowed) < total:  # the run was bound to some CPUs (taskset): part of how it was measured
        words = ["taskset", "-c", ",".join(map(str, allowed)), *words]
    return shlex.join(words)


def run_json(cmd: list[str], out: Path, ranks: int | None) -> dict:
    """Run the command line ``cmd`` (``python -m module ...``, writing its JSON to ``out``) with ``--serial``
    in one process (``ranks`` None) or under ``mpiexec -n ranks -bind-to core`` (the mpiexec beside this
    interpreter, as the ``mpi`` extra installs it), and read that JSON. Each rank is bound to a core of
    its own, one rank per core as on a cluster: its threads (XLA's, the BLAS's) share that core, so
    that one rank uses one core and k ranks k, and the speed-up over one rank is the strong scaling."""
    if ranks is None:
        cmd = [*cmd, "--serial"]
    else:
        mpiexec = shutil.which("mpiexec", path=os.path.dirname(sys.executable)) or "mpiexec"
        cmd = [mpiexec, "-n", str(ranks), "-bind-to", "core", *cmd]
    subprocess.run(cmd, check=True)
    return json.loads(Path(out).read_text())


def write_results(name: str, command: str, tables: list[dict], data: dict | None = None) -> Path:
    """Write ``bench/results/<name>.json`` atomically (a temporary file in the same folder, then
    `os.replace`), so a reader never sees half a file; returns its path. ``data``: further top-level
    entries (e.g. the curves a comparison is made of), beside ``bench``, ``command`` and ``tables``."""
    if not name or "/" in name or name.startswith("."):
        raise ValueError(f"results name {name!r}: a plain file stem is expected")
    for t in tables:
        table(t["title"], t["columns"], t["rows"], t.get("notes", ""))  # validates the shape
    data = {**(data or {}), "bench": name, "command": command,
            "tables": [{"title": t["title"], "columns": list(t["columns"]), "rows": t["rows"],
                        "notes": t.get("notes", "")} for t in tables]}
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"{name}.json"
    fd, tmp = tempfile.mkstemp(dir=RESULTS_DIR, prefix=f".{name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(_plain(data), f, indent=1)
            f.write("\n")
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    print(f"results written to {path}", file=sys.stderr)
    return path

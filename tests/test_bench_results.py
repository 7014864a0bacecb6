"""The bench results files and the tables rendered from them (`bench/results.py`, `bench/make_tables.py`)."""

import json
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

import make_tables  # noqa: E402
import results  # noqa: E402


def test_write_results_is_the_documented_format_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    monkeypatch.setattr(results, "RESULTS_DIR", tmp_path)
    t = results.Table("a table", ["n", "time (s)"], "a note", echo=False)
    t.add(1, 0.25)
    t.add(2, float("nan"))
    path = results.write_results("demo", "python bench/demo.py", [t.as_dict()])
    assert path == tmp_path / "demo.json" and [p.name for p in tmp_path.iterdir()] == ["demo.json"]
    data = json.loads(path.read_text())
    assert data == {"bench": "demo", "command": "python bench/demo.py",
                    "tables": [{"title": "a table", "columns": ["n", "time (s)"], "rows": [[1, 0.25], [2, "nan"]],
                                "notes": "a note"}]}
    page = make_tables.render_results(data)
    assert "`python bench/demo.py`" in page and "| n | time (s) |" in page and "| 1 | 0.25 |" in page


def test_tables_reject_rows_of_the_wrong_width():
    with pytest.raises(ValueError):
        results.table("t", ["a", "b"], [[1]])
    with pytest.raises(ValueError):
        results.write_results("../escape", "cmd", [])


def test_every_test_function_has_a_row():
    rows = make_tables.test_rows()
    names = {(r[0], r[1]) for r in rows}
    assert ("`test_bench_results.py`", "`test_every_test_function_has_a_row`") in names
    assert all(r[2] for r in rows)

"""The bench results files and the tables rendered from them (`bench/results.py`, `bench/make_tables.py`)."""

import json
import re
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


RESULTS_FILES = sorted((BENCH / "results").glob("*.json"))


@pytest.fixture(scope="module")
def pages():
    return make_tables.pages()


@pytest.mark.parametrize("path", RESULTS_FILES, ids=lambda p: p.stem)
def test_every_results_file_is_the_documented_format_and_its_page_is_current(path, pages):
    """Each committed results file is what `write_results` writes (named for its file, rows as wide as
    their columns, a command that runs a bench script), and its page in docs/results is current: its
    rendering, or, for a file named as its script, the script's page, which begins with it."""
    data = json.loads(path.read_text())
    assert data["bench"] == path.stem
    assert "python bench/" in data["command"]
    assert data["tables"]
    for t in data["tables"]:
        assert set(t) == {"title", "columns", "rows", "notes"} and t["title"]
        assert all(len(row) == len(t["columns"]) for row in t["rows"]), t["title"]
    page = make_tables.OUT / f"{path.stem}.md"
    assert pages[page].startswith(make_tables.render_results(data).rstrip("\n"))
    assert page.read_text() == pages[page], f"python bench/make_tables.py renews {page.name}"


def _test_functions(path: Path) -> set[str]:
    """The test functions of a test file as pytest collects them: module-level ``def test*`` and the
    ``def test*`` of ``class Test*``, read from the source text."""
    names, cls = set(), None
    for line in path.read_text().splitlines():
        if match := re.match(r"class (Test\w*)", line):
            cls = match.group(1)
        elif re.match(r"\S", line):
            cls = None
        if match := re.match(r"(?:async )?def (test\w*)", line):
            names.add(match.group(1))
        elif cls and (match := re.match(r"    (?:async )?def (test\w*)", line)):
            names.add(f"{cls}.{match.group(1)}")
    return names


def test_every_test_function_has_a_row_in_the_verification_page():
    """The test inventory (docs/results/verification.md) lists every test function of tests/, and no
    other, as rendered from the current tests."""
    want = {(f"`{p.name}`", f"`{name}`") for p in sorted((BENCH.parent / "tests").glob("test_*.py"))
            for name in _test_functions(p)}
    rows = make_tables.test_rows()
    assert {(r[0], r[1]) for r in rows} == want and len(rows) == len(want)
    assert all(r[2] for r in rows)
    page = BENCH.parent / "docs" / "results" / "verification.md"
    assert page.read_text() == make_tables.render_verification(), "python bench/make_tables.py renews it"

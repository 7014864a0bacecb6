"""The Python snippets of the README and of the docs' cardiac page run as printed (with 2 optimizer
iterations instead of 50 or 100), so the names and signatures they show stay those of the package."""

import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CARDIAC = ROOT / "docs" / "cardiac.md"


def snippet(after: str, iterations: str, source: Path = README) -> dict:
    """Run the first ```python block of ``source`` after the line starting with ``after``, with
    ``iterations`` (e.g. "max_iter=50") replaced by "max_iter=2"; returns its names."""
    text = source.read_text()
    match = re.search(r"```python\n(.*?)```", text[text.index(after):], re.S)
    assert match, f"README: no python block after {after!r}"
    code = match.group(1)
    assert iterations in code
    names = {}
    exec(compile(code.replace(iterations, "max_iter=2"), str(source), "exec"), names)
    return names


def test_readme_python_api_snippet_runs():
    names = snippet("Python API:", "max_iter=50")
    sol, value, grad, result = names["sol"], names["value"], names["grad"], names["result"]
    # Zero control from rest: no motion, so p(tau) = 0 and the control cost is 0, exactly.
    assert value == 0.0
    assert np.all(np.isfinite(grad.xi)) and np.isfinite(grad.tau) and np.any(grad.xi != 0)
    assert len(sol.t) == 751 and np.all(sol.min_det_F > 0)
    # Algorithm 1 is an ascent method: every accepted iterate increases J.
    assert result.iterations == 2 and result.objective > value
    assert np.all(np.diff(result.history["objective"]) > 0)


@pytest.mark.slow
def test_readme_ventricle_snippet_runs():
    names = snippet("The ventricle example in Python", "max_iter=100", CARDIAC)
    value, grad, taylor, result = names["value"], names["grad"], names["taylor"], names["result"]
    assert np.isfinite(value) and np.all(np.isfinite(grad.xi)) and np.isfinite(grad.tau)
    # The exact gradient of the discrete J: remainders O(h^2), the rate in [1.9, 2.1] on the
    # asymptotic range, as in tests/test_gradients.py (a wrong gradient gives 1).
    assert taylor.remainder.size >= 3 and 1.9 <= taylor.rate <= 2.1
    assert result.iterations == 2 and result.objective > value

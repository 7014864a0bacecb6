"""The README's Python API snippet runs as printed (with 2 optimizer iterations instead of 50), so the
names and signatures it shows stay those of the package."""

import re
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def api_snippet() -> str:
    """The first ```python block after the line "Python API:"."""
    text = README.read_text()
    match = re.search(r"```python\n(.*?)```", text[text.index("Python API:"):], re.S)
    assert match, "README: no python block after 'Python API:'"
    return match.group(1)


def test_readme_python_api_snippet_runs():
    code = api_snippet()
    assert "max_iter=50" in code
    names = {}
    exec(compile(code.replace("max_iter=50", "max_iter=2"), str(README), "exec"), names)
    sol, value, grad, result = names["sol"], names["value"], names["grad"], names["result"]
    # Zero control from rest: no motion, so p(tau) = 0 and the control cost is 0, exactly.
    assert value == 0.0
    assert np.all(np.isfinite(grad.xi)) and np.isfinite(grad.tau) and np.any(grad.xi != 0)
    assert len(sol.t) == 751 and np.all(sol.min_det_F > 0)
    # Algorithm 1 is an ascent method: every accepted iterate increases J.
    assert result.iterations == 2 and result.objective > value
    assert np.all(np.diff(result.history["objective"]) > 0)

"""Exceptions with a contract: what the CLI does with them.

`InputError` (bad configuration, bad mesh file, bad parameter) makes the CLI print one line and
exit with status 2. `SolverError` names the time step and the cause (Newton divergence,
``det F <= 0``, non-finite residual) so that a failed run says where and why it failed.
"""

from __future__ import annotations

QUOTE_LIMIT = 80  # characters of a user's value quoted in a message


def quote(value, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)``, cut to ``limit`` characters (ending in "...") when longer."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class HyperocError(Exception):
    """Base class of all errors raised on purpose by hyperoc."""


class InputError(HyperocError, ValueError):
    """Invalid user input: a config entry, a parameter value, a mesh file, a control region."""


class SolverError(HyperocError, RuntimeError):
    """The state or adjoint solver failed at a given time step.

    Attributes
    ----------
    step : int
        Index ``n`` of the failed step ``t_n -> t_{n+1}``.
    time : float
        ``t_{n+1}``, the time level the step tried to reach.
    cause : str
        Short reason: ``"newton"`` (no convergence), ``"detF"`` (element inversion),
        ``"nonfinite"`` (NaN/Inf in the residual).
    """

    def __init__(self, step: int, time: float, cause: str, detail: str = ""):
        self.step, self.time, self.cause, self.detail = int(step), float(time), cause, detail
        msg = f"solver failed at step {self.step} (t = {self.time:.6g}): {cause}"
        super().__init__(msg + (f" ({detail})" if detail else ""))

    def __reduce__(self):  # pickled by its fields (a worker process's failure reaches its parent)
        return type(self), (self.step, self.time, self.cause, self.detail)

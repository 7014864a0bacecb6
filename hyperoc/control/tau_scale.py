"""The spelling of L-BFGS-B's tau scaling, ``"range"`` or a positive number, checked where it enters: the
configuration's ``[optimize] tau_scale`` and `hyperoc.control.optimize.lbfgsb`'s ``tau_scale``.

Imports nothing but the standard library, so that the configuration's checks stay free of JAX.
"""

import math

__all__ = ["is_tau_scale"]


def is_tau_scale(value) -> bool:
    """Whether ``value`` is ``"range"`` or a finite positive number (a bool is not a number here)."""
    if value == "range":
        return True
    return (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            and value > 0)

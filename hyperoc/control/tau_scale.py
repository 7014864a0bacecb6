"""The spelling of the optimizers' tau scaling, ``"range"``, ``"curvature"`` (Newton-CG) or a positive number,
checked where it enters: the configuration's ``[optimize] tau_scale`` and the ``tau_scale`` of
`hyperoc.control.optimize.lbfgsb` and `hyperoc.control.optimize.newton_cg`.

Imports nothing but the standard library, so that the configuration's checks stay free of JAX.
"""

import math

__all__ = ["RULES", "is_tau_scale"]


#: The named rules; "curvature" is measured by Newton-CG at its start.
RULES = ("range", "curvature")


def is_tau_scale(value) -> bool:
    """Whether ``value`` is one of `RULES` or a finite positive number (a bool is not a number here)."""
    if isinstance(value, str):
        return value in RULES
    return (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            and value > 0)

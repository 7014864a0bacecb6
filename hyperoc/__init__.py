"""hyperoc: optimal control of damped hyperelastic bodies under a global volume constraint.

The curated API (the documentation in docs/ gives a tour)::

    mesh        interval, rectangle, box, refine, Mesh; geometry: annulus, thick_shell, ventricle, from_file
    materials   SaintVenantKirchhoff, Fung, Ogden, NeoHookean; Guccione, HolzapfelOgden (fibre frames)
    fibres      transmural_coordinate, rule_based_fibres (helix angle rule), prolate_fibres (analytic, Land)
    controls    BodyForce, ActiveStress, Region
    model       StateModel; mixed: TaylorHoodModel (P2-P1, quasi-static, incompressible allowed)
    dynamics    Scheme, TimeStepper, solve_state (monitor= sees each step's StepRecord), StateSolution;
                statics: solve_static with state-dependent loads FollowerPressure (pressure on the
                deformed boundary), FibreTension (active stress), and NewtonLog, a monitor that
                prints or keeps every Newton iteration
    time        uniform_grid, TimeGrid, TimeTransform
    objectives  Objective, ControlCost, ControlRateCost, PressureAt, PressureRise
    gradients   ReducedFunctional, ControlPoint, taylor_test
    optimizers  barzilai_borwein (the paper's Algorithm 1), lbfgsb, newton_cg
    config      load_config

Importing hyperoc enables JAX's float64 mode (``jax_enable_x64``), which the solvers need, and,
before JAX is imported, passes closed-over arrays to XLA as arguments (`hyperoc._jax`).
"""

from . import _jax  # noqa: F401  (first: it sets JAX's environment before anything imports jax)
from .active import FibreTension
from .controls import ActiveStress, BodyForce, Region
from .config import load_config
from .dynamics import Scheme, StateSolution, TimeStepper, solve_state
from .errors import HyperocError, InputError, SolverError
from .geometry import annulus, from_file, thick_shell, ventricle
from .fibres import prolate_fibres, rule_based_fibres, transmural_coordinate
from .follower import FollowerPressure
from .materials import Fung, Guccione, HolzapfelOgden, NeoHookean, Ogden, SaintVenantKirchhoff
from .mesh import Mesh, box, interval, rectangle, refine
from .mixed import TaylorHoodModel
from .model import StateModel
from .newton import NewtonLog
from .objectives import ControlCost, ControlRateCost, Objective, PressureAt, PressureRise
from .optimize import barzilai_borwein, lbfgsb, newton_cg
from .reduced import ControlPoint, ReducedFunctional
from .statics import solve_static
from .timegrid import TimeGrid, TimeTransform, uniform_grid
from .verification import taylor_test

__version__ = "0.1.0"

__all__ = [
    "ActiveStress", "BodyForce", "Region", "load_config", "Scheme", "StateSolution", "TimeStepper", "solve_state",
    "HyperocError", "InputError", "SolverError", "annulus", "from_file", "thick_shell", "ventricle", "Fung",
    "NeoHookean", "Ogden", "SaintVenantKirchhoff", "Guccione", "HolzapfelOgden", "rule_based_fibres", "prolate_fibres",
    "transmural_coordinate", "Mesh", "box", "interval", "rectangle", "refine", "StateModel", "TaylorHoodModel",
    "ControlCost", "ControlRateCost", "Objective", "PressureAt", "PressureRise", "barzilai_borwein", "lbfgsb", "newton_cg",
    "ControlPoint",
    "ReducedFunctional", "solve_static", "NewtonLog", "FollowerPressure", "FibreTension", "TimeGrid", "TimeTransform", "uniform_grid", "taylor_test",
]

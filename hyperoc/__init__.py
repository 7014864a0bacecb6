"""hyperoc: optimal control of damped hyperelastic bodies under a global volume constraint.

The curated API (see the README for a tour)::

    layers      fem, solvers, mechanics, dynamics, control, cardiac, app (the API reference's table)
    mesh        interval, rectangle, box, refine, Mesh; geometry: annulus, thick_shell, ventricle, from_file
    materials   SaintVenantKirchhoff, Fung, Ogden, NeoHookean; Guccione, HolzapfelOgden (fibre frames)
    fibres      transmural_coordinate, rule_based_fibres (helix angle rule), prolate_fibres (analytic, Land)
    controls    BodyForce, ActiveStress, Region
    model       StateModel; mixed: TaylorHoodModel (P2-P1, quasi-static, incompressible allowed)
    dynamics    Scheme, TimeStepper, solve_state (monitor= sees each step's StepRecord), StateSolution,
                StepStatus; statics: solve_static (-> StaticSolution; StaticOptions: load stepping, Newton, the
                linear solver) with state-dependent loads FollowerPressure (pressure on the deformed boundary),
                FibreTension (active stress), and
                NewtonLog, a monitor that prints or keeps every Newton iteration; NewtonStatus, how a
                Newton solve ended
    time        uniform_grid, TimeGrid, TimeTransform
    objectives  Objective, ControlCost, ControlRateCost (beta/2 ||xi_t||^2), InjectivityPenalty,
                PressureAt, PressureRise, PressureMean
    gradients   ReducedFunctional, ControlPoint, ControlSpace (inner product, Riesz map), taylor_test
                (-> TaylorResult)
    optimizers  barzilai_borwein (the paper's Algorithm 1; BBOptions), lbfgsb, newton_cg (NewtonCGOptions)
                -> OptimizationResult, whose Termination says why the run stopped
    config      load_config

Importing hyperoc is cheap: the names above are imported on first use (PEP 562), so that the
command line answers at once. It sets JAX's float64 mode (``JAX_ENABLE_X64``) and, before JAX is
imported, passes closed-over arrays to XLA as arguments (`hyperoc._jax`); every module that builds
JAX kernels also turns float64 on when it is imported. A process pinned to one CPU imports JAX at
once, so that XLA's thread pool is started with two threads before anything else starts it with one
(`hyperoc.solvers.threads`).
"""

import importlib
import os
import sys


def _pinned_to_one_cpu() -> bool:
    return hasattr(os, "sched_getaffinity") and len(os.sched_getaffinity(0)) == 1


if "jax" in sys.modules or _pinned_to_one_cpu():  # configure (and, pinned, start) JAX now
    from . import _jax  # noqa: F401
else:
    os.environ.setdefault("JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS", "1")  # read by JAX on import (`hyperoc._jax`)
    os.environ.setdefault("JAX_ENABLE_X64", "1")

# public name -> submodule that defines it
_LAZY = {
    "FibreTension": "mechanics.active",
    "ActiveStress": "mechanics.controls",
    "BodyForce": "mechanics.controls",
    "Region": "mechanics.controls",
    "load_config": "app.config",
    "Scheme": "dynamics.stepper",
    "StateSolution": "dynamics.stepper",
    "TimeStepper": "dynamics.stepper",
    "solve_state": "dynamics.stepper",
    "HyperocError": "errors",
    "InputError": "errors",
    "SolverError": "errors",
    "annulus": "fem.geometry",
    "from_file": "fem.geometry",
    "thick_shell": "fem.geometry",
    "ventricle": "fem.geometry",
    "prolate_fibres": "mechanics.fibres",
    "rule_based_fibres": "mechanics.fibres",
    "transmural_coordinate": "mechanics.fibres",
    "FollowerPressure": "mechanics.follower",
    "Fung": "mechanics.materials",
    "Guccione": "mechanics.materials",
    "HolzapfelOgden": "mechanics.materials",
    "NeoHookean": "mechanics.materials",
    "Ogden": "mechanics.materials",
    "SaintVenantKirchhoff": "mechanics.materials",
    "Mesh": "fem.mesh",
    "box": "fem.mesh",
    "interval": "fem.mesh",
    "rectangle": "fem.mesh",
    "refine": "fem.mesh",
    "TaylorHoodModel": "mechanics.mixed",
    "StateModel": "mechanics.model",
    "NewtonLog": "solvers.newton",
    "NewtonStatus": "solvers.newton",
    "ControlCost": "control.objectives",
    "ControlRateCost": "control.objectives",
    "InjectivityPenalty": "control.objectives",
    "PressureMean": "control.objectives",
    "OptimizationResult": "control.optimize",
    "Termination": "control.optimize",
    "ControlSpace": "control.control_space",
    "StepRecord": "dynamics.stepper",
    "StepStatus": "dynamics.stepper",
    "Objective": "control.objectives",
    "PressureAt": "control.objectives",
    "PressureRise": "control.objectives",
    "barzilai_borwein": "control.optimize",
    "lbfgsb": "control.optimize",
    "newton_cg": "control.optimize",
    "ControlPoint": "control.reduced",
    "ReducedFunctional": "control.reduced",
    "solve_static": "dynamics.statics",
    "StaticSolution": "dynamics.statics",
    "StaticOptions": "dynamics.statics",
    "BBOptions": "control.optimize",
    "NewtonCGOptions": "control.optimize",
    "TimeGrid": "dynamics.timegrid",
    "TimeTransform": "dynamics.timegrid",
    "uniform_grid": "dynamics.timegrid",
    "taylor_test": "control.verification",
    "TaylorResult": "control.verification",
}


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module 'hyperoc' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__version__ = "0.1.0"

__all__ = [
    "ActiveStress", "BodyForce", "Region", "load_config", "Scheme", "StateSolution", "TimeStepper", "solve_state",
    "HyperocError", "InputError", "SolverError", "annulus", "from_file", "thick_shell", "ventricle", "Fung",
    "NeoHookean", "Ogden", "SaintVenantKirchhoff", "Guccione", "HolzapfelOgden", "rule_based_fibres",
    "prolate_fibres", "transmural_coordinate", "Mesh", "box", "interval", "rectangle", "refine", "StateModel",
    "TaylorHoodModel", "ControlCost", "ControlRateCost", "InjectivityPenalty", "Objective", "PressureAt",
    "PressureRise", "PressureMean", "barzilai_borwein", "lbfgsb", "newton_cg", "OptimizationResult", "ControlPoint",
    "ControlSpace", "StepRecord", "StepStatus", "ReducedFunctional", "solve_static", "NewtonLog", "NewtonStatus",
    "FollowerPressure", "FibreTension", "TimeGrid", "TimeTransform", "uniform_grid", "taylor_test", "TaylorResult",
    "StaticSolution", "StaticOptions", "Termination", "BBOptions", "NewtonCGOptions",
]

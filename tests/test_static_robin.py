"""Robin springs in statics (`solve_static(..., robin=...)`): the springs of the step's `RobinBoundary` terms
hold a body without Dirichlet boundary.

Newton stops when ``|du|_inf <= 1e-11 |u|_inf`` with quadratic convergence, so the residual left is
``~ |K| 1e-11 |u|``: the balances below hold to 1e-9 of the applied load, where a missing or doubled spring,
a dashpot counted statically or a ramped spring would leave an O(1) imbalance."""

import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.app.cardiac_benchmark import benchmark_config
from hyperoc.app.config import parse_config, set_entries
from hyperoc.dynamics.laws import ExpressionLaw, bestel_pressure
from hyperoc.dynamics.statics import StaticOptions, solve_static, spring_force
from hyperoc.dynamics.stepper import TimeStepper
from hyperoc.dynamics.terms import DynamicPressure, RobinBoundary
from hyperoc.dynamics.timegrid import uniform_grid
from hyperoc.errors import InputError
from hyperoc.fem.mesh import box
from hyperoc.mechanics.follower import FollowerPressure
from hyperoc.mechanics.materials import NeoHookean
from hyperoc.mechanics.model import StateModel


def _free_box():
    """A NeoHookean box with no Dirichlet boundary, springs on two faces (full, normal; dashpots too), a dead
    traction on the top face and a follower pressure on the bottom face."""
    model = StateModel(box(2, 1, 1, size=(1.0, 0.7, 0.5)), NeoHookean(1.0, 1.0), dirichlet=None)
    robin = (RobinBoundary(model, "left", 5.0, 0.5, "full"), RobinBoundary(model, "right", 3.0, 0.2, "normal"))
    load = model.load_vector(traction=(0.12, 0.05, -0.04), neumann="top")
    return model, robin, load, FollowerPressure(model, "bottom", 0.08)


def _resultants(model, forces, u):
    """Net force (3,) and net moment (3,) about the origin of nodal forces (n,) at the deformed nodes X + u."""
    nodal = model.expand(np.asarray(forces))
    x = model.space.nodes + model.expand(np.asarray(u))
    return nodal.sum(axis=0), np.cross(x, nodal).sum(axis=0)


@pytest.mark.parametrize("constrained", [False, True])
def test_the_springs_of_a_free_body_carry_the_applied_load(constrained):
    """The internal force of a free body has no net force (the shape functions sum to 1) and no net moment about
    the deformed nodes (frame indifference), so at equilibrium the springs' reaction balances the applied
    loads, the dead traction and the follower pressure on the deformed face: net force and moment."""
    model, robin, load, pressure = _free_box()
    sol = solve_static(model, load=load, follower=pressure, robin=robin, constraint=None if constrained else "none",
                       options=StaticOptions(steps=2, solver="lu"))
    u = jnp.asarray(sol.u)
    applied = np.asarray(load) + np.asarray(pressure.force(u, 1.0))
    reaction = -np.asarray(spring_force(robin, u))
    net_applied, moment_applied = _resultants(model, applied, sol.u)
    net_reaction, moment_reaction = _resultants(model, reaction, sol.u)
    scale = np.abs(np.asarray(load)).sum()
    print(f"\nmax |u| {np.max(np.abs(sol.u)):.3g}, net load {net_applied}, reaction {net_reaction}")
    assert np.max(np.abs(sol.u)) > 0.05  # the springs are loaded: a large deformation, not a trivial balance
    assert np.max(np.abs(net_applied + net_reaction)) < 1e-9 * scale
    assert np.max(np.abs(moment_applied + moment_reaction)) < 1e-9 * scale


def test_robin_must_be_springs_of_the_model():
    model, robin, load, _ = _free_box()
    other = StateModel(box(1, 1, 1), NeoHookean(1.0, 1.0), dirichlet=None)
    with pytest.raises(InputError, match="robin"):
        solve_static(model, load=load, robin=(robin[0], RobinBoundary(other, "left", 1.0)), constraint="none")


@pytest.mark.slow
def test_the_static_end_diastolic_inflation_is_the_limit_of_slower_dynamic_inflations():
    """The benchmark's end-diastolic inflation on the coarse mesh: the endocardial pressure of the Bestel law at
    the end of diastole (t_sys_pre = 0.17 s), the Robin epicardium and base, no Dirichlet boundary, no
    activation. Static: `solve_static(..., robin=cfg.robin(model))`. Dynamic: the benchmark's step terms (springs
    and dashpots, viscosity, inertia) with the pressure raised as ``P s(t / T)`` (``s`` the C^2 smootherstep),
    dt = 10 ms, compared at t = T. At the end of the ramp ``s' = s'' = 0``, so the quasi-static lag (viscous and
    dashpot ``~ c ds/dt``, inertial ``~ rho d2s/dt2``) is gone and what is left decays as the ramp slows, at least
    like 1/T. Measured (T = 0.1, 0.2, 0.4 s): max|u_dyn - u_static| / max|u_static| = 3.6e-2, 7.8e-3, 1.3e-3
    (rates 2.2, 2.6). Asserted: each doubling of T at least halves the difference, and the slowest ramp is within
    1 % of the static state."""
    cfg = parse_config(set_entries(benchmark_config("0B", mesh="coarse").sections, {"dynamics.solver": "lu"}))
    model = cfg.model()
    P = float(bestel_pressure()(0.17))
    static = solve_static(model, follower=FollowerPressure(model, "endocardium", P), robin=cfg.robin(model),
                          constraint="none", options=StaticOptions(solver="lu"))
    terms = [term for term in cfg.step_terms(model) if not isinstance(term, DynamicPressure)]
    scale, differences = np.max(np.abs(static.u)), []
    for T in (0.1, 0.2, 0.4):
        x = f"(t/{T})"
        ramp = DynamicPressure(model, "endocardium", ExpressionLaw(f"{P}*{x}**3*(10 - 15*{x} + 6*{x}**2)"))
        stepper = TimeStepper(model, cfg.scheme(), "lu", terms=(*terms, ramp), constraint=cfg.constraint(model))
        sol = stepper.run(uniform_grid(T, 0.01), diagnose=False)
        differences.append(np.max(np.abs(sol.y0[-1] - static.u)) / scale)
    rates = np.log2(np.array(differences[:-1]) / np.array(differences[1:]))
    print(f"\nP {P:.4g} Pa, max|u_static| {scale:.3g} m, relative differences {differences}, rates {rates}")
    assert np.all(rates >= 1.0), (differences, rates)
    assert differences[-1] < 1e-2

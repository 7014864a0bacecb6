"""Quasi-static solver: trivial equilibria and independence of the load ramping.

Newton stops when ``|du|_inf <= 1e-11 |u|_inf``; convergence is quadratic, so the returned
equilibrium is within ~1e-11 |u| (times the condition of the problem, O(10) here) of the exact
discrete one. Two solves of the same problem by different load paths must therefore agree to 1e-9
relative; a path-dependent result (e.g. a ramp that forgets part of the load or of the volume
change) differs at O(1/steps).
"""

import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.controls import BodyForce, Region
from hyperoc.errors import InputError
from hyperoc.materials import NeoHookean, Ogden, SaintVenantKirchhoff
from hyperoc.mesh import rectangle
from hyperoc.model import StateModel
from hyperoc.statics import solve_static


@pytest.mark.parametrize("mesh_fn,degree,material", [
    (lambda: rectangle(3), 1, SaintVenantKirchhoff(1.0, 1.0)),
    (lambda: rectangle(2), 2, NeoHookean(1.0, 2.0)),
])
def test_zero_load_gives_zero_displacement_and_pressure(mesh_fn, degree, material):
    model = StateModel(mesh_fn(), material, degree=degree)
    sol = solve_static(model)
    assert sol.u.shape == (model.n,)
    assert np.max(np.abs(sol.u)) <= 1e-14
    assert abs(sol.p) <= 1e-14
    assert sol.volume == pytest.approx(model.mesh.volume(), rel=1e-14)


def test_zero_load_ogden_pressure_balances_reference_stress():
    """The paper's Ogden form has Sigma(0) = 2 sum c_k g_k I at rest; the multiplier balances it:
    R(0) = 2 sum c_k g_k G0 and R(0) + p G0 = 0 give p = -2 sum c_k g_k, with u = 0."""
    og = Ogden(coefficients=(0.3, 0.2), exponents=(2.0, 3.5))
    model = StateModel(rectangle(4), og)
    sol = solve_static(model)
    expected = -2 * sum(c * g for c, g in zip(og.coefficients, og.exponents))
    assert np.max(np.abs(sol.u)) <= 1e-13
    assert sol.p == pytest.approx(expected, rel=1e-12)


@pytest.fixture(scope="module")
def loaded_problem():
    """2D SVK plate clamped on the left, traction on the right, body force on a sub-box, and a 3%
    volume increase; max |grad u| ~ 0.2 (nonlinear)."""
    model = StateModel(rectangle(6), SaintVenantKirchhoff(1.0, 1.0),
                       control=BodyForce(Region("box", lower=(0.5, 0.0), upper=(1.0, 0.5))))
    load = model.load_vector(traction=(0.15, -0.05), neumann="right")
    xi = np.tile([0.0, -0.3], model.control.size // 2)
    V = 1.03 * model.mesh.volume()
    return model, load, xi, V


def test_ramped_loading_reaches_the_same_equilibrium(loaded_problem):
    model, load, xi, V = loaded_problem
    steps = 4
    one = solve_static(model, load=load, xi=xi, volume=V, steps=1)
    ramp = solve_static(model, load=load, xi=xi, volume=V, steps=steps)
    assert len(one.newton_iterations) == 1 and len(ramp.newton_iterations) == steps
    grad = float(model.jitted["max_grad"](jnp.asarray(one.u)))
    print(f"\nmax|grad u| = {grad:.3f}, p = {one.p:.6g}, Newton its 1 step {one.newton_iterations}, "
          f"{steps} steps {ramp.newton_iterations}, |du| = {np.max(np.abs(ramp.u - one.u)):.2e}")
    assert 0.1 < grad < 0.5  # genuinely nonlinear
    assert one.volume == pytest.approx(V, rel=1e-12) and ramp.volume == pytest.approx(V, rel=1e-12)
    scale_u = np.max(np.abs(one.u))
    assert np.max(np.abs(ramp.u - one.u)) <= 1e-9 * scale_u
    assert abs(ramp.p - one.p) <= 1e-9 * max(abs(one.p), 1.0)  # p in units of the moduli (= 1)


def test_secant_predictor_reaches_the_same_equilibrium_in_fewer_newton_iterations(loaded_problem):
    """The secant start ``u_k + (u_k - u_{k-1}) ds_k / ds_{k-1}`` is O(ds^2) from the next
    equilibrium of a smooth load path, the previous equilibrium O(ds): the same end point, and from
    the second increment on Newton starts closer, so it needs no more iterations per increment."""
    model, load, xi, V = loaded_problem
    steps = 8
    previous = solve_static(model, load=load, xi=xi, volume=V, steps=steps)
    secant = solve_static(model, load=load, xi=xi, volume=V, steps=steps, predictor="secant")
    print(f"\nNewton its per increment: previous {previous.newton_iterations}, secant {secant.newton_iterations}")
    assert np.max(np.abs(secant.u - previous.u)) <= 1e-9 * np.max(np.abs(previous.u))
    assert abs(secant.p - previous.p) <= 1e-9 * max(abs(previous.p), 1.0)
    assert secant.newton_iterations[0] == previous.newton_iterations[0]  # no history yet: the same start
    assert np.all(secant.newton_iterations[1:] <= previous.newton_iterations[1:])
    assert secant.newton_iterations.sum() < previous.newton_iterations.sum()


def test_unknown_predictor_is_an_input_error(loaded_problem):
    model, load, xi, V = loaded_problem
    with pytest.raises(InputError, match="predictor"):
        solve_static(model, load=load, steps=2, predictor="quadratic")

"""Control operators and prescribed controls (callable, expression string, NPZ)."""

import numpy as np
import pytest

from hyperoc import (
    ActiveStress,
    BodyForce,
    InputError,
    NeoHookean,
    Region,
    SaintVenantKirchhoff,
    StateModel,
    annulus,
    interval,
    rectangle,
)
from hyperoc.app.config import parse_config


def test_active_stress_1d_is_the_boundary_difference():
    """1D, fibre = 1, omega = whole bar: <f(xi), phi> = int xi phi_x = xi (phi(1) - phi(0)) for a
    constant xi: the load is xi at x = 1 and nothing elsewhere (x = 0 is clamped)."""
    m = StateModel(interval(8), SaintVenantKirchhoff(), control=ActiveStress(Region()))
    load = m.control.load @ np.full(m.control.size, 0.3)
    expected = np.zeros(m.n)
    expected[-1] = 0.3
    np.testing.assert_allclose(load, expected, atol=1e-14)


def test_body_force_load_integrates_the_force():
    """sum of the load vector = int_omega xi . e over the free dofs plus the clamped ones' share."""
    mesh = rectangle(4, dirichlet="left")
    m = StateModel(mesh, SaintVenantKirchhoff(), control=BodyForce(Region("box", lower=(0.5, 0.0), upper=(1.0, 1.0))))
    xi = np.tile([1.0, 0.0], m.control.size // 2)
    assert float(xi @ (m.control.mass @ xi)) == pytest.approx(0.5)  # ||xi||^2 = |omega|
    assert (m.control.load @ xi).sum() == pytest.approx(0.5, rel=1e-12)  # omega does not touch x = 0


def test_prescribed_controls_agree_across_sources(tmp_path):
    text = """
[mesh]
kind = "interval"
n = 10
[dynamics]
T = 1.0
dt = 0.25
[control]
kind = "body_force"
region = { kind = "box", lower = [0.5], upper = [1.0] }
value = "sin(pi * t) * x"
"""
    import tomllib

    cfg = parse_config(tomllib.loads(text), tmp_path)
    model = cfg.model()
    t = cfg.grid().t
    from_expr = cfg.prescribed_control(model, t)
    from_fn = model.control_values(lambda x, tk: np.sin(np.pi * tk) * x[:, 0], t)
    np.testing.assert_allclose(from_expr, from_fn, rtol=0, atol=1e-15)
    np.savez(tmp_path / "xi.npz", xi=from_fn)
    cfg_npz = parse_config(tomllib.loads(text.replace('value = "sin(pi * t) * x"', 'file = "xi.npz"')), tmp_path)
    np.testing.assert_array_equal(cfg_npz.prescribed_control(model, t), from_fn)
    np.savez(tmp_path / "bad.npz", xi=from_fn[:-1])
    bad = parse_config(tomllib.loads(text.replace('value = "sin(pi * t) * x"', 'file = "bad.npz"')), tmp_path)
    with pytest.raises(InputError, match="shape"):
        bad.prescribed_control(model, t)


@pytest.mark.parametrize("region", [Region("box", lower=(2.0,), upper=(3.0,)), Region("tag", tag="nope"),
                                    Region("sector", r_range=(0.1, 0.2))])
def test_region_errors(region):
    with pytest.raises(InputError):
        StateModel(interval(4), SaintVenantKirchhoff(), control=BodyForce(region))


def test_active_stress_fibres_must_match_the_points():
    bad = ActiveStress(Region(), fibres=lambda x, cells: x[..., :1])
    with pytest.raises(InputError, match="fibres must return vectors"):
        StateModel(rectangle(2), SaintVenantKirchhoff(), control=bad)


@pytest.mark.parametrize("degree, curved", [(1, False), (2, False), (2, True)])
def test_lumped_mass_is_positive_and_keeps_the_total(degree, curved):
    """HRZ lumping (`ControlData.lumped_mass`): positive, the same total as the mass matrix (the
    measure of omega), equal to the row sums for P1; for P2 the row sums are no lumping at all
    (zero at the vertices of straight cells, negative on curved ones)."""
    mesh = annulus(0.5, 1.0, structured=True, n_radial=2, n_theta=12, curved=curved)
    model = StateModel(mesh, NeoHookean(1.0, 2.0), degree=degree,
                       control=ActiveStress(Region("sector", r_range=(0.5, 1.0), theta_range=(-1.0, 1.0))))
    M, lumped = model.control.mass, model.control.lumped_mass
    rows = np.asarray(M.sum(axis=1)).ravel()
    assert lumped.shape == (model.control.size,) and lumped.min() > 0
    assert lumped.sum() == pytest.approx(M.sum(), rel=1e-13)
    if degree == 1:
        np.testing.assert_allclose(lumped, rows, rtol=1e-12)
    else:
        assert rows.min() <= 1e-13 * rows.max()


def _profiled_bar(profile):
    from hyperoc import Objective, PressureRise, ReducedFunctional, TimeTransform

    model = StateModel(interval(20), SaintVenantKirchhoff(0.05, 0.05), damping=2e-3,
                       control=BodyForce(Region("box", lower=(0.75,), upper=(1.0,)), profile=profile))
    return ReducedFunctional(model, TimeTransform.for_step(1.75, 0.25, 0.75, 0.25),
                             Objective(at_tau=PressureRise(0.25)))


def _profile_point(J, tau=0.75):
    from hyperoc import ControlPoint
    from hyperoc.control.verification import random_directions

    return ControlPoint(0.05 * random_directions(J, J.zero(tau), seed=3)["xi"].xi, tau)


PROFILE = "1 + 0.8*sin(4*t)"


def test_a_profile_scales_the_control_at_each_level():
    """With a profile g the state is the one of the control g(t_k) xi_k without a profile: the load of level k is
    B (g(t_k) xi_k)."""
    from hyperoc import ControlPoint
    from hyperoc.dynamics.laws import ExpressionLaw

    law = ExpressionLaw(PROFILE)
    J_g, J_1 = _profiled_bar(law), _profiled_bar(None)
    m = _profile_point(J_g)
    t = J_g.transform.grid(m.tau).t
    scaled = ControlPoint(law.values(t)[:, None] * m.xi, m.tau)
    np.testing.assert_allclose(J_g.state(m).pressure, J_1.state(scaled).pressure, rtol=1e-12, atol=1e-15)
    assert not np.allclose(J_1.state(m).pressure, J_g.state(m).pressure, rtol=1e-3)


def test_a_unit_profile_is_no_profile():
    from hyperoc.dynamics.laws import Constant

    J_g, J_1 = _profiled_bar(Constant(1.0)), _profiled_bar(None)
    m = _profile_point(J_g)
    (v_g, g_g), (v_1, g_1) = J_g.value_and_gradient(m), J_1.value_and_gradient(m)
    assert v_g == pytest.approx(v_1, rel=1e-13)
    np.testing.assert_allclose(g_g.xi, g_1.xi, rtol=1e-11, atol=1e-13 * np.abs(g_1.xi).max())
    assert g_g.tau == pytest.approx(g_1.tau, rel=1e-11)


def test_taylor_with_a_time_profile():
    """The tau-gradient includes the profile's rate g'(t) dt_k/dtau at the moving levels: Taylor rates 2 for
    xi, tau and a joint direction (a missing term leaves rate 1 in tau)."""
    from hyperoc import taylor_test
    from hyperoc.control.verification import random_directions
    from hyperoc.dynamics.laws import ExpressionLaw

    J = _profiled_bar(ExpressionLaw(PROFILE))
    m = _profile_point(J)
    for name, dm in random_directions(J, m, seed=5).items():
        r = taylor_test(J, m, dm)
        assert r.remainder.size >= 3, (name, r.as_dict())
        assert 1.9 <= r.rate <= 2.1, (name, r.as_dict())


def test_profile_activation_needs_an_activation():
    cfg = parse_config({"mesh": {"kind": "interval", "n": 4}, "control": {"profile": "activation"}})
    with pytest.raises(InputError, match="needs \\[dynamics.activation\\]"):
        cfg.control_operator()


def test_the_continuous_gradient_refuses_a_profile():
    from hyperoc import Objective, TimeTransform
    from hyperoc.control.continuous_adjoint import ContinuousReducedFunctional
    from hyperoc.dynamics.laws import ExpressionLaw

    model = StateModel(interval(4), SaintVenantKirchhoff(), control=BodyForce(profile=ExpressionLaw("t")))
    with pytest.raises(InputError, match="time profile"):
        ContinuousReducedFunctional(model, TimeTransform.for_step(1.0, 0.25, 0.5), Objective())

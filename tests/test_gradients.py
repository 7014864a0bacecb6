"""Exact discrete gradients: Taylor remainders fall like h^2 for xi, tau and joint directions.

A wrong gradient leaves a remainder O(h) (rate 1); the rate of an exact one is 2 up to terms of
order h^3, so on the asymptotic range it lies in [1.9, 2.1]. `taylor_test` picks that range.
"""

import numpy as np
import pytest

from helpers import bar
from hyperoc import (
    ActiveStress,
    BodyForce,
    ControlPoint,
    NeoHookean,
    Objective,
    PressureAt,
    PressureRise,
    ReducedFunctional,
    Region,
    SaintVenantKirchhoff,
    StateModel,
    TimeTransform,
    box,
    taylor_test,
)
from hyperoc.control.verification import random_directions
from hyperoc.fem.geometry import annulus


def _point(J, tau, amplitude, seed=3):
    base = random_directions(J, J.zero(tau), seed=seed)["xi"].xi
    return ControlPoint(amplitude * base, tau)


def _assert_rates(J, m, seed=5):
    for name, dm in random_directions(J, m, seed=seed).items():
        r = taylor_test(J, m, dm)
        assert r.remainder.size >= 3, (name, r.as_dict())
        assert 1.9 <= r.rate <= 2.1, (name, r.as_dict())


def _model_1d(n=30):
    return bar(n)


@pytest.mark.parametrize("phi1, eps", [("pressure", 0.0), pytest.param("pressure", 0.2, marks=pytest.mark.slow),
                                        pytest.param("rise", 0.2, marks=pytest.mark.slow)])
def test_taylor_1d(phi1, eps):
    at_tau = PressureAt() if phi1 == "pressure" else PressureRise(eps)
    # With eps > 0 the transform has three pieces; for p(tau) the middle one only shapes the grid,
    # and the tau-derivative must account for its tau-independent steps.
    J = ReducedFunctional(_model_1d(), TimeTransform.for_step(4.0, 0.05, 2.0, eps), Objective(at_tau=at_tau))
    _assert_rates(J, _point(J, 2.0, 0.05))


@pytest.mark.slow
@pytest.mark.parametrize("degree", [1, 2])
def test_taylor_2d_annulus(degree):
    mesh = annulus(0.5, 1.0, structured=True, n_radial=2, n_theta=12)
    model = StateModel(mesh, NeoHookean(1.0, 2.0), degree=degree, damping=0.05,
                       control=ActiveStress(Region("sector", r_range=(0.5, 1.0), theta_range=(-1.0, 1.0))))
    J = ReducedFunctional(model, TimeTransform.for_step(1.0, 0.05, 0.5, 0.1), Objective(at_tau=PressureRise(0.1)))
    _assert_rates(J, _point(J, 0.5, 0.5))


@pytest.mark.slow
def test_taylor_3d_box():
    mesh = box(2, dirichlet="left")
    model = StateModel(mesh, SaintVenantKirchhoff(1.0, 1.0), damping=0.05,
                       control=BodyForce(Region("box", lower=(0.5, 0.0, 0.0), upper=(1.0, 1.0, 1.0))))
    J = ReducedFunctional(model, TimeTransform.for_step(0.6, 0.05, 0.3), Objective(at_tau=PressureAt()))
    _assert_rates(J, _point(J, 0.3, 0.5))


@pytest.mark.slow
def test_wrong_gradient_is_detected():
    """The Taylor test can fail: a gradient off by 10% gives rate ~1."""
    J = ReducedFunctional(_model_1d(), TimeTransform.for_step(4.0, 0.05, 2.0), Objective())
    m = _point(J, 2.0, 0.05)
    J0, d = J.value_and_derivative(m)
    dm = random_directions(J, m, seed=1)["xi"]
    dJdm = 1.1 * float(np.sum(d.xi * dm.xi))
    hs = 1e-2 / 2.0 ** np.arange(4)
    r = [abs(J(m + dm * h) - J0 - h * dJdm) for h in hs]
    rates = np.log2(np.array(r[:-1]) / np.array(r[1:]))
    assert np.all(np.abs(rates - 1.0) < 0.1)


@pytest.mark.slow
def test_taylor_2d_annulus_cell_mean():
    """The bulk term on each cell's mean J (mixed P2-P0, `StateModel` volumetric): still exact."""
    mesh = annulus(0.5, 1.0, structured=True, n_radial=2, n_theta=12)
    model = StateModel(mesh, NeoHookean(1.0, 50.0), degree=2, damping=0.05, volumetric="cell-mean",
                       control=ActiveStress(Region("sector", r_range=(0.5, 1.0), theta_range=(-1.0, 1.0))))
    J = ReducedFunctional(model, TimeTransform.for_step(1.0, 0.05, 0.5, 0.1), Objective(at_tau=PressureRise(0.1)))
    _assert_rates(J, _point(J, 0.5, 0.5))

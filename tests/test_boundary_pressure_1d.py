"""1D: the multiplier p is the reaction force at x = 1, the paper's boundary formula.

In 1D ``vol(u) = int (1 + u_x) = 1 + u(1)``: the constraint is ``u(1, t) = u(1, 0)`` and its gradient
G is the unit vector of the dof at x = 1. Integrating the weak form by parts, the strong form holds
with the boundary condition (paper, 1D case)

    p(t) = -(kappa u_xt + P(u_x))(1, t),   P = F S,  S = 2 mu E + lam tr(E),  F = 1 + u_x,  E = (F^2 - 1) / 2.

Discrete counterpart (exact): the momentum row of the step at the last node reads

    p_{n+1/2} = -[M (y1' - y1) / dt + kappa K (y1 + y1') / 2 + (R(y0) + R(y0')) / 2 - B (xi + xi') / 2]_N,

which must hold to round-off (Newton tolerance). For P1 on a uniform mesh, the last row is
``[M a]_N = h (a_{N-1} + 2 a_N) / 6`` with ``a_N = 0``, ``[K v]_N = v_x`` and ``R_N = P(u_x)`` in the
last cell (one-sided differences), ``[B xi]_N = h (xi_{N-1} + 2 xi_N) / 6``. So the discrepancy of
the boundary formula evaluated on the discrete solution,

    D_h = p_h + (kappa v_x + P(u_x))|_last cell = [B xi]_N - [M a]_N = h xi(1, t) / 2 + O(h^2),

is first order, with the known leading term ``h xi(1, t) / 2``, when the control does not vanish at
x = 1; when it vanishes to second order there (``sin^2`` bump on [0.75, 1]), both rows are O(h^2)
(``a(1, t) = 0``) and the method gives second order. With dt = h the time error of the level values
(O(dt^2)) does not spoil either rate. Both cases are asserted.
"""

from functools import lru_cache

import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.dynamics.stepper import Scheme, TimeStepper
from hyperoc.dynamics.timegrid import uniform_grid
from hyperoc.fem.mesh import interval
from hyperoc.mechanics.controls import BodyForce, Region
from hyperoc.mechanics.materials import SaintVenantKirchhoff
from hyperoc.mechanics.model import StateModel

MU = LAM = 0.05
KAPPA = 1e-2
T, A = 2.0, 0.05
CELLS = (50, 100, 200, 400)
TIMES = np.array([0.5, 1.0, 1.5])  # levels of every grid (dt = h), where xi(1, t) != 0

PROFILES = {
    "nonzero_at_1": lambda x: np.sin(np.pi * (x - 0.75) / 0.5) ** 2,  # b(1) = 1
    "zero_at_1": lambda x: np.sin(np.pi * (x - 0.75) / 0.25) ** 2,  # b(1) = b'(1) = 0
}


def first_piola(ux):
    F = 1.0 + ux
    E = 0.5 * (F**2 - 1.0)
    S = 2 * MU * E + LAM * E  # tr(E) = E in 1D
    return F * S


def envelope(t):
    return np.sin(np.pi * t / T) ** 2


@lru_cache(maxsize=None)
def mesh_case(cells):
    """Model and stepper of a mesh (one compiled time loop per mesh, shared by both profiles)."""
    model = StateModel(interval(cells), SaintVenantKirchhoff(mu=MU, lam=LAM), degree=1, damping=KAPPA,
                       control=BodyForce(Region("box", lower=(0.75,), upper=(1.0,))))
    return model, TimeStepper(model, Scheme(theta=0.5))


@lru_cache(maxsize=None)
def solve(cells, profile):
    model, stepper = mesh_case(cells)
    grid = uniform_grid(T, 1.0 / cells)  # dt = h
    x = model.control.coordinates(model.space)[:, 0]
    xi = A * envelope(grid.t)[:, None] * PROFILES[profile](x)[None, :]
    return model, grid, xi, stepper.run(grid, xi)


def boundary_discrepancy(cells, profile):
    """D_h(t) = p_h(t) + (kappa v_x + P(u_x))(1^-, t) at TIMES, from the level values."""
    model, grid, xi, sol = solve(cells, profile)
    h = 1.0 / cells
    x = model.space.nodes[:, 0]
    assert x[-1] == 1.0 and x[-2] == pytest.approx(1.0 - h)  # nodes numbered along the bar
    u, v = sol.displacement()[..., 0], sol.velocity()[..., 0]
    np.testing.assert_allclose(u[:, -1], 0.0, atol=1e-14)  # the constraint u(1, t) = u(1, 0) = 0
    ux = (u[:, -1] - u[:, -2]) / h
    vx = (v[:, -1] - v[:, -2]) / h
    idx = np.rint(TIMES / grid.dt[0]).astype(int)
    np.testing.assert_allclose(sol.t[idx], TIMES, rtol=1e-13)
    flux = KAPPA * vx + first_piola(ux)
    return sol.pressure[idx] + flux[idx], sol.pressure[idx]


@pytest.mark.parametrize("cells", [pytest.param(c, marks=pytest.mark.slow) if c > CELLS[0] else c for c in CELLS])
def test_multiplier_is_the_discrete_reaction_of_the_last_momentum_row(cells):
    model, grid, xi, sol = solve(cells, "nonzero_at_1")
    dt = grid.dt[:, None]
    R = np.array([np.asarray(model.jitted["internal_force"](jnp.asarray(y))) for y in sol.y0])
    inertia = (model.mass @ (np.diff(sol.y1, axis=0) / dt).T).T
    damping = KAPPA * (model.laplace @ (0.5 * (sol.y1[1:] + sol.y1[:-1])).T).T
    load = (model.control.load @ (0.5 * (xi[1:] + xi[:-1])).T).T
    row = (inertia + damping + 0.5 * (R[1:] + R[:-1]) - load)[:, -1]
    p_max = np.max(np.abs(sol.p_steps))
    assert p_max > 1e-3
    # exact up to the Newton tolerance and round-off (measured 3e-15 of max|p|)
    np.testing.assert_allclose(sol.p_steps, -row, rtol=0, atol=1e-10 * p_max)
    # the row is dominated by the stress, not by the O(h) inertia and load terms
    assert np.max(np.abs((inertia - load)[:, -1])) < 0.2 * p_max


@pytest.mark.slow
def test_boundary_formula_discrepancy_is_first_order_with_the_predicted_leading_term():
    D, P = zip(*(boundary_discrepancy(c, "nonzero_at_1") for c in CELLS))
    D, P = np.abs(np.array(D)), np.abs(np.array(P))
    assert np.all(P > 1e-3) and np.all(D[-1] < 0.02 * P[-1])  # p_h and the formula agree as h -> 0
    assert np.all(np.diff(D, axis=0) < 0), "the discrepancy must decrease under refinement at every time"
    rates = np.log2(D.max(axis=1)[:-1] / D.max(axis=1)[1:])
    assert np.all(rates >= 0.9), f"observed rates {rates}"
    assert np.all(rates <= 1.1)  # first order, not better: the [B xi]_N term is O(h)
    # leading term h xi(1, t) / 2 (xi(1, t) = A envelope(t)); relative O(h) remainder (measured 1.4 h)
    h = 1.0 / np.array(CELLS)
    lead = h[:, None] * A * envelope(TIMES)[None, :] / 2
    D_signed = np.array([boundary_discrepancy(c, "nonzero_at_1")[0] for c in CELLS])
    assert np.all(np.abs(D_signed / lead - 1) <= 3 * h[:, None])


@pytest.mark.slow
def test_boundary_formula_discrepancy_is_second_order_when_the_control_vanishes_at_the_end():
    D = np.abs(np.array([boundary_discrepancy(c, "zero_at_1")[0] for c in CELLS]))
    _, P = boundary_discrepancy(CELLS[-1], "zero_at_1")
    assert np.all(np.abs(P) > 5e-4) and np.all(D[-1] < 1e-3 * np.abs(P))
    dmax = D.max(axis=1)
    assert np.all(np.diff(dmax) < 0)
    rates = np.log2(dmax[:-1] / dmax[1:])
    assert np.all(rates >= 1.8), f"observed rates {rates}"

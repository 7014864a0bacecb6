"""Small-control limit: the nonlinear discrete solution tends to an independently built linear one.

For ``xi = eps * xi_hat`` the solution is ``u = eps u_lin + O(eps^2)``, ``p = eps p_lin + O(eps^2)``
where ``(u_lin, p_lin)`` solves the linearization at (u, p) = (0, 0) of the same discrete scheme:

    M u'' + kappa K u' + K_L u + p G0 = B xi_hat,     G0 . u = 0,

with ``K_L`` the Lame stiffness ``int 2 mu eps(v):eps(w) + lam div v div w`` (the SVK tangent at
F = I), ``G0 = int div(phi)`` (the volume gradient at u = 0), M the mass and K the vector Laplacian.
Here every matrix is assembled by hand from P1 strain-displacement (Voigt) formulas with numpy,
without hyperoc's autodiff kernels or assembly, and the Crank-Nicolson step with the per-step
multiplier is written out and solved with scipy.

Second-order Taylor remainder: ``|u_nl / eps - u_lin| / |u_lin| = C eps`` with C ~ |grad u_hat|
(the quadratic part of E and p H u); so it falls 10x per decade of eps, and is asserted in [5, 20]x
per decade (the O(eps^2) correction and round-off, ~1e-11 / eps from Newton's tolerance, are far
below that band at the chosen eps). Any inconsistency between the nonlinear scheme and its
linearization (a wrong theta, a missing damping term, a wrong sign of the control, a wrong mass,
the wrong G0) makes the ratio stall and fails; e.g. theta = 0.6 in hyperoc stalls at 1.8e-2.
(In the linear limit the multiplier weighting only changes p, not u: p is compared too.)
"""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from hyperoc.dynamics.stepper import Scheme, TimeStepper
from hyperoc.dynamics.timegrid import uniform_grid
from hyperoc.fem.mesh import rectangle
from hyperoc.mechanics.controls import BodyForce, Region
from hyperoc.mechanics.materials import SaintVenantKirchhoff
from hyperoc.mechanics.model import StateModel

MU, LAM, KAPPA = 1.0, 1.5, 0.05
LOWER, UPPER = (0.5, 0.0), (1.0, 0.5)  # control region omega (cells whose centroid lies inside)


def p1_linear_operators(points, cells, mu, lam, omega_mask):
    """Full-size (2 nv) P1 matrices M, K, K_L, B_omega (body-force mass on omega) and vector G0."""
    nv = points.shape[0]
    ndof = 2 * nv
    D = np.array([[2 * mu + lam, lam, 0.0], [lam, 2 * mu + lam, 0.0], [0.0, 0.0, mu]])
    local_mass = (np.ones((3, 3)) + np.eye(3)) / 12.0
    rows, cols, vM, vK, vL, vB = [], [], [], [], [], []
    G0 = np.zeros(ndof)
    for c, tri in enumerate(cells):
        x = points[tri]
        J = np.array([x[1] - x[0], x[2] - x[0]]).T
        area = 0.5 * abs(np.linalg.det(J))
        grads = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]]) @ np.linalg.inv(J)  # (3 nodes, d/dx d/dy)
        dofs = np.array([[2 * a, 2 * a + 1] for a in tri]).ravel()
        # strain-displacement matrix, Voigt (eps_xx, eps_yy, 2 eps_xy)
        Bm = np.zeros((3, 6))
        for a in range(3):
            bx, by = grads[a]
            Bm[0, 2 * a] = bx
            Bm[1, 2 * a + 1] = by
            Bm[2, 2 * a], Bm[2, 2 * a + 1] = by, bx
        KL = area * Bm.T @ D @ Bm
        Ke = area * np.kron(grads @ grads.T, np.eye(2))
        Me = area * np.kron(local_mass, np.eye(2))
        G0[dofs] += area * grads.ravel()  # int d N_a / d x_i
        rows.append(np.repeat(dofs, 6))
        cols.append(np.tile(dofs, 6))
        vM.append(Me.ravel())
        vK.append(Ke.ravel())
        vL.append(KL.ravel())
        vB.append(Me.ravel() if omega_mask[c] else np.zeros(36))
    r, cc = np.concatenate(rows), np.concatenate(cols)
    mk = lambda v: sp.csr_matrix((np.concatenate(v), (r, cc)), shape=(ndof, ndof))
    return mk(vM), mk(vK), mk(vL), mk(vB), G0


def linear_crank_nicolson(M, K, KL, G0, loads, dt, kappa, theta=0.5):
    """Theta-scheme with per-step multiplier for the linear system; returns (U (N+1, n), p_steps (N,)).

    y0' = y0 + dt (th y1' + (1 - th) y1)
    M (y1' - y1) + dt [th (kappa K y1' + KL y0') + (1 - th)(kappa K y1 + KL y0)] + dt p' G0
        = dt [th L' + (1 - th) L]
    G0 . y0' = 0
    With y1' = (y0' - y0)/(th dt) - (1 - th)/th y1 the unknowns are (y0', p').
    """
    n = M.shape[0]
    S = (M / (theta * dt) + kappa * K + theta * dt * KL).tocsc()
    lu = spla.splu(S)
    a, b = lu.solve(np.zeros(n)), lu.solve(dt * G0)  # Schur complement on the single multiplier
    y0, y1 = np.zeros(n), np.zeros(n)
    U, P = [y0], []
    for k in range(len(loads) - 1):
        # right-hand side: everything that does not involve (y0', p')
        rhs = (M @ (y0 / (theta * dt) + y1 / theta)
               + kappa * (K @ y0) + theta * dt * kappa * (K @ ((1 - theta) / theta * y1))
               - (1 - theta) * dt * (kappa * (K @ y1) + KL @ y0)
               + dt * (theta * loads[k + 1] + (1 - theta) * loads[k]))
        a = lu.solve(rhs)
        p = (G0 @ a) / (G0 @ b)
        y0n = a - b * p
        y1 = (y0n - y0) / (theta * dt) - (1 - theta) / theta * y1
        y0 = y0n
        U.append(y0)
        P.append(p)
    return np.array(U), np.array(P)


@pytest.fixture(scope="module")
def setting():
    mesh = rectangle(8)
    model = StateModel(mesh, SaintVenantKirchhoff(MU, LAM), degree=1, damping=KAPPA,
                       control=BodyForce(Region("box", lower=LOWER, upper=UPPER)))
    grid = uniform_grid(1.0, 0.05)
    ctrl = model.control
    # xi_hat: a smooth space-time pattern, (N+1, n_nodes, 2) nodal values on omega's nodes
    xc = mesh.points[ctrl.nodes]
    pattern = np.stack([1.0 + xc[:, 1], 0.5 - xc[:, 0] * xc[:, 1]], axis=1)
    shape_t = np.sin(np.pi * grid.t) + 0.5 * grid.t
    xi_hat = (shape_t[:, None, None] * pattern[None]).reshape(len(grid.t), -1)

    # --- independent linear model -------------------------------------------------------------
    pts, cells = mesh.points, mesh.cells
    centroids = pts[cells].mean(axis=1)
    omega = np.all((centroids >= np.array(LOWER) - 1e-12) & (centroids <= np.array(UPPER) + 1e-12), axis=1)
    M, K, KL, Bom, G0 = p1_linear_operators(pts, cells, MU, LAM, omega)
    free_nodes = ~np.isclose(pts[:, 0], 0.0)  # Dirichlet side x = 0
    free = np.flatnonzero(np.repeat(free_nodes, 2))
    R = lambda A: A[free][:, free]
    # load B xi_hat: body force = nodal field on omega's nodes (zero elsewhere), times the omega mass
    xi_full = np.zeros((len(grid.t), pts.shape[0], 2))
    xi_full[:, ctrl.nodes, :] = xi_hat.reshape(len(grid.t), -1, 2)
    loads = (Bom @ xi_full.reshape(len(grid.t), -1).T).T[:, free]
    U_free, p_lin = linear_crank_nicolson(R(M), R(K), R(KL), G0[free], loads, grid.dt[0], KAPPA)
    U_lin = np.zeros((len(grid.t), 2 * pts.shape[0]))
    U_lin[:, free] = U_free
    return model, grid, xi_hat, U_lin.reshape(len(grid.t), -1, 2), p_lin


def test_linear_model_is_nontrivial(setting):
    _, _, _, U_lin, p_lin = setting
    assert np.max(np.abs(U_lin)) > 1e-2 and np.max(np.abs(p_lin)) > 1e-2


@pytest.mark.slow
def test_nonlinear_solution_tends_to_linearized_solution_at_first_order(setting):
    model, grid, xi_hat, U_lin, p_lin = setting
    epsilons = [1e-1, 1e-2, 1e-3]
    err_u, err_p = [], []
    stepper = TimeStepper(model, Scheme(theta=0.5, multiplier="step"))  # compiled once for all eps
    for eps in epsilons:
        sol = stepper.run(grid, eps * xi_hat)
        U = sol.displacement() / eps
        err_u.append(np.linalg.norm(U - U_lin) / np.linalg.norm(U_lin))
        err_p.append(np.linalg.norm(sol.p_steps / eps - p_lin) / np.linalg.norm(p_lin))
    err_u, err_p = np.array(err_u), np.array(err_p)
    print(f"\neps = {epsilons}\n relative u error {err_u}\n relative p error {err_p}")
    ratios_u, ratios_p = err_u[:-1] / err_u[1:], err_p[:-1] / err_p[1:]
    print(f" ratios per decade: u {ratios_u}, p {ratios_p}")
    assert np.all((5 <= ratios_u) & (ratios_u <= 20)), ratios_u
    assert np.all((5 <= ratios_p) & (ratios_p <= 20)), ratios_p
    assert err_u[-1] < 1e-2 and err_p[-1] < 1e-2

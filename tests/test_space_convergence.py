"""Space convergence on manufactured static solutions.

A smooth displacement ``u_ex`` (zero on the Dirichlet side x = 0) and a constant multiplier
``p_ex`` solve the static volume-constrained problem

    -div P(F) = f  in Omega,   (P(F) + p cof F) n = g  on the other sides,   int det F = V

when ``f = -div P(I + grad u_ex)``, ``g = (P + p_ex cof F) n`` (the Piola identity
``div cof F = 0`` makes the multiplier term disappear from the volume equation) and
``V = int det(I + grad u_ex)``. All three are computed by JAX from the material's own energy, with
quadrature far more accurate than the discretization error, so the only error left is that of the
Galerkin method. Lagrange P_k then gives ``||u - u_h||_L2 = O(h^(k+1))`` and
``|u - u_h|_H1 = O(h^k)``.

The amplitudes keep ``max |grad u| ~ 0.2``: well inside the nonlinear regime (the quadratic terms of
E are ~10% of the linear ones, Newton needs 5-7 iterations) yet far from any loss of ellipticity.

3D runs on a slab (see `make_mesh`). Mesh sequences were chosen from measured error sequences so
that the finest pair is asymptotic (observed rates approach the theoretical ones with a relative
correction ~ h / L, so P1 needs h <= 1/16); rates are asserted within 0.1 on that pair.
"""


import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.dynamics.statics import solve_static
from hyperoc.fem.mesh import box, rectangle
from hyperoc.mechanics.materials import NeoHookean, SaintVenantKirchhoff
from hyperoc.mechanics.model import StateModel

# Mesh sequences chosen to reach the asymptotic range: the slow tier.
pytestmark = pytest.mark.slow


def u_2d(x, amp=0.03):
    X, Y = x[0], x[1]
    return amp * jnp.stack([jnp.sin(np.pi * X) * Y * (1 + X), X * X * jnp.sin(np.pi * Y / 2)])


def u_3d(x, amp=0.05):
    X, Y, Z = x[0], x[1], x[2]
    return amp * jnp.stack([jnp.sin(X) * (1 + Y) * (1 + Z),
                            X * jnp.cos(Y) * jnp.exp(Z / 2),
                            jnp.sin(X) * jnp.cos(Z) * (1 + Y * Y)])


NORMALS = {
    2: {"right": (1.0, 0.0), "top": (0.0, 1.0), "bottom": (0.0, -1.0)},
    3: {"right": (1.0, 0.0, 0.0), "top": (0.0, 1.0, 0.0), "bottom": (0.0, -1.0, 0.0),
        "back": (0.0, 0.0, 1.0), "front": (0.0, 0.0, -1.0)},
}


def _pointwise(fn, dim, chunk=8192):
    """Host evaluation of a point function on arrays (..., dim), in fixed-size chunks.

    Fixed chunks mean one compilation per function for the whole mesh sequence.
    """
    jf = jax.jit(jax.vmap(fn))

    def call(x, *args):
        flat = np.asarray(x, dtype=np.float64).reshape(-1, dim)
        n = flat.shape[0]
        padded = np.concatenate([flat, np.zeros(((-n) % chunk, dim))])
        extra = [jnp.broadcast_to(jnp.asarray(a), (chunk,) + np.shape(a)) for a in args]
        out = np.concatenate([np.asarray(jf(jnp.asarray(padded[k:k + chunk]), *extra))
                              for k in range(0, padded.shape[0], chunk)])[:n]
        return out.reshape(np.shape(x)[:-1] + out.shape[1:])

    return call


class Manufactured:
    """Data of the manufactured problem for one material and one exact displacement."""

    def __init__(self, material, u_exact, dim, p_exact=0.3):
        self.dim, self.p_exact = dim, p_exact
        grad = jax.jacfwd(u_exact)
        eye = jnp.eye(dim)

        def piola(x):
            return jax.grad(material.energy_of_F)(eye + grad(x))

        def body_force(x):  # -div P, i.e. -dP_iJ/dX_J
            return -jnp.einsum("iJJ->i", jax.jacfwd(piola)(x))

        def traction(x, n):
            F = eye + grad(x)
            cof = jnp.linalg.det(F) * jnp.linalg.inv(F).T
            return (piola(x) + p_exact * cof) @ n

        self.u = _pointwise(u_exact, dim)
        self.grad = _pointwise(grad, dim)
        self.f = _pointwise(body_force, dim)
        self.g = _pointwise(traction, dim)
        self.detF = _pointwise(lambda x: jnp.linalg.det(eye + grad(x)), dim)

    def solve(self, mesh, material, degree):
        m = StateModel(mesh, material, degree=degree)
        load = m.load_vector(body_force=lambda x, t: self.f(x))
        for side, n in NORMALS[self.dim].items():
            load = load + m.load_vector(traction=lambda x, t, n=n: self.g(x, np.asarray(n)), neumann=side)
        # Exact deformed volume with a rule of degree 2k + 2 (error O(h^(2k+3)), negligible).
        q = m.space.quadrature(2 * degree + 2)
        V = float(np.sum(q.wdx * self.detF(q.x)))
        sol = solve_static(m, load=load, volume=V)
        l2, h1 = m.space.errors(m.expand(sol.u).ravel(), self.u, self.grad)
        max_grad = float(m.jitted["max_grad"](jnp.asarray(sol.u)))
        return l2, h1, abs(sol.p - self.p_exact), max_grad, sol


CASES = {
    # name: (dim, material, exact u, degree, mesh sizes n (h = 1/n))
    "2d-P1-svk": (2, SaintVenantKirchhoff(1.0, 1.0), u_2d, 1, (16, 32, 64)),
    "2d-P2-svk": (2, SaintVenantKirchhoff(1.0, 1.0), u_2d, 2, (4, 8, 16)),
    "3d-P1-neohookean": (3, NeoHookean(1.0, 1.0), u_3d, 1, (4, 8, 16)),
    "3d-P2-neohookean": (3, NeoHookean(1.0, 1.0), u_3d, 2, (2, 4, 6)),
}


def make_mesh(dim, n):
    """Unit square (n x n), or the slab [0, 1]^2 x [0, 1/2] with n x n x n/2 cubes (6 tets each):
    a genuinely 3D body at half the cost of the cube."""
    return rectangle(n) if dim == 2 else box(n, n, max(1, n // 2), size=(1.0, 1.0, 0.5))


@pytest.mark.parametrize("case", list(CASES))
def test_manufactured_static_solution_converges_at_optimal_rates(case):
    dim, material, u_exact, degree, sizes = CASES[case]
    problem = Manufactured(material, u_exact, dim)
    results = [problem.solve(make_mesh(dim, n), material, degree) for n in sizes]
    l2 = np.array([r[0] for r in results])
    h1 = np.array([r[1] for r in results])
    p_err = np.array([r[2] for r in results])
    h = 1.0 / np.array(sizes, dtype=float)
    rate = lambda e: np.log(e[:-1] / e[1:]) / np.log(h[:-1] / h[1:])
    print(f"\n{case}: n = {sizes}, L2 = {l2}, H1 = {h1}, |p - p_ex| = {p_err}")
    print(f"  L2 rates {rate(l2)}, H1 rates {rate(h1)}, p rates {rate(p_err)}, "
          f"max|grad u| = {results[-1][3]:.3f}, Newton its = {results[-1][4].newton_iterations}")

    # Nonlinear regime, not a small-strain check: |grad u| ~ 0.2 and Newton needs several iterations.
    assert 0.1 <= results[-1][3] <= 0.3
    assert results[-1][4].newton_iterations[0] >= 3

    # Theoretical rates on the finest (asymptotic) pair.
    assert abs(rate(l2)[-1] - (degree + 1)) < 0.1, rate(l2)
    assert abs(rate(h1)[-1] - degree) < 0.1, rate(h1)
    # The multiplier converges too (at least as fast as the L2 error, measured rate k+1 .. 2k).
    assert rate(p_err)[-1] > degree + 1 - 0.3, rate(p_err)

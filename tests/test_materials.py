"""Constitutive laws: autodiff stress and tangent against finite differences of W, invariance, inputs.

Finite-difference tolerances (float64, eps = 2.2e-16, F and moduli of order 1):

- P = dW/dF by central differences of W with step h = 1e-5: truncation ~ h^2/6 |d3W| ~ 1e-11 |A|,
  round-off ~ eps |W| / h ~ 2e-11 |W|.
- dP/dF by central second differences of W with step h = 1e-4 (four evaluations per entry):
  truncation ~ h^2/12 |d4W| ~ 1e-9 |A|, round-off ~ 4 eps |W| / (4 h^2) ~ 2e-8 |W|.

Errors are measured relative to ``scale = |P| + |A|`` (Frobenius norms; P and dP/dF have the
same unit since F is dimensionless), which is nonzero at the stress-free state F = I where P = 0.
Asserted: 1e-8 for P and 1e-6 for dP/dF, i.e. ~100x and ~50x above the estimates (measured:
~5e-11 and ~3e-8), while any wrong derivative (an O(1) relative error) fails.
"""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.errors import InputError
from hyperoc.mechanics.materials import (
    Fung,
    NeoHookean,
    Ogden,
    SaintVenantKirchhoff,
    finite_difference_check,
    first_piola,
    material_from_config,
    tangent_modulus,
)

EPS = np.finfo(np.float64).eps

MATERIALS = {
    "svk": SaintVenantKirchhoff(mu=0.7, lam=1.3),
    "fung": Fung(beta=0.5, gamma=0.8, W0=0.1),
    "ogden2": Ogden(coefficients=(0.3, 0.2), exponents=(2.0, 3.5)),
    "neohookean": NeoHookean(mu=0.6, lam=1.1),
}


def rotation(d, seed):
    """A proper rotation (det +1) in d dimensions."""
    rng = np.random.default_rng(seed)
    Q, R = np.linalg.qr(rng.standard_normal((d, d)))
    Q = Q * np.sign(np.diag(R))
    if np.linalg.det(Q) < 0:
        Q[:, 0] = -Q[:, 0]
    return Q


def deformation_gradients(d):
    """Test points: identity, a generic F, and F with a double eigenvalue of C (d >= 2)."""
    rng = np.random.default_rng(10 * d)
    Fs = {"identity": np.eye(d)}
    G = np.eye(d) + 0.25 * rng.standard_normal((d, d))
    assert np.linalg.det(G) > 0.3
    Fs["generic"] = G
    if d >= 2:
        # C = F^T F = R^T diag(1.21, 1.21, 0.81) R: repeated principal stretch, rotated frame.
        Fs["double-eigenvalue"] = rotation(d, 1) @ np.diag([1.1, 1.1, 0.9][:d]) @ rotation(d, 2)
        # C = s^2 I: fully degenerate but not the identity.
        Fs["pure-dilation"] = 1.05 * rotation(d, 3)
    return Fs


_energy = jax.jit(lambda material, F: material.energy_of_F(F), static_argnums=0)
_stress = jax.jit(first_piola, static_argnums=0)


@partial(jax.jit, static_argnums=0)
def _derivatives_and_stencils(material, F, h1=1e-5, h2=1e-4):
    """Autodiff P, dP/dF, and W on the central-difference stencils, in one compiled call.

    One compilation per (material, dimension) keeps the whole file fast.
    """
    d = F.shape[0]
    W = jax.vmap(material.energy_of_F)
    basis = jnp.eye(d * d).reshape(d * d, d, d)
    a, b = basis[:, None], basis[None, :]
    second = [W((F + h2 * (sa * a + sb * b)).reshape(-1, d, d)).reshape(d * d, d * d)
              for sa, sb in ((1, 1), (1, -1), (-1, 1), (-1, -1))]
    return (first_piola(material, F), tangent_modulus(material, F),
            W(F + h1 * basis), W(F - h1 * basis), jnp.stack(second))


def autodiff_and_finite_differences(material, F, h1=1e-5, h2=1e-4):
    """(P, A) by autodiff and (P_fd, A_fd) by central differences of W.

    P_a = (W(F + h1 e_a) - W(F - h1 e_a)) / 2 h1;
    A_ab = (W(F + h2 (e_a + e_b)) - W(F + h2 (e_a - e_b)) - W(F - h2 (e_a - e_b)) + W(F - h2 (e_a + e_b))) / 4 h2^2.
    """
    d = F.shape[0]
    P, A, Wp, Wm, W4 = (np.asarray(x) for x in _derivatives_and_stencils(material, jnp.asarray(F), h1, h2))
    P_fd = ((Wp - Wm) / (2 * h1)).reshape(d, d)
    A_fd = ((W4[0] - W4[1] - W4[2] + W4[3]) / (4 * h2 * h2)).reshape(d, d, d, d)
    return P, A, P_fd, A_fd


CASES = [(name, d, label) for name in MATERIALS for d in (1, 2, 3) for label in deformation_gradients(d)]


@pytest.mark.parametrize("name,d,label", CASES)
def test_autodiff_stress_and_tangent_match_finite_differences_of_energy(name, d, label):
    material = MATERIALS[name]
    F = deformation_gradients(d)[label]
    P, A, P_fd, A_fd = autodiff_and_finite_differences(material, F)
    assert np.all(np.isfinite(P)) and np.all(np.isfinite(A)), (P, A)
    scale = np.linalg.norm(P) + np.linalg.norm(A)
    assert np.linalg.norm(A) > 0.1  # the scale never degenerates (positive moduli at every test point)
    assert np.linalg.norm(P - P_fd) <= 1e-8 * scale, (np.linalg.norm(P - P_fd), scale)
    assert np.linalg.norm(A - A_fd) <= 1e-6 * scale, (np.linalg.norm(A - A_fd), scale)
    # The tangent is a Hessian: major symmetry A[iJkL] = A[kLiJ], to round-off.
    assert np.allclose(A, A.transpose(2, 3, 0, 1), rtol=0, atol=1e-13 * scale)


def test_stress_free_state_and_ogden_reference_stress():
    """At F = I: SVK, Fung and neo-Hookean are stress free; the paper's Ogden form is not.

    With ``W = sum c_k tr(C^g_k - I)``, ``dW/dC = sum c_k g_k C^(g_k - 1)`` so at C = I
    ``P = 2 dW/dC = 2 sum c_k g_k I`` (documented in the Ogden docstring).
    """
    for d in (1, 2, 3):
        I = jnp.eye(d)
        for name in ("svk", "fung", "neohookean"):
            assert np.max(np.abs(np.asarray(_stress(MATERIALS[name], I)))) <= 1e-14
        og = MATERIALS["ogden2"]
        expected = 2 * sum(c * g for c, g in zip(og.coefficients, og.exponents))
        assert np.allclose(np.asarray(_stress(og, I)), expected * np.eye(d), rtol=1e-13, atol=0)


@pytest.mark.parametrize("d", [1, 2, 3])
def test_ogden_identity_with_exponent_below_two_has_finite_tangent(d):
    """gamma in [1, 2): C^(gamma-2) appears in naive formulas; the divided differences must not NaN."""
    og = Ogden(coefficients=(0.4, 0.1), exponents=(1.0, 1.5))
    P, A, P_fd, A_fd = autodiff_and_finite_differences(og, np.eye(d))
    assert np.all(np.isfinite(A))
    scale = np.linalg.norm(P) + np.linalg.norm(A)
    assert np.linalg.norm(P - P_fd) <= 1e-8 * scale
    assert np.linalg.norm(A - A_fd) <= 1e-6 * scale


@pytest.mark.parametrize("name", list(MATERIALS))
@pytest.mark.parametrize("d", [2, 3])
def test_frame_indifference_and_isotropy(name, d):
    """W(QF) = W(F) and P(QF) = Q P(F) (objectivity); W(FQ) = W(F) (all four laws are isotropic).

    Q^T Q = I holds to a few eps, so W changes by ~eps |P| |F| at most: asserted at 1e-12 of that.
    """
    material = MATERIALS[name]
    F = deformation_gradients(d)["generic"]
    Q = rotation(d, 7)
    W = lambda G: float(_energy(material, jnp.asarray(G)))
    P = np.asarray(_stress(material, jnp.asarray(F)))
    tol = 1e-12 * (abs(W(F)) + np.linalg.norm(P) * np.linalg.norm(F))
    assert abs(W(Q @ F) - W(F)) <= tol
    assert abs(W(F @ Q) - W(F)) <= tol
    assert abs(W(F) - W(np.eye(d))) > 1e3 * tol  # F is a genuine deformation, not a rotation
    P_rot = np.asarray(_stress(material, jnp.asarray(Q @ F)))
    assert np.linalg.norm(P_rot - Q @ P) <= 1e-12 * np.linalg.norm(P) * 10


@pytest.mark.parametrize("cfg", [
    {"law": "svk", "mu": -1.0, "lambda": 1.0},
    {"law": "svk", "mu": 0.0},
    {"law": "svk", "mu": 1.0, "lambda": -0.5},
    {"law": "neo-hookean", "mu": -0.1},
    {"law": "fung", "beta": 0.0},
    {"law": "fung", "beta": -0.3},
    {"law": "fung", "beta": 0.1, "gamma": 0.0},
    {"law": "ogden", "coefficients": [0.1], "exponents": [0.5]},
    {"law": "ogden", "coefficients": [0.1, 0.2], "exponents": [2.0, 0.9]},
    {"law": "ogden", "coefficients": [-0.1], "exponents": [2.0]},
    {"law": "ogden", "coefficients": [0.1, 0.2], "exponents": [2.0]},
    {"law": "mooney-rivlin", "c1": 1.0},
    {"law": "svk", "shear": 1.0},
    {"law": "svk", "mu": "one"},
    {"law": "svk", "mu": None},
    {"law": "svk", "mu": True},
    {"law": "ogden", "coefficients": [0.1, "x"], "exponents": [2.0, 3.0]},
    {"law": "svk", "mu": float("nan")},
])
def test_bad_material_parameters_raise_input_error(cfg):
    with pytest.raises(InputError):
        material_from_config(cfg)


@pytest.mark.parametrize("cfg", [
    {"law": "svk", "mu": [1.0, 2.0]},
    {"law": "ogden", "coefficients": 0.5, "exponents": 2.0},
])
def test_wrong_parameter_type_raises_input_error(cfg):
    with pytest.raises(InputError):
        material_from_config(cfg)


def test_direct_construction_is_validated_by_the_model():
    from hyperoc.fem.mesh import interval
    from hyperoc.mechanics.model import StateModel

    with pytest.raises(InputError):
        SaintVenantKirchhoff(mu=-1.0, lam=1.0).validate()
    with pytest.raises(InputError):
        Ogden(coefficients=(0.1,), exponents=(0.5,)).validate()
    with pytest.raises(InputError):
        StateModel(interval(4), Fung(beta=-1.0))


def test_good_config_builds_the_right_law():
    m = material_from_config({"law": "Ogden", "coefficients": [0.3, 0.2], "exponents": [2, 3.5]})
    assert m == MATERIALS["ogden2"]
    assert material_from_config({"law": "svk", "mu": 0.7, "lambda": 1.3}) == MATERIALS["svk"]


@pytest.mark.parametrize("name", ["svk", "ogden2"])
def test_library_finite_difference_check_at_a_generic_state(name):
    """The shipped helper agrees at a generic (stressed) F, where relative errors are well defined.

    Its default step h = 1e-6 gives round-off ~ eps |P| / h ~ 1e-10 relative on the tangent.
    """
    err_P, err_A = finite_difference_check(MATERIALS[name], deformation_gradients(3)["generic"])
    assert err_P < 1e-7 and err_A < 1e-6, (err_P, err_A)


@pytest.mark.parametrize("name", ["svk", "neohookean"])
def test_library_finite_difference_check_at_stress_free_state(name):
    err_P, err_A = finite_difference_check(MATERIALS[name], np.eye(3))
    assert err_P < 1e-6 and err_A < 1e-6, (err_P, err_A)


@pytest.mark.parametrize("cfg", [{"law": "svk", "mu": float("inf")}, {"law": "svk", "mu": float("nan")},
                                 {"law": "svk", "lambda": 1.0, "lam": 2.0}])
def test_non_finite_or_ambiguous_parameters_raise_input_error(cfg):
    with pytest.raises(InputError):
        material_from_config(cfg)

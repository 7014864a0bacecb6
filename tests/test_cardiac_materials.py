"""Fibre-dependent laws (Guccione, Holzapfel-Ogden): derivatives, formulas, invariance, inputs.

Finite-difference tolerances (float64, eps = 2.2e-16), errors relative to ``scale = |P| + |A|``
(Frobenius; nonzero at F = I where P = 0), as in ``test_materials.py`` but with smaller steps:
the exponentials ``exp(b (I4 - 1)^2)`` (b up to 16) make the higher derivatives of W large, and
with the steps of ``test_materials.py`` the truncation error of dP/dF reached 1e-6 (measured, O(h^2)).

- P by central differences of W, step h1 = 2e-6: truncation ~ h1^2/6 |d3W| ~ 7e-13 |d3W|,
  round-off ~ eps |W| / h1 ~ 1e-10 |W|; |W| <= 1e-2 scale at the test points.
- dP/dF by central second differences of W, step h2 = 2.5e-5: truncation ~ h2^2/12 |d4W|
  ~ 5e-11 |d4W| with |d4W| up to ~1e3 scale here, round-off ~ eps |W| / h2^2 ~ 4e-7 |W| ~ 4e-9 scale.

Asserted 1e-9 (P) and 1e-6 (dP/dF); measured at most 1.3e-11 and 1.4e-7 (Holzapfel-Ogden, fibre in
tension). A wrong derivative (an O(1) relative error) fails.

Holzapfel-Ogden's fibre switch ``max(I4 - 1, 0)^2`` has a jump in its second derivative at
``I4 = 1``: finite differences there are meaningless, so the test points keep ``|I4 - 1| > 1e-2``
(asserted), far beyond the stencil's reach (~ 4 h2 |F|).
"""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.errors import InputError
from hyperoc.mechanics.materials import (
    Guccione,
    HolzapfelOgden,
    finite_difference_check,
    first_piola,
    material_from_config,
    tangent_modulus,
    tension_square,
)
from test_materials import rotation  # a proper rotation; its rows serve as an orthonormal frame

MATERIALS = {
    "guccione-p1": Guccione(),  # Land et al. 2015 problems 1/3, bulk modulus 1000 kPa
    "guccione-p2": Guccione(C=10.0, bf=1.0, bt=1.0, bfs=1.0, bulk_modulus=50.0),
    "guccione-isochoric": Guccione(bulk_modulus=50.0, isochoric=True),
    "holzapfel-ogden": HolzapfelOgden(),  # the 2009 fit, bulk modulus 1000 kPa
    "holzapfel-ogden-soft-bulk": HolzapfelOgden(bulk_modulus=5.0),
    # the cardiac elastodynamics benchmark's law: full I1, SI units (Pa)
    "holzapfel-ogden-benchmark-si": HolzapfelOgden(a=59.0, af=18472.0, as_=2481.0, afs=216.0, bulk_modulus=1e6,
                                                    isochoric=False),
}


def stretch_along(frame, stretches):
    """``F = sum_k lambda_k a_k (x) a_k`` for the frame rows a_k: principal stretches along the frame."""
    return frame.T @ np.diag(stretches) @ frame


def sample_points(d):
    """(F, frame) pairs at myocardial strains (~10 %): a generic F with a random frame; the fibre
    stretched (tension branch) and shortened (slack branch), each with a small random shear."""
    rng = np.random.default_rng(100 + d)
    frame = rotation(d, 3 * d)
    shear = 0.03 * rng.standard_normal((d, d))
    return {
        "generic": (np.eye(d) + 0.08 * rng.standard_normal((d, d)), rotation(d, d + 5)),
        "fibre-tension": (stretch_along(frame, [1.12, 0.94, 1.06][:d]) + shear, frame),
        "fibre-slack": (stretch_along(frame, [0.9, 1.1, 0.97][:d]) + shear, frame),
    }


def fibre_invariants(F, frame):
    C = F.T @ F
    return [a @ C @ a for a in frame[:2]]


@partial(jax.jit, static_argnums=0)
def _energies(material, Fs, frame):
    """W at a batch of deformation gradients (n, d, d), one frame."""
    return jax.vmap(lambda G: material.energy_of_F(G, frame))(Fs)


# Compiled once per (material, dimension) and shared by all tests (materials are hashable).
_stress = jax.jit(first_piola, static_argnums=0)
_tangent = jax.jit(tangent_modulus, static_argnums=0)


def W(material, F, frame):
    return float(_energies(material, jnp.asarray(F)[None], jnp.asarray(frame))[0])


def autodiff_and_finite_differences(material, F, frame, h1=2e-6, h2=2.5e-5):
    """(P, A) by autodiff and (P_fd, A_fd) by central differences of W (one batch of W values):

    P_a = (W(F + h1 e_a) - W(F - h1 e_a)) / 2 h1;
    A_ab = (W(F + h2 (e_a + e_b)) - W(F + h2 (e_a - e_b)) - W(F - h2 (e_a - e_b)) + W(F - h2 (e_a + e_b))) / 4 h2^2.
    """
    d = F.shape[0]
    e = np.eye(d * d).reshape(d * d, d, d)
    a, b = e[:, None], e[None, :]
    stencil = [F + h1 * e, F - h1 * e] + [(F + h2 * (sa * a + sb * b)).reshape(-1, d, d)
                                          for sa, sb in ((1, 1), (1, -1), (-1, 1), (-1, -1))]
    Ws = np.asarray(_energies(material, jnp.asarray(np.concatenate(stencil)), jnp.asarray(frame)))
    Wp, Wm, W4 = Ws[: d * d], Ws[d * d: 2 * d * d], Ws[2 * d * d:].reshape(4, d * d, d * d)
    P_fd = ((Wp - Wm) / (2 * h1)).reshape(d, d)
    A_fd = ((W4[0] - W4[1] - W4[2] + W4[3]) / (4 * h2 * h2)).reshape(d, d, d, d)
    F, frame = jnp.asarray(F), jnp.asarray(frame)
    return np.asarray(_stress(material, F, frame)), np.asarray(_tangent(material, F, frame)), P_fd, A_fd


CASES = [(name, d, label) for name in MATERIALS for d in (2, 3) for label in sample_points(d)]


@pytest.mark.parametrize("name,d,label", CASES)
def test_autodiff_stress_and_tangent_match_finite_differences_of_energy(name, d, label):
    material = MATERIALS[name]
    F, frame = sample_points(d)[label]
    assert np.linalg.det(F) > 0.5
    if isinstance(material, HolzapfelOgden):
        assert min(abs(i4 - 1.0) for i4 in fibre_invariants(F, frame)) > 1e-2  # away from the switch
    P, A, P_fd, A_fd = autodiff_and_finite_differences(material, F, frame)
    assert np.all(np.isfinite(P)) and np.all(np.isfinite(A))
    scale = np.linalg.norm(P) + np.linalg.norm(A)
    assert np.linalg.norm(P - P_fd) <= 1e-9 * scale, (np.linalg.norm(P - P_fd), scale)
    assert np.linalg.norm(A - A_fd) <= 1e-6 * scale, (np.linalg.norm(A - A_fd), scale)
    assert np.allclose(A, A.transpose(2, 3, 0, 1), rtol=0, atol=1e-13 * scale)  # a Hessian


@pytest.mark.parametrize("name", [k for k, m in MATERIALS.items() if getattr(m, "isochoric", True) is not False
                                  or not isinstance(m, HolzapfelOgden)])
@pytest.mark.parametrize("d", [2, 3])
def test_stress_free_reference_state(name, d):
    """W(I) = 0 and P(I) = 0 for any frame (Q, the invariants' deviations and U' vanish at E = 0)."""
    material = MATERIALS[name]
    for seed in range(3):
        frame = rotation(d, seed)
        assert abs(W(material, np.eye(d), frame)) <= 1e-14
        P = np.asarray(_stress(material, jnp.eye(d), jnp.asarray(frame)))
        assert np.max(np.abs(P)) <= 1e-12, P


@pytest.mark.parametrize("d", [2, 3])
def test_full_I1_holzapfel_ogden_reference_stress(d):
    """With the full ``I1 = tr C`` (the benchmark's form) the reference state carries the stress S = a I
    (dI1/dE = 2 I; the fibre, sheet and shear terms and the bulk term's U'(1) vanish there): P(I) = a I."""
    material = MATERIALS["holzapfel-ogden-benchmark-si"]
    P = np.asarray(_stress(material, jnp.eye(d), jnp.asarray(rotation(d, 1))))
    np.testing.assert_allclose(P, material.a * np.eye(d), rtol=1e-14, atol=1e-12 * material.a)


@pytest.mark.parametrize("d", [2, 3])
def test_guccione_tangent_at_reference_matches_finite_differences(d):
    """Guccione is smooth at E = 0, so the reference tangent is checked like any other point."""
    material = MATERIALS["guccione-p1"]
    P, A, P_fd, A_fd = autodiff_and_finite_differences(material, np.eye(d), rotation(d, 5))
    scale = np.linalg.norm(A)
    assert np.linalg.norm(P - P_fd) <= 1e-9 * scale and np.linalg.norm(A - A_fd) <= 1e-6 * scale


def test_holzapfel_ogden_reference_tangent_is_the_slack_limit():
    """At I4 = 1 the switch's second derivative jumps (0 -> 2); the documented value is the
    compression limit 0: the tangent at F = I equals that of the law without fibre and sheet terms."""
    material = MATERIALS["holzapfel-ogden"]
    slack = HolzapfelOgden(af=0.0, as_=0.0)
    frame = jnp.asarray(rotation(3, 8))
    A = np.asarray(_tangent(material, jnp.eye(3), frame))
    A0 = np.asarray(_tangent(slack, jnp.eye(3), frame))
    assert np.all(np.isfinite(A)) and np.allclose(A, A0, rtol=1e-13, atol=0)


@pytest.mark.parametrize("d", [2, 3])
def test_guccione_energy_is_the_component_formula(d):
    """W = C/2 (exp(Q) - 1) + bulk_modulus/4 (J^2 - 1 - 2 ln J) with Q in the frame components E_ab = a.E b
    (the code uses the projector form P = I - f f^T)."""
    material = Guccione(C=2.0, bf=8.0, bt=2.0, bfs=4.0, bulk_modulus=30.0)
    F, frame = sample_points(d)["generic"]
    E = 0.5 * (F.T @ F - np.eye(d))
    Eh = frame @ E @ frame.T  # components in (f, s[, n])
    Q = material.bf * Eh[0, 0] ** 2 + material.bt * np.sum(Eh[1:, 1:] ** 2) + 2 * material.bfs * np.sum(Eh[0, 1:] ** 2)
    J = np.linalg.det(F)
    expected = 0.5 * material.C * np.expm1(Q) + material.bulk_modulus / 4 * (J**2 - 1 - 2 * np.log(J))
    assert W(material, F, frame) == pytest.approx(expected, rel=1e-13)


@pytest.mark.parametrize("d", [2, 3])
def test_isochoric_guccione_is_the_law_on_the_isochoric_strain(d):
    """``isochoric=True``: W = C/2 (exp(Q(Ebar)) - 1) + U(J), Ebar = (J^(-2/d) C - I)/2. It equals the
    plain law at J = 1, and without U it does not see a dilatation: W(s F) = W(F)."""
    plain, iso = Guccione(bulk_modulus=30.0), Guccione(bulk_modulus=30.0, isochoric=True)
    F, frame = sample_points(d)["generic"]
    J = np.linalg.det(F)
    unimodular = F / J ** (1.0 / d)
    assert W(iso, unimodular, frame) == pytest.approx(W(plain, unimodular, frame), rel=1e-13)
    U = lambda J: iso.bulk_modulus / 4 * (J**2 - 1 - 2 * np.log(J))
    assert W(iso, F, frame) == pytest.approx(W(plain, unimodular, frame) + U(J), rel=1e-13)
    rest = Guccione(bulk_modulus=0.0, isochoric=True)
    assert W(rest, 1.3 * F, frame) == pytest.approx(W(rest, F, frame), rel=1e-13)


def _uniaxial_stress(material, stretches):
    """``P_11(lambda)`` for ``F = diag(lambda, 1, 1)`` (fibre along x), the first Piola stress."""
    stress = jax.vmap(lambda s: first_piola(material, jnp.diag(jnp.array([s, 1.0, 1.0])), jnp.eye(3))[0, 0])
    return np.asarray(stress(jnp.asarray(stretches)))


def test_guccione_without_bulk_term_loses_ellipticity_in_compression_unless_isochoric():
    """Land problem 2's law with bulk_modulus = 0 (the rest a cell-mean bulk term leaves pointwise): on the full
    strain, the uniaxial stress P(lambda) = C exp(Q) lambda (lambda^2 - 1)/2 peaks where
    3 lambda^2 - 1 + lambda^2 (lambda^2 - 1)^2 = 0, lambda = 0.534 (a compression that the law no longer
    resists); on the isochoric strain it increases for every lambda in (0, 1] and its W grows without
    bound as lambda -> 0 (the transverse Ebar_22 ~ lambda^(-2/3) / 2)."""
    p2 = dict(C=10.0, bf=1.0, bt=1.0, bfs=1.0, bulk_modulus=0.0)
    stretches = np.linspace(0.05, 1.0, 400)
    plain = _uniaxial_stress(Guccione(**p2), stretches)
    iso = _uniaxial_stress(Guccione(**p2, isochoric=True), stretches)
    peak = stretches[np.argmin(plain)]  # P < 0 in compression: the peak magnitude is the minimum
    roots = np.roots([1.0, 0.0, -2.0, 0.0, 4.0, 0.0, -1.0])  # lambda^6 - 2 lambda^4 + 4 lambda^2 - 1 = 0
    expected = min(r.real for r in roots if abs(r.imag) < 1e-12 and 0 < r.real < 1)
    assert abs(peak - expected) <= stretches[1] - stretches[0] and abs(expected - 0.534) < 5e-4
    assert np.all(np.diff(iso) > 0)
    material = Guccione(**p2, isochoric=True)
    assert W(material, np.diag([1e-3, 1.0, 1.0]), np.eye(3)) > 1e6 * W(material, np.diag([0.5, 1.0, 1.0]), np.eye(3))


@pytest.mark.parametrize("label", ["generic", "fibre-tension", "fibre-slack"])
def test_holzapfel_ogden_energy_is_the_documented_formula(label):
    m = HolzapfelOgden(bulk_modulus=30.0)
    F, frame = sample_points(3)[label]
    C, J = F.T @ F, np.linalg.det(F)
    f, s = frame[0], frame[1]
    pos = lambda x: max(x, 0.0)
    expected = (m.a / (2 * m.b) * np.expm1(m.b * (J ** (-2 / 3) * np.trace(C) - 3))
                + m.af / (2 * m.bf) * np.expm1(m.bf * pos(f @ C @ f - 1) ** 2)
                + m.as_ / (2 * m.bs) * np.expm1(m.bs * pos(s @ C @ s - 1) ** 2)
                + m.afs / (2 * m.bfs) * np.expm1(m.bfs * (f @ C @ s) ** 2)
                + m.bulk_modulus / 4 * (J**2 - 1 - 2 * np.log(J)))
    assert W(m, F, frame) == pytest.approx(expected, rel=1e-13)


@pytest.mark.parametrize("name", list(MATERIALS))
@pytest.mark.parametrize("d", [2, 3])
def test_objectivity_and_material_symmetry(name, d):
    """W(QF) = W(F), P(QF) = Q P(F) (objectivity); W(F R^T, frame R^T) = W(F, frame) (rotating the
    body together with its fibres); the fibre frame matters, W(F R^T, frame) != W(F, frame), except
    for Guccione with bf = bt = bfs (problem 2 of Land et al.), where Q = bf |E|^2 is isotropic."""
    material = MATERIALS[name]
    F, frame = sample_points(d)["fibre-tension"]
    Q, R = rotation(d, 11), rotation(d, 12)
    P = np.asarray(_stress(material, jnp.asarray(F), jnp.asarray(frame)))
    tol = 1e-12 * (abs(W(material, F, frame)) + np.linalg.norm(P) * np.linalg.norm(F))
    assert abs(W(material, Q @ F, frame) - W(material, F, frame)) <= tol
    assert abs(W(material, F @ R.T, frame @ R.T) - W(material, F, frame)) <= tol
    if name == "guccione-p2":
        assert abs(W(material, F @ R.T, frame) - W(material, F, frame)) <= tol
    else:
        assert abs(W(material, F @ R.T, frame) - W(material, F, frame)) > 1e3 * tol
    P_rot = np.asarray(_stress(material, jnp.asarray(Q @ F), jnp.asarray(frame)))
    assert np.linalg.norm(P_rot - Q @ P) <= 1e-12 * np.linalg.norm(P) * 10


def test_guccione_is_transversely_isotropic_and_holzapfel_ogden_is_not():
    """Rotating (s, n) about f leaves Guccione unchanged; Holzapfel-Ogden sees the sheet."""
    F, frame = sample_points(3)["generic"]
    t = 0.7
    spun = frame.copy()
    spun[1], spun[2] = np.cos(t) * frame[1] + np.sin(t) * frame[2], -np.sin(t) * frame[1] + np.cos(t) * frame[2]
    g, ho = MATERIALS["guccione-p1"], MATERIALS["holzapfel-ogden"]
    assert W(g, F, spun) == pytest.approx(W(g, F, frame), rel=1e-13)
    assert abs(W(ho, F, spun) - W(ho, F, frame)) > 1e-6 * abs(W(ho, F, frame))


@pytest.mark.parametrize("d", [2, 3])
def test_fibre_direction_is_stiffer(d):
    """Uniaxial stretch lambda = 1.1 along a, F = I + (lambda - 1) a (x) a: the same J = lambda either way,
    so Guccione's energies differ only in Q = b E_aa^2 with b = bf (along f) or bt (across):
    exactly W = C/2 expm1(b E^2) + U(J), and the fibre direction carries more energy and normal
    stress (the volumetric part, the same in both, dominates the stress at bulk modulus 1000 kPa).
    Holzapfel-Ogden: f (af = 18.5 kPa) > s (as = 2.5 kPa) in energy and stress."""
    lam, frame = 1.1, rotation(d, 21)
    E, J = (lam**2 - 1) / 2, lam
    along = lambda a: np.eye(d) + (lam - 1) * np.outer(a, a)
    g = MATERIALS["guccione-p1"]
    U = g.bulk_modulus / 4 * (J**2 - 1 - 2 * np.log(J))
    Wf, Ws = W(g, along(frame[0]), frame), W(g, along(frame[1]), frame)
    assert Wf == pytest.approx(0.5 * g.C * np.expm1(g.bf * E**2) + U, rel=1e-12)
    assert Ws == pytest.approx(0.5 * g.C * np.expm1(g.bt * E**2) + U, rel=1e-12)
    ho = MATERIALS["holzapfel-ogden"]
    for m in (g, ho):
        normal_stress = lambda a: float(a @ np.asarray(_stress(m, jnp.asarray(along(a)), jnp.asarray(frame))) @ a)
        assert W(m, along(frame[0]), frame) > W(m, along(frame[1]), frame)
        assert normal_stress(frame[0]) > normal_stress(frame[1]) + 0.1 > 0.1


def test_holzapfel_ogden_fibres_bear_no_compression():
    """With I4f, I4s < 1 the fibre and sheet terms are off: W equals the law with af = as = 0."""
    frame = rotation(3, 31)
    F = stretch_along(frame, [0.9, 0.95, 1.16])
    assert max(fibre_invariants(F, frame)) < 1
    ho = MATERIALS["holzapfel-ogden"]
    assert W(ho, F, frame) == pytest.approx(W(HolzapfelOgden(af=0.0, as_=0.0), F, frame), rel=1e-14)
    stretched = stretch_along(frame, [1.1, 1.0, 1.0])
    assert W(ho, stretched, frame) > W(HolzapfelOgden(af=0.0), stretched, frame)


@pytest.mark.parametrize("cfg,word", [
    ({"law": "guccione", "C": -2.0}, "C"),
    ({"law": "guccione", "C": 0.0}, "C"),
    ({"law": "guccione", "bf": -8.0}, "bf"),
    ({"law": "guccione", "bt": 0.0}, "bt"),
    ({"law": "guccione", "bfs": float("nan")}, "bfs"),
    ({"law": "guccione", "bulk_modulus": -1.0}, "bulk_modulus"),
    ({"law": "guccione", "C": float("inf")}, "C"),
    ({"law": "guccione", "mu": 1.0}, "unknown"),
    ({"law": "holzapfel-ogden", "a": 0.0}, "a"),
    ({"law": "holzapfel-ogden", "b": -1.0}, "b"),
    ({"law": "holzapfel-ogden", "af": -1.0}, "af"),
    ({"law": "holzapfel-ogden", "as": -0.5}, "as"),
    ({"law": "holzapfel-ogden", "bfs": 0.0}, "bfs"),
    ({"law": "holzapfel-ogden", "bulk_modulus": 0.0}, "bulk_modulus"),
    ({"law": "holzapfel-ogden", "bs": "big"}, "bs"),
    ({"law": "guccione", "isochoric": 1}, "isochoric"),
    ({"law": "guccione", "isochoric": "yes"}, "isochoric"),
])
def test_bad_parameters_raise_input_error_naming_the_parameter(cfg, word):
    with pytest.raises(InputError, match=word):
        material_from_config(cfg)


def test_direct_construction_is_validated():
    with pytest.raises(InputError, match="Guccione: C must be"):
        Guccione(C=-1.0).validate()
    with pytest.raises(InputError, match="Holzapfel-Ogden: bulk_modulus must be"):
        HolzapfelOgden(bulk_modulus=-3.0).validate()


def test_missing_frame_is_an_input_error():
    with pytest.raises(InputError, match="material frame"):
        Guccione().energy_of_F(jnp.eye(3))
    with pytest.raises(InputError, match="material frame"):
        HolzapfelOgden().energy_of_F(jnp.eye(3), jnp.eye(3)[:1])  # fibre only, no sheet


def test_config_builds_the_laws():
    assert (material_from_config({"law": "Guccione", "C": 10, "bf": 1, "bt": 1, "bfs": 1})
            == Guccione(C=10.0, bf=1.0, bt=1.0, bfs=1.0))
    assert material_from_config({"law": "guccione", "isochoric": True}) == Guccione(isochoric=True)
    ho = material_from_config({"law": "holzapfel-ogden", "as": 2.0, "bulk_modulus": 500})
    assert ho == HolzapfelOgden(as_=2.0, bulk_modulus=500.0)


def test_library_finite_difference_check_takes_a_frame():
    F, frame = sample_points(2)["fibre-tension"]
    err_P, err_A = finite_difference_check(MATERIALS["holzapfel-ogden"], F, frame=frame)
    assert err_P < 1e-7 and err_A < 1e-6, (err_P, err_A)


def test_the_c2_tension_switch_is_the_published_square_outside_its_width():
    """`tension_square(x, w)`: equal to ``max(x, 0)^2`` outside ``(0, w)``; its first and second derivatives
    continuous at 0 and w (one-sided jax derivatives a distance 1e-9 w apart differ by O(1e-9) of the scale
    ``w`` of the second derivative's jump it removes, 2); convex, increasing, and at most 0.0346 w^2 below
    the square (the maximum of ``s^2 - q(s)`` on [0, 1])."""
    w = 0.02
    x = np.array([-0.3, -1e-3, 0.0, w, 1.5 * w, 0.4])
    np.testing.assert_allclose(tension_square(x, w), np.maximum(x, 0.0) ** 2, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(tension_square(x, 0.0), np.maximum(x, 0.0) ** 2)
    d1 = jax.vmap(jax.grad(lambda y: tension_square(y, w)))
    d2 = jax.vmap(jax.grad(jax.grad(lambda y: tension_square(y, w))))
    for at in (0.0, w):
        side = jnp.array([at - 1e-9 * w, at + 1e-9 * w])
        assert abs(float(jnp.diff(d1(side))[0])) < 1e-8 * w and abs(float(jnp.diff(d2(side))[0])) < 1e-7
    inside = jnp.linspace(0.0, w, 2001)
    assert np.all(np.asarray(d1(inside)) >= 0) and np.all(np.asarray(d2(inside)) >= 0)
    gap = np.max(np.asarray(inside**2 - tension_square(inside, w)))
    assert 0.0345 * w**2 < gap < 0.0346 * w**2
    assert abs(float(jax.grad(jax.grad(lambda y: tension_square(y, 0.0)))(1e-9)) - 2.0) < 1e-12  # the jump w removes


@pytest.mark.parametrize("label", ["generic", "fibre-tension", "fibre-slack"])
def test_the_codes_sigmoid_switch_is_their_formula_and_tends_to_the_published_one(label):
    """``switch_steepness = k``: the fibre and sheet terms ``a_i/(2b_i) chi_k(I4_i) (exp(b_i (I4_i - 1)^2) - 1)``
    with ``chi_k = 1 / (1 + exp(-k (I4 - 1)))`` (the participating codes' form, k = 100); as k grows they tend to
    the published ``<I4 - 1>^2`` terms away from I4 = 1 (``chi_k`` within ``exp(-k |I4 - 1|)`` of the step)."""
    F, frame = sample_points(3)[label]
    C, J = F.T @ F, np.linalg.det(F)
    f, s = frame[0], frame[1]
    m = HolzapfelOgden(bulk_modulus=30.0, switch_steepness=100.0)
    chi = lambda x: 1.0 / (1.0 + np.exp(-100.0 * x))
    term = lambda a, b, x: a / (2 * b) * chi(x) * np.expm1(b * x**2)
    expected = (m.a / (2 * m.b) * np.expm1(m.b * (J ** (-2 / 3) * np.trace(C) - 3))
                + term(m.af, m.bf, f @ C @ f - 1) + term(m.as_, m.bs, s @ C @ s - 1)
                + m.afs / (2 * m.bfs) * np.expm1(m.bfs * (f @ C @ s) ** 2)
                + m.bulk_modulus / 4 * (J**2 - 1 - 2 * np.log(J)))
    assert W(m, F, frame) == pytest.approx(expected, rel=1e-13)
    steep, published = HolzapfelOgden(bulk_modulus=30.0, switch_steepness=1e5), HolzapfelOgden(bulk_modulus=30.0)
    assert W(steep, F, frame) == pytest.approx(W(published, F, frame), rel=1e-10)


def test_the_sigmoid_switch_resists_fibre_shortening_and_excludes_the_c2_one():
    """Near I4 = 1 the codes' switch bears half the fibre term in compression, where the published one bears
    none; with both switches given the law is refused in one line."""
    shortened = np.diag([0.99, 1.0, 1.0])
    published, sigmoid = HolzapfelOgden(bulk_modulus=30.0), HolzapfelOgden(bulk_modulus=30.0, switch_steepness=100.0)
    extra = W(sigmoid, shortened, np.eye(3)) - W(published, shortened, np.eye(3))
    x = 0.99**2 - 1
    assert extra == pytest.approx(sigmoid.af / (2 * sigmoid.bf) * np.expm1(sigmoid.bf * x**2) / (1 + np.exp(-100 * x)),
                                  rel=1e-10)
    with pytest.raises(InputError, match="switch_width or switch_steepness, not both"):
        material_from_config({"law": "holzapfel-ogden", "switch_width": 0.02, "switch_steepness": 100.0})

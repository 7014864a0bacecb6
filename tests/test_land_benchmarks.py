"""Land et al. (2015) problems 1 and 2 (hyperoc.cardiac.land): setups and a coarse beam solve.

- Beam setup: the published parameters, fibres along x, clamped face x = 0, and the pressure on the
  face z = 0 pushing up with resultant p |face| = 0.004 kPa x 10 mm^2 at rest.
- Ventricle setup: the endocardial pressure on the open cavity wall has, at rest, the resultant of
  the same pressure on the lid closing the cavity at the base, with the opposite sign: ``-p A_lid e_z``
  (the closed surface wall + lid has zero total area vector), A_lid = area of the polygon spanned by
  the rim of the endocardial surface (exact for the faceted surface).
- Coarse beam solve (n = 1, P2, bulk modulus 500 C): the tip must move up (the pressure acts on the
  bottom face), and by less than linear Timoshenko beam theory for the same small-strain moduli: the
  conforming displacement FE model is stiffer than the continuum, the follower pressure turns with the
  rotating bottom face, the arc-length-preserving bending shortens the vertical travel, and Guccione's
  exp(Q) stiffens with strain, all of which lower the deflection. Small-strain moduli of
  ``C/2 Q + K/2 (tr eps)^2`` (K the bulk modulus): along the fibres (uniaxial stress)
  ``E = C bf + K C bt / (C bt + 2 K)``, transverse shear ``G = C bfs / 2``; deflection ``q L^4 / (8 E I) + q L^2 /
  (2 k G A)`` with q = p b, I = b t^3 / 12, A = b t, k = 5/6.
"""

import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.cardiac.land import (
    BEAM,
    PUBLISHED,
    VENTRICLE,
    Formulation,
    LoadStepping,
    beam_deflection,
    beam_problem,
    node_position,
    ventricle_problem,
)
from hyperoc.errors import InputError

BULK_MODULUS = 1000.0  # kPa, = 500 C for the beam


def resultant(fol, n):
    return np.asarray(fol.facet_forces(jnp.zeros(n))).reshape(-1, 3).sum(axis=0)


def test_beam_setup_is_land_problem_1():
    model, fol = beam_problem(1, bulk_modulus=BULK_MODULUS)
    mat = model.material
    assert (mat.C, mat.bf, mat.bt, mat.bfs, mat.bulk_modulus) == (2.0, 8.0, 2.0, 4.0, BULK_MODULUS)
    fibres = np.unique(np.asarray(model.material_frames)[..., 0, :].reshape(-1, 3), axis=0)  # frame row 0 = f
    np.testing.assert_array_equal(fibres, [[1.0, 0.0, 0.0]])
    clamped = np.setdiff1d(np.arange(model.space.num_dofs), model.free) // 3
    assert np.all(model.space.nodes[clamped, 0] == 0.0)
    assert np.sum(model.space.nodes[:, 0] == 0.0) * 3 == clamped.size
    np.testing.assert_allclose(resultant(fol, model.n), [0.0, 0.0, BEAM["pressure"] * 10.0], atol=1e-15)
    np.testing.assert_array_equal(node_position(model, np.zeros(model.n), BEAM["point"]), BEAM["point"])
    with pytest.raises(InputError, match="not a node"):
        node_position(model, np.zeros(model.n), (10.0, 0.25, 1.0))


def test_ventricle_pressure_resultant_is_the_lid_force():
    model, fol = ventricle_problem(6.0, bulk_modulus=BULK_MODULUS, degree=1)
    mesh = model.mesh
    endo = mesh.boundary("endocardium")
    edges = np.sort(np.concatenate([endo[:, [i, j]] for i, j in ((0, 1), (1, 2), (0, 2))]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    rim = np.unique(uniq[counts == 1])  # vertices of the open rim of the cavity wall
    x = mesh.points[rim]
    assert np.allclose(x[:, 2], 5.0)
    x = x[np.argsort(np.arctan2(x[:, 1], x[:, 0]))]
    area = 0.5 * abs(np.sum(x[:, 0] * np.roll(x[:, 1], -1) - np.roll(x[:, 0], -1) * x[:, 1]))
    p = VENTRICLE["pressure"]
    np.testing.assert_allclose(resultant(fol, model.n), [0.0, 0.0, -p * area], rtol=1e-13, atol=1e-11 * p * area)
    assert 0.8 * np.pi * 49 * (1 - 25 / 289) < area < np.pi * 49 * (1 - 25 / 289)  # inscribed in the base ellipse


@pytest.mark.slow
def test_coarse_beam_deflects_up_by_less_than_linear_beam_theory():
    res = beam_deflection(1, Formulation(BULK_MODULUS), LoadStepping(steps=4))
    C, bf, bt, bfs, p = (BEAM[k] for k in ("C", "bf", "bt", "bfs", "pressure"))
    E = C * bf + BULK_MODULUS * C * bt / (C * bt + 2 * BULK_MODULUS)
    G = C * bfs / 2
    q, L, b, t = p * 1.0, 10.0, 1.0, 1.0
    linear = q * L**4 / (8 * E * b * t**3 / 12) + q * L**2 / (2 * 5 / 6 * G * b * t)
    rise = res.values["z_tip"] - BEAM["point"][2]
    print(f"\ncoarse tip rise {rise:.4f} mm, linear Timoshenko {linear:.4f} mm, Newton {res.newton_iterations}, "
          f"dofs {res.dofs}, max |J - 1| {res.max_volume_change:.2e}")
    assert 0.0 < rise < linear
    assert res.min_det_F > 0
    assert set(PUBLISHED[1]) == set(res.values)  # bench_land.py compares every reported value

"""The bulk term on each cell's mean J (`StateModel` ``volumetric="cell-mean"``): mixed u-p, P2-P0.

``Pi = int W_rest dx + sum_e |e| U(theta_e)``, ``theta_e = |e|^-1 int_e det F dx``: the mixed
formulation with a pressure constant per cell, condensed. What is checked:

- consistency: under a homogeneous deformation J is constant, so ``theta_e = J`` and the energy and
  force are those of the pointwise formulation, to round-off;
- no locking (Land et al. problem 1, the Guccione beam, on the coarsest mesh): for a formulation
  that is stable in the incompressible limit the discrete solution depends on the bulk modulus k only
  through the physical compressibility, ``z(k) = z(inf) + O(mu / k)`` with mu the law's small-strain
  moduli (Guccione: C bf, C bt, C bfs, at most 16 kPa here). Raising k from 1e3 to 1e5 kPa may
  then move the tip by at most ``max(mu) / 1e3`` relative. The pointwise formulation locks: its
  beam stiffens with k far beyond that bound;
- Land problem 2 (the ventricle inflated to 10 kPa, coarsest mesh): with Guccione on the full strain
  a cell folds inside while keeping its mean J (det F -> 0 at about 0.36 of the load);
  with Guccione on the isochoric strain (`Guccione(isochoric=True)`, the Simo-Taylor-Pister split)
  the rest energy grows without bound as a point is compressed to J -> 0 (unless it keeps its
  shape) and the full load is reached;
- exact gradients of the reduced functional through it (Taylor rate 2, `tests/test_gradients.py`);
- the tangent is the Hessian of this energy: `tests/test_tangent.py` (cell-mean cases).
"""

import jax.numpy as jnp
import numpy as np
import pytest

import hyperoc as ho
from hyperoc.cardiac.land import (
    BEAM,
    VENTRICLE,
    Formulation,
    LoadStepping,
    VentricleMesh,
    beam_deflection,
    ventricle_apex,
)
from hyperoc.errors import InputError, SolverError
from hyperoc.fem.mesh import box, rectangle

TOL = 1e-13  # rounding only: the same quadrature sums, taken per cell first


def _fixed_frame(dim):
    frame = np.eye(dim)
    return lambda x: np.broadcast_to(frame, x.shape[:-1] + frame.shape)


@pytest.mark.parametrize("mesh,material,degree", [
    pytest.param(rectangle(3), ho.NeoHookean(1.0, 40.0), 2, id="neo-Hookean-2d-P2", marks=pytest.mark.slow),
    pytest.param(box(2), ho.Guccione(), 1, id="Guccione-3d-P1", marks=pytest.mark.slow),
    pytest.param(box(1), ho.HolzapfelOgden(), 2, id="Holzapfel-Ogden-3d-P2", marks=pytest.mark.slow),
    pytest.param(box(1), ho.Guccione(isochoric=True), 2, id="Guccione-isochoric-3d-P2"),
])
def test_homogeneous_deformation_is_unchanged(mesh, material, degree):
    G = np.array([[0.08, 0.03, -0.02], [0.01, -0.05, 0.04], [0.02, 0.06, 0.03]])[: mesh.dim, : mesh.dim]
    energy, force = [], []
    for volumetric in ("pointwise", "cell-mean"):
        model = ho.StateModel(mesh, material, degree=degree, frames=_fixed_frame(mesh.dim), dirichlet=None,
                              volumetric=volumetric)
        u = jnp.asarray(model.interpolate(lambda x: x @ G.T))
        energy.append(float(model.strain_energy(u)))
        force.append(np.asarray(model.internal_force(u)))
        theta = np.asarray(model.cell_mean_J(u))
    assert abs(energy[1] - energy[0]) <= TOL * abs(energy[0])
    assert np.max(np.abs(force[1] - force[0])) <= TOL * np.max(np.abs(force[0]))
    assert np.allclose(theta, np.linalg.det(np.eye(mesh.dim) + G), rtol=TOL, atol=0)


def test_bad_choices_are_input_errors():
    with pytest.raises(InputError, match="volumetric must be one of"):
        ho.StateModel(box(1), ho.NeoHookean(), volumetric="mean")
    with pytest.raises(InputError, match="SaintVenantKirchhoff has none"):
        ho.StateModel(box(1), ho.SaintVenantKirchhoff(1.0, 1.0), volumetric="cell-mean")


@pytest.mark.slow
def test_cell_mean_beam_does_not_lock():
    moduli = BEAM["C"] * max(BEAM["bf"], BEAM["bt"], BEAM["bfs"])  # kPa, the largest small-strain modulus
    bound = moduli / 1e3
    change = {}
    for volumetric in ("pointwise", "cell-mean"):
        z = [beam_deflection(1, Formulation(k, volumetric=volumetric)).values["z_tip"] for k in (1e3, 1e5)]
        change[volumetric] = abs(z[1] - z[0]) / abs(z[0])
        print(f"\n{volumetric}: z_tip {z[0]:.5f} (bulk modulus 1e3), {z[1]:.5f} (1e5): relative change "
              f"{change[volumetric]:.2e}, bound {bound:.2e}")
    assert change["cell-mean"] <= bound
    assert change["pointwise"] > bound  # the locking the mixed form removes


@pytest.mark.slow
def test_cell_mean_ventricle_needs_the_isochoric_law():
    """Land problem 2, h = 6 mm (1602 dofs), bulk modulus 1000 kPa. Full strain: a cell folds and the solve
    stops before 0.4 of the load (20 increments, halved up to 8 times). Isochoric strain: 10 kPa is
    reached with det F > 0 at every quadrature point and the apex pushed down (z = -17 mm at rest)."""
    with pytest.raises(SolverError) as failure:
        ventricle_apex(VentricleMesh(6.0), Formulation(1000.0, volumetric="cell-mean"), LoadStepping(20, 8))
    print(f"\nfull strain, cell-mean: {failure.value}")
    assert failure.value.time < 0.4
    res = ventricle_apex(VentricleMesh(6.0), Formulation(1000.0, volumetric="cell-mean", isochoric=True),
                         LoadStepping(20, 40))
    print(f"\nisochoric, cell-mean: z_endo {res.values['z_endo']:.5f}, min det F {res.min_det_F:.3f}, "
          f"{res.newton_iterations.sum()} Newton iterations")
    assert res.min_det_F > 0
    assert res.values["z_endo"] < VENTRICLE["endo_apex"][2] - 5.0  # mm: the benchmark apex moves ~9 mm

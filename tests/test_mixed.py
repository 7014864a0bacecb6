"""Taylor-Hood P2-P1 (`hyperoc.mechanics.mixed.TaylorHoodModel`): ``L(u, p) = int W_rest + p (J - 1) - p^2/(2 k)``
with k the bulk modulus.

What is checked:

- the element tangent is the Hessian of the Lagrangian (plus ``b`` times the volume), to round-off;
- patch test: uniaxial tension of an incompressible neo-Hookean cube. The exact solution (an affine
  displacement, a constant pressure) lies in P2 x P1, so the discrete solution is exact up to
  Newton's stopping test, and its pressure is the analytical one;
- at ``k = inf`` the deformed volume equals the reference volume (the constraint tested with the
  P1 hats, which sum to 1);
- no locking on the Land beam: raising k from 1e3 to inf moves the tip by at most the bound of
  `tests/test_volumetric.py` (``max(mu) / 1e3`` relative);
- Land problem 2 at bulk modulus inf on the coarsest ventricle: Guccione on the full strain folds (det F -> 0
  before half the load, as with the cell-mean form); on the isochoric strain the full load is reached;
- bad arguments are `InputError`.
"""

import io
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hyperoc as ho
from hyperoc.cardiac import land
from hyperoc.cardiac.land import BEAM, PUBLISHED, VENTRICLE, beam_deflection, load_state, save_state, ventricle_apex
from hyperoc.dynamics.statics import StaticOptions, solve_static
from hyperoc.errors import InputError, SolverError
from hyperoc.fem.mesh import box, rectangle, refine
from hyperoc.io import write_npz
from hyperoc.mechanics.mixed import TaylorHoodModel
from hyperoc.solvers.linsolve import DenseSolver

ROUNDOFF = 1e-12  # relative: the same sums in another order


def _fixed_frame(dim):
    return lambda x: np.broadcast_to(np.eye(dim), x.shape[:-1] + (dim, dim))


@pytest.mark.parametrize("mesh,material,bulk", [
    pytest.param(rectangle(2), ho.NeoHookean(1.0, 40.0), None, id="neo-Hookean-2d", marks=pytest.mark.slow),
    pytest.param(box(1), ho.Guccione(isochoric=True), None, id="Guccione-isochoric-3d", marks=pytest.mark.slow),
    pytest.param(box(1), ho.Guccione(bulk_modulus=0.0), math.inf, id="Guccione-incompressible-3d",
                 marks=pytest.mark.slow),
])
def test_tangent_is_the_hessian_of_the_lagrangian(mesh, material, bulk):
    model = TaylorHoodModel(mesh, material, bulk_modulus=bulk, frames=_fixed_frame(mesh.dim), dirichlet=None,
                            pin_rigid=False)
    rng = np.random.default_rng(1)
    x = jnp.asarray(model.unknowns(0.05 * rng.standard_normal(model.n_u), rng.standard_normal(model.n_p)))
    b = 0.3
    K = DenseSolver(model).assemble(model.tangent_blocks(x, 1.0, b))
    H = jax.hessian(lambda y: model.strain_energy(y) + b * model.volume(y))(x)
    assert float(jnp.max(jnp.abs(K - H))) <= ROUNDOFF * float(jnp.max(jnp.abs(H)))


def uniaxial_patch(mesh, mu: float, stretch: float) -> TaylorHoodModel:
    """The unit cube on three symmetry planes with the dead traction ``t e_x``, ``t = mu (l - l^-2)``,
    on x = 1 that stretches incompressible neo-Hookean to ``l`` (below)."""
    return TaylorHoodModel(mesh, ho.NeoHookean(mu, 0.0), bulk_modulus=math.inf, dirichlet=None,
                           dirichlet_components={"left": (0,), "bottom": (1,), "front": (2,)}, pin_rigid=False,
                           neumann="right", traction=(mu * (stretch - stretch**-2), 0.0, 0.0))


@pytest.mark.slow
def test_uniaxial_patch_test_is_exact():
    """Cube [0, 1]^3 on three symmetry planes (u_x = 0 at x = 0, u_y = 0 at y = 0, u_z = 0 at z = 0), dead
    traction t e_x on x = 1, incompressible neo-Hookean (``W_rest = mu/2 (I1 - 3) - mu ln J``). Exact:
    ``F = diag(l, l^-1/2, l^-1/2)`` with ``t = mu (l - l^-2)`` and ``p = mu (1 - 1/l)`` (from
    ``P = mu (F - F^-T) + p cof F``, lateral faces free)."""
    mu, stretch = 1.5, 1.2
    model = uniaxial_patch(box(2), mu, stretch)
    sol = solve_static(model, load=model.traction_load, constraint="none", options=StaticOptions(steps=4))
    F = np.asarray(model.deformation_gradient(jnp.asarray(sol.u)))
    exact = np.diag([stretch, stretch**-0.5, stretch**-0.5])
    # The error left is below Newton's last increment, <= rtol |x|_inf (Scheme: rtol = 1e-11, |x|_inf = 0.25
    # here); F's error is the gradient of a P2 field of that size on cells of size h = 1/2, at most
    # 2 degree / h = 8 times it (inverse inequality on the reference shape functions, up to its constant).
    tol = 10 * ho.Scheme().rtol
    assert np.max(np.abs(F - exact)) <= tol
    assert np.max(np.abs(model.pressure(sol.u) - mu * (1 - 1 / stretch))) <= tol * mu
    assert abs(sol.volume - 1.0) <= tol



@pytest.mark.slow
def test_newton_monitor_reports_the_pressure_field_apart():
    """The uniaxial patch above, monitored: every record has the pressure field's residual and
    increment besides the displacement's. The first iteration starts at the stress-free reference
    (u = 0, q = 0: J = 1, so the field's equations ``int (J - 1) psi`` vanish exactly) with the
    force residual ``|f / steps|_2`` of the dead traction; each load step ends converged."""
    steps = 2
    model = uniaxial_patch(box(1), mu=1.5, stretch=1.2)
    text = io.StringIO()
    log = ho.NewtonLog(text)
    sol = solve_static(model, load=model.traction_load, constraint="none",
                       options=StaticOptions(steps=steps, monitor=log))
    first = log.records[0]
    assert first.field_residual == 0.0 and first.field_increment > 0
    assert first.residual == pytest.approx(np.linalg.norm(model.traction_load[: model.n_u]) / steps, rel=1e-12)
    assert all(r.field_residual is not None and np.isfinite(r.field_increment) for r in log.records)
    assert [r.converged for r in log.records].count(True) == steps == len(sol.newton_iterations)
    assert all("|dq|" in line for line in text.getvalue().splitlines())

@pytest.mark.slow
def test_incompressible_beam_keeps_its_volume_and_does_not_lock():
    moduli = BEAM["C"] * max(BEAM["bf"], BEAM["bt"], BEAM["bfs"])  # kPa, the largest small-strain modulus
    res = {k: beam_deflection(1, land.Formulation(k, volumetric="taylor-hood")) for k in (1e3, math.inf)}
    z = {k: r.values["z_tip"] for k, r in res.items()}
    print(f"\nTaylor-Hood beam n = 1: z_tip {z[1e3]:.5f} (bulk modulus 1e3), {z[math.inf]:.5f} (inf)")
    assert abs(z[math.inf] - z[1e3]) <= moduli / 1e3 * abs(z[math.inf])
    # Newton's last increment is <= rtol |x| (1e-11) and the constraint residual after it is of its square:
    # what is left is the round-off of the quadrature sums.
    assert abs(res[math.inf].volume_change) <= ROUNDOFF
    assert abs(res[1e3].volume_change) > ROUNDOFF  # the compressible body does change its volume


#: the benchmark's incompressible law: Taylor-Hood, bulk modulus inf, Guccione on the isochoric strain
INCOMPRESSIBLE = land.Formulation(math.inf, volumetric="taylor-hood", isochoric=True)


@pytest.fixture(scope="module")
def incompressible_ventricle():
    """Land problem 2, h = 6 mm (1706 unknowns), bulk modulus inf, Guccione on the isochoric strain."""
    return ventricle_apex(land.VentricleMesh(6.0), INCOMPRESSIBLE, land.LoadStepping(steps=20))


@pytest.mark.slow
def test_incompressible_ventricle_needs_the_isochoric_law(incompressible_ventricle):
    """Land problem 2, h = 6 mm (1706 unknowns), bulk modulus inf: with Q on the full strain J folds to 0
    between the vertices although every hat-weighted mean of J - 1 vanishes; on the isochoric strain the
    10 kPa are reached with det F > 0 and the apex pushed down (z = -17 mm at rest; ~9 mm in the benchmark)."""
    with pytest.raises(SolverError) as failure:
        ventricle_apex(land.VentricleMesh(6.0), land.Formulation(math.inf, volumetric="taylor-hood"),
                       land.LoadStepping(20, 8))
    assert failure.value.time < 0.5
    res = incompressible_ventricle
    print(f"\nTaylor-Hood, isochoric, k = inf: z_endo {res.values['z_endo']:.5f}, min det F {res.min_det_F:.3f}")
    assert res.min_det_F > 0
    assert res.values["z_endo"] < VENTRICLE["endo_apex"][2] - 5.0
    assert set(PUBLISHED[2]) == set(res.values)  # bench_land.py compares every reported value


@pytest.mark.slow
def test_ventricle_restarted_from_its_own_solution_needs_no_load_stepping(incompressible_ventricle):
    """``coarse=`` wiring: a mesh is its own 0-fold refinement, so the prolongation of a solution to
    the same mesh is that solution (displacement and pressure), and Newton at the full load stops at
    once (one iteration: the step it computes is below the stopping test) with the same values (1e-9,
    `tests/test_static.py`); a coarse result on an unrelated mesh is an InputError."""
    res = incompressible_ventricle
    again = ventricle_apex(land.VentricleMesh(6.0), INCOMPRESSIBLE, land.LoadStepping(steps=20), coarse=res)
    assert again.params["start"] == "prolonged" and again.newton_iterations.tolist() == [1]
    for key, value in res.values.items():
        assert again.values[key] == pytest.approx(value, rel=1e-9)
    with pytest.raises(InputError):
        ventricle_apex(land.VentricleMesh(9.0), INCOMPRESSIBLE, coarse=res)


@pytest.mark.slow
def test_saved_state_reloads_with_the_same_mesh_and_solution(incompressible_ventricle, tmp_path):
    """`save_state` / `load_state`: the model rebuilt from the saved parameters is the same mesh (gmsh
    and refinement are deterministic: bitwise equal points), so the state prolongs as the original
    does; a missing file is an InputError."""
    res = incompressible_ventricle
    loaded = load_state(save_state(res, tmp_path / "level.npz"))
    assert np.array_equal(loaded.model.mesh.points, res.model.mesh.points)
    assert np.array_equal(loaded.u, res.u) and loaded.values == res.values and loaded.params == res.params
    assert np.array_equal(loaded.model.prolong(loaded.model, loaded.u), res.model.prolong(res.model, res.u))
    with pytest.raises(InputError, match="save_state"):
        load_state(tmp_path / "missing.npz")


def test_state_with_other_parameter_names_is_an_input_error(tmp_path):
    """A state whose parameters lack one that `ventricle_apex` takes (here ``bulk_modulus``, saved as
    ``kappa``) is refused with the names, before any model is built."""
    params = {"problem": 2, "mesh_size": 6.0, "kappa": 1000.0, "degree": 2, "curved": True, "base": "clamped",
              "refinements": 0, "volumetric": "pointwise", "isochoric": False}
    path = write_npz(tmp_path / "old.npz", u=np.zeros(3), values=np.array("{}"), params=np.array(json.dumps(params)))
    with pytest.raises(InputError, match="lacks the parameter.s. bulk_modulus"):
        load_state(path)


def test_bad_arguments_are_input_errors():
    with pytest.raises(InputError, match="bulk modulus must be > 0"):
        TaylorHoodModel(box(1), ho.Guccione(), bulk_modulus=-1.0)
    with pytest.raises(InputError, match="no separate bulk term"):
        TaylorHoodModel(box(1), ho.SaintVenantKirchhoff(1.0, 1.0))
    with pytest.raises(InputError, match="'degree' is fixed"):
        TaylorHoodModel(box(1), ho.Guccione(), degree=1)
    with pytest.raises(InputError, match="P2-P1"):
        beam_deflection(1, land.Formulation(1000.0, degree=1, volumetric="taylor-hood"))
    with pytest.raises(InputError, match="no mass on p"):
        TaylorHoodModel(box(1), ho.NeoHookean()).mass


def test_prolong_carries_displacement_and_pressure_to_the_refined_mesh():
    """P2 displacement and P1 pressure on straight cells are nested spaces: a quadratic displacement
    (zero on the clamped side x = 0, as reduced vectors are) and an affine pressure come back as
    their interpolants on the refined mesh, to round-off."""
    def model(mesh):
        return TaylorHoodModel(mesh, ho.NeoHookean(1.0, 2.0), bulk_modulus=math.inf)

    coarse, fine = model(rectangle(3)), model(refine(rectangle(3)))
    disp = lambda x: np.stack([x[:, 0] * x[:, 1], x[:, 0] ** 2 - 0.5 * x[:, 0] * x[:, 1]], axis=1)
    pressure = lambda x: 1.0 + 2.0 * x[:, 0] - 3.0 * x[:, 1]
    x = coarse.unknowns(coarse.interpolate(disp)[: coarse.n_u], pressure(coarse.mesh.points))
    out = fine.prolong(coarse, x)
    exact = fine.unknowns(fine.interpolate(disp)[: fine.n_u], pressure(fine.mesh.points))
    assert np.max(np.abs(out - exact)) <= ROUNDOFF * np.max(np.abs(exact))

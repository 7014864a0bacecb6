"""Quasi-static solver: trivial equilibria and independence of the load ramping.

Newton stops when ``|du|_inf <= 1e-11 |u|_inf``; convergence is quadratic, so the returned
equilibrium is within ~1e-11 |u| (times the condition of the problem, O(10) here) of the exact
discrete one. Two solves of the same problem by different load paths must therefore agree to 1e-9
relative; a path-dependent result (e.g. a ramp that forgets part of the load or of the volume
change) differs at O(1/steps).
"""

import contextlib
import gc
import io
import weakref

import jax.numpy as jnp
import numpy as np
import pytest

from hyperoc.dynamics.statics import StaticOptions, solve_static
from hyperoc.errors import InputError
from hyperoc.fem.mesh import rectangle, refine
from hyperoc.mechanics.controls import BodyForce, Region
from hyperoc.mechanics.materials import NeoHookean, Ogden, SaintVenantKirchhoff
from hyperoc.mechanics.model import StateModel
from hyperoc.solvers.linsolve import SparseSolver
from hyperoc.solvers.newton import NewtonLog


@pytest.mark.parametrize("mesh_fn,degree,material", [
    (lambda: rectangle(3), 1, SaintVenantKirchhoff(1.0, 1.0)),
    (lambda: rectangle(2), 2, NeoHookean(1.0, 2.0)),
])
def test_zero_load_gives_zero_displacement_and_pressure(mesh_fn, degree, material):
    model = StateModel(mesh_fn(), material, degree=degree)
    sol = solve_static(model)
    assert sol.u.shape == (model.n,)
    assert np.max(np.abs(sol.u)) <= 1e-14
    assert abs(sol.p) <= 1e-14
    assert sol.volume == pytest.approx(model.mesh.volume(), rel=1e-14)


def test_zero_load_ogden_pressure_balances_reference_stress():
    """The paper's Ogden form has Sigma(0) = 2 sum c_k g_k I at rest; the multiplier balances it:
    R(0) = 2 sum c_k g_k G0 and R(0) + p G0 = 0 give p = -2 sum c_k g_k, with u = 0."""
    og = Ogden(coefficients=(0.3, 0.2), exponents=(2.0, 3.5))
    model = StateModel(rectangle(4), og)
    sol = solve_static(model)
    expected = -2 * sum(c * g for c, g in zip(og.coefficients, og.exponents))
    assert np.max(np.abs(sol.u)) <= 1e-13
    assert sol.p == pytest.approx(expected, rel=1e-12)


@pytest.fixture(scope="module")
def loaded_problem():
    """2D SVK plate clamped on the left, traction on the right, body force on a sub-box, and a 3%
    volume increase; max |grad u| ~ 0.2 (nonlinear)."""
    model = StateModel(rectangle(6), SaintVenantKirchhoff(1.0, 1.0),
                       control=BodyForce(Region("box", lower=(0.5, 0.0), upper=(1.0, 0.5))))
    load = model.load_vector(traction=(0.15, -0.05), neumann="right")
    xi = np.tile([0.0, -0.3], model.control.size // 2)
    V = 1.03 * model.mesh.volume()
    return model, load, xi, V


def test_ramped_loading_reaches_the_same_equilibrium(loaded_problem):
    model, load, xi, V = loaded_problem
    steps = 4
    one = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(steps=1))
    ramp = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(steps=steps))
    assert len(one.newton_iterations) == 1 and len(ramp.newton_iterations) == steps
    grad = float(model.jitted["max_grad"](jnp.asarray(one.u)))
    print(f"\nmax|grad u| = {grad:.3f}, p = {one.p:.6g}, Newton its 1 step {one.newton_iterations}, "
          f"{steps} steps {ramp.newton_iterations}, |du| = {np.max(np.abs(ramp.u - one.u)):.2e}")
    assert 0.1 < grad < 0.5  # genuinely nonlinear
    assert one.volume == pytest.approx(V, rel=1e-12) and ramp.volume == pytest.approx(V, rel=1e-12)
    scale_u = np.max(np.abs(one.u))
    assert np.max(np.abs(ramp.u - one.u)) <= 1e-9 * scale_u
    assert abs(ramp.p - one.p) <= 1e-9 * max(abs(one.p), 1.0)  # p in units of the moduli (= 1)


def test_secant_predictor_reaches_the_same_equilibrium_in_fewer_newton_iterations(loaded_problem):
    """The secant start ``u_k + (u_k - u_{k-1}) ds_k / ds_{k-1}`` is O(ds^2) from the next
    equilibrium of a smooth load path, the previous equilibrium O(ds): the same end point, and from
    the second increment on Newton starts closer, so it needs no more iterations per increment."""
    model, load, xi, V = loaded_problem
    steps = 8
    previous = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(steps=steps))
    secant = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(steps=steps, predictor="secant"))
    print(f"\nNewton its per increment: previous {previous.newton_iterations}, secant {secant.newton_iterations}")
    assert np.max(np.abs(secant.u - previous.u)) <= 1e-9 * np.max(np.abs(previous.u))
    assert abs(secant.p - previous.p) <= 1e-9 * max(abs(previous.p), 1.0)
    assert secant.newton_iterations[0] == previous.newton_iterations[0]  # no history yet: the same start
    assert np.all(secant.newton_iterations[1:] <= previous.newton_iterations[1:])
    assert secant.newton_iterations.sum() < previous.newton_iterations.sum()


def test_unknown_predictor_is_an_input_error(loaded_problem):
    model, load, xi, V = loaded_problem
    with pytest.raises(InputError, match="predictor"):
        solve_static(model, load=load, options=StaticOptions(steps=2, predictor="quadratic"))


def test_warm_start_from_a_nearby_equilibrium_converges_at_full_load(loaded_problem):
    """``guess`` = the equilibrium at 0.9 of the loads (and of the volume change) is O(0.1) from the
    full-load one, nearer than the undeformed state: Newton at the full load from it reaches the
    same equilibrium (1e-9, module docstring) in fewer iterations than from zero, without stepping."""
    model, load, xi, V = loaded_problem
    V0 = model.mesh.volume()
    near = solve_static(model, load=0.9 * load, xi=0.9 * xi, volume=V0 + 0.9 * (V - V0))
    cold = solve_static(model, load=load, xi=xi, volume=V)
    warm = solve_static(model, load=load, xi=xi, volume=V, guess=near.u, options=StaticOptions(steps=4))
    print(f"\nNewton its: from zero {cold.newton_iterations}, from the 0.9-load equilibrium {warm.newton_iterations}")
    assert warm.from_guess and not cold.from_guess
    assert len(warm.newton_iterations) == 1 and warm.newton_iterations[0] < cold.newton_iterations[0]
    assert np.max(np.abs(warm.u - cold.u)) <= 1e-9 * np.max(np.abs(cold.u))
    assert abs(warm.p - cold.p) <= 1e-9 * max(abs(cold.p), 1.0)



def test_newton_from_a_guess_starts_from_the_least_squares_multiplier(loaded_problem):
    """A guess is a displacement; its multiplier is the one that best balances the forces there,
    ``p0 = -G.r / G.G`` with ``r = R(u) - f``, ``G = vol'(u)``, so Newton's first residual is the
    least-squares one ``|r + p0 G|_2`` (with p0 = 0 it would be ``|r|_2``)."""
    model, load, xi, V = loaded_problem
    V0 = model.mesh.volume()
    near = solve_static(model, load=0.9 * load, xi=0.9 * xi, volume=V0 + 0.9 * (V - V0))
    log = NewtonLog()
    solve_static(model, load=load, xi=xi, volume=V, guess=near.u, options=StaticOptions(monitor=log))
    u = jnp.asarray(near.u)
    r = np.asarray(model.internal_force(u) - load - model.jax_operators[2] @ jnp.asarray(xi))
    G = np.asarray(model.volume_gradient(u))
    fitted = r - (G @ r) / (G @ G) * G
    assert log.records[0].residual == pytest.approx(np.linalg.norm(fitted), rel=1e-12)
    assert np.linalg.norm(fitted) < np.linalg.norm(r)  # 0.0055 < 0.0149: the check above tells p0 from 0

def inverted_guess(model):
    """u = (-2 x, 0): F = diag(-1, 1), det F = -1 everywhere; Newton cannot start from it."""
    return model.interpolate(lambda x: np.stack([-2 * x[:, 0], 0 * x[:, 1]], axis=1))


def test_a_guess_newton_cannot_start_from_falls_back_to_load_stepping(loaded_problem):
    """An inverted guess (u = (-2 x, 0): F = diag(-1, 1), det F = -1 everywhere) fails; the load
    stepping then runs as without it and gives the same equilibrium. The failed attempt's Newton
    iterations are counted as rejected: with one linear solve per Newton iteration, the solver's
    calls are the accepted plus the rejected iterations."""
    model, load, xi, V = loaded_problem
    inverted = inverted_guess(model)
    plain = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(steps=2))
    lin = SparseSolver(model, "lu")
    with pytest.warns(RuntimeWarning, match="Newton from the guess failed"):
        fallback = solve_static(model, load=load, xi=xi, volume=V, guess=inverted,
                                options=StaticOptions(steps=2, solver=lin))
    assert not fallback.from_guess and len(fallback.newton_iterations) == 2
    assert plain.guess_failure is None and fallback.guess_failure.split(",")[0] in ("detF", "nonfinite", "newton")
    assert np.max(np.abs(fallback.u - plain.u)) <= 1e-9 * np.max(np.abs(plain.u))
    assert plain.rejected_iterations == 0 and fallback.rejected_iterations > 0
    assert lin.stats["calls"] == fallback.newton_iterations.sum() + fallback.rejected_iterations


def test_halved_load_increments_count_their_newton_iterations_as_rejected(loaded_problem):
    """12 times the loads in one increment, full Newton steps: the first attempt fails, the halved
    increments reach the same equilibrium as a 4-step ramp; every linear solve (one per Newton
    iteration) is an accepted or a rejected iteration."""
    model, load, xi, V = loaded_problem
    lin = SparseSolver(model, "lu")
    opts = dict(load=12 * load, xi=12 * xi, volume=V)
    cut = solve_static(model, **opts, options=StaticOptions(steps=1, cutbacks=8, line_search=False, solver=lin))
    ramp = solve_static(model, **opts, options=StaticOptions(steps=4, line_search=False))
    assert len(cut.newton_iterations) > 1 and cut.rejected_iterations > 0
    assert lin.stats["calls"] == cut.newton_iterations.sum() + cut.rejected_iterations
    assert np.max(np.abs(cut.u - ramp.u)) <= 1e-9 * np.max(np.abs(ramp.u))


def test_a_named_solver_is_made_once_per_model_and_an_instance_is_the_one_called(loaded_problem):
    """Solves naming the same solver reuse one instance (and so its compiled Newton solve); a solver
    instance passed in is the one the compiled solve calls (its stats count the solves)."""
    model, load, xi, V = loaded_problem
    solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(solver="lu"))
    named = model.__dict__["_static_solvers"]["lu"]
    calls = named.stats["calls"]
    again = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(solver="lu"))
    assert model.__dict__["_static_solvers"]["lu"] is named
    assert named.stats["calls"] == calls + again.newton_iterations.sum()
    mine = SparseSolver(model, "lu")
    own = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(solver=mine))
    assert mine.stats["calls"] == own.newton_iterations.sum()
    assert named.stats["calls"] == calls + again.newton_iterations.sum()


def test_release_kernels_frees_the_compiled_solves_and_a_new_solve_rebuilds_them(loaded_problem):
    """`StateModel.release_kernels` drops the cached Newton solves (and with them their linear solver
    and its factorization: nothing else refers to them); solving again recompiles the same program,
    so the equilibrium is the same to round-off."""
    model, load, xi, V = loaded_problem
    before = solve_static(model, load=load, xi=xi, volume=V)
    compiled = [weakref.ref(fn) for fn, _ in model.__dict__["_static_solves"].values()]
    model.release_kernels()
    gc.collect()
    assert compiled and all(ref() is None for ref in compiled)
    after = solve_static(model, load=load, xi=xi, volume=V)
    assert np.max(np.abs(after.u - before.u)) <= 1e-12 * np.max(np.abs(before.u))


def test_guess_of_the_wrong_size_is_an_input_error(loaded_problem):
    model, load, xi, V = loaded_problem
    with pytest.raises(InputError, match="guess"):
        solve_static(model, load=load, guess=np.zeros(model.n + 1))


@pytest.mark.slow
def test_nested_iteration_from_the_prolonged_coarse_equilibrium():
    """Nested iteration on a smooth problem: the coarse equilibrium carried to the refined mesh
    (`StateModel.prolong`) is within the coarse discretization error of the fine one, so Newton at
    the full load converges from it in fewer iterations than from the undeformed state, to the
    same fine equilibrium (1e-9)."""
    def problem(mesh):
        model = StateModel(mesh, NeoHookean(1.0, 2.0), degree=2)
        return model, model.load_vector(traction=(0.2, -0.1), neumann="right")

    coarse, coarse_load = problem(rectangle(3))
    fine, load = problem(refine(rectangle(3)))
    V = 1.02 * fine.mesh.volume()
    coarse_sol = solve_static(coarse, load=coarse_load, volume=V)
    cold = solve_static(fine, load=load, volume=V)
    warm = solve_static(fine, load=load, volume=V, guess=fine.prolong(coarse, coarse_sol.u))
    print(f"\nNewton its on the fine mesh: from zero {cold.newton_iterations}, nested {warm.newton_iterations}")
    assert warm.from_guess and warm.newton_iterations[0] < cold.newton_iterations[0]
    assert np.max(np.abs(warm.u - cold.u)) <= 1e-9 * np.max(np.abs(cold.u))


def test_monitor_sees_every_newton_iteration_of_every_load_step(loaded_problem):
    """The monitor gets one record per Newton iteration, numbered within each load step, the last
    of each step converged. The first iteration starts at u = 0, p = 0, where R(0) = 0 (stress-free
    reference), so its residual is exactly ``|s f|_2`` (f = load + B xi) and its constraint residual
    ``s |V - V0|`` at the first load factor s = 1/steps. Monitoring changes nothing in the solve."""
    model, load, xi, V = loaded_problem
    steps, text = 3, io.StringIO()
    log = NewtonLog(text)
    plain = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(steps=steps))
    watched = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(steps=steps, monitor=log))
    print("\n" + text.getvalue())
    assert np.array_equal(watched.newton_iterations, plain.newton_iterations)
    assert np.max(np.abs(watched.u - plain.u)) <= 1e-14 * np.max(np.abs(plain.u))
    records = log.records
    assert len(records) == plain.newton_iterations.sum() == len(text.getvalue().splitlines())
    ends = np.cumsum(plain.newton_iterations)
    for k, (start, end) in enumerate(zip([0, *ends[:-1]], ends)):
        step = records[start:end]
        assert [r.iteration for r in step] == list(range(1, end - start + 1))
        assert all(r.load == pytest.approx((k + 1) / steps, rel=1e-15) for r in step)
        assert step[-1].converged and not any(r.converged for r in step[:-1])
    f = np.asarray(load) + np.asarray(model.jax_operators[2] @ jnp.asarray(xi))
    assert records[0].residual == pytest.approx(np.linalg.norm(f) / steps, rel=1e-12)
    assert records[0].constraint == pytest.approx((V - model.mesh.volume()) / steps, rel=1e-12)
    assert all(r.step == 1.0 for r in records)  # this smooth problem needs no backtracking
    assert all(r.field_residual is None and r.field_increment is None for r in records)  # no pressure field
    assert text.getvalue().splitlines()[-1].split("(")[0].rstrip().endswith("converged")


def test_monitor_counts_the_iterations_of_rejected_attempts(loaded_problem):
    """An inverted guess (as above) fails and load stepping follows; the monitor sees the failed
    iterations too: records = accepted + rejected iterations."""
    model, load, xi, V = loaded_problem
    inverted = inverted_guess(model)
    log = NewtonLog()
    with pytest.warns(RuntimeWarning, match="Newton from the guess failed"):
        sol = solve_static(model, load=load, xi=xi, volume=V, guess=inverted,
                           options=StaticOptions(steps=2, monitor=log))
    assert not sol.from_guess and sol.rejected_iterations > 0
    assert len(log.records) == sol.newton_iterations.sum() + sol.rejected_iterations



def test_a_solve_keeps_no_reference_to_its_monitor(loaded_problem):
    """The compiled solve is cached on the model; the monitor is not (after a converged solve and
    after a failing one), so a `NewtonLog` and all it holds are freed with the caller's reference."""
    model, load, xi, V = loaded_problem
    for guess, expect_warning in ((None, None), (inverted_guess(model), RuntimeWarning)):
        log = NewtonLog()
        ref = weakref.ref(log)
        with pytest.warns(expect_warning) if expect_warning else contextlib.nullcontext():
            solve_static(model, load=load, xi=xi, volume=V, guess=guess, options=StaticOptions(steps=2, monitor=log))
        del log
        gc.collect()
        assert ref() is None

class _FailsOnce(SparseSolver):
    """LU that raises on its first solve, as PARDISO or SuperLU does on a bad K."""

    def host_solve(self, *args):
        if self.stats["calls"] == 0:
            self.stats["calls"] += 1
            raise np.linalg.LinAlgError("injected failure")
        return super().host_solve(*args)


def test_a_failed_linear_solve_is_reported_not_converged(loaded_problem):
    """A linear solve that fails returns NaN; Newton from the guess stops at once (no backtracking on
    NaN), the monitor shows a NaN increment, not converged, and the solution says why the guess
    failed before load stepping took over."""
    model, load, xi, V = loaded_problem
    log = NewtonLog()
    plain = solve_static(model, load=load, xi=xi, volume=V, options=StaticOptions(steps=2))
    with pytest.warns(RuntimeWarning, match="linear solve failed: injected failure"):
        sol = solve_static(model, load=load, xi=xi, volume=V, guess=plain.u,
                           options=StaticOptions(steps=2, solver=_FailsOnce(model, "lu"), monitor=log))
    first = log.records[0]
    assert np.isnan(first.increment) and not first.converged and first.step == 1.0
    assert not sol.from_guess and sol.rejected_iterations == 1
    assert sol.guess_failure == "newton, Newton iteration 1: linear solve failed: injected failure"
    assert np.max(np.abs(sol.u - plain.u)) <= 1e-9 * np.max(np.abs(plain.u))

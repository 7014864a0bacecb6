"""Chord Newton on the sparse path (`hyperoc.solvers.newton.newton` with ``chord=True``): the same
time-stepping solution as full Newton to the stopping test's tolerance, a refresh when the kept
Jacobian no longer contracts, and its options checked."""

import numpy as np
import pytest

import hyperoc as ho
from hyperoc.errors import InputError
from hyperoc.fem.geometry import annulus
from hyperoc.solvers.linsolve import DenseSolver, SparseSolver
from hyperoc.solvers.newton import CHORD_MARGIN, CHORD_RATE

STEPS = 20


@pytest.fixture(scope="module")
def model():
    mesh = annulus(0.5, 1.0, structured=True, n_radial=3, n_theta=16)
    control = ho.BodyForce(ho.Region("sector", r_range=(0.5, 0.7), theta_range=(-np.pi, np.pi)))
    return ho.StateModel(mesh, ho.SaintVenantKirchhoff(0.05, 0.05), damping=2e-3, control=control)


def push(model, grid):
    """A body force on the inner ring, ramped smoothly from rest (a large motion over the steps)."""
    return 0.2 * np.sin(np.pi * grid.t / 2)[:, None] ** 2 * np.ones((1, model.control.size))


def solve(model, newton, solver=None, dt=0.05):
    grid = ho.uniform_grid(T=STEPS * dt, dt=dt)
    st = ho.TimeStepper(model, ho.Scheme(newton=newton), solver or SparseSolver(model, "lu"))
    return st, st.run(grid, push(model, grid), diagnose=False)


@pytest.fixture(scope="module")
def full(model):
    return solve(model, "full")[1]


@pytest.fixture(scope="module")
def chord(model):
    return solve(model, "auto")


def test_chord_newton_is_the_default_on_host_solvers_and_full_newton_on_traced_ones(model, chord):
    st, _ = chord
    assert st.chord
    assert not ho.TimeStepper(model, ho.Scheme(), "dense").chord
    assert not ho.TimeStepper(model, ho.Scheme(), SparseSolver(model, "minres")).chord


def test_chord_solution_matches_full_newton_within_the_stopping_tolerance(full, chord):
    """Each step stops with at most ``CHORD_MARGIN rtol |u|`` left (the rate bound of the stopping
    test); the energy-stable scheme carries a step's error on without growth, so after N steps the
    two solutions differ by at most ``N CHORD_MARGIN rtol max|u|``. The pressure, a reaction that
    amplifies what is left of u, agrees to the relative 1e-9 the docs promise for chord Newton."""
    _, sol = chord
    rtol = ho.Scheme().rtol
    scale = np.max(np.abs(full.y0))
    assert np.max(np.abs(sol.y0 - full.y0)) <= STEPS * CHORD_MARGIN * rtol * scale
    assert np.max(np.abs(sol.pressure - full.pressure)) <= 1e-9 * np.max(np.abs(full.pressure))
    assert sol.volume_drift() <= 1e-12


def test_chord_newton_factors_far_less_often_than_full_newton(full, chord):
    st, sol = chord
    assert st.solver.stats["factorizations"] <= STEPS // 4
    assert st.solver.stats["kept_solves"] >= np.sum(sol.newton_iterations) - st.solver.stats["factorizations"]
    assert st.solver.stats["failed"] == 0  # the first iteration's missing factorization is no failure


def test_a_kept_jacobian_that_does_not_contract_is_refreshed(model, full, chord):
    """A factorization kept from steps 100 times longer (a mass term 100 times smaller) contracts by
    about 1 - 1/100 on the short steps, which would take thousands of iterations: the rate is known
    after two kept solves, so the first step takes at most two iterations more than from a fresh
    factorization, whose one refresh then serves every step as it does from a fresh start; the
    solution is the same."""
    solver = SparseSolver(model, "lu")
    rest = ho.uniform_grid(T=5.0, dt=5.0)
    ho.TimeStepper(model, ho.Scheme(), solver).run(rest, 0 * push(model, rest), diagnose=False)  # keeps K(dt = 5)
    solver.reset_stats()
    st, sol = solve(model, "auto", solver=solver)
    fresh_stepper, fresh = chord
    assert sol.newton_iterations[0] <= fresh.newton_iterations[0] + 2
    assert solver.stats["factorizations"] == fresh_stepper.solver.stats["factorizations"]
    assert np.max(np.abs(sol.y0 - full.y0)) <= STEPS * ho.Scheme().rtol * np.max(np.abs(full.y0))


def _linear_chord(rate, rtol, u_error=1.0, p_error=0.0, iterations=60):
    """A chord iteration converging linearly with ``rate`` to u* = 1, p* = 1 (errors ``u_error rate^k`` of
    u and ``p_error rate^k`` of p): per iteration ``(u, du, p, dp, u_left, p_left)``, the increments
    ``d_k = e_{k+1} - e_k`` and the errors left after the update, relative to the tolerances ``rtol |u + du|``
    and ``rtol |p + dp|``."""
    rows = []
    for k in range(iterations):
        e, e_next, ep, ep_next = (x * rate**j for x in (u_error, p_error) for j in (k, k + 1))
        rows.append((np.full(3, 1.0 + e), np.full(3, e_next - e), 1.0 + ep, ep_next - ep,
                     e_next / (rtol * (1.0 + e_next)), ep_next / (rtol * (1.0 + ep_next))))
    return rows


def _chord_decisions(rows, rtol):
    """``(settled, rate)`` of `chord_stopping_test` (NumPy) at every iteration of ``rows``."""
    from hyperoc.solvers.newton import chord_stopping_test, small_increment

    small = lambda a, b, rt, at: small_increment(a, b, None, rt, at, inf_norm=lambda v: np.max(np.abs(v)))
    previous, out = np.inf, []
    for u, du, p, dp, *_ in rows:
        increment = np.max(np.abs(du))
        settled, rate = chord_stopping_test(u, du, np.float64(p), np.float64(dp), increment, previous, small,
                                            tol=(rtol, 0.0), xp=np)
        out.append((bool(settled), float(rate)))
        previous = increment
    return out


@pytest.mark.parametrize("rate", [0.02, 0.05, 0.09])
@pytest.mark.parametrize("block", ["u", "p"])
@pytest.mark.parametrize("side", [0.95, 1.05])
def test_a_contracting_chord_iteration_stops_at_the_first_iterate_within_the_tolerance(rate, block, side):
    """On a geometric sequence the error left after an update is exactly ``rate / (1 - rate)`` times the
    increment, the policy's estimate: it stops at the first iterate whose u is within ``CHORD_MARGIN rtol
    |u|`` and whose p is within ``rtol |p|``, never before (the rate is unknown at the first). The sequence
    puts the error of ``block`` left after iteration K = 3 at ``side`` times its tolerance (the other block
    far within), so the stop is K or K + 1 by 5 %; the rate reported is the sequence's, below `CHORD_RATE`
    (no refresh)."""
    rtol, K = 1e-8, 3
    tolerance = {"u": CHORD_MARGIN * rtol, "p": rtol}[block]
    first = side * tolerance / rate ** (K + 1)
    rows = _linear_chord(rate, rtol, *((first, 1e-3 * first) if block == "u" else (1e-3 * first, first)))
    decisions = _chord_decisions(rows, rtol)
    stop = [settled for settled, _ in decisions].index(True)
    within = [k >= 1 and u_left <= CHORD_MARGIN and p_left <= 1.0 for k, (*_, u_left, p_left) in enumerate(rows)]
    assert stop == within.index(True) == K + (side > 1)
    assert all(r == pytest.approx(rate, rel=1e-6) and r < CHORD_RATE for _, r in decisions[1:stop + 1])


def test_a_stalled_chord_iteration_asks_for_a_refresh_and_stops_only_at_the_round_off_floor():
    """Rate 0.5 > `CHORD_RATE`: every rate reported asks the loop for a refresh, and the test, which
    cannot trust the rate, stops only when the increment itself meets the unscaled tolerance."""
    rtol = 1e-8
    rows = _linear_chord(0.5, rtol)
    decisions = _chord_decisions(rows, rtol)
    stop = [settled for settled, _ in decisions].index(True)
    assert all(rate > CHORD_RATE for _, rate in decisions[1:stop + 1])
    floor = [np.max(np.abs(du)) <= rtol * np.max(np.abs(u + du)) for u, du, *_ in rows]
    assert stop == floor.index(True)


def test_chord_on_a_traced_solver_or_an_unknown_strategy_is_an_input_error(model):
    with pytest.raises(InputError, match="chord"):
        ho.TimeStepper(model, ho.Scheme(newton="chord"), "dense")
    with pytest.raises(InputError, match="newton"):
        ho.Scheme(newton="quasi")


def test_the_newton_strategy_is_a_dynamics_setting_of_the_config():
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "examples" / "annulus-2d.toml"
    assert ho.load_config(example).scheme().newton == "auto"
    assert ho.load_config(example, ["dynamics.newton=full"]).scheme().newton == "full"
    with pytest.raises(InputError, match="newton"):
        ho.load_config(example, ["dynamics.newton=quasi"])


def test_static_solves_take_chord_newton_only_on_request(model):
    """`Scheme.chord_with`: time stepping uses chord Newton for "auto" where the solver can, static
    solves only for "chord"; "chord" with a solver that keeps no factorization is refused."""
    from hyperoc.dynamics.statics import StaticOptions, solve_static

    lu, dense = SparseSolver(model, "lu"), DenseSolver(model)
    assert ho.Scheme().chord_with(lu, auto=True) and not ho.Scheme().chord_with(lu, auto=False)
    assert ho.Scheme(newton="chord").chord_with(lu, auto=False)
    assert not ho.Scheme(newton="full").chord_with(lu, auto=True)
    with pytest.raises(InputError, match="chord"):
        solve_static(model, options=StaticOptions(scheme=ho.Scheme(newton="chord"), solver="minres"))
    with pytest.raises(InputError, match="chord"):
        ho.Scheme(newton="chord").chord_with(dense, auto=True)


EXAMPLES = {
    # the shipped 2D example as it is (P2, active stress along fibres)
    "annulus-2d": [],
    # the shipped 3D example, coarse and short, with a prescribed contraction on its control region
    "ventricle-3d": ["mesh.h=5.0", "dynamics.T=6.0", "optimize.tau0=2.0", 'control.value="-3.0 * sin(pi * t / 6)**2"'],
}


@pytest.mark.parametrize("name", EXAMPLES)
def test_the_pressure_of_the_examples_is_full_newtons_to_1e_9(name):
    """The multiplier p is a reaction: stopping a chord iteration on u alone can leave it wrong in its
    eighth digit while u is right to the tolerance. With p's own stopping test, the default scheme
    (chord Newton) gives full Newton's p(t) to 1e-9 of max|p| on the shipped 2D and 3D examples."""
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "examples" / f"{name}.toml"
    cfg = ho.load_config(example, EXAMPLES[name])
    model, grid = cfg.model(), cfg.grid()
    xi = cfg.prescribed_control(model, grid.t)
    runs = {newton: ho.TimeStepper(model, ho.Scheme(newton=newton), "auto").run(grid, xi, diagnose=False)
            for newton in ("auto", "full")}
    assert ho.TimeStepper(model, ho.Scheme(), "auto").chord  # the default is chord Newton here
    full = runs["full"].pressure
    assert np.max(np.abs(full)) > 0
    assert np.max(np.abs(runs["auto"].pressure - full)) <= 1e-9 * np.max(np.abs(full))


def test_the_chord_stopping_test_takes_the_same_decisions_on_numpy_and_jax():
    """`chord_stopping_test` is the one policy of the serial (traced) and distributed (NumPy) loops:
    on the same values it takes the same decision; it waits for p while p is not settled, stops on u
    and p settled, and at the round-off floor when the contraction stalls."""
    import jax.numpy as jnp

    from hyperoc.solvers.newton import chord_stopping_test, small_increment

    rtol, atol = 1e-11, 1e-15
    u = np.ones(4)
    cases = [
        # (du, p, dp, increment, previous, expected)
        (1e-16 * u, 1.0, 1e-8, 1e-16, 1e-14, False),    # u settled, p not (rate 0.01: left |dp| 1e-10 > 1e-11 |p|)
        (1e-16 * u, 1.0, 1e-14, 1e-16, 1e-14, True),    # both settled
        (1e-10 * u, 1.0, 0.0, 1e-10, np.inf, False),    # rate unknown: |du| itself must meet the scaled test
        (1e-14 * u, 1.0, 1e-6, 1e-14, 2e-14, True),     # contraction stalled at round-off: stop
        (1e-10 * u, 1.0, 0.0, 1e-10, 2e-10, False),     # stalled but not at round-off: go on (refresh)
        (1e-16 * u, 0.0, 0.0, 1e-16, 1e-14, True),      # unconstrained: p = dp = 0
    ]
    for du, p, dp, inc, prev, expected in cases:
        decisions = []
        for xp in (np, jnp):
            small = lambda a, b, rt, at, xp=xp: small_increment(xp.asarray(a), xp.asarray(b), None, rt, at)
            settled, _ = chord_stopping_test(xp.asarray(u), xp.asarray(du), xp.asarray(p), xp.asarray(dp),
                                             xp.asarray(inc), xp.asarray(prev), small, tol=(rtol, atol), xp=xp)
            decisions.append(bool(settled))
        assert decisions == [expected, expected], (du[0], p, dp, inc, prev)


def test_the_chord_decisions_are_the_same_on_numpy_and_traced_jax():
    """`chord_counts`, `chord_accepts` and `chord_next` are the serial (traced) and distributed (NumPy) loops'
    decisions after the stopping test: on one sequence of iterations both array libraries take the same
    ones, and they are the policy's: a failed kept solve is no iteration and asks for a refresh; a fresh
    step is taken even without decrease; a chord step is taken if it decreases ``|r|^2``, else rejected
    and refreshed; a rate above `CHORD_RATE` refreshes; after a rejection the rate is unknown."""
    import jax
    import jax.numpy as jnp

    from hyperoc.solvers.newton import chord_accepts, chord_counts, chord_next

    sequence = [
        # (refresh, solved, converged, decreased, increment, previous)
        #     -> (counted, accepted, refresh next, previous next)
        ((False, False, False, False, np.inf, np.inf), (False, False, True, np.inf)),  # no factorization yet
        ((True, True, False, False, 1e-2, np.inf), (True, True, False, 1e-2)),  # fresh: taken, rate unknown
        ((False, True, False, True, 5e-4, 1e-2), (True, True, False, 5e-4)),  # rate 0.05: keep
        ((False, True, False, True, 2.5e-4, 5e-4), (True, True, True, 2.5e-4)),  # rate 0.5 > CHORD_RATE: refresh
        ((False, True, False, False, 1e-4, 2.5e-4), (True, False, True, np.inf)),  # no decrease: rejected
        ((False, True, True, False, 1e-12, 1e-10), (True, True, False, 1e-12)),  # converged: taken
    ]

    def decide(xp, refresh, solved, converged, decreased, increment, previous):
        rate = increment / previous
        accepted = chord_accepts(solved, converged, decreased, refresh, xp=xp)
        return (chord_counts(refresh, solved, xp=xp), accepted, *chord_next(accepted, rate, increment, xp=xp))

    traced = jax.jit(lambda *args: decide(jnp, *args))
    for inputs, expected in sequence:
        with np.errstate(divide="ignore", invalid="ignore"):
            numpy = decide(np, *inputs)
        jax_ = traced(*(jnp.asarray(v) for v in inputs))
        as_python = lambda d: (bool(d[0]), bool(d[1]), bool(d[2]), float(d[3]))
        assert as_python(numpy) == as_python(jax_) == expected, (inputs, numpy, jax_)


class _DenseLayout:
    """One rank's `hyperoc.distributed.layout.Layout` as the distributed Newton uses it, on dense NumPy arrays
    (the "element blocks" are the whole K)."""

    n_u = None

    def __init__(self, n):
        self.owned_size, self.factorizations, self._K = n, 0, None

    def local_of_owned(self, x):
        return x

    def dot(self, a, b):
        return float(a @ b)

    def inf_norm(self, v):
        return float(np.max(np.abs(v)))

    def all_finite(self, v):
        return bool(np.all(np.isfinite(v)))

    def factor(self, K):
        self._K, self.factorizations = np.array(K), self.factorizations + 1

    def solve(self, *columns):
        return np.linalg.solve(self._K, np.column_stack(columns))


class _DenseChordSolver:
    """`SparseSolver.refresh_solve` / `kept_solve` (traced, through host callbacks) on a dense K."""

    def __init__(self, n):
        self.n, self.kept, self.factorizations = n, None, 0

    def _refresh(self, K, col, row, r_u, r_c):
        K, col = np.asarray(K), np.asarray(col)
        self.kept, self.factorizations = (K, np.linalg.solve(K, col), np.asarray(row)), self.factorizations + 1
        return self._kept_solve(r_u, r_c)

    def _kept_solve(self, r_u, r_c):
        from hyperoc.solvers.linsolve import eliminate_border

        if self.kept is None:  # no factorization yet: NaN asks the loop for a refresh
            return np.full(self.n + 1, np.nan)
        K, b, row = self.kept
        du, dp = eliminate_border(np.column_stack([np.linalg.solve(K, np.asarray(r_u)), b]), row, float(r_c))
        return np.append(du, dp)

    def _callback(self, fn, *args):
        import jax
        import jax.numpy as jnp

        out = jax.pure_callback(fn, jax.ShapeDtypeStruct((self.n + 1,), jnp.float64), *args)
        return out[:-1], out[-1]

    def refresh_solve(self, K, col, row, r_u, r_c):
        return self._callback(self._refresh, K, col, row, r_u, r_c)

    def kept_solve(self, r_u, r_c):
        return self._callback(self._kept_solve, r_u, r_c)


@pytest.mark.parametrize("stiffening", [0.1, 2.0, 30.0])
def test_the_serial_and_distributed_chord_loops_take_the_same_decisions(stiffening):
    """The serial chord Newton (traced, `hyperoc.solvers.newton.newton` with ``chord=True``) and the distributed
    one (NumPy, `hyperoc.distributed.newton.newton` with a `KeptJacobian`, here on one rank's dense layout) on
    the same bordered problem ``A u + c u^3 - b + p g = 0``, ``g . u = 0.1`` from the same start: the same
    iterations and factorizations (the decisions: refresh, acceptance, stop) and the same solution to the
    tolerance. Stiffer cubic terms (c) contract more slowly, so the chord iteration refreshes and rejects."""
    import jax.numpy as jnp

    from hyperoc.distributed.newton import KeptJacobian
    from hyperoc.distributed.newton import newton as distributed_newton
    from hyperoc.solvers.newton import NewtonOptions, newton

    n, rng = 6, np.random.default_rng(0)
    A = 3 * np.eye(n) + 0.3 * rng.standard_normal((n, n))
    A, b, g = A + A.T, rng.standard_normal(n), np.ones(n) / n
    rows = lambda xp, u, p: xp.concatenate([A @ u + stiffening * u**3 - b + p * g, xp.atleast_1d(g @ u - 0.1)])
    tangent = lambda xp, u: (A + xp.diag(3 * stiffening * u**2), g, g)
    x0, rtol = np.append(2.0 * np.ones(n), 0.5), 1e-12

    solver = _DenseChordSolver(n)
    x_serial, it_serial, status_serial = newton(lambda x: rows(jnp, x[:-1], x[-1]), lambda x: tangent(jnp, x[:-1]),
                                                solver, jnp.asarray(x0),
                                                NewtonOptions(rtol, 0.0, 50, line_search=False), chord=True)
    layout = _DenseLayout(n)
    x_dist, it_dist, status_dist = distributed_newton(lambda u, p: rows(np, u, p), lambda u, p: tangent(np, u), layout,
                                                      x0, NewtonOptions(rtol, 0.0, 50), kept=KeptJacobian())
    assert int(status_serial) == int(status_dist) == 0
    assert (int(it_serial), solver.factorizations) == (it_dist, layout.factorizations)
    assert layout.factorizations > 1  # the sequence refreshes: a decision the two loops take alike
    np.testing.assert_allclose(np.asarray(x_serial), x_dist, rtol=0.0, atol=1e-10 * np.abs(x_dist).max())

"""Optimizers: ascent, rejected failing trials, exact resume, and the time-shift property."""

from functools import cache

import numpy as np
import pytest
import scipy.linalg

from helpers import bar
from hyperoc import (
    ControlPoint,
    NeoHookean,
    Objective,
    ReducedFunctional,
    Region,
    SaintVenantKirchhoff,
    SolverError,
    StateModel,
    TimeTransform,
    barzilai_borwein,
    lbfgsb,
)
from hyperoc.control.adjoint import Adjoint
from hyperoc.control.objectives import ControlCost, PressureAt
from hyperoc.control.optimize import (
    BBOptions,
    BBStepRule,
    BoxProblem,
    CurvaturePairs,
    NewtonCGOptions,
    newton_cg,
    tau_scaling,
)
from hyperoc.control.problems import vibrating_bar
from hyperoc.dynamics.stepper import TimeStepper
from hyperoc.errors import InputError


def _J(tau=1.0, T=3.0, dt=0.05, n=20, alpha=2e-2, omega=(0.75, 1.0), material=SaintVenantKirchhoff(0.05, 0.05)):
    adjoint = _adjoint(n, omega, material)
    return ReducedFunctional(adjoint.stepper.model, TimeTransform.for_step(T, dt, tau),
                             Objective(running=(ControlCost(alpha),), at_tau=PressureAt()), adjoint=adjoint)


@cache
def _adjoint(n, omega, material):
    """The state solver and adjoint of the bar, shared by the functionals of `_J` on it (each has its own
    counts and evaluations), so that its step compiles once per process rather than once per functional."""
    return Adjoint(TimeStepper(bar(n, omega=omega, material=material)))


@pytest.mark.slow
@pytest.mark.parametrize("method", ["bb", "bb-abbmin", "bb-blockwise", "bb-spg", "lbfgsb", "lbfgsb-tau-x10",
                                    "lbfgsb-tau-x0.1", "lbfgsb-inactive-bounds", "newton"])
def test_optimizers_converge_on_a_well_posed_case(method, bar_reference):
    """`vibrating_bar` has an interior, nondegenerate maximizer. Every method must reach
    ||G|| <= 1e-6 ||G0|| with J increasing at the first step, and all must agree on the maximizer.

    Near a nondegenerate maximizer |m - m*| <= ||G|| / lambda with lambda the curvature of -J; with
    ||G|| <= 1e-6 ||G0|| here and <= 1e-7 ||G0|| at the reference, the two points lie within
    1.1e-6 ||G0|| / lambda of each other, and their J within O(||G||^2 / lambda) (quadratic model)."""
    _converges_to_the_reference(method, *bar_reference)


@pytest.mark.parametrize("method", ["bb", "lbfgsb", "newton", "newton-curvature"])
def test_optimizers_converge_on_a_coarse_well_posed_case(method):
    """The test above, one method of each optimizer, on the coarse bar (h = 0.1, dt = 0.2): the same
    bounds, with that problem's reference maximizer and curvature."""
    _converges_to_the_reference(method, *_bar_reference(0.1, 0.2))


def test_newton_tau_curvature_is_the_second_derivative_in_tau():
    """``tau_scale = "curvature"``: the weight of tau in Newton-CG's metric is |d^2 J / d tau^2| at the start,
    a forward difference of the exact gradient (relative error ~sqrt(eps_mach)), against the centred second
    difference of J's values with h = 1e-3 (relative error ~h^2 / 12 times the ratio of the fourth to the
    second derivative): they agree to 1e-5, and the metric's gradient has its tau-part divided by that weight."""
    from hyperoc.control.optimize.box import BoxProblem
    from hyperoc.control.optimize.newton import _tau_curvature
    from hyperoc.control.optimize.run import Run

    J = vibrating_bar(0.1, 0.2)
    m0 = ControlPoint(0.01 * np.ones_like(J.zero(1.5).xi), 1.5)
    run = Run(BoxProblem.around(J, m0.tau))
    m, current, _ = run.start(m0)
    weight = _tau_curvature(run, m, current, {"hessian_products": 0})
    h = 1e-3
    values = [J(ControlPoint(m.xi, m.tau + k * h)) for k in (-1, 0, 1)]
    assert weight == pytest.approx(abs(values[0] - 2 * values[1] + values[2]) / h**2, rel=1e-5)
    G = BoxProblem(J, run.box.tau_range, tau_weight=weight).metric.gradient(current.g)
    assert G.tau == pytest.approx(current.g.tau / weight, rel=1e-14) and np.array_equal(G.xi, current.G.xi)


def _converges_to_the_reference(method, ref, lam, J):
    if method == "lbfgsb-inactive-bounds":  # the "range" scaling of tau applies (`tau_scaling`)
        bound = 10 * np.max(np.abs(ref.point.xi))
        res = lbfgsb(J, J.zero(2.0), max_iter=100, gtol=1e-6, xi_bounds=(-bound, bound))
        assert np.max(np.abs(res.point.xi)) < bound
    elif method.startswith("newton"):
        res = newton_cg(J, J.zero(2.0), max_iter=100, gtol=1e-6,
                        options=NewtonCGOptions(tau_scale="curvature" if method.endswith("curvature") else 1.0))
    elif method.startswith("lbfgsb"):
        res = lbfgsb(J, J.zero(2.0), max_iter=100, gtol=1e-6,
                     tau_scale=float(method.rpartition("x")[2]) if "tau" in method else "range")
    else:
        res = barzilai_borwein(J, J.zero(2.0), max_iter=300, gtol=1e-6,
                               options=BBOptions(steps="blockwise" if method == "bb-blockwise" else "joint",
                                                 bb_step="abbmin" if method == "bb-abbmin" else "bb1",
                                                 nonmonotone=10 if method == "bb-spg" else 0))
    hist = res.history
    assert hist["objective"][1] > hist["objective"][0]
    assert res.converged and hist["grad_norm"][-1] <= 1e-6 * hist["grad_norm"][0]
    G0 = hist["grad_norm"][0]
    assert J.norm(res.point - ref.point) <= 1.1e-6 * G0 / lam
    assert abs(res.objective - ref.objective) <= 4 * (1e-6 * G0) ** 2 / lam


@pytest.mark.slow
def test_bounded_optimizers_reach_the_same_kkt_point(bar_reference):
    """Bounds ``|xi| <= b`` at half the unconstrained maximizer's largest value, so that they are
    active: projected BB and L-BFGS-B must both reach a projected gradient ``||P(m + G) - m||`` <=
    1e-6 of its start, in the lumped metric where the nodal clip is the projection
    (`ControlSpace.metric(bounded=True)`; with the consistent-mass gradient, projected BB stopped at a point that is not
    a KKT point, and L-BFGS-B's KKT point did not pass the test), and they must agree.

    Why they agree to this tolerance: with the same active set (strict complementarity), the
    active values are both the bound and J restricted to the free coordinates F has a
    nondegenerate maximizer there, so as in the unconstrained test ``|m - m*| <= eps / lambda_F``
    for each (eps its final projected gradient, lambda_F the least curvature of -J on F in the
    lumped metric, from forward differences of the exact gradient), and J within ``eps^2 / lambda_F``
    of J* up to a factor 2 each.

    Projected Newton-CG reaches it too. The spectral projected gradient method (``nonmonotone = 10``)
    reaches the same point and, by its line search, never falls below the least J of its last 10
    iterates, which projected BB (the paper's Algorithm 1, unguarded) does here."""
    _, _, J = bar_reference
    ref = bar_reference[0]
    b = 0.5 * np.max(np.abs(ref.point.xi))
    runs = [lbfgsb(J, J.zero(2.0), max_iter=200, gtol=1e-6, xi_bounds=(-b, b)),
            barzilai_borwein(J, J.zero(2.0), max_iter=400, gtol=1e-6, xi_bounds=(-b, b)),
            barzilai_borwein(J, J.zero(2.0), max_iter=400, gtol=1e-6, xi_bounds=(-b, b),
                             options=BBOptions(nonmonotone=10)),
            newton_cg(J, J.zero(2.0), max_iter=100, gtol=1e-6, xi_bounds=(-b, b))]
    for res in runs:
        assert res.converged and res.history["grad_norm"][-1] <= 1e-6 * res.history["grad_norm"][0]
        assert np.max(np.abs(res.point.xi)) <= b
    # L-BFGS-B works on scaled values ``z = c xi``: a value on the bound comes back within an ulp or two
    active = [np.abs(res.point.xi) >= b * (1 - 4 * np.finfo(float).eps) for res in runs]
    assert active[0].any() and all(np.array_equal(active[0], a) for a in active[1:])
    metric = J.space.metric(bounded=True)
    lam = _least_curvature_on(J, metric, runs[0].point, free=~active[0])
    eps = [res.history["grad_norm"][-1] for res in runs]
    for other, e in zip(runs[1:], eps[1:]):
        assert metric.norm(runs[0].point - other.point) <= (eps[0] + e) / lam
        assert abs(runs[0].objective - other.objective) <= 4 * max(eps[0], e) ** 2 / lam
    falls = [_falls_below_window(res.history["objective"], 10) for res in runs[1:3]]
    assert falls[0] > 0 and falls[1] == 0


@pytest.mark.slow
@pytest.mark.parametrize("run", [barzilai_borwein, lbfgsb, newton_cg])
def test_callback_reports_the_stopping_measure(run, bar_reference):
    """The callback (the CLI's progress bar) gets the measure the stopping test reads: with active
    bounds the projected gradient norm, which differs from ``||G||`` (what the bar showed before)."""
    _, _, J = bar_reference
    b = 0.5 * np.max(np.abs(bar_reference[0].point.xi))
    seen = []
    res = run(J, J.zero(2.0), max_iter=8, xi_bounds=(-b, b),
              callback=lambda k, m, value, measure: seen.append((k, value, measure,
                                                                 J.norm(J.value_and_gradient(m)[1]))))
    assert [k for k, *_ in seen] == list(range(1, res.iterations + 1))
    assert tuple(v for _, v, _, _ in seen) == res.history["objective"][1:]
    assert tuple(e for _, _, e, _ in seen) == res.history["grad_norm"][1:]
    assert any(abs(e - full) > 0.1 * full for _, _, e, full in seen)


def _falls_below_window(values, M):
    """How many iterates have J below the least of the M before them."""
    return sum(values[k] < min(values[max(0, k - M):k]) for k in range(1, len(values)))


def _least_curvature_on(J, metric, m, free, h=1e-6):
    """Least eigenvalue of ``-H v = lambda W v`` on the free xi values and tau (H by forward
    differences of the exact derivative, W the metric's weights)."""
    cols = np.flatnonzero(np.append(free.ravel(), True))
    size = m.xi.size + 1

    def derivative(z):
        point = ControlPoint(z[:-1].reshape(m.xi.shape), float(z[-1]))
        return J.dual(J.value_and_gradient(point)[1]).flat()[cols]

    z0 = m.flat()
    d0 = derivative(z0)
    H = np.column_stack([(derivative(z0 + h * np.eye(size)[c]) - d0) / h for c in cols])
    W = np.append(metric.weights.ravel(), 1.0)[cols]
    lam = scipy.linalg.eigh(-(H + H.T) / 2, np.diag(W), eigvals_only=True)[0]
    assert lam > 0, "the bounded maximizer must be nondegenerate on its free coordinates"
    return lam


def test_curvature_pairs_are_an_spd_inverse_satisfying_the_newest_secant_equation():
    """The preconditioner of Newton-CG is the L-BFGS inverse from pairs (s, y = A s) of an SPD A:
    B y = s holds exactly for the newest pair (the BFGS update's secant equation), B is symmetric
    and positive definite in the metric, and it is the identity without pairs (round-off tolerances)."""
    rng = np.random.default_rng(0)
    weights = rng.uniform(0.5, 2.0, 7)  # a diagonal metric on (xi (3, 2), tau)

    class Metric:
        @staticmethod
        def inner(a, b):
            return float(np.sum(weights * a.flat() * b.flat()))

    point = lambda z: ControlPoint(z[:6].reshape(3, 2), float(z[6]))
    Q = rng.standard_normal((7, 7))
    A = Q @ Q.T + 0.1 * np.eye(7)  # y = W^-1 A s: the Riesz representative, so <s, y> = s^T A s > 0
    apply_A = lambda v: point(np.linalg.solve(np.diag(weights), A @ v.flat()))
    B = CurvaturePairs(Metric(), memory=4)
    r = point(rng.standard_normal(7))
    assert B(r).flat() == pytest.approx(r.flat(), abs=0)
    for _ in range(6):
        s = point(rng.standard_normal(7))
        y = apply_A(s)
        B.add([(s, y, Metric.inner(s, y))])
    assert len(B.pairs) == 4
    s, y, _ = B.pairs[-1]
    np.testing.assert_allclose(B(y).flat(), s.flat(), rtol=1e-10, atol=1e-12 * np.abs(s.flat()).max())
    columns = np.column_stack([B(point(e)).flat() for e in np.eye(7)])
    gram = np.diag(weights) @ columns  # <e_i, B e_j> in the metric
    np.testing.assert_allclose(gram, gram.T, rtol=1e-10, atol=1e-12 * np.abs(gram).max())
    assert np.linalg.eigvalsh((gram + gram.T) / 2)[0] > 0


@pytest.mark.slow
def test_newton_cg_converges_superlinearly(bar_reference):
    """Near the nondegenerate maximizer Newton-CG with the forcing term ``min(0.5, sqrt(||G|| / ||G0||))``
    converges q-superlinearly (order 1.5 in exact arithmetic; the forward-difference Hessian adds a
    linear term of relative size ~1e-8 cond, negligible here): once the full step is taken the
    contraction ``||G_{k+1}|| / ||G_k||`` must keep falling, and fall below 1e-3, where a first-order
    method contracts by a constant factor. Measured: 0.03, 1e-3, 7e-5."""
    _, _, J = bar_reference
    res = newton_cg(J, J.zero(2.0), max_iter=30, gtol=1e-11)
    g = np.array(res.history["grad_norm"])
    assert res.converged and res.iterations <= 15
    tail = g[1:][-3:] / g[:-1][-3:]
    assert np.all(np.diff(tail) < 0) and tail[-1] < 1e-3
    assert res.history["step"][-3:] == (1.0, 1.0, 1.0)


def test_newton_cg_falls_back_to_the_gradient(monkeypatch):
    """Where the search along the Newton direction finds no ascent, Newton-CG steps along G instead of
    stopping (it stopped on the paper's bounded variant after 10 iterations from a restart). Here the
    direction is made a descent direction (-G), so every iteration must take the gradient step and J
    must still rise at each."""
    import hyperoc.control.optimize.newton as newton

    runs, bounds = {}, (-0.01, 0.01)
    for nonconcave in (False, True):
        monkeypatch.setattr(newton, "_newton_direction", lambda box, m, G, *args: (G * -1.0, nonconcave))
        J = _J()
        runs[nonconcave] = res = newton_cg(J, J.zero(1.0), max_iter=3, options=NewtonCGOptions(max_backtracks=4),
                                           xi_bounds=bounds)
        assert res.iterations == 3 and res.evaluations["gradient_steps"] == 3
        assert np.all(np.diff(res.history["objective"]) > 0)
    # a direction of nonconcavity extends full steps along itself only, never the fallback's full step
    # along G (full in the box here): the same iterates, and no solve more
    assert runs[True].history["objective"] == runs[False].history["objective"]
    assert runs[True].evaluations["state_solves"] == runs[False].evaluations["state_solves"]
    assert runs[True].evaluations["nonconcave_iterations"] == 3


def test_bb_step_rules_on_a_quadratic():
    """For J = -1/2 m.A m (A SPD) the curvature along s is ``<s, -y> = s.A s``, so BB1 = ss / sAs and
    BB2 = sAs / sAAs, both in [1/lambda_max, 1/lambda_min], BB2 <= BB1 (Cauchy-Schwarz), equal
    when s is an eigenvector; ABBmin takes BB1 when BB2/BB1 >= 0.8, else the least recent BB2."""
    A = np.diag([1.0, 10.0])
    rules = {name: BBStepRule(name) for name in BBStepRule.RULES}
    steps = []
    for s in (np.array([1.0, 0.0]), np.array([1.0, 1.0]), np.array([0.0, 1.0])):
        y = -A @ s
        got = {name: rule(s @ s, s @ y, y @ y, 1.0) for name, rule in rules.items()}
        assert all(concave for _, concave in got.values())
        bb1, bb2 = got["bb1"][0], got["bb2"][0]
        assert 1 / 10 - 1e-15 <= bb2 <= bb1 <= 1 + 1e-15
        steps.append((bb1, bb2, got["abbmin"][0]))
    assert steps[0][0] == steps[0][1] == steps[0][2] == 1.0  # eigenvector: BB1 = BB2, ratio 1
    bb1, bb2, abb = steps[1]  # ratio 11**2 / (2 * 101) = 0.6 < 0.8: the least short step so far
    assert bb2 / bb1 < 0.8 and abb == min(steps[0][1], bb2)
    assert steps[2][2] == steps[2][0] == 0.1  # eigenvector again: the long step
    nonconcave = BBStepRule("abbmin")(2.0, 1.0, 8.0, 1.0)
    assert nonconcave == (0.5, False)  # |s| / |y|, flagged for a monotone search
    with pytest.raises(InputError):
        BBStepRule("bb3")
    for bad in (-1, 2.5, True):
        with pytest.raises(InputError, match="nonmonotone"):
            BBOptions(nonmonotone=bad)


@cache
def _bar_reference(h, dt):
    """Reference maximizer (Algorithm 1 to ||G|| <= 1e-7 ||G0||: L-BFGS-B's line search ends at ~3e-7,
    where J's changes reach round-off), lambda, the smallest eigenvalue of
    -Hessian(J) there in the inner product of the control space: ``-H v = lambda W v`` with H from
    forward differences of the exact gradient (one per coordinate) and W the Gram matrix of `inner`,
    and the reduced functional (compiled once per process)."""
    J = vibrating_bar(h, dt)
    ref = barzilai_borwein(J, J.zero(2.0), max_iter=300, gtol=1e-7)
    assert ref.history["grad_norm"][-1] <= 1e-7 * ref.history["grad_norm"][0]
    flat = ref.point.flat()

    def point(z):
        return ControlPoint(z[:-1].reshape(ref.point.xi.shape), float(z[-1]))

    def derivative(z):  # dJ/dm in coordinates (dual vector)
        return J.dual(J.value_and_gradient(point(z))[1]).flat()

    d0, h = derivative(flat), 1e-6
    H = np.column_stack([(derivative(flat + h * e) - d0) / h for e in np.eye(flat.size)])
    W = np.column_stack([J.dual(point(e)).flat() for e in np.eye(flat.size)])
    lam = scipy.linalg.eigh(-(H + H.T) / 2, W, eigvals_only=True)[0]
    assert lam > 0, "the reference point must be a nondegenerate maximizer"
    return ref, lam, J


@pytest.fixture(scope="module")
def bar_reference():
    """`_bar_reference` of the bar with h = 0.05, dt = 0.1."""
    return _bar_reference(0.05, 0.1)


@pytest.mark.slow
@pytest.mark.parametrize("run", [barzilai_borwein, newton_cg])
def test_resume_replays_to_the_same_result(tmp_path, run):
    full = run(_J(), _J().zero(1.0), max_iter=8, cache_dir=tmp_path / "full")
    J = _J()
    run(J, J.zero(1.0), max_iter=4, cache_dir=tmp_path / "cut")  # "interrupted" after 4
    J2 = _J()
    resumed = run(J2, J2.zero(1.0), max_iter=8, cache_dir=tmp_path / "cut")
    assert resumed.evaluations["cache_hits"] >= 5  # the first iterations came from the cache
    assert resumed.evaluations["state_solves"] < full.evaluations["state_solves"]
    np.testing.assert_array_equal(resumed.point.xi, full.point.xi)
    assert resumed.point.tau == full.point.tau
    assert resumed.history["objective"] == full.history["objective"]


class _FailsBeyond(ReducedFunctional):
    """The state 'solver' fails when the control exceeds a threshold (to test rejection)."""

    limit = 0.02

    def value_and_derivative(self, m):
        if np.max(np.abs(m.xi)) > self.limit:
            raise SolverError(3, 0.15, "detF", "test: control too large")
        return super().value_and_derivative(m)


@pytest.mark.parametrize("run", [barzilai_borwein, lbfgsb, newton_cg])
def test_failing_trial_points_are_rejected_not_fatal(run):
    base = _J()
    J = _FailsBeyond(base.model, base.transform, base.objective, adjoint=base.adjoint)
    res = run(J, J.zero(1.0), max_iter=6)
    assert res.failed_trials > 0
    assert np.max(np.abs(res.point.xi)) <= J.limit
    assert res.objective >= res.history["objective"][0]


def test_bounds_are_respected():
    J = _J()
    res = lbfgsb(J, J.zero(1.0), xi_bounds=(-0.01, 0.01), max_iter=5)
    assert np.max(np.abs(res.point.xi)) <= 0.01 + 1e-12
    for run in (barzilai_borwein, newton_cg):
        res = run(J, J.zero(1.0), xi_bounds=(-0.01, 0.01), max_iter=5)
        assert np.max(np.abs(res.point.xi)) <= 0.01 + 1e-12


def test_time_shift_of_a_control_keeps_J():
    """Zero initial state: delaying a control by k steps delays the response exactly, so any value
    reachable at tau is reachable at tau + k dt; hence the optimal value cannot decrease with tau.
    On uniform grids the discrete scheme is time invariant, so the identity holds to round-off."""
    dt, T = 0.05, 3.0
    J1, J2 = _J(tau=1.0, T=T, dt=dt), _J(tau=1.5, T=T, dt=dt)
    assert np.allclose(J1.transform.dt(1.0), dt) and np.allclose(J2.transform.dt(1.5), dt)
    rng = np.random.default_rng(0)
    xi1 = np.zeros((J1.N + 1, J1.model.control.size))
    n1 = J1.transform.tau_index
    xi1[: n1 + 1] = 0.02 * np.cumsum(rng.standard_normal((n1 + 1, xi1.shape[1])), axis=0) / np.sqrt(n1)
    xi1[0] = 0.0
    shift = J2.transform.tau_index - n1
    xi2 = np.zeros((J2.N + 1, xi1.shape[1]))
    xi2[shift: shift + n1 + 1] = xi1[: n1 + 1]
    assert J2(ControlPoint(xi2, 1.5)) == pytest.approx(J1(ControlPoint(xi1, 1.0)), rel=1e-9, abs=1e-15)


@pytest.mark.slow
def test_optimal_value_does_not_decrease_with_tau():
    """The property itself, on a small linear-ish case (alpha = 10 keeps the optimal control small;
    with smaller alpha the optimizer runs away to element collapse): maximize over xi at fixed tau (zero initial
    state) for tau = 0.8, 1.2, 1.6; each optimum is converged to ||G|| <= 1e-6 ||G0||; near a
    nondegenerate maximum the value error is quadratic in that (~1e-12 relative), so the optimal
    values must be non-decreasing up to 1e-8 relative."""
    values = []
    for tau in (0.8, 1.2, 1.6):
        J = _J(tau=tau, T=2.4, dt=0.05, alpha=10.0, omega=(0.25, 0.5), material=NeoHookean(0.05, 0.05))
        res = barzilai_borwein(BoxProblem.around(J, tau, fix_tau=True), J.zero(tau), gtol=1e-6, max_iter=200)
        assert res.converged and res.point.tau == tau
        values.append(res.objective)
    assert values[0] > 0
    assert all(b >= a * (1 - 1e-8) for a, b in zip(values, values[1:])), values


@pytest.mark.slow
def test_tau_scaling_normalizes_both_blocks_to_their_ranges(bar_reference):
    """``"range"``: c L_tau = (hi - lo) sqrt(|Q|), |Q| = 2 |omega| (omega = [0.25, 0.5], s in (0, 2));
    1 without two finite bounds or with tau fixed; a number passes through; anything else is an
    input error."""
    _, _, J = bar_reference
    c = tau_scaling(J, "range", (0.5, 3.0), (-0.2, 0.2))
    assert c == pytest.approx(0.4 * np.sqrt(2 * 0.25) / 2.5, rel=1e-12)
    assert tau_scaling(J, "range", (0.5, 3.0), (None, 0.2)) == 1.0
    assert tau_scaling(J, "range", (2.0, 2.0), (-0.2, 0.2)) == 1.0
    assert tau_scaling(J, 7, (0.5, 3.0), (-0.2, 0.2)) == 7.0
    for bad in (0.0, -1.0, float("nan"), "auto", True, "curvature"):
        with pytest.raises(InputError, match="tau_scale"):
            tau_scaling(J, bad, (0.5, 3.0), (-0.2, 0.2))


@pytest.mark.slow
def test_lbfgsb_with_a_p2_control_on_a_curved_annulus():
    """P2 control nodes (row-sum lumping of their mass is zero or negative at vertices): the scaled
    variables stay finite, J increases from the start and the bounds hold."""
    from hyperoc import ActiveStress, PressureRise, annulus

    mesh = annulus(0.5, 1.0, structured=True, n_radial=2, n_theta=12)
    model = StateModel(mesh, NeoHookean(1.0, 2.0), degree=2, damping=0.05,
                       control=ActiveStress(Region("sector", r_range=(0.5, 1.0), theta_range=(-1.0, 1.0))))
    J = ReducedFunctional(model, TimeTransform.for_step(1.0, 0.05, 0.5, 0.1),
                          Objective(running=(ControlCost(1e-2),), at_tau=PressureRise(0.1)))
    res = lbfgsb(J, J.zero(0.5), xi_bounds=(-0.05, 0.05), max_iter=3)
    assert np.all(np.isfinite(res.point.xi)) and np.isfinite(res.objective)
    assert res.objective > res.history["objective"][0]
    assert np.max(np.abs(res.point.xi)) <= 0.05 + 1e-12


@pytest.mark.slow
def test_bounded_newton_cg_preconditions_cg_by_the_h1_cost(monkeypatch):
    """With bounds on xi Newton-CG works in the lumped L2-in-time metric (its nodal clip is the projection), while
    an H^1-in-time cost (beta > 0) couples the levels: its CG starts from the inverse of the cost's Hessian
    (`BoxProblem.cost_inverse`), which resolves that coupling at once. Both runs reach the same KKT point; without
    the preconditioner CG pays for the coupling product by product (measured on this bar: 56 Hessian products
    against 610)."""
    from hyperoc.control.objectives import ControlRateCost
    from hyperoc.control.optimize.box import BoxProblem

    J = ReducedFunctional(bar(20), TimeTransform.for_step(3.0, 0.05, 1.0),
                          Objective(running=(ControlCost(2e-2), ControlRateCost(2e-2)), at_tau=PressureAt()))
    assert BoxProblem(J, (0.1, 2.9), (-10.0, 10.0)).cost_inverse is not None
    runs = {"preconditioned": newton_cg(J, J.zero(1.0), xi_bounds=(-10.0, 10.0), gtol=1e-6, max_iter=60)}
    monkeypatch.setattr(BoxProblem, "cost_inverse", property(lambda self: None))
    runs["plain"] = newton_cg(J, J.zero(1.0), xi_bounds=(-10.0, 10.0), gtol=1e-6, max_iter=60)
    a, b = runs["preconditioned"], runs["plain"]
    assert a.converged and b.converged
    assert a.point.tau == pytest.approx(b.point.tau, abs=1e-6) and a.objective == pytest.approx(b.objective, rel=1e-9)
    assert 4 * a.evaluations["hessian_products"] <= b.evaluations["hessian_products"]

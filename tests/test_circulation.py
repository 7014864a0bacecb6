"""The cavity closed by a lumped circulation (`hyperoc.dynamics.constraint.Circulation`) on the coarse benchmark
ventricle (`hyperoc/data/cardiac-benchmark.toml`, its prescribed pressure left out: the LV pressure is the
multiplier), a fast activation ramp from a low aortic pressure so that a few steps of 1 ms pass through filling,
isovolumic contraction and ejection.

- In every phase the step's row holds to Newton's tolerance (1e-10 relative): the volume of the previous level in
  an isovolumic step, the mitral inflow ``V' - V = dt (p_a - p') / R_m`` in filling, the trapezoidal Windkessel
  ``C (Pa' - Pa) / dt + (Pa + Pa') / (2 R) = Q``, ``p' = (Pa + Pa') / 2 + R_c Q`` in ejection (Pa' the carried one).
- The valves switch where their conditions say, one step after the condition (explicit switching), recomputed
  here from the carried states and the cavity volumes.
- The 0D balance over the run: ``C (Pa_N - Pa_0) + sum dt (Pa + Pa') / (2 R)`` equals the volume ejected (the
  volume lost over the ejection steps): the discrete Windkessel conserves what it receives.
- The exact gradient through an ejection (the adjoint of the carried aortic pressure): Taylor rates 2.00 +- 0.05
  in xi, tau and jointly (1.00 without the adjoint of the carried state), the same with binomial checkpointing.
- Bad input: a negative resistance or compliance, an atrial pressure that is not finite, a circulation table
  without the constraint: one line, exit 2, nothing written (the circulation on MPI ranks: tests/test_distributed.py).
- Resumable runs save and restore the carried state: a resumed run equals one that ran through, bitwise.
- Two beats of the benchmark ventricle (slow): the PV loop closes, the second beat repeats the first.
"""

import itertools
import json
import pathlib
import tomllib

import numpy as np
import pytest

import hyperoc
from hyperoc import ControlPoint, Objective, PressureAt, ReducedFunctional, TimeTransform, taylor_test
from hyperoc.app.cli import main
from hyperoc.app.config import parse_config, set_entries, time_law
from hyperoc.control.adjoint import Adjoint
from hyperoc.control.revolve import Binomial
from hyperoc.control.verification import random_directions
from hyperoc.dynamics.constraint import Circulation
from hyperoc.dynamics.laws import ExpressionLaw, Periodic, bestel_activation
from hyperoc.dynamics.resumable import Segments, run_resumable
from hyperoc.dynamics.stepper import TimeStepper
from hyperoc.dynamics.terms import PrescribedTension
from hyperoc.dynamics.timegrid import uniform_grid
from hyperoc.errors import InputError

BENCHMARK = pathlib.Path(hyperoc.__file__).parent / "data" / "cardiac-benchmark.toml"
#: SI: a peripheral resistance and compliance of a human systemic circulation (0.75 mmHg s/mL, 2 mL/mmHg), a
#: low aortic pressure so that the ramp opens the aortic valve within a few steps
WINDKESSEL = {"resistance": 1e8, "compliance": 1.5e-8, "characteristic_resistance": 5e6, "atrial_pressure": 1000.0,
              "mitral_resistance": 5e6, "aortic_pressure": 2000.0, "phase": "filling"}
FILLING, ISOVOLUMIC, EJECTION = 2.0, 0.0, 1.0


def benchmark_data():
    data = tomllib.loads(BENCHMARK.read_text())
    del data["dynamics"]["pressure"]
    return set_entries(data, {"mesh.variant": "coarse", "dynamics.solver": "lu"})


@pytest.fixture(scope="module")
def run():
    """12 steps of 1 ms under the activation 5e6 t Pa (50 kPa at 10 ms): the solution, the constraint, the cavity
    volumes at the levels (13,), the carried states before each step (12, 3), the first the initial one, and the
    stepper."""
    cfg = parse_config(benchmark_data())
    model = cfg.model()
    con = Circulation(model, **WINDKESSEL)
    terms = [PrescribedTension(model, ExpressionLaw("5e6*t")) if isinstance(t, PrescribedTension) else t
             for t in cfg.step_terms(model)]
    stepper = TimeStepper(model, cfg.scheme(), "lu", terms=terms, constraint=con)
    sol = stepper.run(uniform_grid(0.012, 0.001), diagnose=False)
    V = con.cavity.volumes(sol.y0)
    before = np.concatenate([np.asarray(con.carried(0.0))[None], sol.multiplier_states[:-1]])
    return sol, con, V, before, stepper


def test_every_phase_holds_its_row_and_the_run_passes_through_filling_contraction_and_ejection(run):
    sol, con, V, before, _ = run
    dt = np.diff(sol.t)
    phases = before[:, 2]
    print(f"\nphases {phases}, p {sol.p_steps}, Pa {sol.multiplier_states[:, 1]}, V {V}")
    assert {FILLING, ISOVOLUMIC, EJECTION} <= set(phases)
    p, Pa, Pa_new = sol.p_steps, before[:, 1], sol.multiplier_states[:, 1]
    Q = -np.diff(V) / dt
    for n, phase in enumerate(phases):
        if phase == ISOVOLUMIC:
            assert abs(V[n + 1] - V[n]) <= 1e-10 * V[n]
        elif phase == FILLING:
            inflow = dt[n] * (con.p_atrial - p[n]) / con.R_mitral
            assert abs(V[n + 1] - V[n] - inflow) <= 1e-10 * V[n]
        else:
            windkessel = con.C * (Pa_new[n] - Pa[n]) / dt[n] + (Pa[n] + Pa_new[n]) / (2 * con.R)
            assert abs(windkessel - Q[n]) <= 1e-10 * V[n] / dt[n]
            assert abs(p[n] - (Pa[n] + Pa_new[n]) / 2 - con.Rc * Q[n]) <= 1e-10 * abs(p[n])


def test_the_valves_switch_where_their_conditions_say(run):
    sol, con, V, before, _ = run
    Q = -np.diff(V) / np.diff(sol.t)
    p, Pa_new = sol.p_steps, sol.multiplier_states[:, 1]
    for n, phase in enumerate(before[:, 2]):
        if phase == EJECTION:
            expected = EJECTION if Q[n] > 0 else ISOVOLUMIC
        elif phase == FILLING:
            expected = FILLING if p[n] < con.p_atrial else ISOVOLUMIC
        else:
            expected = EJECTION if p[n] > Pa_new[n] else FILLING if p[n] < con.p_atrial else ISOVOLUMIC
        assert sol.multiplier_states[n, 2] == expected, (n, phase, p[n], Pa_new[n], Q[n])


def test_the_windkessel_stores_and_drains_what_the_ventricle_ejects(run):
    sol, con, V, before, _ = run
    dt = np.diff(sol.t)
    Pa, Pa_new = before[:, 1], sol.multiplier_states[:, 1]
    drained = np.sum(dt * (Pa + Pa_new) / (2 * con.R))
    ejected = -np.sum(np.diff(V)[before[:, 2] == EJECTION])
    assert ejected > 0
    stored = con.C * (Pa_new[-1] - Pa[0])
    assert abs(stored + drained - ejected) <= 1e-10 * V[0], (stored, drained, ejected)


def test_a_resumed_run_restores_the_carried_circulation_state(run, tmp_path):
    """`hyperoc.dynamics.resumable.run_resumable` in segments of 4 steps: its segments save the carried
    ``(p, Pa, phase)``; a run whose last segment is solved again from the saved ones ends bitwise equal to the
    run that solved them all, and to the plain run's phases."""
    sol, con, _, _, stepper = run
    grid = uniform_grid(0.012, 0.001)
    through = run_resumable(stepper, grid, segments=Segments(tmp_path / "segments", 4))
    assert through.multiplier_states.shape == (12, 3)
    (tmp_path / "segments" / "segment_00002.npz").unlink()
    resumed = run_resumable(stepper, grid, segments=Segments(tmp_path / "segments", 4))
    np.testing.assert_array_equal(resumed.y0, through.y0)
    np.testing.assert_array_equal(resumed.multiplier_states, through.multiplier_states)
    np.testing.assert_array_equal(through.multiplier_states[:, 2], sol.multiplier_states[:, 2])


def test_a_periodic_bestel_law_repeats_its_beat():
    """``{bestel = "activation", period = T}`` is the law of one beat integrated on [0, T], repeated: equal values
    a period apart (to round-off of t mod T), the beat itself the Bestel law of t_end = T; a period <= 0 is refused."""
    law = time_law({"bestel": "activation", "period": 0.8})
    t = np.linspace(0.0, 0.79, 80)
    np.testing.assert_allclose(law.values(t + 0.8), law.values(t), rtol=1e-9, atol=1e-9 * np.abs(law.values(t)).max())
    np.testing.assert_array_equal(law.values(t), bestel_activation(0.8).values(t))
    with pytest.raises(InputError, match="period"):
        Periodic(bestel_activation(0.8), -1.0)


@pytest.mark.parametrize("name, value, message", [
    ("resistance", -1e8, "resistance"), ("compliance", 0.0, "compliance"),
    ("atrial_pressure", float("nan"), "atrial_pressure"), ("mitral_resistance", -1.0, "mitral_resistance"),
    ("characteristic_resistance", -1.0, "characteristic_resistance"), ("phase", "systole", "phase"),
])
def test_bad_parameters_are_an_input_error_of_one_line(run, name, value, message):
    sol, con, *_ = run
    with pytest.raises(InputError, match=message) as err:
        Circulation(con.model, **{**WINDKESSEL, name: value})
    assert "\n" not in str(err.value)


def circulation_settings() -> list:
    """``--set`` entries of the coarse benchmark with the circulation of `WINDKESSEL`."""
    quoted = lambda v: f'"{v}"' if isinstance(v, str) else repr(v)
    return ['mesh.variant="coarse"', 'dynamics.constraint="circulation"',
            *(f"dynamics.circulation.{k}={quoted(v)}" for k, v in WINDKESSEL.items())]


@pytest.mark.parametrize("entries, message", [
    (["dynamics.circulation.resistance=-1e8"], "resistance"),
    (["dynamics.circulation.compliance=-1e-8"], "compliance"),
    (["dynamics.circulation.atrial_pressure=nan"], "atrial_pressure"),
    (['dynamics.activation.law={bestel="activation", period=-0.8}'], "period"),
    (['dynamics.constraint="cavity_volume"'], "circulation"),
])
def test_bad_circulation_input_is_one_line_exit_2(tmp_path, capsys, entries, message):
    out = tmp_path / "out"
    settings = [*circulation_settings(), "dynamics.T=0.002", *entries]
    code = main(["simulate", str(BENCHMARK), "--out", str(out), "--no-progress",
                 *(a for s in settings for a in ("--set", s))])
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and "\n" not in err, err
    assert not out.exists()


def test_exact_gradient_through_an_ejection():
    """An active-stress control on the whole wall, J = p(tau) - alpha/2 ||xi||^2, over 4 steps of 1 ms that all
    eject (the phase stays "ejection": the derivative of a run whose phase sequence the perturbations keep).
    The ejection row reads the carried aortic pressure Pa_n, which every earlier step moved: its adjoint
    (`hyperoc.control.adjoint.Adjoint.step`'s lambda_s) is needed for the rate 2. Smooth material (Guccione) as in
    `tests/test_cavity_constraint.py`, full Newton."""
    data = benchmark_data()
    data["material"] = {"law": "guccione", "C": 2000.0, "bf": 8.0, "bt": 2.0, "bfs": 4.0, "bulk_modulus": 1e6,
                        "viscosity": 100.0}
    cfg = parse_config(set_entries(data, {"control.kind": "active_stress", "dynamics.newton": "full"}))
    model = cfg.model()
    con = Circulation(model, **{**WINDKESSEL, "aortic_pressure": 500.0, "phase": "ejection"})
    terms = [PrescribedTension(model, ExpressionLaw("5e6*t")) if isinstance(t, PrescribedTension) else t
             for t in cfg.step_terms(model)]
    stepper = TimeStepper(model, cfg.scheme(), "lu", terms=terms, constraint=con)
    J = ReducedFunctional(model, TimeTransform.for_step(0.004, 0.001, 0.002), Objective(at_tau=PressureAt()),
                          adjoint=Adjoint(stepper))
    m = ControlPoint(2e4 * random_directions(J, J.zero(0.002), seed=3)["xi"].xi, 0.002)
    states = stepper.run(uniform_grid(0.004, 0.001), diagnose=False).multiplier_states
    assert np.all(states[:, 2] == EJECTION) and np.ptp(states[:, 1]) > 0.05 * states[0, 1], states
    for name, dm in random_directions(J, m, seed=5).items():
        r = taylor_test(J, m, dm)
        print(name, r.as_dict())
        assert r.remainder.size >= 3, (name, r.as_dict())
        assert abs(r.rate - 2.0) <= 0.05, (name, r.as_dict())
    # binomial checkpointing recomputes the steps from one kept state and its carried (p, Pa, phase): the same
    # states bit for bit, so the same derivative to round-off
    full = J.derivative(m)
    J.schedule = Binomial(1)
    kept = J.derivative(m)
    for a, b in ((full.xi, kept.xi), (full.tau, kept.tau)):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())


@pytest.mark.slow
def test_two_beats_of_the_benchmark_ventricle_close_their_pressure_volume_loop(tmp_path):
    """`examples/cardiac-circulation.toml` (coarse benchmark mesh, Bestel activation of period T = 0.8 s, 320 steps
    of 5 ms; about 3 min): ``simulate`` writes the PV loop, each beat passes through filling, isovolumic
    contraction, ejection and isovolumic relaxation, the pressures are physiological (end-diastolic 1-2 kPa, peak
    12-16 kPa), and the second beat repeats the first: ``|V(2T) - V(T)|`` is below a tenth of the first beat's
    ``|V(T) - V(0)|`` (the run starts unloaded; the aortic pressure starts near its end-of-beat value), measured
    3e-4 of the stroke volume. The summary's ejections are the loop's corners."""
    out = tmp_path / "out"
    assert main(["simulate", str(pathlib.Path(__file__).parents[1] / "examples" / "cardiac-circulation.toml"),
                 "--out", str(out), "--no-progress"]) == 0
    assert (out / "pv_loop.png").stat().st_size > 0
    with np.load(out / "results.npz") as r:
        t, V, p, phase = r["t"], r["constrained_cavity_volume"], r["p"], r["phase"]
    T, n = 0.8, len(t) // 2
    assert abs(t[n] - T) < 1e-12 and abs(t[-1] - 2 * T) < 1e-12
    second = slice(n, None)
    stroke = np.ptp(V[second])
    periodicity, first = abs(V[-1] - V[n]) / stroke, abs(V[n] - V[0]) / stroke
    print(f"\nstroke volume {stroke * 1e6:.2f} mL, periodicity |V(2T) - V(T)| / SV {periodicity:.2e} (first beat "
          f"{first:.2e}), EDP {p[n]:.0f} Pa, peak {p[second].max():.0f} Pa")
    assert periodicity < first / 10
    beat = json.loads((out / "summary.json").read_text())["beat"]
    # the summary's end-diastolic and end-systolic volumes of the second beat, at its aortic valve's opening and
    # closing, lie within one step's volume change of the beat's largest and smallest volumes: a valve switches
    # from the converged step, at most one step after its condition (a step of backflow as it closes)
    assert len(beat["ejections"]) == 2 and beat["isovolumic_volume_change"] <= 1e-10
    second_ejection, step = beat["ejections"][1], np.max(np.abs(np.diff(V[second])))
    assert abs(second_ejection["end_diastolic_volume"] - V[second].max()) <= step
    assert abs(second_ejection["end_systolic_volume"] - V[second].min()) <= step
    assert 1000 <= p[n] <= 2000 and 12e3 <= p[second].max() <= 16e3
    for beat in (phase[:n], phase[n:]):
        # one ejection, between an isovolumic contraction and an isovolumic relaxation, then filling (the valve
        # may flutter between filling and isovolumic at diastasis, where the inflow vanishes)
        groups = [int(k) for k, _ in itertools.groupby(beat)]
        assert groups.count(1) == 1, groups
        k = groups.index(1)
        assert 0 < k and groups[k - 1] == 0 and groups[k + 1:k + 3] == [0, 2], groups

"""The command line: outputs of simulate/check-gradient, and bad input -> one line, exit status 2."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from helpers import small_1d_toml
from hyperoc.app.cli import main
from hyperoc.io import read_npz

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

SMALL_1D = small_1d_toml()
#: SMALL_1D with a control that grows until an element inverts (a step fails a few steps in).
FAILING_1D = SMALL_1D.replace('value = "0.05 * sin(pi * t)"', 'value = "50.0 * t"')


def _write(tmp_path, text, name="c.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_simulate_writes_outputs(tmp_path):
    from hyperoc.app.config import load_config

    cfg = _write(tmp_path, SMALL_1D)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "out"), "--no-progress", "--set", "dynamics.dt=0.1"]) == 0
    out = tmp_path / "out"
    ran = load_config(out / "config.toml")  # the configuration that ran
    assert ran.sections == load_config(cfg, ["dynamics.dt=0.1"]).sections and ran["dynamics"]["dt"] == 0.1
    summary = json.loads((out / "summary.json").read_text())
    data = read_npz(out / "results.npz")
    for key in ("t", "p", "volume", "nodes", "displacement", "xi"):
        assert key in data
    assert data["displacement"].shape == (21, 21, 1)  # T = 2, dt = 0.1: 21 levels, n = 20: 21 nodes
    assert summary["volume_drift"] < 1e-12
    assert (out / "pressure.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / summary["files"]["time_series"]).exists()


def test_simulate_figures_name_the_run_and_carry_units(tmp_path, monkeypatch):
    """Every figure of a run is titled with the config file's name and its axes carry [output] units."""
    import hyperoc.app.plotting

    figures = []
    monkeypatch.setattr(hyperoc.app.plotting, "save_figure", lambda fig, path: figures.append((Path(path).name, fig)) or path)
    units = '[output]\nunits = { time = "ms", length = "mm", pressure = "kPa", control = "kPa/mm" }\n'
    cfg = _write(tmp_path, SMALL_1D + units, "bar-run.toml")
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "out"), "--no-progress", "--set", "dynamics.dt=0.1"]) == 0
    figures = dict(figures)
    assert set(figures) == {"pressure.png", "displacement.png", "velocity.png", "control.png", "control_snapshots.png"}
    titles = {name: (fig._suptitle or fig.axes[0].title).get_text() for name, fig in figures.items()}
    assert titles == {"pressure.png": "bar-run: pressure", "displacement.png": "bar-run: displacement u",
                      "velocity.png": "bar-run: velocity u_t", "control.png": "bar-run: control xi",
                      "control_snapshots.png": "bar-run: control xi"}
    assert (figures["pressure.png"].axes[0].get_ylabel(), figures["pressure.png"].axes[-1].get_xlabel()) == (
        "pressure p [kPa]", "time t [ms]")
    assert figures["velocity.png"].axes[0].get_ylabel() == "u_t(x, t) [mm/ms]"
    assert figures["displacement.png"].axes[0].get_title().endswith(" ms")
    assert figures["control.png"].axes[1].get_ylabel() == "control xi [kPa/mm]"
    assert figures["control_snapshots.png"].axes[0].get_ylabel() == "xi(x, t) [kPa/mm]"


def test_check_gradient_json(tmp_path, capsys):
    cfg = _write(tmp_path, SMALL_1D)
    assert main(["check-gradient", str(cfg), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res) == {"xi", "tau", "joint"}
    for r in res.values():
        assert 1.9 <= r["rate"] <= 2.1 and r["passed"]


@pytest.fixture
def terminal(monkeypatch):
    """stderr taken for a terminal, where the progress bars are drawn (capsys' stderr is not one)."""
    import hyperoc.app.cli

    monkeypatch.setattr(hyperoc.app.cli, "_stderr_is_terminal", lambda: True)


def test_progress_bar_labels_the_compilation(tmp_path, capsys, terminal):
    """Steps driven from Python (here a host sparse solver): the bar says "compiling" until the
    first step has run, then counts time steps."""
    cfg = _write(tmp_path, SMALL_1D)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "o"), "--set", "dynamics.solver=lu"]) == 0
    err = capsys.readouterr().err
    assert err.index("compiling:") < err.index("time steps:")


def test_simulate_1d_progress_by_blocks_gives_the_same_solution(tmp_path, capsys, terminal):
    """1D P1 (compiled loop): the bar advances by blocks of steps after "compiling", and the solution
    is bitwise the one of the loop run in one piece (--no-progress)."""
    cfg = _write(tmp_path, SMALL_1D)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "bar")]) == 0
    err = capsys.readouterr().err
    assert err.index("compiling:") < err.index("time steps:")
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "quiet"), "--no-progress"]) == 0
    bar, quiet = (np.load(tmp_path / name / "results.npz") for name in ("bar", "quiet"))
    for key in ("displacement", "velocity", "p", "volume"):
        np.testing.assert_array_equal(bar[key], quiet[key])


def test_no_progress_bars_when_stderr_is_not_a_terminal(tmp_path, capsys):
    """Output going to a file or a pipe gets no progress bar frames (carriage-return redraws)."""
    cfg = _write(tmp_path, SMALL_1D)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "o"), "--set", "dynamics.dt=0.1"]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "compiling" not in err and "time steps" not in err


def test_pressure_extrema_leave_out_extrapolated_levels(tmp_path, capsys):
    """The end levels' pressures extrapolate the computed mid-step multipliers: the summary's extrema
    are over the interior levels (here a constant load, whose pressure grows to the end)."""
    cfg = _write(tmp_path, SMALL_1D.replace('"0.05 * sin(pi * t)"', '"0.05"'))
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "o"), "--set", "dynamics.dt=0.1"]) == 0
    summary, data = json.loads((tmp_path / "o" / "summary.json").read_text()), read_npz(tmp_path / "o" / "results.npz")
    assert np.argmax(data["p"]) == data["t"].size - 1  # the extrapolated end level would be the maximum
    assert summary["pressure_max"] == np.max(data["p"][1:-1]) and summary["t_pressure_max"] == data["t"][-2]
    assert summary["pressure_min"] == np.min(data["p"][1:-1])
    assert f"max p = {summary['pressure_max']:.6g} at t = {data['t'][-2]:.6g};" in capsys.readouterr().out


@pytest.mark.parametrize(
    "change, message",
    [
        (("mu = 0.05", 'mu = "soft"'), "mu must be a number"),
        (("mu = 0.05", "mu = -1.0"), "mu must be > 0"),
        (("dt = 0.05", "dt = 0.0"), "dt must be > 0"),
        (("lower = [0.75], upper = [1.0]", "lower = [2.0], upper = [3.0]"), "contains no cell"),
        (("tau0 = 1.0", "tau0 = 5.0"), "tau"),
        (("tau0 = 1.0", 'tau0 = 1.0\nsteps = "diagonal"'), "steps must be 'joint' or 'blockwise'"),
        (("tau0 = 1.0", 'tau0 = 1.0\ntau_scale = "auto"'), "tau_scale must be 'range', 'curvature' or a positive number"),
        (("tau0 = 1.0", "tau0 = 1.0\ntau_scale = -2.0"), "tau_scale must be 'range', 'curvature' or a positive number"),
        (("tau0 = 1.0", 'tau0 = 1.0\nmethod = "lbfgsb"\ntau_scale = "curvature"'), "'curvature' applies to method newton"),
        (("tau0 = 1.0", "tau0 = 1.0\nnonmonotone = -1"), "nonmonotone must be >= 0"),
        (("tau0 = 1.0", "tau0 = 1.0\nnonmonotone = 2.5"), "nonmonotone must be"),
        (("tau0 = 1.0", 'tau0 = 1.0\nmethod = "newton"\nmax_cg = 0'), "max_cg must be >= 1"),
        (("tau0 = 1.0", 'tau0 = 1.0\nmethod = "newton-cg"'), "method must be 'bb', 'lbfgsb' or 'newton'"),
        (("n = 20", "n = 20\nfixed_components = [1]"), "fixed_components"),
        (('kind = "interval"\nn = 20', 'kind = "file"\nfile = "missing.msh"'), "mesh file not found"),
        (("[objective]", "[objektive]"), "unknown section"),
        (("n = 20", "n = 20\nrefinements = -1"), "refinements must be >= 0"),
        (("n = 20", "n = 20\nrefinements = 1.5"), "refinements must be"),
        (("mu = 0.05", 'mu = 0.05\nvolumetric = "cell-mean"'), "needs a law with a separate bulk term"),
        (("mu = 0.05", 'mu = 0.05\nvolumetric = "mean"'), "volumetric must be 'pointwise' or 'cell-mean'"),
        (('law = "svk"\nmu = 0.05\nlambda = 0.05', 'law = "guccione"\nisochoric = "yes"'), "isochoric must be"),
    ],
)
def test_bad_input_exit_2(tmp_path, capsys, change, message):
    cfg = _write(tmp_path, SMALL_1D.replace(*change))
    cmd = "optimize" if "tau0" in change[1] else "simulate"
    assert main([cmd, str(cfg), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hyperoc: error:") and message in lines[0], lines
    assert not (tmp_path / "o").exists()  # checked before anything is written


def test_version_and_help(capsys):
    import hyperoc

    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0 and capsys.readouterr().out.strip() == f"hyperoc {hyperoc.__version__}"
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    assert "TOML configuration file" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    assert "exit status:" in text and "2  bad input" in text and "[optimize]" in text and "example:" in text


def test_missing_config_exit_2(tmp_path):
    assert main(["simulate", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")]) == 2


def test_solver_failure_names_step(tmp_path, capsys):
    cfg = _write(tmp_path, FAILING_1D)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "o"), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "solver failed at step" in err and ("detF" in err or "newton" in err or "nonfinite" in err)


def test_log_steps_prints_each_step_and_the_failing_one(tmp_path, capsys):
    """``--log-steps``: one line per step; on a failure the last line is the step the error names."""
    cfg = _write(tmp_path, SMALL_1D)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "ok"), "--log-steps"]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("step ")]
    assert [int(line.split()[1]) for line in lines] == list(range(40))  # SMALL_1D: T = 2, dt = 0.05
    assert all(", min det F " in line and ", dV " in line for line in lines)
    cfg = _write(tmp_path, FAILING_1D)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "bad"), "--log-steps"]) == 1
    err = capsys.readouterr().err
    failing = re.search(r"solver failed at step (\d+) .*?: (\w+)", err)
    last = [line for line in err.splitlines() if line.startswith("step ")][-1]
    assert last.startswith(f"step {failing.group(1)} ") and last.endswith(f"FAILED: {failing.group(2)}")


@pytest.mark.parametrize("name", ["simulate-1d.toml", "annulus-2d.toml"])
def test_examples_parse(name):
    from hyperoc.app.config import load_config

    cfg = load_config(EXAMPLES / name)
    model = cfg.model()
    assert model.n > 0 and model.control is not None


def test_config_sliding_gamma_d_and_checkpointing(tmp_path):
    """``[mesh] fixed_components`` fixes only those components on gamma_d (here u_y on the box's
    face y = 0, with the three in-plane rigid motions pinned); ``[optimize] checkpoint_every``
    reaches the reduced functional."""
    from hyperoc.app.config import load_config
    from hyperoc.app.workflows import build_reduced
    from hyperoc.control.revolve import EveryK

    text = SMALL_1D.replace('kind = "interval"\nn = 20', 'kind = "box"\nnx = 2\ndirichlet = "bottom"\nfixed_components = [1]')
    text = text.replace("lower = [0.75], upper = [1.0]", "lower = [0.0, 0.0, 0.5], upper = [1.0, 1.0, 1.0]")
    text = text.replace('value = "0.05 * sin(pi * t)"\n', "").replace("max_iter = 4", "max_iter = 4\ncheckpoint_every = 5")
    cfg = load_config(_write(tmp_path, text))
    model = cfg.model()
    assert len(model.pinned_dofs) == 3
    clamped = load_config(_write(tmp_path, text.replace("fixed_components = [1]\n", ""), "clamped.toml")).model()
    assert model.n == clamped.n + 2 * 9 - 3  # 9 nodes on y = 0: x and z free, minus the three pins
    assert build_reduced(cfg, 1.0).schedule == EveryK(5)


@pytest.mark.parametrize("mesh, cells", [('kind = "interval"\nn = 20', 20), ('kind = "rectangle"\nnx = 2', 8),
                                         ('kind = "annulus"\nh = 0.5', None)])
def test_config_mesh_refinements(tmp_path, mesh, cells):
    """``[mesh] refinements = k`` refines the mesh built k times (2^(d k) cells); curved generators
    refine onto their exact surfaces (the annulus keeps its boundary vertices on the circles)."""
    from hyperoc.app.config import load_config

    base = load_config(_write(tmp_path, SMALL_1D.replace('kind = "interval"\nn = 20', mesh))).mesh()
    fine = load_config(_write(tmp_path, SMALL_1D.replace('kind = "interval"\nn = 20', mesh + "\nrefinements = 2"),
                              "fine.toml")).mesh()
    assert fine.num_cells == 4**base.dim * base.num_cells
    assert cells is None or base.num_cells == cells
    if base.dim == 2 and base.is_curved:
        radius = np.linalg.norm(fine.points[fine.boundary_vertices("outer")], axis=1)
        np.testing.assert_allclose(radius, 1.0, rtol=1e-12)


def test_config_cell_mean_volumetric(tmp_path):
    """``[material] volumetric = "cell-mean"`` reaches the model; its energy is the cell-mean one."""
    from hyperoc.app.config import load_config

    text = SMALL_1D.replace('law = "svk"', 'law = "neo-hookean"\nvolumetric = "cell-mean"')
    model = load_config(_write(tmp_path, text.replace("n = 20", "n = 20\ndegree = 2"))).model()
    assert model.volumetric == "cell-mean"
    u = model.interpolate(lambda x: 0.1 * x**2)  # exact in P2: J = 1 + 0.2 x, linear in each cell
    J, w = 1 + 0.2 * model.quad.x[..., 0], model.quad.wdx
    theta = np.sum(w * J, axis=1) / np.sum(w, axis=1)
    np.testing.assert_allclose(np.asarray(model.cell_mean_J(u)), theta, rtol=1e-14)
    mu, lam = 0.05, 0.05  # W = mu/2 (J^2 - 1) - mu ln J  +  lam/2 (ln J)^2 on theta
    expected = np.sum(w * (0.5 * mu * (J**2 - 1) - mu * np.log(J))) + np.sum(np.sum(w, axis=1) * 0.5 * lam * np.log(theta) ** 2)
    assert abs(float(model.strain_energy(u)) - expected) <= 1e-13 * abs(expected)


@pytest.mark.parametrize("method", ["lbfgsb", "newton"])
def test_set_overrides_config_entries_and_optimize_records_what_ran(tmp_path, capsys, method):
    """``--set`` and ``--method`` change the run (here a bound |xi| <= 0.01 that the optimizer hits,
    and L-BFGS-B or Newton-CG with at most 3 Hessian products per iteration); the output folder's
    config.toml is the configuration that ran, so reloading it gives the same sections, and
    ``--resume`` refuses an override that changes the problem, naming the key."""
    from hyperoc.app.config import load_config

    cfg, out = _write(tmp_path, SMALL_1D), tmp_path / "o"
    sets = ["optimize.xi_bounds=[-0.01, 0.01]", "optimize.max_iter=2"] + (["optimize.max_cg=3"] if method == "newton" else [])
    overrides = [a for s in sets for a in ("--set", s)] + ["--method", method]
    assert main(["optimize", str(cfg), "--out", str(out), "--no-progress", *overrides]) == 0
    ran = load_config(out / "config.toml")
    assert ran.sections == load_config(cfg, [*sets, f"optimize.method={method}"]).sections
    assert ran["optimize"]["method"] == method and ran["optimize"]["xi_bounds"] == [-0.01, 0.01]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["iterations"] <= 2 and np.max(np.abs(np.load(out / "results.npz")["xi"])) == pytest.approx(0.01)
    products = summary["optimization"]["evaluations"].get("hessian_products", 0)
    assert (0 < products <= 3 * summary["iterations"]) if method == "newton" else products == 0
    capsys.readouterr()
    assert main(["optimize", "--resume", str(out), "--set", "optimize.xi_bounds=[-0.02, 0.02]"]) == 2
    assert "--resume: optimize.xi_bounds would change the problem" in capsys.readouterr().err


@pytest.mark.parametrize("override, message", [
    ("dynamics.dt=abc", "dt must be a number"),
    ("dynamics.dt", "expected SECTION.KEY=VALUE"),
    ("dt=0.1", "expected SECTION.KEY"),
    ("dynamicz.dt=0.1", "unknown section"),
    ("mesh.n.x=1", "n is not a table"),
    ("material.mu=-1", "mu must be > 0"),
])
def test_bad_override_exit_2(tmp_path, capsys, override, message):
    cfg = _write(tmp_path, SMALL_1D)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "o"), "--no-progress", "--set", override]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hyperoc: error:") and message in err[0], err
    assert not (tmp_path / "o").exists()


def test_set_entries_is_the_mapping_form_of_set():
    """Python callers change a configuration with the same dotted paths as ``--set``, values typed."""
    from hyperoc.app.config import apply_overrides, set_entries

    data = {"mesh": {"n": 10}, "control": {"region": {"kind": "box"}}}
    entries = {"mesh.n": 20, "dynamics.dt": 0.1, "control.region.kind": "ball"}
    assert set_entries(data, entries) == apply_overrides(data, ["mesh.n=20", "dynamics.dt=0.1", "control.region.kind=ball"])
    assert data == {"mesh": {"n": 10}, "control": {"region": {"kind": "box"}}}  # the caller's dict is not changed


@pytest.mark.parametrize("name", ["paper-1d.toml", "simulate-1d.toml", "annulus-2d.toml", "ventricle-3d.toml"])
def test_config_to_toml_reloads_to_the_same_config_from_another_folder(tmp_path, name):
    from hyperoc.app.config import load_config

    cfg = load_config(EXAMPLES / name)
    again = load_config(_write(tmp_path, cfg.to_toml()))
    assert again.sections == cfg.sections


def test_config_to_toml_makes_file_paths_absolute(tmp_path):
    from hyperoc.app.config import load_config

    (tmp_path / "run").mkdir()
    text = SMALL_1D.replace('value = "0.05 * sin(pi * t)"', 'file = "xi.npz"')
    cfg = load_config(_write(tmp_path / "run", text))  # the control file is read only when asked for
    model = cfg.model()
    xi = np.random.default_rng(0).standard_normal((41, model.control.size))  # T = 2, dt = 0.05: 41 levels
    np.savez(tmp_path / "run" / "xi.npz", xi=xi)
    again = load_config(_write(tmp_path, cfg.to_toml()))
    assert again["control"]["file"] == str((tmp_path / "run" / "xi.npz").resolve())
    np.testing.assert_array_equal(again.prescribed_control(model, again.grid().t), xi)


def test_log_steps_says_which_checkpoint_segment_a_failure_stopped(tmp_path, capsys):
    """With checkpoints, the segment line of a run whose step fails says so, before the error names the step."""
    cfg = _write(tmp_path, FAILING_1D)
    args = ["simulate", str(cfg), "--out", str(tmp_path / "bad"), "--log-steps", "--set", "output.checkpoint_every=1"]
    assert main(args) == 1
    err = capsys.readouterr().err
    failed = int(re.search(r"solver failed at step (\d+) ", err).group(1))
    segments = [line for line in err.splitlines() if line.startswith("segment ")]
    assert len(segments) == failed + 1 and "stopped by a failed step" in segments[-1]  # one step per segment
    assert all(" solved in " in line for line in segments[:-1])

"""Bad input never reaches a traceback: every hostile input below ends with exit status 2, one line
on stderr and no output folder (or an empty one), before any solve; the configuration reference in
docs/ is the schema's."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import small_1d_toml
from hyperoc.app.cli import main

ROOT = Path(__file__).resolve().parents[1]

SMALL_1D = small_1d_toml()

# --set overrides of SMALL_1D -> a fragment of the one-line message
BAD_SETTINGS = [
    ("dynamics.damping=nan", "damping must be a finite number"),
    ("dynamics.kappa=2e-4", "[dynamics] kappa is now called damping"),
    ("material.kappa=100", "[material] kappa is now called bulk_modulus"),
    ("dynamics.density=inf", "density must be a finite number"),
    ("dynamics.density=0", "density must be > 0"),
    ("objective.alpha=nan", "alpha must be a finite number"),
    ("objective.alpha=-1", "alpha must be >= 0"),
    ("objective.beta=-0.5", "beta must be >= 0"),
    ("objective.beta=inf", "beta must be a finite number"),
    ("objective.phi1=volume", "phi1 must be 'pressure', 'pressure_rise' or 'pressure_mean'"),
    ("objective.phi1=pressure_rise", "needs eps > 0"),
    ("objective.eps=0.1", "eps does not apply to phi1 = 'pressure'"),
    ("material.mu=nan", "mu must be a finite number"),
    ("material.mu=-1", "mu must be > 0"),
    ("material.law=rubber", "unknown material law"),
    ("dynamics.dt=0", "dt must be > 0"),
    ("dynamics.T=-1", "T must be > 0"),
    ("dynamics.dt=5", "dt = 5 must be <= T = 2"),
    ("dynamics.dt=0.03", "not a whole number of steps"),
    ("dynamics.theta=2", "theta must be <= 1"),
    ("dynamics.solver=magic", "solver 'magic' unknown"),
    ("mesh.n=0", "n must be >= 1"),
    ("mesh.n=1.5", "n must be an integer"),
    ("mesh.n=true", "n must be an integer"),
    ("mesh.degree=3", "degree must be 1 or 2"),
    ("mesh.r_inner=0.2", "r_inner does not apply to kind = 'interval'"),
    ("mesh.kind=sphere", "kind must be"),
    ("mesh.n=1000000000", "or --force to run anyway"),
    ("mesh.refinements=40", "or --force to run anyway"),
    ("dynamics.dt=1e-9", "time levels"),
    ('control.value="1/(x - 1)"', "is inf at t = 0, x = [1.0]"),
    ('control.value="log(x - 2)"', "is nan at t = 0"),
    ('control.value="x.__class__"', "attribute access not allowed"),
    ('control.value="sin(x"', "invalid syntax"),
    ("control.value=true", "must be an expression string"),
    ('control.value=["x", "t"]', "needs 1 expression(s)"),
    ("control.region.lower=[2.0]", "lower < upper"),
    ("control.region.kind=cone", "kind must be"),
    ("optimize.xi_bounds=[1.0, -1.0]", "xi_bounds must be [lower, upper] with lower < upper"),
    ("optimize.max_iter=-1", "max_iter must be >= 1"),
    ("optimize.gtol=-1e-6", "gtol must be >= 0"),
    ("optimize.tau0=nan", "tau0 must be a finite number"),
    ("optimize.tau0=5.0", "[optimize] tau0 = 5 must lie in (0, T - eps)"),
    ("optimize.nonmonotone=-1", "nonmonotone must be >= 0"),
    ("optimize.checkpoint_snapshots=3", None),  # valid: the next case adds the conflicting option
    ("output.snapshot_times=0.5", "snapshot_times must be a list"),
    ("output.snapshot_times=[100.0]", "snapshot_times must lie in [0, T = 2]"),
    ("output.series_every=0", "series_every must be >= 1"),
    ('output.units.speed="mm/ms"', "[output] units unknown key 'speed' (keys: time, length, pressure, control)"),
    ("output.units.time=1", "[output] units time must be a string, got 1"),
    ('output.units="mm"', "[output] units must be a table"),
    ("objektive.alpha=1", "unknown section [objektive]"),
    ("mesh.m=3", "unknown key 'm'"),
    ("dt=0.1", "expected SECTION.KEY"),
]
BAD_SETTINGS = [(s, m) for s, m in BAD_SETTINGS if m is not None] + [
    ("optimize.checkpoint_every=2\0optimize.checkpoint_snapshots=3", "exclude each other"),
    ("optimize.tau0=0.5\0optimize.tau_starts=[0.5]", "tau0 or tau_starts, not both"),
    ("optimize.method=lbfgsb\0optimize.nonmonotone=3", "nonmonotone does not apply to method = 'lbfgsb'"),
]


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _command(setting: str) -> str:
    """The command that reads the setting: optimize for the optimizer's and the objective's."""
    return "optimize" if setting.startswith(("optimize.", "objective.")) else "simulate"


def _assert_refused(code, capsys, out: Path, fragment: str):
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("hyperoc: error: "), err
    assert fragment in lines[0], lines[0]
    assert len(lines[0]) < 400, lines[0]
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("setting, fragment", BAD_SETTINGS, ids=[s for s, _ in BAD_SETTINGS])
def test_bad_setting_exit_2(tmp_path, capsys, setting, fragment):
    cfg, out = _write(tmp_path / "c.toml", SMALL_1D), tmp_path / "out"
    sets = [a for s in setting.split("\0") for a in ("--set", s)]
    code = main([_command(setting), str(cfg), "--out", str(out), "--no-progress", *sets])
    _assert_refused(code, capsys, out, fragment)


def _npz(path: Path, **arrays) -> Path:
    np.savez(path, **arrays)
    return path


def _control_file(tmp_path, kind: str) -> str:
    """A ``[control] file`` of each broken kind (SMALL_1D has 41 levels and 6 control nodes)."""
    if kind == "missing":
        return "nope.npz"
    if kind == "text":
        return _write(tmp_path / "xi.npz", "not an archive").name
    if kind == "npy":
        np.save(tmp_path / "xi.npy", np.zeros((41, 6)))
        return "xi.npy"
    if kind == "no xi":
        return _npz(tmp_path / "xi.npz", control=np.zeros((41, 6))).name
    if kind == "nan":
        xi = np.zeros((41, 6))
        xi[3, 2] = np.nan
        return _npz(tmp_path / "xi.npz", xi=xi).name
    if kind == "shape":
        return _npz(tmp_path / "xi.npz", xi=np.zeros((40, 6))).name
    return _npz(tmp_path / "xi.npz", xi=np.array(["a", "b"])).name


@pytest.mark.parametrize("kind, fragment", [
    ("missing", "control file not found"), ("text", "not a readable NPZ archive"), ("npy", "not an NPZ archive"),
    ("no xi", "has no array 'xi' (found: control)"), ("nan", "non-finite value (nan) at level 3, entry 2"),
    ("shape", "must have shape (levels, n_ctrl) = (41, 6), got (40, 6)"),
    ("strings", "must be a real array (levels, n_ctrl) or (levels, n_nodes, components)"),
])
def test_bad_control_file_exit_2(tmp_path, capsys, kind, fragment):
    name = _control_file(tmp_path, kind)
    cfg = _write(tmp_path / "c.toml", SMALL_1D.replace('value = "0.05 * sin(pi * t)"', f'file = "{name}"'))
    out = tmp_path / "out"
    _assert_refused(main(["simulate", str(cfg), "--out", str(out), "--no-progress"]), capsys, out, fragment)


def test_control_value_and_file_exclude_each_other(tmp_path, capsys):
    cfg = _write(tmp_path / "c.toml", SMALL_1D.replace('value = "0.05', 'file = "xi.npz"\nvalue = "0.05'))
    out = tmp_path / "out"
    _assert_refused(main(["simulate", str(cfg), "--out", str(out)]), capsys, out, "give value or file, not both")


def test_long_expression_is_quoted_short(tmp_path, capsys):
    value = "x + " * 2600 + "y"  # over the 10,000 characters allowed
    cfg = _write(tmp_path / "c.toml", SMALL_1D.replace('"0.05 * sin(pi * t)"', f'"{value}"'))
    out = tmp_path / "out"
    _assert_refused(main(["simulate", str(cfg), "--out", str(out)]), capsys, out, "longer than 10000 characters")


def _paths(tmp_path) -> dict:
    """Hostile paths: a file, a folder, a file under a file, bad TOML, bad bytes."""
    (tmp_path / "folder.toml").mkdir()
    _write(tmp_path / "a_file", "x")
    _write(tmp_path / "bad.toml", "[mesh\nkind = ")
    (tmp_path / "binary.toml").write_bytes(b"\xff\xfe\x00[mesh]")
    _write(tmp_path / "garbage.msh", "garbage")
    mesh = _write(tmp_path / "mesh.toml",
                  SMALL_1D.replace('kind = "interval"\nn = 20', 'kind = "file"\nfile = "garbage.msh"'))
    return {"cfg": str(_write(tmp_path / "c.toml", SMALL_1D)), "file": str(tmp_path / "a_file"), "mesh": str(mesh),
            "folder": str(tmp_path / "folder.toml"), "bad": str(tmp_path / "bad.toml"),
            "binary": str(tmp_path / "binary.toml"), "missing": str(tmp_path / "missing.toml")}


@pytest.mark.parametrize("args, fragment", [
    (["simulate", "{folder}", "--out", "{out}"], "is not a file (a directory?)"),
    (["simulate", "{missing}", "--out", "{out}"], "config file not found"),
    (["simulate", "{bad}", "--out", "{out}"], "invalid TOML"),
    (["simulate", "{binary}", "--out", "{out}"], "invalid TOML"),
    (["simulate", "{mesh}", "--out", "{out}"], "cannot read mesh file"),
    (["simulate", "{cfg}", "--out", "{file}"], "is a file, not a folder"),
    (["simulate", "{cfg}", "--out", "{file}/sub/dir"], "is a file, so no folder can be made under it"),
    (["simulate", "{cfg}", "--out", "/proc/hyperoc-out"], "/proc is not writable"),
    (["optimize", "{cfg}"], "optimize needs CONFIG and --out DIR"),
    (["optimize", "--resume", "{out}"], "has no config.toml"),
    (["optimize", "--resume", "{folder}"], "has no config.toml"),
    (["simulate", "{cfg}", "--out", "{out}", "--log-steps", "--workers", "abc"], "unrecognized arguments"),
    (["optimize", "{cfg}", "--out", "{out}", "--workers", "abc"], "invalid int value"),
    (["optimize", "{cfg}", "--out", "{out}", "--method", "sgd"], "invalid choice"),
    (["explode"], "invalid choice"),
    ([], "required: command"),
])
def test_bad_paths_and_options_exit_2(tmp_path, capsys, args, fragment):
    paths = {**_paths(tmp_path), "out": str(tmp_path / "out")}
    code = main([a.format(**paths) for a in args])
    _assert_refused(code, capsys, tmp_path / "out", fragment)


def test_bad_input_in_a_real_process(tmp_path):
    """The console entry point: one line, exit 2, nothing written, and no JAX import needed for it."""
    cfg = _write(tmp_path / "c.toml", SMALL_1D.replace("damping = 2e-3", "damping = nan"))
    code = ("import sys; from hyperoc.app.cli import main; rc = main(sys.argv[1:]); "
            "assert 'jax' not in sys.modules; sys.exit(rc)")
    proc = subprocess.run([sys.executable, "-c", code, "simulate", str(cfg), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines() == ["hyperoc: error: config: [dynamics] damping must be a finite number, got nan"]
    assert not (tmp_path / "o").exists()


def test_force_runs_past_the_memory_estimate(tmp_path, capsys, monkeypatch):
    """``--force`` skips the resource guard: with 'no memory available' the run still completes."""
    import hyperoc.app.preflight

    monkeypatch.setattr(hyperoc.app.preflight, "available_memory", lambda: 1)
    cfg, out = _write(tmp_path / "c.toml", SMALL_1D), tmp_path / "out"
    _assert_refused(main(["simulate", str(cfg), "--out", str(out), "--no-progress"]), capsys, out, "--force")
    assert main(["simulate", str(cfg), "--out", str(out), "--no-progress", "--force", "--set", "dynamics.dt=0.1"]) == 0
    assert (out / "summary.json").exists()


def test_configuration_reference_is_the_schemas():
    """docs/configuration.md is what ``python -m hyperoc.app.config --reference`` prints, and it lists
    every key of every section."""
    from hyperoc.app.config import reference_markdown
    from hyperoc.app.schema import SECTIONS

    text = reference_markdown()
    assert (ROOT / "docs" / "configuration.md").read_text() == text
    for name, model in SECTIONS.items():
        assert f"## [{name}]" in text
        for key, field in model.model_fields.items():
            assert f"| `{field.alias or key}` |" in text


def test_output_units_table(tmp_path, capsys):
    """``[output] units`` takes the four units (each "-" unless given); an unknown key is one line."""
    from hyperoc.app.config import load_config

    units = '\n[output]\nunits = {time = "ms", length = "mm", pressure = "kPa", control = "kPa/mm"}\n'
    cfg = load_config(_write(tmp_path / "c.toml", SMALL_1D + units))
    assert cfg["output"]["units"] == {"time": "ms", "length": "mm", "pressure": "kPa", "control": "kPa/mm"}
    assert load_config(_write(tmp_path / "again.toml", cfg.to_toml()))["output"] == cfg["output"]
    partial = load_config(_write(tmp_path / "p.toml", SMALL_1D + '[output]\nunits = {length = "mm"}\n'))
    assert partial["output"]["units"] == {"time": "-", "length": "mm", "pressure": "-", "control": "-"}
    assert load_config(_write(tmp_path / "d.toml", SMALL_1D))["output"]["units"]["time"] == "-"
    bad, out = _write(tmp_path / "bad.toml", SMALL_1D + units.replace("control", "force")), tmp_path / "out"
    _assert_refused(main(["simulate", str(bad), "--out", str(out)]), capsys, out, "units unknown key 'force'")


def test_keys_of_other_kinds_at_their_defaults_are_dropped(tmp_path):
    """A config.toml written with every default (as before keys were tied to kinds) still loads,
    and the sections keep only the keys that apply."""
    from hyperoc.app.config import load_config

    text = SMALL_1D.replace("n = 20", "n = 20\nr_inner = 0.5\nstructured = false").replace(
        "alpha = 2e-3", "alpha = 2e-3\neps = 0.0").replace(
        "max_iter = 4", 'max_iter = 4\ntau_scale = "range"\nmax_cg = 20')
    cfg = load_config(_write(tmp_path / "c.toml", text))
    assert cfg["mesh"] == {"kind": "interval", "n": 20, "length": 1.0, "degree": 1, "refinements": 0,
                           "clamped": True, "scale": 1.0}
    assert "eps" not in cfg["objective"] and not {"tau_scale", "max_cg"} & set(cfg["optimize"])
    assert load_config(_write(tmp_path / "again.toml", cfg.to_toml()))["mesh"] == cfg["mesh"]


def test_material_errors_need_no_jax():
    """A bad material parameter is reported by the checks that run before JAX is imported."""
    code = ("import sys; from hyperoc.app.cli import main; "
            "rc = main(['simulate', 'examples/simulate-1d.toml', '--out', sys.argv[1], '--set', 'material.mu=-1']); "
            "print(rc, 'jax' in sys.modules)")
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code, str(root / "never-written")], cwd=root, capture_output=True,
                         text=True, check=True)
    assert out.stdout.split() == ["2", "False"]
    assert "mu must be > 0" in out.stderr and not (root / "never-written").exists()


def test_simulate_does_not_read_the_optimizers_tau(tmp_path, capsys):
    """``[optimize] tau0`` is read by the commands that optimize: with T below it, ``simulate`` runs and
    ``optimize`` names the key it reads."""
    from hyperoc.app.config import load_config
    from hyperoc.errors import InputError

    cfg = load_config(ROOT / "examples" / "ventricle-3d.toml", ["dynamics.T=4"])
    with pytest.raises(InputError, match=r"\[optimize\] tau0 = 10 must lie in \(0, T - eps\) = \(0, 3\)"):
        cfg.tau_starts()
    starts = _write(tmp_path / "starts.toml", SMALL_1D.replace("tau0 = 1.0", "tau_starts = [0.5, 2.5]"))
    with pytest.raises(InputError, match=r"\[optimize\] tau_starts\[1\] = 2.5 must lie in \(0, T - eps\)"):
        load_config(starts).tau_starts()
    path, out = _write(tmp_path / "c.toml", SMALL_1D), tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "--no-progress", "--set", "optimize.tau0=5",
                 "--set", "dynamics.dt=0.1"]) == 0


def test_paths_resolve_from_the_config_or_from_where_set_is_typed(tmp_path, monkeypatch, capsys):
    """A relative ``file`` in a config is taken from the config's folder; one given with ``--set`` from
    the working directory; a missing one is named resolved, with the rule."""
    from hyperoc.app.config import load_config

    (tmp_path / "configs").mkdir()
    (tmp_path / "work").mkdir()
    path = _write(tmp_path / "configs" / "c.toml", SMALL_1D.replace('value = "0.05 * sin(pi * t)"',
                                                                   'file = "xi.npz"'))
    monkeypatch.chdir(tmp_path / "work")
    assert load_config(path).control_path() == tmp_path / "configs" / "xi.npz"
    assert load_config(path, ['control.file="xi.npz"']).control_path() == tmp_path / "work" / "xi.npz"
    mesh = _write(tmp_path / "configs" / "m.toml", SMALL_1D.replace('kind = "interval"\nn = 20',
                                                                    'kind = "file"\nfile = "m.msh"'))
    assert load_config(mesh).mesh_path() == tmp_path / "configs" / "m.msh"
    assert load_config(mesh, ['mesh.file="m.msh"']).mesh_path() == tmp_path / "work" / "m.msh"
    out = tmp_path / "out"
    _assert_refused(main(["simulate", str(path), "--out", str(out)]), capsys, out,
                    f"control file not found: {tmp_path / 'configs' / 'xi.npz'} ([control] file = 'xi.npz'; "
                    f"a relative path is taken from the config's folder {tmp_path / 'configs'}, one given with --set "
                    "from the working directory)")

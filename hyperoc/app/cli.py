"""Command line: ``hyperoc simulate | optimize | check-gradient | reproduce | benchmark``.

Exit status: 0 success; 1 solver failure (the message names the time step and the cause);
2 bad input (config, mesh or control file, output folder, parameter, a problem too large for the
memory), with one line on stderr, no traceback and nothing written.

Every input is checked before anything is written or solved, in order of cost: the configuration
against its schema, the output folder, the files it names, the problem's size, the mesh and the
prescribed control on the actual space-time grid (`hyperoc.app.preflight`, no JAX imported: these
errors come at once), then the model, with the material law's own checks
(`hyperoc.app.workflows.check_run`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .. import __version__
from ..errors import InputError, SolverError

__all__ = ["main"]

CONFIG_HELP = "TOML configuration file (sections [mesh], [material], [dynamics], ...; see examples/)"
OUT_HELP = "output folder (created if missing)"
FORCE_HELP = "run even if the estimated memory exceeds what is available"

EPILOG = """\
exit status:
  0  success
  1  solver failure (the message names the time step and the cause)
  2  bad input: config, mesh or control file, output folder, option, or a problem too large
     for the memory (one line on stderr; nothing is written)

config sections (all optional; reference: docs/configuration.md, or python -m hyperoc.app.config --reference):
  [mesh] [material] [fibres] [dynamics] [control] [objective] [optimize] [output]

example:
  hyperoc simulate examples/simulate-1d.toml --out run --set dynamics.T=3
  hyperoc optimize examples/paper-1d.toml --out opt        (and, if interrupted: hyperoc optimize --resume opt)
  hyperoc optimize --resume opt --set optimize.max_iter=200     (continue a run that stopped at its budget)
  hyperoc simulate examples/paper-1d.toml --out replay --set 'control.file="opt/results.npz"'   (replay its control)
  hyperoc simulate CONFIG --out run --set output.checkpoint_every=50   (if interrupted: hyperoc simulate --resume run)
  hyperoc benchmark cardiac-elastodynamics --step 1 --out beat   (and, if interrupted: the same with --resume)
"""


class _Parser(argparse.ArgumentParser):
    """argparse's usage errors as `InputError` (one line, exit 2) instead of usage text and SystemExit."""

    def error(self, message):
        raise InputError(message)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="hyperoc", description="Optimal control of hyperelastic bodies under a volume constraint",
                                epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    s = sub.add_parser("simulate", help="forward solve with a prescribed control", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("config", nargs="?", help=CONFIG_HELP)
    s.add_argument("--out", metavar="DIR", help=OUT_HELP)
    s.add_argument("--resume", metavar="DIR",
                   help="continue an interrupted run in DIR, checkpointed by [output] checkpoint_every (its "
                        "config.toml is reused)")
    s.add_argument("--log-steps", action="store_true",
                   help="one line per time step on stderr (Newton iterations, min det F, volume drift, pressure) "
                        "instead of the progress bar, for output going to a file")
    o = sub.add_parser("optimize", help="optimize the control and the time tau", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    o.add_argument("config", nargs="?", help=CONFIG_HELP)
    o.add_argument("--out", metavar="DIR", help=OUT_HELP)
    o.add_argument("--resume", metavar="DIR",
                   help="continue an interrupted or stopped run in DIR (its config.toml is reused; --set may raise "
                        "optimize.max_iter or change optimize.gtol)")
    o.add_argument("--method", choices=["bb", "lbfgsb", "newton"], help="override [optimize] method")
    o.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler for multi-start (default: local processes)")
    o.add_argument("--workers", type=int, default=2)
    g = sub.add_parser("check-gradient", help="Taylor tests of the exact gradient", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    g.add_argument("config", help=CONFIG_HELP)
    g.add_argument("--json", action="store_true", help="print the results as JSON")
    g.add_argument("--seed", type=int, default=0)
    r = sub.add_parser("reproduce", help="reproduce a paper experiment, or its hybrid problem on a beating ventricle")
    r.add_argument("experiment", choices=["paper-1d", "lv-beat"],
                   help="paper-1d: the paper's 1D experiment; lv-beat: max dp/dt of an isovolumic contraction of "
                        "the benchmark ventricle by an apical active tension and a free time")
    r.add_argument("--out", required=True, metavar="DIR", help=OUT_HELP)
    r.add_argument("--quick", action="store_true",
                   help="paper-1d: the headline only (skip the diagnostic runs of the problem as stated)")
    r.add_argument("--workers", type=int, default=None,
                   help="paper-1d: processes running the independent studies in parallel (default: min(2, CPUs))")
    b = sub.add_parser("benchmark", help="run a community benchmark and compare with its published curves",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    b.add_argument("benchmark", choices=["cardiac-elastodynamics"],
                   help="cardiac-elastodynamics: problem 1 of Arostica et al. (2025), CMAME 435:117485")
    add_benchmark_arguments(b)
    b.add_argument("--solver", default=None, choices=["lu", "pardiso"],
                   help="sparse direct solver of the steps: SuperLU (lu, the default) or MKL PARDISO (pardiso: "
                        "multithreaded, needs the mkl wheel)")
    for q in (s, o, r, b):
        q.add_argument("--no-progress", action="store_true",
                       help="no progress bar (there is none either when stderr is not a terminal)")
    for q in (s, o, g):
        q.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", dest="overrides",
                       help="override a config entry, e.g. --set optimize.xi_bounds=[-0.05,0.05] (repeatable; "
                            "VALUE is read as TOML, else as a string)")
    for q in (s, o, g):
        q.add_argument("--force", action="store_true", help=FORCE_HELP)
    return p


def _checked_config(config, overrides, out, command: str, force: bool):
    """The validated `Config`: the schema, the output folder, the files the config names, the
    problem's size, the mesh and the prescribed control (`hyperoc.app.preflight.check_inputs`), then
    the model (`hyperoc.app.workflows.check_run`). Returns ``(cfg, model)``; nothing has been written."""
    from .config import load_config
    from .preflight import check_inputs, check_output_dir

    cfg = load_config(config, overrides)
    if out is not None:
        check_output_dir(out)
    mesh = check_inputs(cfg, command, force)
    _start_compiler()  # before anything compiles: JAX fixes its cache at the first compilation
    from .workflows import check_run  # the solvers and JAX: only for input that passed the checks above

    return cfg, check_run(cfg, command, mesh)


def _check_resume_changes(config: Path, overrides: list) -> None:
    """`InputError` naming the first entry that ``overrides`` change in the recorded ``config``, other
    than the optimizer's budget (`hyperoc.app.config.BUDGET_KEYS`, which leaves every iterate before
    the stop as it was: the cached evaluations replay them): a resumed run continues the recorded problem."""
    from .config import BUDGET_KEYS, load_config

    allowed = [f"optimize.{k}" for k in BUDGET_KEYS]
    recorded, changed = load_config(config).sections, load_config(config, overrides).sections
    for section, entries in changed.items():
        for key in sorted(set(entries) | set(recorded[section])):
            name = f"{section}.{key}"
            if name not in allowed and entries.get(key) != recorded[section].get(key):
                raise InputError(f"--resume: {name} would change the problem recorded in {config} "
                                 f"({recorded[section].get(key)!r} -> {entries.get(key)!r}); only "
                                 f"{', '.join(allowed)} may change on resume (a new run needs CONFIG --out DIR)")


def _run_folder(args, command: str) -> tuple[Path, Path]:
    """The output folder and the config of a new run (CONFIG --out DIR) or of a resumed one (--resume DIR:
    DIR/config.toml)."""
    if args.resume:
        out = Path(args.resume)
        config = out / "config.toml"
        if not config.is_file():
            raise InputError(f"--resume: {out} has no config.toml (is it a {command} output folder?)")
        if args.config or args.out:
            raise InputError(f"--resume continues the run configured in {config}; CONFIG and --out apply to a new run")
        return out, config
    if not (args.config and args.out):
        raise InputError(f"{command} needs CONFIG and --out DIR (or --resume DIR)")
    return Path(args.out), Path(args.config)


def _optimize(args) -> None:
    overrides = args.overrides + ([f"optimize.method={args.method}"] if args.method else [])
    out, config = _run_folder(args, "optimize")
    if args.resume:
        _check_resume_changes(config, overrides)
    cfg, model = _checked_config(config, overrides, out, "optimize", args.force)
    from .workflows import optimize, resume_state

    done = 0
    if args.resume:
        state = resume_state(cfg, out)
        for path, reason in state["dropped"]:
            print(f"hyperoc: warning: damaged evaluation cache entry {path} ({reason}): dropped, it will be recomputed",
                  file=sys.stderr)
        done = state["iterations"]
        print(f"resuming: {state['evaluations']} evaluations cached, {done} iterations done", file=sys.stderr)
    # --resume continues this very problem (with the budget given last, so that a further --resume keeps it)
    _record_config(cfg, out)
    # a resumed run reads the copy out/config.toml: its folder names it in the figures
    summary = optimize(cfg, out, progress=_progress(args), scheduler=args.scheduler, workers=args.workers,
                       model=model, iterations_done=done, title=out.resolve().name if args.resume else None)
    print(f"tau = {summary.get('tau', float('nan')):.6g}  J = {summary.get('objective', float('nan')):.6g}  "
          f"converged = {summary.get('converged')}  -> {out / 'summary.json'}")
    _print_stop(summary, out)


def _print_stop(summary: dict, out: Path) -> None:
    """The optimizer's stop reason, a best iterate it did not end at, and the physics warnings."""
    opt = summary.get("optimization", {})
    if opt.get("message"):
        print(f"stopped: {opt['message']}")
    best = opt.get("best")
    if best:
        print(f"best iterate: J = {best['objective']:.6g} at iteration {best['iteration']} (tau = {best['tau']:.6g}), "
              f"above the final J = {opt['objective']:.6g}: {out / best['file']}")
    for w in summary.get("warnings", []):
        print(f"warning: {w}", file=sys.stderr)


def _stderr_is_terminal() -> bool:
    return sys.stderr.isatty()


def _progress(args) -> bool:
    """Progress bars: unless ``--no-progress``, and only on a terminal: redrawn with carriage returns,
    they would fill a log file (a pipe, ``nohup``, CI) with frames."""
    return not args.no_progress and _stderr_is_terminal()


def _start_compiler() -> None:
    """After the input is checked: JAX, with its persistent compilation cache (`hyperoc._jax`)."""
    from .._jax import enable_compilation_cache

    enable_compilation_cache()


def _record_config(cfg, out: Path) -> None:
    """``out/config.toml``: the configuration that runs, overrides and defaults included (written
    after every check, so that bad input leaves no file behind)."""
    from ..io import atomic_write_text

    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "config.toml", cfg.to_toml())


def _print_step(record) -> None:
    """``--log-steps``: one `hyperoc.dynamics.stepper.StepRecord` per line, flushed (a log file follows the run)."""
    print(f"step {record.step} t = {record.t:.6g}: {record.describe()}", file=sys.stderr, flush=True)


def _simulate(args) -> None:
    out, config = _run_folder(args, "simulate")
    if args.resume and args.overrides:
        raise InputError("--resume continues the recorded solve: --set would change it")
    cfg, model = _checked_config(config, args.overrides, out, "simulate", args.force)
    from .workflows import simulate

    if args.resume and not cfg["output"].get("checkpoint_every"):
        raise InputError(f"--resume: {config} has no [output] checkpoint_every, so {out} holds no checkpoints")
    _refuse_checkpointed(out, args.resume, f"--resume {out}")
    _record_config(cfg, out)
    summary = simulate(cfg, out, progress=_progress(args) and not args.log_steps,
                       monitor=_print_step if args.log_steps else None,
                       on_segment=_print_segment if args.log_steps else None, model=model)
    print(f"max p = {summary['pressure_max']:.6g} at t = {summary['t_pressure_max']:.6g}; "
          f"volume drift {summary['volume_drift']:.2e} -> {out / 'summary.json'}")
    for w in summary["warnings"]:
        print(f"warning: {w}", file=sys.stderr)


def _check_gradient(args) -> None:
    cfg, _ = _checked_config(args.config, args.overrides, None, "optimize", args.force)
    from .workflows import check_gradient

    if not args.json:
        print("Taylor tests along xi, tau and (xi, tau) (a few state and adjoint solves each):", flush=True)
    res = check_gradient(cfg, seed=args.seed, report=None if args.json else _print_taylor)
    if args.json:
        print(json.dumps(res, indent=2))


def _print_taylor(name: str, r: dict) -> None:
    print(f"{name:6s} rate {r['rate']:.3f} ({'pass' if r['passed'] else 'FAIL'}: expected 2)  "
          f"remainders {', '.join(f'{x:.2e}' for x in r['remainder'])}", flush=True)


def _reproduce(args) -> None:
    from .preflight import check_output_dir

    if args.experiment == "lv-beat" and (args.quick or args.workers is not None):
        raise InputError("--quick and --workers apply to paper-1d, not to lv-beat")
    out = check_output_dir(args.out)
    if args.experiment == "lv-beat":
        _reproduce_lv_beat(out, _progress(args))
        return
    from .._cache import cache_environment
    from .paper import reproduce_paper_1d

    cache_environment()  # for the workers' JAX (this process imports none)

    reproduce_paper_1d(out, quick=args.quick, progress=_progress(args), workers=args.workers)


def _reproduce_lv_beat(out: Path, progress: bool) -> None:
    from .lv_beat import reproduce_lv_beat

    _start_compiler()
    s = reproduce_lv_beat(out, progress=progress)
    rise = s["pressure_rise_at_tau"]
    print(f"tau* = {s['tau']:.4g} s  J* = {s['objective']:.6g}  converged = {s['converged']} (relative projected "
          f"gradient {s['relative_gradient']:.2g}, {s['iterations']} iterations)")
    print(f"dp/dt at tau*: {rise['optimized']:.4g} Pa/s with the control, {rise['uncontrolled']:.4g} without "
          f"({100 * s['pressure_rise_gain']:+.1f} %); {s['wall_time_s']:.0f} s -> {out / 'summary.json'}")


def add_benchmark_arguments(parser) -> None:
    """The options of the cardiac benchmark's run (`hyperoc benchmark cardiac-elastodynamics`, and on MPI ranks
    `hyperoc.app.distributed_benchmark`), its linear solver aside."""
    parser.add_argument("--step", default="1", choices=["0A", "0B", "1"],
                        help="0A: active tension only, 0B: endocardial pressure only, 1: both (default)")
    parser.add_argument("--out", required=True, metavar="DIR", help=OUT_HELP)
    parser.add_argument("--degree", type=int, default=1, choices=[1, 2], help="Lagrange degree of the displacement")
    parser.add_argument("--mesh", default="reference", choices=["reference", "coarse"],
                        help="the benchmark's reference mesh (default) or hyperoc's coarse mesh of its domain")
    parser.add_argument("--end-time", type=float, default=None, metavar="T",
                        help="stop at T seconds (default: the whole beat, 1 s)")
    parser.add_argument("--dt", type=float, default=None, metavar="DT",
                        help="time step in seconds, at most 10 ms, the sampling interval of the codes' curves "
                             "(default: the benchmark's, 1 ms)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run checkpointed in DIR (every 50 steps), if there is one")


def checked_benchmark(args, solver: str | None):
    """``(out, cfg, model)`` of a benchmark run of ``args`` (`add_benchmark_arguments`) with the serial linear
    ``solver`` (None: the shipped config's); `InputError` before anything is written."""
    from .preflight import check_output_dir

    out = check_output_dir(args.out)
    _refuse_checkpointed(out, args.resume, "--resume")
    if args.end_time is not None and not 0.0 < args.end_time <= 1.0:
        raise InputError(f"--end-time must lie in (0, 1] s, got {args.end_time}")
    from ..cardiac.benchmark import SAMPLE_DT

    if args.dt is not None and not 0.0 < args.dt <= SAMPLE_DT:
        raise InputError(f"--dt must lie in (0, {SAMPLE_DT}] s, got {args.dt}")
    from .cardiac_benchmark import benchmark_config
    from .workflows import check_run

    cfg = benchmark_config(args.step, degree=args.degree, mesh=args.mesh, T=args.end_time, dt=args.dt,
                           solver=solver)
    return out, cfg, check_run(cfg, "simulate")


def _benchmark(args) -> None:
    out, _, model = checked_benchmark(args, args.solver)
    _start_compiler()
    from .cardiac_benchmark import run_benchmark
    from .cardiac_benchmark_report import write_benchmark_outputs

    progress = _progress(args)
    record = run_benchmark(args.step, out, degree=args.degree, mesh=args.mesh, T=args.end_time, dt=args.dt,
                           solver=args.solver, progress=progress, on_segment=None if progress else _print_segment,
                           model=model)
    write_benchmark_outputs(out, record)
    print_comparison(record, out)


def _refuse_checkpointed(out: Path, resume, how: str) -> None:
    """`InputError` for a new run (``resume`` false) into a folder holding a checkpointed one: it would mix
    the two solves' segments; ``how``: the option that continues it."""
    from ..dynamics.resumable import SEGMENTS_DIR

    if (out / SEGMENTS_DIR).exists() and not resume:
        raise InputError(f"--out {out} holds a checkpointed run: use {how} to continue it, or another folder")


def _print_segment(index: int, count: int, segment: dict, solved: bool) -> None:
    """One line per checkpoint segment on stderr (a log file follows a long run); a segment in which a step
    failed says so (the error that follows names the step)."""
    failed = bool((segment["status"] != 0).any())
    what = "read back" if not solved else (f"{'stopped by a failed step' if failed else 'solved'} in "
                                           f"{segment['wall_time']:.1f} s")
    print(f"segment {index + 1}/{count} {what}: {int(segment['newton_iterations'].sum())} Newton iterations",
          file=sys.stderr, flush=True)


def print_comparison(record: dict, out: Path) -> None:
    """Per quantity: the share of the codes' sampling times where hyperoc lies inside their band, and the peaks."""
    print(f"step {record['step']}, P{record['degree']}, {record['unknowns']} unknowns, {record['wall_time']:.0f} s, "
          f"{record['newton_iterations']['total']} Newton iterations")
    for quantity, c in record["comparison"].items():
        peak = c.get("peak")
        peaks = f"; peak {peak['hyperoc']:.4g} (codes {peak['codes'][0]:.4g} to {peak['codes'][1]:.4g})" if peak else ""
        print(f"  {quantity:7s} inside the codes' band at {100 * c['inside']:.0f} % of the times, "
              f"worst {100 * c['worst']:.2g} % outside{peaks}")
    print(f"-> {out / 'benchmark.json'}, {out / 'displacements.png'}, {out / 'volume.png'}")


COMMANDS = {"simulate": _simulate, "optimize": _optimize, "check-gradient": _check_gradient, "reproduce": _reproduce,
            "benchmark": _benchmark}


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
        COMMANDS[args.command](args)
    except InputError as exc:
        print(f"hyperoc: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except SolverError as exc:
        print(f"hyperoc: solver failure: {_one_line(exc)}", file=sys.stderr)
        return 1
    return 0


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

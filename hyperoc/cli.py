"""Command line: ``hyperoc simulate | optimize | check-gradient | reproduce``.

Exit status: 0 success; 1 solver failure (the message names the time step and the cause);
2 bad input (config, mesh file, parameter), with one line on stderr and no traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from . import __version__
from .errors import InputError, SolverError

__all__ = ["main"]

CONFIG_HELP = "TOML configuration file (sections [mesh], [material], [dynamics], ...; see examples/)"
OUT_HELP = "output folder (created if missing)"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hyperoc", description="Optimal control of hyperelastic bodies under a volume constraint")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("simulate", help="forward solve with a prescribed control")
    s.add_argument("config", help=CONFIG_HELP)
    s.add_argument("--out", required=True, metavar="DIR", help=OUT_HELP)
    s.add_argument("--log-steps", action="store_true",
                   help="one line per time step on stderr (Newton iterations, min det F, volume drift, pressure) "
                        "instead of the progress bar, for output going to a file")
    o = sub.add_parser("optimize", help="optimize the control and the time tau")
    o.add_argument("config", nargs="?", help=CONFIG_HELP)
    o.add_argument("--out", metavar="DIR", help=OUT_HELP)
    o.add_argument("--resume", metavar="DIR", help="continue an interrupted run in DIR (its config.toml is reused)")
    o.add_argument("--method", choices=["bb", "lbfgsb", "newton"], help="override [optimize] method")
    o.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler for multi-start (default: local processes)")
    o.add_argument("--workers", type=int, default=2)
    g = sub.add_parser("check-gradient", help="Taylor tests of the exact gradient")
    g.add_argument("config", help=CONFIG_HELP)
    g.add_argument("--json", action="store_true", help="print the results as JSON")
    g.add_argument("--seed", type=int, default=0)
    r = sub.add_parser("reproduce", help="reproduce a paper experiment")
    r.add_argument("experiment", choices=["paper-1d"])
    r.add_argument("--out", required=True, metavar="DIR", help=OUT_HELP)
    r.add_argument("--quick", action="store_true", help="skip the resolution and well-posedness studies")
    r.add_argument("--workers", type=int, default=None,
                   help="processes running the independent studies in parallel (default: min(2, CPUs))")
    for q in (s, o, r):
        q.add_argument("--no-progress", action="store_true", help="no progress bar")
    for q in (s, o, g):
        q.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", dest="overrides",
                       help="override a config entry, e.g. --set optimize.xi_bounds=[-0.05,0.05] (repeatable; "
                            "VALUE is read as TOML, else as a string)")
    return p


def _optimize(args) -> None:
    from .config import load_config
    from .workflows import check_run, optimize

    overrides = args.overrides + ([f"optimize.method={args.method}"] if args.method else [])
    if args.resume:
        out = Path(args.resume)
        config = out / "config.toml"
        if not config.exists():
            raise InputError(f"--resume: {out} has no config.toml (is it an optimize output folder?)")
        if overrides:
            raise InputError(f"--resume continues the run configured in {config}; --set and --method apply to a new run")
    else:
        if not (args.config and args.out):
            raise InputError("optimize needs CONFIG and --out DIR (or --resume DIR)")
        out, config = Path(args.out), Path(args.config)
    cfg = load_config(config, overrides)
    model = check_run(cfg, "optimize")
    if not args.resume:
        _record_config(cfg, out)  # --resume continues this very problem
    summary = optimize(cfg, out, progress=not args.no_progress, scheduler=args.scheduler, workers=args.workers,
                       model=model)
    print(f"tau = {summary.get('tau', float('nan')):.6g}  J = {summary.get('objective', float('nan')):.6g}  "
          f"converged = {summary.get('converged')}  -> {out / 'summary.json'}")


def _record_config(cfg, out: Path) -> None:
    """``out/config.toml``: the configuration that runs, overrides and defaults included (written
    after `hyperoc.workflows.check_run`, so that bad input leaves no file behind)."""
    from .io import atomic_write_text

    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "config.toml", cfg.to_toml())


def _print_step(record) -> None:
    """``--log-steps``: one `hyperoc.dynamics.StepRecord` per line, flushed (a log file follows the run)."""
    print(f"step {record.step} t = {record.t:.6g}: {record.describe()}", file=sys.stderr, flush=True)


def _run(args) -> None:
    if args.command == "simulate":
        from .config import load_config
        from .workflows import check_run, simulate

        cfg = load_config(args.config, args.overrides)
        model = check_run(cfg, "simulate")
        _record_config(cfg, Path(args.out))
        summary = simulate(cfg, args.out, progress=not (args.no_progress or args.log_steps),
                           monitor=_print_step if args.log_steps else None, model=model)
        print(f"max p = {summary['pressure_max']:.6g} at t = {summary['t_pressure_max']:.6g}; "
              f"volume drift {summary['volume_drift']:.2e} -> {Path(args.out) / 'summary.json'}")
        for w in summary["warnings"]:
            print(f"warning: {w}", file=sys.stderr)
    elif args.command == "optimize":
        _optimize(args)
    elif args.command == "check-gradient":
        from .config import load_config
        from .workflows import check_gradient

        res = check_gradient(load_config(args.config, args.overrides), seed=args.seed)
        if args.json:
            print(json.dumps(res, indent=2))
        else:
            for name, r in res.items():
                print(f"{name:6s} rate {r['rate']:.3f}  remainders {', '.join(f'{x:.2e}' for x in r['remainder'])}")
    elif args.command == "reproduce":
        from .paper import reproduce_paper_1d

        reproduce_paper_1d(Path(args.out), quick=args.quick, progress=not args.no_progress, workers=args.workers)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    try:
        _run(args)
    except InputError as exc:
        print(f"hyperoc: error: {exc}", file=sys.stderr)
        return 2
    except SolverError as exc:
        print(f"hyperoc: solver failure: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

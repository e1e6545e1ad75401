"""``testbed campaign | report | reproduce``: subcommands for the lead to wire into testbed/cli.py.

>>> sub = parser.add_subparsers(dest="command")
>>> add_campaign_parsers(sub)      # registers campaign, report, reproduce with handlers

Each handler is set as ``func`` (``args.func(args) -> exit code``), thin over
:mod:`testbed.campaign` (run_campaign, write_report, reproduce_va_raim_2015).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from testbed.schema import ConfigError, exit_code


def _positive_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole number, got {text!r}")
    return n


def _workers(text: str) -> int | str:
    """``--workers``: a positive whole number or ``auto``."""
    if text == "auto":
        return text
    try:
        return _positive_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected a positive whole number or auto, got {text!r}") from None


WORKERS_HELP = ("local worker processes running the chunk rows: a number, or auto (the default: one per core when "
                "the run is big enough to repay their start, else this process with draw blocks on threads)")


def _interrupted(out: Path) -> int:
    """Ctrl-C: what is kept and how to go on, instead of a traceback (exit 130, the shell's code for SIGINT)."""
    print(f"interrupted: the chunks finished so far are stored in {out}; the same command with --resume completes "
          "the run")
    return 130


def _cmd_campaign(args: argparse.Namespace) -> int:
    from testbed.campaign.report import headlines, report_inputs, write_report
    from testbed.campaign.runner import run_campaign
    from testbed.campaign.spec import load_spec

    loaded = load_spec(args.spec, trials=args.trials)  # every spec problem is reported before any work starts
    out = Path(args.out) if args.out else Path("campaigns") / loaded.spec.name
    try:
        res = run_campaign(loaded, out, resume=args.resume, scheduler=args.scheduler, progress=not args.quiet,
                           restart=args.restart, workers=args.workers)
    except KeyboardInterrupt:
        return _interrupted(out)
    print(f"{res.cells} cells, {res.trials} trials: {res.chunks_run} chunks run, {res.chunks_skipped} already stored; "
          f"{res.wall_s:.1f} s ({res.epochs_per_s:,.0f} sortie-epochs/s)")
    inputs = report_inputs(out)  # read once: the headlines and the report share its detection table
    for line in headlines(inputs):
        print(line)
    if not args.no_report:
        idx = write_report(out, inputs=inputs)
        print(f"report: {idx}")
    print(f"results: {out}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from testbed.campaign.report import write_report

    try:
        idx = write_report(args.dir)
    except FileNotFoundError as exc:
        raise ConfigError(Path(args.dir), [f"not a campaign folder: {exc}"]) from None
    print(f"report: {idx}")
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from testbed.campaign.reproduce import PAPERS, reproduce_va_raim_2015
    from testbed.sim.preflight import check_output_folder

    if args.paper not in PAPERS:
        raise ConfigError("command line", [f"unknown paper {args.paper!r}; expected one of {sorted(PAPERS)}"])
    ignored = [o for o, v in (("--scheduler", args.scheduler), ("--resume", args.resume),
                              ("--workers", args.workers != "auto")) if v]
    if args.paper != "va-raim-2015" and ignored:  # refused, not silently ignored
        raise ConfigError("command line", [f"{' and '.join(ignored)}: only va-raim-2015's campaigns take them; "
                                           f"{args.paper} runs in-process from the start"])
    out = Path(args.out) if args.out else Path("campaigns") / f"reproduce-{args.paper}"
    check_output_folder(out, "--out")
    if args.paper == "dpe-vertical":
        from testbed.campaign.reproduce_dpe import reproduce_dpe_vertical

        idx = reproduce_dpe_vertical(out, trials=2000 if args.full else 30, progress=not args.quiet)
    elif args.paper == "won-2013":
        from testbed.campaign.reproduce_won import reproduce_won_2013

        idx = reproduce_won_2013(out, trials=200 if args.full else 50, progress=not args.quiet)
    else:
        try:
            idx = reproduce_va_raim_2015(out, full=args.full, scheduler=args.scheduler, resume=args.resume,
                                         progress=not args.quiet, workers=args.workers)
        except KeyboardInterrupt:
            return _interrupted(out)
    print(f"reproduction: {idx}")
    return 0


def add_campaign_parsers(subparsers) -> None:
    """Register ``campaign``, ``report`` and ``reproduce`` on an argparse subparsers object."""
    p = subparsers.add_parser("campaign", help="run a fault-injection Monte Carlo campaign from a spec")
    p.add_argument("spec", help="campaign spec: a shipped name (see `testbed approaches`) or a TOML file")
    p.add_argument("--trials", type=_positive_int, help="override the spec's trials per cell (a quick look)")
    p.add_argument("--out", help="result folder (default: campaigns/<spec name>)")
    p.add_argument("--scheduler", help="Dask scheduler address (default: this machine, see --workers)")
    p.add_argument("--workers", type=_workers, default="auto", help=WORKERS_HELP)
    again = p.add_mutually_exclusive_group()  # both at once would discard what --resume means to keep
    again.add_argument("--resume", action="store_true", help="complete an interrupted run in --out (same spec and "
                                                             "inputs)")
    again.add_argument("--restart", action="store_true", help="discard the run stored in --out and start over")
    p.add_argument("--no-report", action="store_true", help="do not draw the figures and report.md")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_campaign)

    p = subparsers.add_parser("report", help="redraw a campaign's figures and report.md from stored results")
    p.add_argument("dir", help="campaign result folder")
    p.set_defaults(func=_cmd_report)

    p = subparsers.add_parser("reproduce", help="reproduce a source paper's experiments "
                                                      "(va-raim-2015, won-2013, dpe-vertical)")
    p.add_argument("paper", help="va-raim-2015 | won-2013 | dpe-vertical")
    p.add_argument("--full", action="store_true", help="the paper's scale: 1e5 sorties x 60 s per setting "
                                                      "(dpe-vertical: 2000 sorties per cell, docs/design/dpe.md §7.3; "
                                                      "won-2013: 200 runs per case, else 50)")
    p.add_argument("--out", help="result folder (default: campaigns/reproduce-<paper>)")
    p.add_argument("--scheduler", help="va-raim-2015: Dask scheduler address (default: this machine, see --workers)")
    p.add_argument("--workers", type=_workers, default="auto", help="va-raim-2015: " + WORKERS_HELP)
    p.add_argument("--resume", action="store_true", help="va-raim-2015: complete the experiments stored in --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_reproduce)


def main(argv: list[str] | None = None) -> int:
    """``python -m testbed.campaign <campaign|report|reproduce> ...``: the same commands as ``testbed campaign`` ..."""
    parser = argparse.ArgumentParser(prog="python -m testbed.campaign")
    sub = parser.add_subparsers(dest="command", required=True)
    add_campaign_parsers(sub)
    args = parser.parse_args(argv)
    from testbed.threads import sleep_idle_threads

    sleep_idle_threads()  # a process setting, as testbed's own main applies it
    return exit_code(lambda: args.func(args))

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
from testbed.sim.budget import add_allow_large, budget_gate


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


def _chunks_kept(resume_hint: str, written_at_the_end: str, restart: bool = False) -> str:
    """What a folder of campaigns keeps when its command stops early (OutputSet.folder's ``kept``)."""
    rest = ("the earlier run there, its report included, was discarded as --restart asks" if restart
            else f"{written_at_the_end} as they were")
    return f"the chunks finished so far are stored there ({resume_hint}); {rest}"


def _cmd_campaign(args: argparse.Namespace) -> int:
    from testbed.campaign.budget import campaign_estimate
    from testbed.campaign.report import REPORT_ENTRIES, headlines, report_inputs, write_report
    from testbed.campaign.runner import run_campaign
    from testbed.campaign.spec import load_spec
    from testbed.outputs import OutputSet

    loaded = load_spec(args.spec, trials=args.trials)  # every spec problem is reported before any work starts
    out = Path(args.out) if args.out else Path("campaigns") / loaded.spec.name
    budget_gate(lambda: campaign_estimate(loaded, workers=args.workers, scheduler=args.scheduler, out_dir=out,
                                          resume=args.resume), args.allow_large)
    with OutputSet() as outs:  # the chunks are stored as they finish; the report goes into place at the end
        outs.folder(out, "--out", entries=() if args.no_report else REPORT_ENTRIES,
                    kept=_chunks_kept("the same command with --resume completes the run", "report.md and figures/ are",
                                      args.restart))
        res = run_campaign(loaded, out, resume=args.resume, scheduler=args.scheduler, progress=not args.quiet,
                           restart=args.restart, workers=args.workers)
        print(f"{res.cells} cells, {res.trials} trials: {res.chunks_run} chunks run, {res.chunks_skipped} already "
              f"stored; {res.wall_s:.1f} s ({res.epochs_per_s:,.0f} sortie-epochs/s)")
        inputs = report_inputs(out)  # read once: the headlines and the report share its detection table
        for line in headlines(inputs):
            print(line)
        if not args.no_report:
            idx = write_report(out, inputs=inputs, outputs=outs)
            outs.commit()
            print(f"report: {idx}")
        print(f"results: {out}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from testbed.campaign.report import write_report
    from testbed.outputs import OutputSet

    with OutputSet() as outs:
        idx = write_report(args.dir, outputs=outs)
        outs.commit()
        print(f"report: {idx}")
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from testbed.studies.budget import reproduction_estimate
    from testbed.studies.reproduce import PAPERS, reproduce_va_raim_2015
    from testbed.outputs import OutputSet

    if args.paper not in PAPERS:
        raise ConfigError("command line", [f"unknown paper {args.paper!r}; expected one of {sorted(PAPERS)}"])
    ignored = [o for o, v in (("--scheduler", args.scheduler), ("--resume", args.resume),
                              ("--workers", args.workers != "auto")) if v]
    if args.paper != "va-raim-2015" and ignored:  # refused, not silently ignored
        raise ConfigError("command line", [f"{' and '.join(ignored)}: only va-raim-2015's campaigns take them; "
                                           f"{args.paper} runs in-process from the start"])
    if args.paper == "won-2013" and args.restart:
        raise ConfigError("command line", ["--restart: won-2013 stores no campaign to discard (it runs from the "
                                           "start every time); va-raim-2015 and dpe-vertical take it"])
    out = Path(args.out) if args.out else Path("campaigns") / f"reproduce-{args.paper}"
    budget_gate(lambda: reproduction_estimate(args.paper, args.full, workers=args.workers, out_dir=out,
                                              resume=args.resume), args.allow_large)
    kept = {"va-raim-2015": _chunks_kept("the same command with --resume completes the experiments",
                                         "the reports and reproduce.md are"),
            "dpe-vertical": _chunks_kept("the same command continues them",
                                         "the report, results.json and reproduce.md are")}.get(args.paper)
    with OutputSet() as outs:  # every report and summary into place together, at the end
        outs.folder(out, "--out", kept=kept)
        if args.paper == "dpe-vertical":
            from testbed.studies.reproduce_dpe import QUICK_TRIALS, reproduce_dpe_vertical

            idx = reproduce_dpe_vertical(out, trials=2000 if args.full else QUICK_TRIALS, progress=not args.quiet,
                                         restart=args.restart, outputs=outs)
        elif args.paper == "won-2013":
            from testbed.studies.reproduce_won import reproduce_won_2013

            idx = reproduce_won_2013(out, trials=200 if args.full else 50, progress=not args.quiet, outputs=outs)
        else:
            idx = reproduce_va_raim_2015(out, full=args.full, scheduler=args.scheduler, resume=args.resume,
                                         progress=not args.quiet, workers=args.workers,
                                         restart=args.restart, outputs=outs)
        outs.commit()
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
    add_allow_large(p)
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
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="va-raim-2015: complete the experiments stored in --out")
    again.add_argument("--restart", action="store_true", help="va-raim-2015, dpe-vertical: discard the campaigns "
                                                              "stored in --out and start over")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_allow_large(p)
    p.set_defaults(func=_cmd_reproduce)


def main(argv: list[str] | None = None) -> int:
    """``python -m testbed.campaign <campaign|report|reproduce> ...``: the same commands as ``testbed campaign`` ..."""
    parser = argparse.ArgumentParser(prog="python -m testbed.campaign")
    sub = parser.add_subparsers(dest="command", required=True)
    add_campaign_parsers(sub)
    args = parser.parse_args(argv)
    from testbed.heap import keep_freed_memory
    from testbed.threads import sleep_idle_threads

    keep_freed_memory()  # process settings, as testbed's own main applies them
    sleep_idle_threads()
    return exit_code(lambda: args.func(args))

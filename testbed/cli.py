"""The ``testbed`` command. Thin: it parses, calls library functions, prints."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from pathlib import Path

# Only the standard library at the top: the packages load inside main's Ctrl-C handler (a Ctrl-C in the
# first seconds of a command is exit 130 with a message too, not a traceback).


def _cmd_approaches(args: argparse.Namespace) -> int:
    from testbed.config import list_approaches, list_campaigns
    from testbed.resources import approaches_dir, campaigns_dir, shipped_from

    print(f"shipped approaches in {approaches_dir()} ({shipped_from()}):")
    for name, desc in list_approaches():
        print(f"  {name:22s} {desc}  [{name}.toml]")
    print("fly one with `testbed fly NAME`, or any approach file with `testbed fly PATH.toml`")
    print(f"shipped campaign specs in {campaigns_dir()}:")
    for name, desc in list_campaigns():
        print(f"  {name:22s} {desc}  [campaigns/{name}.toml]")
    print("run one with `testbed campaign NAME --out DIR` (`--trials N` for a quick look)")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from testbed.api import check_file

    bad = 0
    for f in args.files:
        problems = check_file(f)
        if problems:
            bad += 1
            print(f"{f}: {len(problems)} problem(s)")
            for p in problems:
                print(f"  {p}")
        else:
            print(f"{f}: ok")
    return 1 if bad else 0


def _cmd_fly(args: argparse.Namespace) -> int:
    import dataclasses

    from testbed.schema import ConfigError
    from testbed.api import (TRUTH_SUFFIXES, check_run_arguments, default_rrd_path, fly_approach,
                             print_flight_summary, print_run_summary, run_approach)
    from testbed.config import fault_from_option, load_approach, with_overrides
    from testbed.outputs import OutputSet
    from testbed.sim.budget import budget_gate, flight_estimate

    faults, problems = [], []
    for text in args.fault or []:  # every --fault's problems at once
        try:
            faults.append(fault_from_option(text))
        except ConfigError as err:
            problems += err.problems
    if problems:
        raise ConfigError("command line", problems)
    if args.flight_only and faults:
        raise ConfigError("command line", ["--fault: a flight without sensors has nothing to inject into "
                                           "(drop --flight-only)"])
    # --seed is unused without sensors, but not nonsense either
    check_run_arguments(seed=args.seed, gust_seed=args.gust_seed, **({} if args.flight_only else dict(
        block_s=args.block, port=args.port, linger_s=args.linger if args.live else 0.0)))
    ap = load_approach(args.approach)  # the default recording is named after it
    budget_gate(lambda: flight_estimate(with_overrides(ap, monitors=args.monitors, faults=faults or None),
                                        sensors=not args.flight_only), args.allow_large)
    with OutputSet() as outs:  # the recording and the truth: both or neither
        truth = outs.file(args.truth, "--truth", TRUTH_SUFFIXES) if args.truth else None
        staged_truth = outs.staged(truth) if truth else None
        if args.flight_only:
            result = fly_approach(ap, gust_seed=args.gust_seed, truth_path=staged_truth)
            outs.commit()
            print_flight_summary(result)
        else:
            rrd = None if args.no_record else Path(args.rrd) if args.rrd is not None else default_rrd_path(ap, args.seed)
            if rrd is not None:
                outs.file(rrd, "--rrd", (".rrd",))

            def landed(result):  # the recording is complete (and the truth written): all into place, then say so
                outs.commit()
                print_run_summary(dataclasses.replace(result, rrd_path=rrd))

            if args.live:
                print(f"live: serving on {args.bind}:{args.port} once the checks pass; connect with: rerun --connect "
                      f"rerun+http://{'127.0.0.1' if args.bind in ('0.0.0.0', '127.0.0.1') else args.bind}:{args.port}/proxy",
                      flush=True)
            run_approach(ap, seed=args.seed, rrd_path=rrd, live=args.live,
                         bind_ip=args.bind, port=args.port, block_s=args.block, monitors=args.monitors, faults=faults,
                         gust_seed=args.gust_seed, truth_path=truth,
                         linger_s=args.linger if args.live else 0.0, on_landed=landed, outputs=outs,
                         progress=lambda text: print(text, file=sys.stderr, flush=True))
        if args.truth:
            print(f"truth written to {args.truth}")
    return 0


def _cmd_export_rinex(args: argparse.Namespace) -> int:
    from testbed.api import check_run_arguments, export_rinex
    from testbed.config import load_approach
    from testbed.outputs import OutputSet

    check_run_arguments(seed=args.seed, gust_seed=args.gust_seed)
    ap = load_approach(args.approach)
    with OutputSet() as outs:  # the observations, the navigation file and the truth: all three or none
        folder = outs.folder(args.dir, "DIR", entries=tuple(f"{ap.name}{s}" for s in (".obs", ".nav", ".truth.csv")),
                             complete=True)
        obs, nav = export_rinex(ap, outs.staged_folder(folder), seed=args.seed, gust_seed=args.gust_seed)
        outs.commit()
        obs, nav = args.dir / outs.final(obs).name, args.dir / outs.final(nav).name
        print(f"wrote {obs}\nwrote {nav}")
        from testbed.sensors.gnss.rinex_text import read_lines

        systems = ",".join(ln[0] for _, ln in read_lines(obs, "observation", "O").header("SYS / # / OBS TYPES")
                           if ln[0] != " ")
        print(f"check with RTKLIB: rnx2rtkp -p 0 -sys {systems} -o out.pos {obs} {nav}  (iono/tropo models off: see "
              f"docs/guide/rinex.md)")
    return 0


def _cmd_monitor(args: argparse.Namespace) -> int:
    from testbed.outputs import OutputSet
    from testbed.replay.run import monitor_rinex, print_summary

    with OutputSet() as outs:  # --out's files and --rrd: all or none
        run = monitor_rinex(args.obs, args.nav, config=args.config, out_dir=args.out, rrd_path=args.rrd,
                            reference=args.reference, table_format=args.format, monitors=tuple(args.monitors),
                            outputs=outs)
        outs.commit()
        print_summary(run)
    return 0


def _cmd_observability(args: argparse.Namespace) -> int:
    from testbed.api import check_run_arguments
    from testbed.navigation.observability import format_tables

    check_run_arguments(seed=args.seed)
    print(format_tables(seed=args.seed))
    return 0


def _cmd_calibrate_dpe(args: argparse.Namespace) -> int:
    from testbed.schema import ConfigError
    from testbed.api import check_run_arguments
    from testbed.studies.budget import calibration_estimate
    from testbed.studies.dpe_calibration import SET_C_TRAJECTORIES, calibrate_dpe, write_record
    from testbed.sim.budget import budget_gate
    from testbed.config import load_approach
    from testbed.outputs import OutputSet

    check_run_arguments(seed=args.seed)
    out = Path(args.out)
    if out.exists() and out.is_dir():
        raise ConfigError(out, ["--out: expected a file path for the calibration record, got a folder"])
    if out.parent.exists() and not out.parent.is_dir():
        raise ConfigError(out, [f"--out: {out.parent} is a file, not a folder"])
    if not out.parent.is_dir():
        raise ConfigError(out, [f"--out: the folder {out.parent} does not exist"])
    if args.resume and args.work is None:
        raise ConfigError("command line", ["--resume: expected --work DIR too (the chunks a run stored are resumed "
                                           "from its work folder; without one nothing is stored)"])
    if args.method == "importance":
        given = [f for f, v in (("--work", args.work), ("--resume", args.resume), ("--scheduler", args.scheduler)) if v]
        if given:
            raise ConfigError("command line", [f"{', '.join(given)}: read only with --method tail (the importance-"
                                               "sampled calibration runs its chunks on --workers processes)"])
    elif args.workers != 1:
        raise ConfigError("command line", ["--workers: read only with --method importance (the tail calibration "
                                           "runs its chunks here or on --scheduler)"])
    trajectories = SET_C_TRAJECTORIES if args.trajectories == ["set-c"] else tuple(args.trajectories or ())
    for t in (args.approach, *trajectories):
        load_approach(t)  # every named approach reads before any work (exit 2 naming the file and key)
    budget_gate(lambda: calibration_estimate(args.approach, args.sorties, trajectories, args.method, args.workers),
                args.allow_large)
    if args.method == "importance":
        return _calibrate_dpe_measured(args, out, trajectories)
    with OutputSet() as outs:
        outs.file(out, "--out")
        if args.work is not None:
            outs.folder(args.work, "--work", kept="the chunks finished so far are kept there (the same command "
                                                  "with --resume continues)")
        with _as_config_error(args.approach):  # too few epochs for the tail levels, and the like
            rec = calibrate_dpe(args.approach, sorties=args.sorties, p_hmi=args.p_hmi, seed=args.seed,
                                trajectories=trajectories, chunk=args.chunk, work=args.work, resume=args.resume,
                                scheduler=args.scheduler, progress=lambda m: print(m, flush=True))
        write_record(rec, outs.staged(out))
        outs.commit()
        v = rec["validation"]
        print(f"K = {rec['k']:.3f} (sigma_z {rec['sigma_z']:.3f}, b_z {rec['b_z']:+.3f}, {rec['k_from']}; "
              f"{rec['n_calibration']} calibration epochs, deepest tail level {rec['deepest_level']:.1e}) for "
              f"P_HMI = {rec['p_hmi']:g} per epoch")
        print(f"held-out: {v['epochs']} epochs, tails {'hold' if v['tails_hold'] else 'DO NOT hold'} at "
              f"{v['levels_checked']} levels (worst observed/bound {v['worst_ratio']:.2f}), |e| > VPL {v['exceedances']} "
              f"(allowed {v['allowed']}): {'PASSED' if v['passed'] else 'FAILED'}")
        print(f"wrote {out}; use it with [dpe] k_factor = \"{out}\"")
    return 0 if v["passed"] else 1


@contextlib.contextmanager
def _as_config_error(approach):
    """A calibration's ValueError (bad arguments, too few epochs) as a ConfigError naming the approach: exit 2."""
    from testbed.schema import ConfigError

    try:
        yield
    except ConfigError:
        raise
    except ValueError as exc:
        raise ConfigError(Path(approach), [f"calibrate-dpe: {exc}"]) from None


def _calibrate_dpe_measured(args: argparse.Namespace, out: Path, trajectories: tuple[str, ...]) -> int:
    """`testbed calibrate-dpe --method importance`: K at a measured tail (docs/design/dpe.md §6.8)."""
    from testbed.outputs import OutputSet
    from testbed.studies.dpe_calibration import write_record
    from testbed.studies.dpe_measured import calibrate_dpe_measured

    with OutputSet() as outs:
        outs.file(out, "--out")
        with _as_config_error(args.approach):
            rec = calibrate_dpe_measured(args.approach, sorties=args.sorties, p_hmi=args.p_hmi, seed=args.seed,
                                         trajectories=trajectories, chunk=args.chunk, workers=args.workers,
                                         progress=lambda m: print(m, flush=True))
        write_record(rec, outs.staged(out))
        outs.commit()
    v = rec["validation"]
    if rec["k"] is None:
        print(f"no K: the tail is not measured at P_HMI = {rec['p_hmi']:g} in "
              + "; ".join(f"{n} (deepest settled upper bound {f['deepest_settled_upper']:.2g})"
                          for n, f in (rec["strata"] | {"all strata": rec["overall"]}).items() if f["k"] is None)
              + f": more sorties (--sorties, now {args.sorties})")
    else:
        lo, hi = rec["interval"]
        print(f"K = {rec['k']:.3f} ({rec['k_from']}): P(|e| > K*sigma + |m|) measured at {lo:.3g}-{hi:.3g} per epoch "
              f"(95 %), {rec['trials']} importance-sampled calibration epochs, P_HMI = {rec['p_hmi']:g}")
        print("held-out: " + "; ".join(f"{n} {r['estimate']:.3g} [{r['interval'][0]:.3g}, {r['interval'][1]:.3g}]"
                                       if r.get("settled") else f"{n} not settled"
                                       for n, r in v["rates"].items())
              + f": {'PASSED' if v['passed'] else 'FAILED'}")
    print(f"wrote {out}" + (f"; use it with [monitor.dpe] k_factor = \"{out}\"" if v["passed"] else
                            " (a record whose held-out check failed is refused as a k_factor)"))
    return 0 if v["passed"] else 1


def build_parser() -> argparse.ArgumentParser:
    from testbed.monitors import monitor_names
    from testbed.schema import arg_in_range as _in_range
    from testbed.sim.budget import add_allow_large

    p = argparse.ArgumentParser(prog="testbed", description="GNSS/vision integrity testbed for approaches into ZUNZ")
    sub = p.add_subparsers(dest="command", required=True)

    f = sub.add_parser("fly", help="fly an approach and print a summary")
    f.add_argument("approach", nargs="?", default="zunz-rwy05-final",
                   help="shipped approach name or path to an approach TOML (default: zunz-rwy05-final)")
    f.add_argument("--truth", type=Path, help="write the full-rate truth trajectory (.npz, .csv or .parquet)")
    f.add_argument("--gust-seed", type=int, help="override the approach's gust seed")
    f.add_argument("--seed", type=int, default=0, help="seed of every sensor random draw (default 0)")
    f.add_argument("--rrd", type=Path, help="recording path (default runs/<approach>-seed<seed>.rrd)")
    f.add_argument("--no-record", action="store_true", help="write no recording")
    f.add_argument("--live", action="store_true", help="also serve the stream to a Rerun viewer (gRPC)")
    f.add_argument("--bind", default="127.0.0.1", help="live server address (default loopback 127.0.0.1)")
    f.add_argument("--port", type=int, default=9876, help="live server port (default 9876)")
    f.add_argument("--linger", type=float, default=60.0, help="with --live: seconds to keep serving after landing (default %(default)g)")
    f.add_argument("--block", type=float, default=5.0,
                   help="simulated seconds between live updates (default 5: ~0.1 s of wall time)")
    f.add_argument("--monitors", nargs="+", choices=monitor_names(),
                   help="override the approach's monitors")
    f.add_argument("--fault", action="append", metavar="KIND:KEY=VALUE,...",
                   help="add a fault to the approach's schedule, the keys of a [[faults]] table, e.g. "
                        "gps_step:prn=random,bias_m=60,onset_s=100 (repeatable)")
    f.add_argument("--flight-only", action="store_true", help="fly without sensors, monitors or recording")
    add_allow_large(f)
    f.set_defaults(func=_cmd_fly)

    a = sub.add_parser("approaches", help="list the shipped approaches and campaign specs, and where they are read from")
    a.set_defaults(func=_cmd_approaches)

    r = sub.add_parser("export-rinex", help="fly an approach and write RINEX 3.04 observation + navigation files")
    r.add_argument("approach", help="shipped approach name or path to an approach TOML")
    r.add_argument("dir", type=Path, help="output folder")
    r.add_argument("--seed", type=int, default=0, help="sensor seed (same as testbed fly --seed)")
    r.add_argument("--gust-seed", type=int, help="override the approach's gust seed")
    r.set_defaults(func=_cmd_export_rinex)

    m = sub.add_parser("monitor", help="run GPS RAIM (FDE, protection levels) over a RINEX observation file")
    m.add_argument("obs", type=Path, help="RINEX 2.xx/3.xx observation file (.gz, .Z and Hatanaka .crx too)")
    m.add_argument("nav", type=Path, help="RINEX 2.xx/3.xx GPS (or mixed) navigation file of the same day")
    m.add_argument("--config", type=Path, help="TOML with [rinex] (corrections, error model) and [integrity] tables")
    m.add_argument("--out", type=Path, help="folder for the per-epoch table, summary.json and (with --reference) "
                                            "Stanford diagrams")
    m.add_argument("--rrd", type=Path, help="write a Rerun recording (the flight's layout)")
    m.add_argument("--reference", type=Path, help="reference trajectory (t_gps, pos_ecef_x/y/z columns; .csv, "
                                                  ".parquet, .npz), or 'marker': the header's APPROX POSITION XYZ "
                                                  "as a static one (a surveyed station); gives errors, MI/HMI and "
                                                  "Stanford diagrams")
    m.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="per-epoch table format")
    m.add_argument("--monitors", nargs="+", default=["gps_raim"], metavar="MONITOR",
                   help="the monitors to run, each reading GNSS alone (default gps_raim; e.g. gps_raim araim); "
                        "each gets its own per-epoch table with its own columns")
    m.set_defaults(func=_cmd_monitor)

    from testbed.campaign_cli import add_campaign_parsers

    add_campaign_parsers(sub)

    o = sub.add_parser("observability", help="the Won et al. paper's observability tables: its simplified model and "
                                             "the consistent one along a racetrack, an RF turn and the straight "
                                             "final (~15 s)")
    o.add_argument("--seed", type=int, default=0, help="seed of the random lines of sight, features and h_V")
    o.set_defaults(func=_cmd_observability)

    k = sub.add_parser("calibrate-dpe", help="fit the dpe monitor's K on fault-free sorties and validate it on "
                                             "held-out ones (writes a record [dpe] k_factor can name)")
    k.add_argument("approach", nargs="?", default="zunz-rwy05-dpe", help="approach with the dpe settings to calibrate (default: %(default)s)")
    k.add_argument("--out", required=True, type=Path, help="the calibration record to write (.json)")
    k.add_argument("--sorties", type=_in_range(int, 6, 100_000), default=60,
                   help="sorties per set (calibration and validation; ~140 epochs and ~0.6 s each on 2 cores; "
                        "6-100000, default %(default)s)")
    k.add_argument("--p-hmi", type=_in_range(float, 1e-12, 0.01), default=1e-7,
                   help="per-epoch HMI probability K is for (1e-12-0.01, default %(default)g)")
    k.add_argument("--seed", type=int, default=0, help="seed of the sorties' draws (default %(default)s)")
    k.add_argument("--trajectories", nargs="+", metavar="APPROACH",
                   help="approaches whose trajectories the sorties fly, with APPROACH's DPE and correlator settings "
                        "(default: its own; set-c: zunz-rwy05-final zunz-rwy05-rnp va-raim-2015, docs/design/dpe.md §6.4)")
    k.add_argument("--chunk", type=_in_range(int, 1, 100_000), default=25, help="sorties per chunk (a unit of work; default %(default)s)")
    k.add_argument("--work", type=Path, help="folder keeping every chunk as it finishes (a killed run resumes)")
    k.add_argument("--resume", action="store_true", help="continue the calibration stored in --work")
    k.add_argument("--scheduler", help="Dask scheduler address: chunks run on its workers")
    k.add_argument("--method", choices=("tail", "importance"), default="tail",
                   help="tail: a Gaussian fitted to the measured tails, extrapolated to --p-hmi; importance: the tail "
                        "measured at --p-hmi by importance sampling of the SIS and thermal draws (docs/design/dpe.md "
                        "§6.8; at 150 sorties a set five of six strata were measured); default %(default)s")
    k.add_argument("--workers", type=_in_range(int, 1, 257), default=1,
                   help="--method importance: processes running the chunks (default %(default)s)")
    add_allow_large(k)
    k.set_defaults(func=_cmd_calibrate_dpe)

    c = sub.add_parser("check", help="validate approach (or campaign) files and explain every problem")
    c.add_argument("files", nargs="+", type=Path)
    c.set_defaults(func=_cmd_check)
    return p


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:  # while the packages load (exit_code handles it once a command runs)
        print("interrupted before any work", file=sys.stderr)
        return 130


def _main(argv: list[str] | None) -> int:
    from testbed.heap import keep_freed_memory
    from testbed.schema import exit_code
    from testbed.threads import sleep_idle_threads

    args = build_parser().parse_args(argv)
    keep_freed_memory()  # process settings: the command applies them, library calls never do (testbed.heap,
    sleep_idle_threads()  # testbed.threads)
    try:
        return exit_code(lambda: args.func(args))
    except BrokenPipeError:  # output piped into `head` and the like: stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # the exit-time flush goes nowhere
        return 0


if __name__ == "__main__":
    sys.exit(main())

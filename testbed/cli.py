"""The ``testbed`` command. Thin: it parses, calls library functions, prints."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from testbed.schema import ConfigError


def _cmd_approaches(args: argparse.Namespace) -> int:
    from testbed.config import list_approaches

    for name, desc in list_approaches():
        print(f"{name:22s} {desc}")
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
    from testbed.api import fly_approach, print_flight_summary

    result = fly_approach(args.approach, gust_seed=args.gust_seed, truth_path=args.truth)
    print_flight_summary(result)
    if args.truth:
        print(f"truth written to {args.truth}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="testbed", description="GNSS/vision integrity testbed for approaches into ZUNZ")
    sub = p.add_subparsers(dest="command", required=True)

    f = sub.add_parser("fly", help="fly an approach and print a summary")
    f.add_argument("approach", nargs="?", default="zunz-rwy05-final",
                   help="shipped approach name or path to an approach TOML (default: zunz-rwy05-final)")
    f.add_argument("--truth", type=Path, help="write the full-rate truth trajectory (.npz, .csv or .parquet)")
    f.add_argument("--gust-seed", type=int, help="override the approach's gust seed")
    f.set_defaults(func=_cmd_fly)

    a = sub.add_parser("approaches", help="list the shipped approaches")
    a.set_defaults(func=_cmd_approaches)

    c = sub.add_parser("check", help="validate approach (or campaign) files and explain every problem")
    c.add_argument("files", nargs="+", type=Path)
    c.set_defaults(func=_cmd_check)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

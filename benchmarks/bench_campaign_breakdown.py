"""Benchmark: where a reproduction experiment's time goes, and the floor its compiled kernels set.

Usage::

    python benchmarks/bench_campaign_breakdown.py [--experiment where-vision-pays] [--sorties 300]

Runs chunk 0 (``--sorties`` sorties) of every setting of one experiment of
``testbed reproduce va-raim-2015`` as the driver does (one chunk row, block-major, shared
draws on), on one thread under :mod:`cProfile`, and splits its time into: the compiled
kernels (:mod:`testbed.integrity.kernels`, their own time), the monitors' numpy glue (the
rest of the monitors' time), the draws, the tables, and the rest. Prints milliseconds per
block-cell (100 sorties of one setting) and, for each part, the experiment's ``--full``
projection on two worker processes if that part were all that remained (the kernels' share is
the floor that only faster kernels lower). The profiler adds a few per cent to the Python
parts; the shares, not the absolute times, are the figures to read
(``benchmarks/bench_campaign.py`` times the projection itself).
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import pstats

#: (label, functions whose cumulative time the part is) in the order they are subtracted
PARTS = (
    ("draws", ("draw_block",)),
    ("tables", ("_shared_tables", "_paired_columns", "_chunk_tables")),
    ("monitors", ("monitor_block",)),
)


def main() -> None:
    from testbed.campaign.cli_commands import _positive_int  # argparse prints its message and exits 2
    from testbed.campaign.reproduce import experiments

    ap = argparse.ArgumentParser()
    ap.add_argument("--experiment", default="where-vision-pays", choices=sorted(experiments(200)))
    ap.add_argument("--sorties", type=_positive_int, default=300,
                    help="sorties per setting (chunk 0; a multiple of the reproduction's 100-sortie blocks)")
    args = ap.parse_args()
    if args.sorties % 100:
        ap.error(f"--sorties: expected a multiple of 100, got {args.sorties}")

    from testbed import memo
    from testbed.campaign.reproduce import FULL_TRIALS, loaded_experiments
    from testbed.campaign.runner import cell_context, run_chunk, run_chunk_row
    from testbed.campaign.spec import expand_cells
    from testbed.heap import keep_freed_memory

    keep_freed_memory()  # as the campaign driver runs
    le = loaded_experiments(2 * args.sorties)[args.experiment]
    le = dataclasses.replace(le, spec=le.spec.model_copy(update={"chunk_trials": args.sorties}))
    cells = expand_cells(le)
    for c in cells:
        cell_context(c, le.spec)
    run_chunk(le, 0, 1)  # compile and warm on blocks the timed chunk does not draw
    memo.clear()
    prof = cProfile.Profile()
    prof.enable()
    run_chunk_row(le, 0, list(range(len(cells))), threads=1)
    prof.disable()
    stats = pstats.Stats(prof).stats  # {(file, line, name): (cc, nc, tottime, cumtime, callers)}
    total = max(v[3] for v in stats.values())
    cum = {}
    for (_, _, fn), v in stats.items():
        cum[fn] = cum.get(fn, 0.0) + v[3]
    kernels = sum(v[2] for (f, _, _), v in stats.items() if "/integrity/kernels/" in f.replace("\\", "/"))
    parts = {label: sum(cum.get(fn, 0.0) for fn in fns) for label, fns in PARTS}
    parts["monitors"] -= kernels  # the monitors' own time beside their compiled kernels: the glue
    shares = {"compiled kernels": kernels, "monitor glue": parts["monitors"], "draws": parts["draws"],
              "tables": parts["tables"]}
    shares["rest"] = total - sum(shares.values())
    block_cells = len(cells) * args.sorties / le.spec.block_trials
    full_s = total * FULL_TRIALS / args.sorties / 2  # two worker processes: two chunk rows side by side
    print(f"{args.experiment}: {len(cells)} settings x {args.sorties} sorties, one thread under cProfile: "
          f"{total:.2f} s, {total / block_cells * 1e3:.1f} ms per block-cell")
    for label, s in shares.items():
        print(f"  {label:17s} {s / block_cells * 1e3:6.2f} ms per block-cell ({100 * s / total:4.1f} %) -> "
              f"--full {full_s * s / total / 60:5.1f} min on two workers if it were all that remained")
    floor = total - shares["monitor glue"] - shares["rest"]  # what fusing the glue into the kernels would leave
    print(f"  kernels + draws + tables together: {100 * floor / total:4.1f} % -> --full {full_s * floor / total / 60:5.1f} "
          "min: the floor while the kernels, draws and tables stay as they are")


if __name__ == "__main__":
    main()

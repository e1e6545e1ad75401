"""Benchmark: campaign throughput in sortie-epochs per second (GPS RAIM + VA-RAIM).

Usage::

    python benchmarks/bench_campaign.py [--trials 2000] [--block 100] [--chunk 1000] [--per-experiment 1000] [--repeats 3]

Runs a fault-free + GPS-step campaign on the seed-000 sortie (approach
``va-raim-2015``, 61 epochs at 1 Hz, 720 dpi, DE 1 px) in-process, into a
temporary folder, with a fixed start and with consecutive sorties, and prints:
wall time, trials/s, sortie-epochs/s (after the one-off flight and geometry,
which are timed separately, and an untimed warm-up run of each; the median of
``--repeats`` alternating runs) and their ratio. Then the projected time of
``testbed reproduce va-raim-2015 --full`` (1e5 sorties x 60 s = ~6e6 epochs per
setting): chunk 0 (``--per-experiment`` sorties) of every setting of every
experiment, run as the driver runs it (one chunk row, block-major:
:func:`testbed.campaign.runner.run_chunk_row`) with the cells' shared draws
(:mod:`testbed.memo`) and again without them, and cell by cell (each cell's whole
chunk in turn), side by side; each experiment's geometry is paid once. The shared-draws
run is repeated (``--repeats``, interleaved with the others): the projection is the sum of
the experiments' medians, with the range their fastest and slowest runs give (one run
of an experiment moves by up to ~15 % on this shared machine).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

SPEC = """
name = "bench"
approaches = ["va-raim-2015"]
monitors = ["gps_raim", "va_raim"]
trials = {trials}
block_trials = {block}
chunk_trials = {chunk}
base_seed = 1
per_epoch_trials = 20

[[faults]]
kind = "gps_step"
magnitudes = [0.0, 50.0]
onset_s = 20.0

[sweep]
camera_dpi = [720.0]
{sorties}"""

CONSECUTIVE = """
[sorties]
start = "consecutive"
sortie_s = 60.0
"""


def main() -> None:
    from testbed.campaign.cli_commands import _positive_int  # argparse prints its message and exits 2

    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=_positive_int, default=2000, help="trials per cell (2 cells)")
    ap.add_argument("--block", type=_positive_int, default=100)
    ap.add_argument("--chunk", type=_positive_int, default=1000)
    ap.add_argument("--per-experiment", type=_positive_int, default=1000,
                    help="sorties timed per reproduction experiment (one chunk of its first setting; a multiple of 100)")
    ap.add_argument("--repeats", type=_positive_int, default=3,
                    help="timed runs with shared draws per experiment (the projection is their median)")
    args = ap.parse_args()
    if args.chunk % args.block or args.per_experiment % 100:  # the specs' own rule, said before any work
        ap.error(f"--chunk ({args.chunk}) must be a multiple of --block ({args.block}), and --per-experiment "
                 f"({args.per_experiment}) of the reproduction's 100-sortie blocks")

    from testbed.campaign.reproduce import FULL_TRIALS, loaded_experiments
    from testbed.campaign.runner import cell_context, run_campaign, run_chunk, run_chunk_row
    from testbed.campaign.spec import expand_cells, load_spec
    from testbed import memo
    from testbed.integrity.batching import available_cores

    cores = available_cores()
    with tempfile.TemporaryDirectory() as tmp:
        kinds = {"fixed start": "", "consecutive 60 s sorties": CONSECUTIVE}
        loaded, setup_s = {}, {}
        for i, (kind, extra) in enumerate(kinds.items()):
            spec = Path(tmp) / f"bench{i}.toml"
            spec.write_text(SPEC.format(trials=args.trials, block=args.block, chunk=args.chunk, sorties=extra))
            loaded[kind] = load_spec(spec)
            t0 = time.perf_counter()
            for c in expand_cells(loaded[kind]):
                cell_context(c, loaded[kind].spec)  # flight (JSBSim) + geometry (every sky window), once
            setup_s[kind] = time.perf_counter() - t0
            run_campaign(loaded[kind], Path(tmp) / f"warm{i}", progress=False)  # kernels, tables: not timed
        walls = {kind: [] for kind in kinds}
        for r in range(args.repeats):  # alternating, so a slow spell does not fall on one kind
            for i, kind in enumerate(kinds):
                res = run_campaign(loaded[kind], Path(tmp) / f"out{i}-{r}", progress=False)
                walls[kind].append(res.wall_s)
        for kind in kinds:
            wall = float(np.median(walls[kind]))
            print(f"{kind}: flight + geometry (once): {setup_s[kind]:.2f} s; campaign end to end (store included), "
                  f"{res.trials} sorties, GPS RAIM + VA-RAIM: {wall:.2f} s (median of {len(walls[kind])}), "
                  f"{res.trials / wall:,.0f} sorties/s, {res.epochs_per_s * res.wall_s / wall:,.0f} sortie-epochs/s "
                  f"(one process, {cores} cores: draw blocks on threads)")
    ratio = float(np.median(walls["consecutive 60 s sorties"])) / float(np.median(walls["fixed start"]))
    print(f"start times spread / fixed, after the one-off geometry: {ratio:.2f}x")

    # the --full reproduction: chunk 0 of every setting, as the driver runs it (one chunk row, block-major:
    # each block through every cell in turn), with the cells' shared draws (testbed.memo) and without
    # them; and cell by cell (each cell's whole chunk in turn, the order before run_chunk_row), shared
    print(f"--full reproduction ({FULL_TRIALS} sorties x 61 epochs per setting), chunk 0 ({args.per_experiment} "
          "sorties) of every setting timed as one chunk row (block-major), shared draws on / off, and cell by cell:")
    modes = (("on", memo.DEFAULT_LIMIT_BYTES, True), ("off", 0, True), ("cell by cell", memo.DEFAULT_LIMIT_BYTES, False))
    total = {m: 0.0 for m, _, _ in modes}
    low = high = 0.0
    n_settings = 0
    for name, le in loaded_experiments(2 * args.per_experiment).items():
        le = dataclasses.replace(le, spec=le.spec.model_copy(update={"chunk_trials": args.per_experiment}))
        cells = expand_cells(le)
        t0 = time.perf_counter()
        for c in cells:
            cell_context(c, le.spec)
        setup_s = time.perf_counter() - t0
        run_chunk(le, 0, 1)  # warm (kernels, chi-square tables) on blocks the timed chunk does not draw
        runs = {m: [] for m, _, _ in modes}
        for mode, cap, row in _schedule(modes, args.repeats):
            memo.clear()
            with memo.limit(cap):
                t0 = time.perf_counter()
                if row:
                    tables = list(run_chunk_row(le, 0, list(range(len(cells)))).values())
                else:
                    tables = [run_chunk(le, i, 0) for i in range(len(cells))]
                dt = time.perf_counter() - t0
            epochs = args.per_experiment * len(cells) * int(tables[0]["trials"].column("epochs")[0].as_py())
            runs[mode].append(epochs / dt)
        rates = {m: float(np.median(r)) for m, r in runs.items()}
        proj = {m: FULL_TRIALS * 61 * len(cells) / np.array(r) + setup_s for m, r in runs.items()}
        for m in total:
            total[m] += float(np.median(proj[m]))
        low += float(proj["on"].min())
        high += float(proj["on"].max())
        n_settings += len(cells)
        full = float(np.median(proj["on"]))
        print(f"  {name:26s} {'+'.join(le.spec.monitors):16s} {len(cells):3d} settings: "
              f"{rates['on']:9,.0f} sortie-epochs/s shared ({rates['on'] / rates['off']:.2f}x unshared "
              f"{rates['off']:,.0f}; {rates['on'] / rates['cell by cell']:.2f}x cell by cell "
              f"{rates['cell by cell']:,.0f}) -> {full / 60:6.1f} min (median of {len(runs['on'])}: "
              f"{proj['on'].min() / 60:.1f}-{proj['on'].max() / 60:.1f}; geometry {setup_s:.1f} s once)")
    memo.clear()
    print(f"  all {n_settings} settings: {total['on'] / 3600:.2f} h on this machine ({cores} cores, one process; "
          f"the sum of the experiments' medians; {low / 3600:.2f}-{high / 3600:.2f} h from their fastest and "
          f"slowest runs); {total['off'] / 3600:.2f} h without shared draws; {total['cell by cell'] / 3600:.2f} h "
          "cell by cell")


def _schedule(modes: tuple, repeats: int) -> list:
    """The timed runs of one experiment: the shared-draws run ``repeats`` times, the others once, interleaved
    (on, off, on, cell by cell, on, ...) so a slow spell of the shared machine does not fall on one mode."""
    on, rest = modes[0], list(modes[1:])
    order = [on]
    for i in range(1, repeats):
        if rest:
            order.append(rest.pop(0))
        order.append(on)
    return order + rest


if __name__ == "__main__":
    main()

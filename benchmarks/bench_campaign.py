"""Benchmark: campaign throughput in sortie-epochs per second (GPS RAIM + VA-RAIM).

Usage::

    python benchmarks/bench_campaign.py [--trials 2000] [--block 100] [--chunk 1000] [--per-experiment 1000] [--repeats 3]

Runs a fault-free + GPS-step campaign on the VA-RAIM paper's sortie (approach
``va-raim-2015``, 61 epochs at 1 Hz, 720 dpi, DE 1 px) in-process, into a
temporary folder, with a fixed start and with consecutive sorties, and prints:
wall time, trials/s, sortie-epochs/s (after the one-off flight and geometry,
which are timed separately, and an untimed warm-up run of each; the median of
``--repeats`` alternating runs) and their ratio. Then the projected time of
``testbed reproduce va-raim-2015 --full`` (1e5 sorties x 60 s = ~6e6 epochs per
setting): one chunk (``--per-experiment`` sorties) of every setting of every
experiment on each of one worker process per core, side by side, as the driver runs a
``--full`` reproduction (``--workers auto``: a chunk row per worker, block-major,
:func:`testbed.campaign.runner.run_chunk_row`), with the cells' shared draws
(:mod:`testbed.memo`) and again without them, and cell by cell (each cell's whole
chunk in turn); each experiment's geometry is paid once (by each worker, side by side).
Beside it, the same rows one after the other in this process, each row's blocks on
threads (how the driver ran them before ``--workers``). The shared-draws runs on
workers and on threads are repeated (``--repeats``, interleaved with the others): the
projection is the sum of the experiments' medians, with the range their fastest and
slowest runs give (one run of an experiment moves by up to ~15 % on this shared machine).
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
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
    from testbed.heap import keep_freed_memory

    keep_freed_memory()  # the process settings `testbed campaign` applies (run_campaign, a library call, does not)
    from testbed.campaign_cli import _positive_int  # argparse prints its message and exits 2

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

    from testbed.studies.reproduce import FULL_TRIALS, experiments
    from testbed.campaign.context import cell_context
    from testbed.campaign.runner import run_campaign
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

    # the --full reproduction as the driver runs it (--workers auto): chunk rows on one worker process per core,
    # each row block-major (each block through every cell in turn), with the cells' shared draws (testbed.memo)
    # and without them; and cell by cell (each cell's whole chunk in turn, the order before run_chunk_row), shared
    print(f"--full reproduction ({FULL_TRIALS} sorties x 61 epochs per setting): chunks 0-{cores - 1} "
          f"({args.per_experiment} sorties each) of every setting, one chunk row on each of {cores} worker "
          "processes side by side (as the driver runs a --full reproduction), shared draws on / off, and cell by cell:")
    modes = (("on", memo.DEFAULT_LIMIT_BYTES, True), ("threads", memo.DEFAULT_LIMIT_BYTES, True),
             ("off", 0, True), ("cell by cell", memo.DEFAULT_LIMIT_BYTES, False))
    total = {m: 0.0 for m, _, _ in modes}
    low = high = 0.0
    n_settings = 0
    for name in experiments(200):
        with ProcessPoolExecutor(cores, mp_context=multiprocessing.get_context("spawn"), initializer=_worker_setup,
                                 initargs=(name, args.per_experiment, cores)) as pool:
            n_cells, setup_s = max(pool.map(_setup_of, range(cores)))  # the workers' geometry, side by side
            _worker_setup(name, args.per_experiment, cores)  # and here, for the same rows on threads
            runs = {m: [] for m, _, _ in modes}
            for mode, cap, row in _schedule(modes, args.repeats):
                t0 = time.perf_counter()
                if mode == "threads":  # the rows one after the other in this process, each one's blocks on threads
                    epochs = sum(_timed_row(k, cap, row, threads=cores) for k in range(cores))
                else:
                    epochs = sum(pool.map(_timed_row, range(cores), [cap] * cores, [row] * cores))
                runs[mode].append(epochs / (time.perf_counter() - t0))
            peaks: dict[int, float] = {}
            for _ in range(20):  # ask until every worker has answered (a quick task can go to the same one twice)
                peaks.update(pool.map(_peak_rss_gb, range(cores)))
                if len(peaks) >= cores:
                    break
            peak_gb = max(peaks.values())
            _WORKER.clear()
        rates = {m: float(np.median(r)) for m, r in runs.items()}
        proj = {m: FULL_TRIALS * 61 * n_cells / np.array(r) + setup_s for m, r in runs.items()}
        for m in total:
            total[m] += float(np.median(proj[m]))
        low += float(proj["on"].min())
        high += float(proj["on"].max())
        n_settings += n_cells
        full = float(np.median(proj["on"]))
        print(f"  {name:26s} {n_cells:3d} settings: "
              f"{rates['on']:9,.0f} sortie-epochs/s shared ({rates['on'] / rates['threads']:.2f}x the same rows on "
              f"threads in one process {rates['threads']:,.0f}; {rates['on'] / rates['off']:.2f}x unshared "
              f"{rates['off']:,.0f}; {rates['on'] / rates['cell by cell']:.2f}x cell by cell "
              f"{rates['cell by cell']:,.0f}) -> {full / 60:6.1f} min (median of {len(runs['on'])}: "
              f"{proj['on'].min() / 60:.1f}-{proj['on'].max() / 60:.1f}; geometry {setup_s:.1f} s once; a worker's "
              f"peak resident memory {peak_gb:.2f} GB)")
    print(f"  all {n_settings} settings: {total['on'] / 3600:.2f} h on this machine ({cores} worker processes; "
          f"the sum of the experiments' medians; {low / 3600:.2f}-{high / 3600:.2f} h from their fastest and "
          f"slowest runs); {total['threads'] / 3600:.2f} h on threads in one process; {total['off'] / 3600:.2f} h "
          f"without shared draws; {total['cell by cell'] / 3600:.2f} h cell by cell")


#: a bench worker's experiment: (loaded spec with chunks of --per-experiment sorties, cells, geometry seconds)
_WORKER: dict = {}


def _worker_setup(name: str, per_experiment: int, cores: int) -> None:
    """Pool initializer: experiment ``name`` with one chunk per worker and one more, which warms the kernels and
    tables here (not timed, on blocks no timed row draws); the cells' flight and geometry timed."""
    from testbed import memo
    from testbed.studies.reproduce import loaded_experiments
    from testbed.campaign.context import cell_context
    from testbed.campaign.runner import run_chunk
    from testbed.campaign.spec import expand_cells
    from testbed.heap import keep_freed_memory

    keep_freed_memory()  # as a campaign worker runs
    le = loaded_experiments((cores + 1) * per_experiment)[name]
    le = dataclasses.replace(le, spec=le.spec.model_copy(update={"chunk_trials": per_experiment}))
    cells = expand_cells(le)
    t0 = time.perf_counter()
    for c in cells:
        cell_context(c, le.spec)
    _WORKER.update(loaded=le, cells=len(cells), setup_s=time.perf_counter() - t0)
    run_chunk(le, 0, cores, threads=1)
    memo.clear()


def _peak_rss_gb(_: int) -> tuple[int, float]:
    """(this worker's pid, its peak resident memory so far in GB; Linux reports ru_maxrss in KiB)."""
    import os
    import resource

    return os.getpid(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9


def _setup_of(_: int) -> tuple[int, float]:
    return _WORKER["cells"], _WORKER["setup_s"]


def _timed_row(chunk: int, cap: int, row: bool, threads: int = 1) -> int:
    """Chunk ``chunk`` of every setting on this worker (a chunk row, or cell by cell; its blocks on ``threads``);
    its sortie-epochs."""
    from testbed import memo
    from testbed.campaign.runner import run_chunk, run_chunk_row

    le, n = _WORKER["loaded"], _WORKER["cells"]
    memo.clear()
    with memo.limit(cap):
        if row:
            tables = list(run_chunk_row(le, chunk, list(range(n)), threads=threads).values())
        else:
            tables = [run_chunk(le, i, chunk, threads=threads) for i in range(n)]
    memo.clear()
    return le.spec.chunk_trials * n * int(tables[0]["trials"].column("epochs")[0].as_py())


def _schedule(modes: tuple, repeats: int) -> list:
    """The timed runs of one experiment: the first two modes (worker processes and threads, shared draws)
    ``repeats`` times each, side by side, the others once, interleaved (on, threads, off, on, threads, cell by
    cell, on, threads, ...) so a slow spell of the shared machine does not fall on one mode."""
    pair, rest = list(modes[:2]), list(modes[2:])
    order = list(pair)
    for i in range(1, repeats):
        if rest:
            order.append(rest.pop(0))
        order += pair
    return order + rest


if __name__ == "__main__":
    main()

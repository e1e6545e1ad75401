"""Benchmark: a campaign on a Dask cluster against the in-process driver, and what a task holds.

Usage::

    python benchmarks/bench_dask.py [--experiment where-vision-pays] [--trials 2000] [--workers 2]

Runs one experiment of the VA-RAIM reproduction (``--trials`` sorties per setting, chunks of
1000) four ways, each into a fresh temporary folder, and prints the wall time of each and
their ratios:

1. in-process (``workers=1``: chunk rows, draw blocks on threads);
2. the local pool (``workers=--workers``: chunk rows on that many spawned single-threaded
   worker processes, each paying its start, the flight and the sky geometry inside the clock,
   as a run does);
3. a local Dask cluster of ``--workers`` single-threaded worker processes, one task per
   chunk row (:func:`testbed.campaign.plan.worker_tasks`: the cells of a row share their
   draws on the worker);
4. the same cluster, one task per (cell, chunk) (how the Dask path ran before: every
   task draws what the cells would share).

The stores hold the same tables (checked, bit for bit, NaN equal to NaN). The flight and the
sky geometry are computed before the clock starts in the driver and in every Dask worker.
With fewer than two chunk rows per worker the rows are cut (``worker_tasks``), and the cut
rows share less: use ``--trials`` of at least 2000 per worker.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path


def _warm(spec_json: str, source: str) -> int:
    """On a worker: every cell's flight and sky geometry (what a long campaign pays once per worker process)."""
    from testbed.campaign import context
    from testbed.campaign import plan
    from testbed.campaign import runner

    loaded = runner.worker_spec(spec_json, source)
    for c in plan.cells_of(loaded):
        context.cell_context(c, loaded.spec)
    return len(plan.cells_of(loaded))


def main() -> None:
    from testbed.heap import keep_freed_memory

    keep_freed_memory()  # the process settings `testbed campaign` applies (run_campaign, a library call, does not)
    from testbed.campaign_cli import _positive_int  # argparse prints its message and exits 2
    from testbed.studies.reproduce import experiments

    ap = argparse.ArgumentParser()
    ap.add_argument("--experiment", default="where-vision-pays", choices=sorted(experiments(200)))
    ap.add_argument("--trials", type=_positive_int, default=2000, help="sorties per setting")
    ap.add_argument("--workers", type=_positive_int, default=2)
    args = ap.parse_args()

    import pyarrow.parquet as pq
    from distributed import Client, LocalCluster

    from testbed.campaign import context
    from testbed.campaign import runner
    from testbed.studies.reproduce import loaded_experiments
    from testbed.campaign.spec import expand_cells
    from testbed.campaign.store import tables_equal

    le = loaded_experiments(args.trials)[args.experiment]
    le = dataclasses.replace(le, spec=le.spec.model_copy(update={"chunk_trials": 1000}))
    cells = expand_cells(le)
    for c in cells:
        context.cell_context(c, le.spec)
    epochs = args.trials * len(cells) * 61
    print(f"{args.experiment}: {len(cells)} settings x {args.trials} sorties x 61 epochs = {epochs:.3g} sortie-epochs")

    by_row = runner.worker_tasks
    one_cell = lambda todo, workers: [(k, [(c, n)]) for c, k, n in todo]  # noqa: E731
    walls, tables = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        runner.run_campaign(le, Path(tmp) / "in-process", progress=False)
        walls["in-process"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        runner.run_campaign(le, Path(tmp) / "local pool", progress=False, workers=args.workers)
        walls["local pool"] = time.perf_counter() - t0
        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            client.run(_warm, le.spec.model_dump_json(), str(le.source))  # as the driver: before the clock
            for name, tasks in (("dask, a task per chunk row", by_row), ("dask, a task per cell", one_cell)):
                runner.worker_tasks = tasks  # what run_campaign calls
                try:
                    t0 = time.perf_counter()
                    runner.run_campaign(le, Path(tmp) / name, scheduler=client, progress=False)
                    walls[name] = time.perf_counter() - t0
                finally:
                    runner.worker_tasks = by_row
        for name in walls:
            tables[name] = pq.read_table(Path(tmp) / name / "trials.parquet")
    ref = walls["in-process"]
    for name, w in walls.items():
        same = tables_equal(tables[name], tables["in-process"])
        print(f"  {name:28s} {w:7.1f} s  {epochs / w:10,.0f} sortie-epochs/s  {ref / w:5.2f}x in-process"
              f"  tables {'identical' if same else 'DIFFER'}")
    print(f"  a task per chunk row / a task per cell: "
          f"{walls['dask, a task per cell'] / walls['dask, a task per chunk row']:.2f}x faster")


if __name__ == "__main__":
    main()

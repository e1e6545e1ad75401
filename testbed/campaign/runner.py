"""The campaign runner: fly once, sample many.

Work is split in three levels:

- a **cell context** (:mod:`.context`) is computed once per cell and cached per process: the flight, the GNSS
  geometry and the vision geometry;
- a **draw block** of ``block_trials`` trials (:mod:`.blocks`) draws its trials in one batch and runs the monitors
  on it, giving the block's table columns (:mod:`.tables`);
- a **chunk** (:func:`run_chunk`, ``chunk_trials`` trials = whole blocks) is the unit of scheduling and storage: a
  pure function of (spec, cell, chunk) returning small tables, which the driver writes atomically (:mod:`.store`).

This module executes the plan (:mod:`.plan`): chunk rows in this process (draw blocks on threads), on local worker
processes, or on a Dask cluster, with a progress bar.
"""

from __future__ import annotations

import contextlib
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa

from testbed.campaign.blocks import run_block
from testbed.campaign.context import cached, cell_context
from testbed.campaign.exercised import check_faults_exercised
from testbed.campaign.plan import cells_of, chunk_plan, chunk_rows, check_workers, local_workers, worker_tasks
from testbed.campaign.sampling import check_sampling
from testbed.campaign.spec import CampaignSpec, LoadedSpec, load_spec, resolve_spec
from testbed.campaign.store import ResultStore
from testbed.campaign.tables import chunk_tables
from testbed.heap import keep_freed_memory
from testbed.integrity.batching import available_cores, physical_memory_bytes
from testbed.pool import WorkerPool
from testbed.schema import ConfigError
from testbed.sim.preflight import check_output_folder
from testbed.threads import sleep_idle_threads


def run_chunk(loaded: LoadedSpec, cell_index: int, chunk: int, threads: int | None = None
              ) -> dict[str, pa.Table | None]:
    """A chunk's tables (pure function of spec, cell and chunk index, whatever ``threads``).

    threads : its draw blocks run on this many threads (None: one per core); each block's
    monitors run on one thread.
    """
    return run_chunk_row(loaded, chunk, [cell_index], threads)[cell_index]


def run_chunk_row(loaded: LoadedSpec, chunk: int, cells: list[int], threads: int | None = None
                  ) -> dict[int, dict[str, pa.Table | None]]:
    """Chunk ``chunk`` of each of ``cells``: ``{cell: tables}``, each what :func:`run_chunk` returns.

    Block-major: each draw block runs every cell in turn (blocks side by side on
    ``threads``), so what a sweep's cells draw alike for a block (:mod:`testbed.memo`) is
    drawn once and reused while it is still in the processor's cache: 0.98–1.36× the
    cell-by-cell order per experiment of the VA-RAIM reproduction (``benchmarks/bench_campaign.py``).
    """
    spec = loaded.spec
    ctxs = [cell_context(cells_of(loaded)[c], spec) for c in cells]
    per_chunk = spec.chunk_trials // spec.block_trials
    n_blocks = -(-spec.trials // spec.block_trials)
    blocks = range(chunk * per_chunk, min((chunk + 1) * per_chunk, n_blocks))

    def every_cell(b: int) -> list[dict]:
        return [run_block(ctx, spec, b) for ctx in ctxs]

    n_threads = available_cores() if threads is None else int(threads)
    if n_threads > 1 and len(blocks) > 1:  # blocks are independent: sample and monitor them side by side
        with ThreadPoolExecutor(min(n_threads, len(blocks))) as pool:
            per_block = list(pool.map(every_cell, blocks))
    else:
        per_block = [every_cell(b) for b in blocks]
    throttle = float(os.environ.get("TESTBED_CAMPAIGN_THROTTLE_S", "0") or 0)  # test hook: slow chunks down
    if throttle > 0:
        time.sleep(throttle * len(cells))
    return {c: chunk_tables(c, ctx, [r[i] for r in per_block]) for i, (c, ctx) in enumerate(zip(cells, ctxs))}


def _worker_row(spec_json: str, source: str, chunk: int, cells: list[int]) -> dict:
    """Entry point on a worker process (Dask's or the local pool's): rebuild the spec from its JSON (cheap, cached
    per process) and run chunk ``chunk`` of ``cells`` (:func:`run_chunk_row`)."""

    keep_freed_memory()  # a worker process runs nothing but campaign chunks
    sleep_idle_threads()  # beside the other workers (effective unless OpenMP started before the first row)
    return run_chunk_row(worker_spec(spec_json, source), chunk, cells, threads=1)  # the workers are the parallelism


def worker_spec(spec_json: str, source: str) -> LoadedSpec:
    """The spec a worker rebuilds from its JSON, cached per process."""

    return cached(("loaded", spec_json, source),
                   lambda: resolve_spec(CampaignSpec.model_validate_json(spec_json), Path(source)))


@contextlib.contextmanager
def _local_results(workers: int):
    """``(results, workers)``: ``results(fn, tasks)`` runs ``(tag, args)`` tasks on ``workers`` local processes
    (:class:`testbed.pool.WorkerPool`: spawned, a script calling :func:`run_campaign` with ``workers`` > 1 needs
    the usual ``if __name__ == "__main__":`` guard) and yields ``(tag, result)`` as they finish. Interrupted,
    the workers stop at once: the rows in flight were not stored, and a resume runs them."""
    with WorkerPool(workers) as pool:
        yield pool.unordered, workers


@contextlib.contextmanager
def _dask_results(client, own: bool, name: str):
    """``(results, workers)`` of a Dask client (closed at the end if ``own``), as :func:`_local_results`; a
    task ``(k, row)`` has the key ``name-k-<first cell>-<last cell>``."""
    try:
        from distributed import as_completed

        def results(fn, tasks):
            futs = {client.submit(fn, *args, pure=False, key=f"{name}-{k}-{row[0][0]}-{row[-1][0]}"): (k, row)
                    for (k, row), args in tasks}
            for fut in as_completed(list(futs)):
                yield futs[fut], fut.result()

        yield results, sum(client.nthreads().values())
    finally:
        if own:
            client.close()


# ----------------------------------------------------------------------------- driver

@dataclass
class CampaignResult:
    out_dir: Path
    cells: int
    trials: int
    chunks_run: int
    chunks_skipped: int
    wall_s: float
    epochs_run: int

    @property
    def epochs_per_s(self) -> float:
        return self.epochs_run / self.wall_s if self.wall_s > 0 else float("nan")


def run_campaign(spec: str | Path | LoadedSpec, out_dir: str | Path, *, resume: bool = False,
                 scheduler: str | object | None = None, progress: bool = True,
                 max_chunks: int | None = None, restart: bool = False, workers: int | str = 1) -> CampaignResult:
    """Run (or resume) a campaign into ``out_dir``.

    Parameters
    ----------
    spec : a spec file or a :class:`LoadedSpec` (validated before any work starts).
    out_dir : result folder (manifest, Parquet parts, consolidated tables).
    resume : continue a run in ``out_dir`` (same spec and inputs), skipping stored chunks.
    restart : discard a stored run in ``out_dir`` and start over.
    scheduler : None = on this machine (``workers``); a Dask scheduler address, or a
        ``distributed.Client`` / ``LocalCluster``, sends the same chunk tasks there.
    progress : show a rich progress bar (trials/s, ETA).
    max_chunks : stop after this many new chunks (tests; the run stays resumable).
    workers : without a scheduler: 1 = in this process (a chunk's draw blocks on one thread per
        core); N = chunk rows on N local worker processes; ``"auto"`` = one per core (no more than the
        memory holds) for a campaign big enough to repay their start (:func:`local_workers`). The tables
        are the same bit for bit.
    """

    # no process setting here (a library call): the commands apply them where the process starts
    # (testbed.heap, testbed.threads), and so does each worker process (_worker_row)

    check_workers(workers, scheduler)
    loaded = spec if isinstance(spec, LoadedSpec) else load_spec(spec)
    check_output_folder(out_dir, "--out")
    check_faults_exercised(loaded)  # a fault no trial can exercise: refused before any chunk is drawn
    check_sampling(loaded, cells_of(loaded))  # an importance plan it cannot draw: refused likewise
    client, own = _client(scheduler) if scheduler is not None else (None, False)  # reachable before any work
    store = ResultStore(out_dir)
    cells = cells_of(loaded)
    try:
        store.open(loaded, cells, resume=resume, restart=restart)
    except BaseException:
        if own:
            client.close()
        raise
    plan = chunk_plan(loaded)
    done = store.done_chunks()
    # chunk-major: a row (chunk k of every cell) runs block-major, so what the cells share (memo) is reused hot
    todo = sorted((p for p in plan if (p[0], p[1]) not in done), key=lambda p: (p[1], p[0]))
    if max_chunks is not None:
        todo = todo[:max_chunks]
    total_trials = sum(n for _, _, n in plan)
    done_trials = total_trials - sum(n for c, k, n in plan if (c, k) not in done)
    n_local = local_workers(workers, todo, available_cores(), physical_memory_bytes()) if client is None else 0
    wall0 = time.perf_counter()
    epochs_run = chunks_run = 0
    run_index = store.start_run()
    bar = _Progress(total_trials, done_trials, loaded.spec.name, enabled=progress)

    def stored(k: int, row: list[tuple[int, int]], tables: dict) -> None:
        nonlocal epochs_run, chunks_run
        for c, n in row:
            store.write_chunk(c, k, tables[c])
            epochs_run += n * _epochs_of(tables[c])
            chunks_run += 1
            bar.advance(n)
        store.update_run(run_index, time.perf_counter() - wall0, chunks_run, epochs_run)

    with bar:
        if n_local == 1:
            for k, row in chunk_rows(todo):
                stored(k, row, run_chunk_row(loaded, k, [c for c, _ in row]))
        else:
            sj, src = loaded.spec.model_dump_json(), str(loaded.source)
            pool = (_local_results(n_local) if client is None
                    else _dask_results(client, own, f"campaign-{loaded.hash}"))
            with pool as (results, n):
                tasks = [((k, tuple(row)), (sj, src, k, [c for c, _ in row])) for k, row in worker_tasks(todo, n)]
                for (k, row), tables in results(_worker_row, tasks):
                    stored(k, list(row), tables)
    if len(store.done_chunks()) == len(plan):
        store.finalize()
    wall = time.perf_counter() - wall0
    store.update_run(run_index, wall, chunks_run, epochs_run, finished=True)
    return CampaignResult(Path(out_dir), len(cells), total_trials, len(todo), len(done), wall, epochs_run)


def _epochs_of(tables: dict) -> int:
    t = tables.get("trials")
    if t is None or t.num_rows == 0:
        return 0
    return int(t.column("epochs")[0].as_py())


def _client(scheduler):
    from distributed import Client

    if isinstance(scheduler, str):
        try:
            return Client(scheduler, timeout="10s"), True
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError("command line", [f"--scheduler {scheduler!r}: no Dask scheduler answered ({exc}); "
                                               "expected the address of a running scheduler, e.g. "
                                               "tcp://127.0.0.1:8786"]) from None
    if isinstance(scheduler, Client):
        return scheduler, False
    return Client(scheduler), True  # a cluster object


class _Progress:
    """A rich progress bar with trials/s and ETA (a no-op when disabled)."""

    def __init__(self, total: int, done: int, name: str, enabled: bool = True) -> None:
        self.enabled = enabled
        if enabled:
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TaskProgressColumn, TextColumn,
                                       TimeElapsedColumn, TimeRemainingColumn)

            self.p = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                              TaskProgressColumn(), TextColumn("{task.fields[rate]} trials/s"),
                              TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), transient=False)
            self.task = self.p.add_task(name, total=total, completed=done, rate="-")
            self.t0 = time.perf_counter()
            self.n = 0

    def __enter__(self):
        if self.enabled:
            self.p.__enter__()
        return self

    def __exit__(self, *exc):
        if self.enabled:
            self.p.__exit__(*exc)

    def advance(self, n: int) -> None:
        if self.enabled:
            self.n += n
            rate = self.n / max(time.perf_counter() - self.t0, 1e-9)
            self.p.update(self.task, advance=n, rate=f"{rate:,.0f}")

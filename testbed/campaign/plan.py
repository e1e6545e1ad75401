"""A campaign's plan: its cells, the (cell, chunk) tasks, how they are grouped for worker processes, and how many
local workers run them.
"""

from __future__ import annotations

import numpy as np

from testbed.campaign.context import cached
from testbed.campaign.spec import Cell, LoadedSpec, expand_cells
from testbed.schema import ConfigError


def cells_of(loaded: LoadedSpec) -> list[Cell]:
    return cached(("cells", loaded.hash, str(loaded.source)), lambda: expand_cells(loaded))


def chunk_plan(loaded: LoadedSpec) -> list[tuple[int, int, int]]:
    """Every (cell, chunk, n_trials) task of a campaign, in order."""
    spec = loaded.spec
    n_chunks = -(-spec.trials // spec.chunk_trials)
    out = []
    for c in range(len(cells_of(loaded))):
        for k in range(n_chunks):
            out.append((c, k, min(spec.chunk_trials, spec.trials - k * spec.chunk_trials)))
    return out


def chunk_rows(todo: list[tuple[int, int, int]]) -> list[tuple[int, list[tuple[int, int]]]]:
    """Tasks ``(cell, chunk, n)`` grouped by chunk: ``[(chunk, [(cell, n), ...]), ...]`` in chunk order
    (the unit :func:`run_chunk_row` runs)."""
    rows: dict[int, list[tuple[int, int]]] = {}
    for c, k, n in todo:
        rows.setdefault(k, []).append((c, n))
    return sorted(rows.items())


def worker_tasks(todo: list[tuple[int, int, int]], workers: int) -> list[tuple[int, list[tuple[int, int]]]]:
    """The tasks of ``todo`` for worker processes (Dask's or the local pool's): chunk rows (:func:`chunk_rows`), so a
    worker draws once what a row's cells share (:mod:`testbed.memo`; a task per cell would draw it once per cell:
    1.7-2.3x the work in the VA-RAIM reproduction). Rows are cut into runs of consecutive cells when there are fewer
    than two tasks per worker, so a campaign of few chunks still keeps every worker busy."""
    rows = chunk_rows(todo)
    want = 2 * max(int(workers), 1)
    if not rows or len(rows) >= want:
        return rows
    pieces = -(-want // len(rows))
    out = []
    for k, cells in rows:
        size = -(-len(cells) // pieces)
        out += [(k, cells[i:i + size]) for i in range(0, len(cells), size)]
    return out


#: The local pool's worker processes start in a few seconds (interpreter, imports, the kernels from numba's cache)
#: and each rebuilds the cells' flight and sky geometry (side by side, so no later than the driver would), then
#: compute faster than threads (docs/performance.md): measured end to end (``benchmarks/bench_dask.py``), gps-faults at 4000
#: sorties per setting (160 000 cell-sorties, ~35 s) took 40.4 s on the pool and 35.1 s in-process, so a pool
#: needs a few minutes of computing to pay for itself: below this many cell-sorties a campaign stays in-process.
POOL_MIN_CELL_SORTIES = 500_000


#: memory a local worker may take: one peaked at 1.2-2.5 GB resident on the reproduction's experiments (its cells'
#: contexts, the memo's 512 MiB, the blocks' arrays), so "auto" starts no more workers than the memory holds
WORKER_MEMORY_BYTES = 3 * 2**30


def local_workers(workers: int | str, todo: list[tuple[int, int, int]], cores: int,
                  memory_bytes: int | None = None) -> int:
    """How many local worker processes run ``todo`` (1: the driver's own process, blocks on threads).

    ``workers`` a number: that many, at most one per task (:func:`worker_tasks`). ``"auto"``: one per core, at most
    one per :data:`WORKER_MEMORY_BYTES` of ``memory_bytes`` (the machine's, when known), when there are at least
    two chunk rows and :data:`POOL_MIN_CELL_SORTIES` cell-sorties to run, else 1. Processes rather than threads
    because the monitors' numpy steps hold the interpreter lock: two worker processes run the reproduction's
    chunk rows faster than the same rows on two threads, side by side in ``benchmarks/bench_campaign.py``
    (its figures: docs/performance.md).
    """
    if workers == "auto":
        big = len(chunk_rows(todo)) >= 2 and sum(n for _, _, n in todo) >= POOL_MIN_CELL_SORTIES
        n = max(int(cores), 1)
        if memory_bytes is not None:
            n = min(n, max(int(memory_bytes // WORKER_MEMORY_BYTES), 1))
        return n if big else 1
    return max(min(int(workers), len(worker_tasks(todo, int(workers)))), 1)


def check_workers(workers: int | str, scheduler=None) -> None:
    """A ``workers`` value :func:`run_campaign` takes: a positive whole number or ``"auto"``, and only without a
    Dask scheduler (whose workers are the parallelism); else a :class:`ConfigError` before any work."""
    ok = workers == "auto" or (isinstance(workers, (int, np.integer)) and not isinstance(workers, bool)
                               and workers >= 1)
    if not ok:
        raise ConfigError("command line", [f"--workers {workers!r}: expected a positive whole number or 'auto'"])
    if scheduler is not None and workers not in (1, "auto"):
        raise ConfigError("command line", [f"--workers {workers!r} and --scheduler: the Dask scheduler's workers "
                                           "run the chunks; give one or the other"])

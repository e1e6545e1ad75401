"""Run a batched monitor on chunks of trials, on threads, and stack the outputs.

The monitors' per-epoch math never mixes trials, so a batch can be cut along its
first (trial) axis and the pieces computed independently; numpy and the
compiled kernels release the GIL, so the pieces run in parallel on threads
with no copies. Chunks of a few thousand epochs also keep the temporaries in
cache. The stacked result is bit-identical to the unchunked one.
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from testbed.records import MonitorOutput, epoch_array_pairs, map_epoch_arrays

#: Epochs per chunk: large enough that numpy's per-call overhead is noise, small
#: enough for the per-epoch temporaries to stay in cache.
CHUNK_EPOCHS = 4096


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not Linux
        return max(os.cpu_count() or 1, 1)


def physical_memory_bytes() -> int | None:
    """This machine's physical memory, or None where the system does not say."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):  # not POSIX, or the name is unknown here
        return None


def trial_chunks(batch_shape: tuple[int, ...], chunk_epochs: int | None = None, multiple_of: int = 1) -> list[slice]:
    """Equal slices of the first axis of ``batch_shape = (B..., T)``, about ``chunk_epochs`` epochs each.

    The number of chunks is rounded up to a multiple of ``multiple_of`` (the thread count)
    so the threads finish together. A batch with no trial axis (a single run, shape (T,))
    is one chunk.
    """
    chunk_epochs = CHUNK_EPOCHS if chunk_epochs is None else chunk_epochs
    if len(batch_shape) < 2 or batch_shape[0] <= 1:
        return [slice(None)]
    n = batch_shape[0]
    total = int(np.prod(batch_shape, dtype=np.int64))
    k = max(1, round(total / max(chunk_epochs, 1)))
    k = min(n, -(-k // multiple_of) * multiple_of)
    edges = np.linspace(0, n, k + 1).round().astype(int)
    return [slice(int(a), int(b)) for a, b in itertools.pairwise(edges) if b > a]


def map_trial_chunks(fn: Callable[[slice], MonitorOutput], batch_shape: tuple[int, ...],
                     threads: int | None = None, chunk_epochs: int | None = None) -> MonitorOutput:
    """``fn(slice)`` for every chunk of trials (on ``threads`` threads; None = every core), stacked.

    Each worker copies its chunk into the stacked output as soon as it is done (copies
    release the GIL), so the stacking runs in parallel and only one chunk's arrays are
    alive per thread.
    """
    n_threads = available_cores() if threads is None else int(threads)
    if n_threads < 1:
        raise ValueError(f"threads: expected >= 1 or None, got {threads}")
    chunks = trial_chunks(batch_shape, chunk_epochs, n_threads)
    if len(chunks) == 1:
        return fn(chunks[0])
    n_trials = batch_shape[0]
    lock = threading.Lock()
    stacked: list[MonitorOutput] = []

    def run(sl: slice) -> None:
        part = fn(sl)
        with lock:
            if not stacked:
                stacked.append(_allocate_stacked(part, n_trials))
        _write_chunk(stacked[0], part, sl)

    if n_threads == 1:
        for c in chunks:
            run(c)
    else:
        with ThreadPoolExecutor(min(n_threads, len(chunks))) as pool:
            list(pool.map(run, chunks))
    return stacked[0]


def _allocate_stacked(part: MonitorOutput, n_trials: int) -> MonitorOutput:
    """An output shaped like ``part`` with ``n_trials`` trials (per-trial arrays uninitialised)."""
    def like(a: np.ndarray, meta) -> np.ndarray:
        return np.empty((n_trials,) + a.shape[1:], a.dtype) if meta["batched"] else a

    return map_epoch_arrays(part, like)


def _write_chunk(out: MonitorOutput, part: MonitorOutput, sl: slice) -> None:
    """Copy the chunk ``part`` into trials ``sl`` of ``out`` (same layout as :func:`_allocate_stacked`)."""
    if part.name != out.name:
        raise ValueError(f"chunk outputs disagree: {part.name!r} vs {out.name!r}")
    for o, p, meta in epoch_array_pairs(out, part):
        if meta["batched"]:
            o[sl] = p

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
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from testbed.heap import keep_freed_memory
from testbed.records import MonitorOutput

#: Epochs per chunk: large enough that numpy's per-call overhead is noise, small
#: enough for the per-epoch temporaries to stay in cache.
CHUNK_EPOCHS = 4096


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not Linux
        return max(os.cpu_count() or 1, 1)


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
    """``fn(slice)`` for every chunk of trials (on ``threads`` threads; None = every core), stacked."""
    n_threads = available_cores() if threads is None else int(threads)
    if n_threads < 1:
        raise ValueError(f"threads: expected >= 1 or None, got {threads}")
    keep_freed_memory()  # chunks allocate and free large arrays: keep them in the heap (testbed.heap)
    chunks = trial_chunks(batch_shape, chunk_epochs, n_threads)
    if len(chunks) == 1:
        return fn(chunks[0])
    if n_threads == 1:
        parts = [fn(c) for c in chunks]
    else:
        with ThreadPoolExecutor(min(n_threads, len(chunks))) as pool:
            parts = list(pool.map(fn, chunks))
    return stack_outputs(parts)


def stack_outputs(parts: list[MonitorOutput]) -> MonitorOutput:
    """Concatenate MonitorOutputs of consecutive trial chunks along the trial axis.

    Per-epoch arrays (and diagnostics arrays, which all lead with the batch axes) are
    concatenated; names, times, level and reason tables come from the first part and
    must agree; a nested MonitorOutput diagnostic is stacked the same way.
    """
    first = parts[0]
    out = {}
    for f in ("pos_enu", "clock", "hpl", "vpl", "test_stat", "threshold", "alert", "available", "n_used",
              "excluded", "reason"):
        out[f] = np.concatenate([getattr(p, f) for p in parts], axis=0)
    diag = {}
    for k, v in first.diagnostics.items():
        vs = [p.diagnostics[k] for p in parts]
        if isinstance(v, MonitorOutput):
            diag[k] = stack_outputs(vs)
        elif isinstance(v, np.ndarray) and v.ndim > 0:
            diag[k] = np.concatenate(vs, axis=0)
        else:
            diag[k] = v
    return MonitorOutput(name=first.name, t=first.t, service_levels=first.service_levels, reasons=first.reasons,
                         diagnostics=diag, **out)

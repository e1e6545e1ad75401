"""Results shared by the cells of a sweep: a bounded memo, off unless a campaign turns it on.

The cells of a campaign differ in one or two settings and, with common random numbers, draw
from the same seeds: a GPS-step magnitude sweep draws the same camera frames in every cell, a
camera sweep the same pseudoranges and the same dithering. A function whose result is fixed by
its key (a seed's identity, a digest of its input arrays, the settings it reads) is computed
once per process and reused, so every cell gets the very arrays it would have computed:
results are bit-identical with and without sharing (tested).

Shared values are frozen (their arrays read-only): a caller that writes into one fails loudly
instead of corrupting another cell. The store is bounded in bytes, least recently used first.
"""

from __future__ import annotations

import dataclasses
import hashlib
import threading
import weakref
from collections import OrderedDict
from contextlib import contextmanager
from typing import Any, Callable, Iterator

import numpy as np

#: Default byte budget of the store. The driver runs a chunk row block-major (every cell of a block in
#: turn, :func:`testbed.campaign.runner.run_chunk_row`), so what is reused is one block's draws per thread:
#: where-vision-pays' 90 cells share ~140 MB a block (6 magnitudes' pseudoranges at 17 MB, 15 cameras'
#: frames at 2.1 MB, their step-1 fixes), ~280 MB on two threads.
DEFAULT_LIMIT_BYTES = 512 << 20

_lock = threading.Lock()
_store: OrderedDict[tuple, tuple[Any, int, object]] = OrderedDict()
_state = {"bytes": 0, "limit": DEFAULT_LIMIT_BYTES, "hits": 0, "misses": 0}
_on = threading.local()  # per thread: a flight beside a campaign chunk in one process shares nothing
#: every array a shared value holds, by id, weakly (an entry leaves with its array): :func:`is_shared` tells
#: a caller that an array it was handed is one the store shares, not merely read-only (a broadcast view is
#: read-only too). Single dict operations, atomic under the GIL: no lock, which a collection could re-enter.
_held: dict[int, weakref.ref] = {}


@contextmanager
def sharing() -> Iterator[None]:
    """Turn the memo on for the block in this thread (nested uses keep it on; the store, one per process,
    outlives it)."""
    _on.depth = getattr(_on, "depth", 0) + 1
    try:
        yield
    finally:
        _on.depth -= 1


@contextmanager
def limit(limit_bytes: int) -> Iterator[None]:
    """Hold at most ``limit_bytes`` inside the block (0: share nothing, as benchmarks compare)."""
    with _lock:
        old, _state["limit"] = _state["limit"], int(limit_bytes)
    try:
        yield
    finally:
        with _lock:
            _state["limit"] = old


def active() -> bool:
    return getattr(_on, "depth", 0) > 0


def clear() -> None:
    with _lock:
        _store.clear()
        _state.update(bytes=0, hits=0, misses=0)


def counts() -> dict[str, int]:
    """Hits, misses, entries and bytes held (benchmarks and tests)."""
    with _lock:
        return {"hits": _state["hits"], "misses": _state["misses"], "entries": len(_store), "bytes": _state["bytes"]}


def shared(key: tuple, make: Callable[[], Any], guard: object = None) -> Any:
    """``make()``, or the value an earlier call with ``key`` made while sharing is on.

    ``key`` must fix the result completely (every input that changes it); ``make`` must not
    depend on anything else. ``guard``: an input object the key names by ``id()`` (a record
    another shared call returned), or a tuple of them; the entry holds it, and serves only a call
    passing those very objects, so a recycled id never matches. Off (the default): ``make()`` every
    time, nothing kept.
    """
    if not active():
        return make()
    with _lock:
        got = _store.get(key)
        if got is not None and _same(got[2], guard):
            _store.move_to_end(key)
            _state["hits"] += 1
            return got[0]
        _state["misses"] += 1
    value = make()  # outside the lock: another thread may compute the same key meanwhile (same value)
    size = _freeze(value)
    with _lock:
        if 0 < _state["limit"] and size <= _state["limit"]:
            old = _store.pop(key, None)
            _state["bytes"] += size - (old[1] if old is not None else 0)
            _store[key] = (value, size, guard)
            while _state["bytes"] > _state["limit"]:
                _, (_, s, _) = _store.popitem(last=False)
                _state["bytes"] -= s
    return value


def _same(held: object, guard: object) -> bool:
    if isinstance(guard, tuple) and isinstance(held, tuple):
        return len(held) == len(guard) and all(a is b for a, b in zip(held, guard))
    return held is guard


def seed_key(seed: np.random.SeedSequence | np.random.Generator) -> tuple:
    """The identity of a fresh generator's stream (its SeedSequence: entropy, spawn key, pool size).

    Only for a generator nothing has drawn from yet (a just-spawned child): the key says
    nothing of how far a used one has advanced.
    """
    ss = getattr(seed.bit_generator, "seed_seq", None) if isinstance(seed, np.random.Generator) else seed
    if not isinstance(ss, np.random.SeedSequence):
        raise TypeError(f"seed_key: expected a SeedSequence-seeded generator, got {type(ss).__name__}")
    return ("seed", ss.entropy, ss.spawn_key, ss.pool_size, ss.n_children_spawned)


def digest(*arrays: Any) -> bytes:
    """A content digest of arrays (dtype, shape and bytes) and plain values."""
    h = hashlib.blake2b(digest_size=20)
    for a in arrays:
        if isinstance(a, np.ndarray):
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(np.ascontiguousarray(a).view(np.uint8).reshape(-1))
        else:
            h.update(repr(a).encode())
        h.update(b"|")
    return h.digest()


def is_shared(a: np.ndarray) -> bool:
    """Whether ``a`` is an array of a value the store has shared (frozen by :func:`shared`)."""
    ref = _held.get(id(a))
    return ref is not None and ref() is a


def _hold(a: np.ndarray) -> None:
    key = id(a)

    def gone(ref, key=key):
        if _held.get(key) is ref:
            _held.pop(key, None)

    _held[key] = weakref.ref(a, gone)


def _freeze(value: Any, depth: int = 0) -> int:
    """Make the arrays of a value read-only (dataclasses, tuples, lists, dicts: three levels deep);
    the bytes they own (a view counts nothing: its base is the geometry's, held elsewhere)."""
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
        _hold(value)
        return value.nbytes if value.flags.owndata else 0
    if depth > 3:
        return 0
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return sum(_freeze(getattr(value, f.name), depth + 1) for f in dataclasses.fields(value))
    if isinstance(value, (tuple, list)):
        return sum(_freeze(v, depth + 1) for v in value)
    if isinstance(value, dict):
        return sum(_freeze(v, depth + 1) for v in value.values())
    return 0

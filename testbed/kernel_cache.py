"""numba's on-disk kernel cache, kept in step with every kernel source, not only each kernel's own file.

numba's ``cache=True`` compiles a function again when *its own* file changes (the cache index
holds that file's modification time and size, its "source stamp"), not when a helper it calls
from another file does: after an edit of ``integrity/kernels/small.py``, the cached machine code
of ``integrity/kernels/vision.py`` still holds the old helper, and runs it without a word. Each
module that defines cached kernels therefore ends with ``keep_in_step(sys.modules[__name__])``,
which adds a digest of every kernel source (and of the constants they compile in) to the stamp
its kernels' indexes are written with and checked against. An index written before an edit no
longer matches, and numba compiles afresh (once, ~15-20 s). A process started before the edit
keeps writing its own (old) stamp, which the next new process does not trust either: each
process runs code built from the sources it imported. An installed package never changes under
its cache; this is for the working copy.
"""

from __future__ import annotations

import functools
import hashlib
import types
from pathlib import Path
from typing import Iterable

from numba.core.registry import CPUDispatcher

PACKAGE = Path(__file__).resolve().parent

#: Every module of the package with ``cache=True`` kernels, relative to the package
#: (``tests/test_kernel_cache.py`` checks that the list is complete and each calls :func:`keep_in_step`).
KERNEL_SOURCES = (
    "integrity/araim/kernels.py",
    "integrity/kernels/calibration.py",
    "integrity/kernels/dpe.py",
    "integrity/kernels/geometry.py",
    "integrity/kernels/ranges.py",
    "integrity/kernels/small.py",
    "integrity/kernels/vision.py",
    "navigation/kernels.py",
    "rinex/kernels.py",
)
#: what the digest covers: the kernels and the module whose constants they compile in (C_LIGHT, OMEGA_EARTH)
DIGESTED = KERNEL_SOURCES + ("frames.py",)


@functools.lru_cache(maxsize=8)
def sources_digest(paths: tuple[Path, ...]) -> str:
    """A digest of the files' contents, in order (read once per process)."""
    h = hashlib.blake2b(digest_size=16)
    for p in paths:
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def keep_in_step(module: types.ModuleType, sources: Iterable[Path] | None = None) -> int:
    """Stamp the cache indexes of ``module``'s kernels with a digest of ``sources`` as well as their own file.

    sources : the files whose edits must reach the module's compiled code (default: the package's
        :data:`DIGESTED`: a helper of any kernel module may be compiled into any other).

    Returns the number of kernels stamped. (numba's index file keeps the stamp it was written
    with and ignores its entries when the stamp differs: ``IndexDataCacheFile._source_stamp``;
    the test in ``tests/test_kernel_cache.py`` fails if a numba release renames it.)
    """
    paths = tuple(Path(p) for p in sources) if sources is not None else tuple(PACKAGE / s for s in DIGESTED)
    digest = sources_digest(paths)
    n = 0
    for d in vars(module).values():
        if isinstance(d, CPUDispatcher) and d.__module__ == module.__name__ and d._cache.cache_path is not None:
            index = d._cache._cache_file
            own = getattr(index, "_testbed_own_stamp", index._source_stamp)  # idempotent on a second call
            index._testbed_own_stamp = own
            index._source_stamp = (own, digest)
            n += 1
    return n


def _marker(monitor: str) -> Path:
    """The file that says ``monitor``'s kernels were compiled from the current sources (beside numba's cache)."""
    import numba

    base = Path(numba.config.CACHE_DIR) if numba.config.CACHE_DIR else PACKAGE / "integrity" / "kernels" / "__pycache__"
    digest = sources_digest(tuple(PACKAGE / s for s in DIGESTED))
    return base / f"testbed-prepared-{monitor}-{digest}"


def compiled_before(monitor: str) -> bool:
    """Whether ``monitor``'s kernels were compiled from these sources by an earlier run (a guess from a
    marker file, for the first-run notice only: numba's own cache decides what is really compiled)."""
    return _marker(monitor).exists()


def mark_compiled(monitor: str) -> None:
    """Leave the marker :func:`compiled_before` reads (silently skipped where the cache is not writable)."""
    try:
        path = _marker(monitor)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch()
    except OSError:
        pass

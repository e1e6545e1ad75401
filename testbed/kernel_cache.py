"""numba's on-disk kernel cache, kept in step with every kernel source, not only each kernel's own file.

numba's ``cache=True`` compiles a function again when *its own* file changes (the cache index
holds that file's modification time and size), not when a helper it calls from another file
does: after an edit of ``integrity/kernels/small.py``, the cached machine code of
``integrity/kernels/vision.py`` still holds the old helper, and runs it without a word. Each
module that defines cached kernels therefore ends with ``keep_in_step(sys.modules[__name__])``:
a digest of all kernel sources is kept beside the module's cache, and when it differs the
indexes of the module's kernels are emptied, so numba compiles them afresh (once, ~15-20 s).
An installed package never changes under its cache; this is for the working copy.
"""

from __future__ import annotations

import functools
import hashlib
import os
import types
from pathlib import Path
from typing import Iterable

from numba.core.registry import CPUDispatcher

PACKAGE = Path(__file__).resolve().parent

#: Every module of the package with ``cache=True`` kernels, relative to the package
#: (``tests/test_architecture.py`` checks that the list is complete and each calls :func:`keep_in_step`).
KERNEL_SOURCES = (
    "integrity/kernels/calibration.py",
    "integrity/kernels/dpe.py",
    "integrity/kernels/geometry.py",
    "integrity/kernels/ranges.py",
    "integrity/kernels/small.py",
    "integrity/kernels/vision.py",
    "navigation/kernels.py",
    "rinex/kernels.py",
)


@functools.lru_cache(maxsize=8)
def sources_digest(paths: tuple[Path, ...]) -> str:
    """A digest of the files' contents, in order (read once per process)."""
    h = hashlib.blake2b(digest_size=16)
    for p in paths:
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def keep_in_step(module: types.ModuleType, sources: Iterable[Path] | None = None) -> int:
    """Empty the cache indexes of ``module``'s kernels if a kernel source changed since they were written.

    sources : the files whose edits must reach the module's compiled code (default: the package's
        :data:`KERNEL_SOURCES`, every kernel module: a helper of any of them may be inlined).

    Returns the number of kernels whose index was emptied (0 when the digest matches). A cache
    directory that cannot be written is left alone: numba cannot cache there either.
    """
    paths = tuple(Path(p) for p in sources) if sources is not None else tuple(PACKAGE / s for s in KERNEL_SOURCES)
    digest = sources_digest(paths)
    caches = [d._cache for d in vars(module).values()
              if isinstance(d, CPUDispatcher) and d.__module__ == module.__name__ and d._cache.cache_path is not None]
    if not caches:
        return 0
    stamp = Path(caches[0].cache_path) / f"{module.__name__.rsplit('.', 1)[-1]}.sources"
    try:
        if stamp.read_text() == digest:
            return 0
    except OSError:
        pass  # no stamp yet: the cache may predate this check, so it is not trusted
    try:
        for c in caches:
            c.flush()
        tmp = stamp.with_name(f"{stamp.name}.{os.getpid()}.tmp")
        tmp.write_text(digest)
        os.replace(tmp, stamp)  # atomic: a worker process starting beside this one reads either digest
    except OSError:
        return 0
    return len(caches)

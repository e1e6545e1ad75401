"""The benchmarks' one timing rule: the median wall time of ``repeats`` calls (the host is shared and noisy)."""

from __future__ import annotations

import statistics
import time


def median_time(fn, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)

"""Benchmark: batched VA-RAIM against a straightforward per-epoch reference.

Usage::

    /work/venv/bin/python benchmarks/bench_va_raim.py [--epochs 10000 100000] [--repeats 3]

The scenario is the VA-RAIM paper §3.1 (tests/test_va_raim_scenario.py): 3 landmarks,
1 Hz over the 60 s sortie, DO-229 almanac GPS with a 5° mask (8 satellites),
1 px detections, 5 cm survey error. Batches of B trials × 61 epochs.

The reference (``tests/va_raim_reference.py``) is what one would write first: a
Python loop over trials and epochs, small numpy matrices per epoch, the
calibration as a running state. The batched monitor runs as shipped: chunks of
trials on one thread per core (``--threads`` to pin it). The script asserts that it gives the same
numbers as the batched monitor (position, SSE, threshold, HPL/VPL, alerts,
vision ranges, calibrated ranges) on a sample of trials, then prints the
median epochs/s of both and their ratio.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_va_raim_scenario import make_scenario  # noqa: E402
from va_raim_reference import check_same_numbers, va_raim_reference  # noqa: E402

from testbed.integrity.batching import available_cores  # noqa: E402
from testbed.heap import keep_freed_memory  # noqa: E402

keep_freed_memory()  # as the CLI and campaigns do (off with TESTBED_SYSTEM_MALLOC=1)
from testbed.integrity.va_raim import VaRaimSettings, va_raim  # noqa: E402


# ----------------------------------------------------------------------------- benchmark


sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import median_time as _median_time  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--epochs", type=int, nargs="+", default=[10_000, 100_000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ref-trials", type=int, default=20, help="trials timed with the per-epoch reference")
    ap.add_argument("--threads", type=int, default=None, help="threads of the batched monitor (default: every core)")
    args = ap.parse_args(argv)
    st = VaRaimSettings(variant="seed")  # every vision row in use (the reference implements the seed method)
    rng = np.random.default_rng(2024)
    T = 61
    cores = available_cores() if args.threads is None else args.threads
    for n_ep in args.epochs:
        B = max(1, n_ep // T)
        sc = make_scenario(rng, (B,))
        out = va_raim(sc.gnss, sc.vision, sc.frame, st, threads=args.threads)  # warm caches (chi2, kernels)
        n = B * T
        t_all = _median_time(lambda: va_raim(sc.gnss, sc.vision, sc.frame, st, threads=args.threads), args.repeats)
        t_one = _median_time(lambda: va_raim(sc.gnss, sc.vision, sc.frame, st, threads=1), args.repeats)
        trials = list(range(min(args.ref_trials, B)))
        check_same_numbers(sc, out, st, trials)
        t_ref = _median_time(lambda: va_raim_reference(sc.gnss, sc.vision, sc.frame, st, trials), args.repeats)
        rate, rate1 = n / t_all, n / t_one
        rrate = len(trials) * T / t_ref
        print(f"{n:7d} epochs ({B} trials x {T}): batched {rate:8.0f} epochs/s on {cores} thread(s) "
              f"({t_all:.3f} s), {rate1:8.0f} on 1 | per-epoch reference {rrate:6.0f} epochs/s "
              f"({len(trials) * T} epochs) | ratio {rate / rrate:6.1f}x | same numbers: yes "
              f"(medians of {args.repeats})")


if __name__ == "__main__":
    main()

"""Benchmark: the DPE approach's real-time factor alone and beside CPU-bound neighbour processes, for
numba's OpenMP threads left as they are, told to sleep when idle (OMP_WAIT_POLICY=passive, what the
testbed's commands set), and cut to one thread.

Run: python benchmarks/bench_dpe_neighbour.py [--runs 3] [--neighbours N]

Each setting flies ``zunz-rwy05-dpe`` (no recording) in a fresh process (OpenMP reads its settings
when it starts), ``--runs`` times, alternating the settings; the neighbours are Python busy
loops, one per core by default (``--neighbours``; a campaign's worker processes are such
neighbours). Prints the loop's real-time factor (simulated seconds / seconds of the loop) per run
and the medians, and each setting's median beside the neighbours as a ratio of it alone.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys

RUN = """
from testbed.api import run_approach
r = run_approach("zunz-rwy05-dpe", rrd_path=None)
t = r.loop.timings
print(r.flight.summary.duration_s / (t.flight + t.sensors + t.monitors + t.logging), t.monitors)
"""
SETTINGS = {
    "OpenMP as it is": {},
    "OMP_WAIT_POLICY=passive": {"OMP_WAIT_POLICY": "passive"},
    "one thread": {"NUMBA_NUM_THREADS": "1"},
}


def fly(extra: dict) -> tuple[float, float]:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "NUMBA_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", RUN], env={**env, **extra}, capture_output=True, text=True,
                         check=True).stdout.split()
    return float(out[-2]), float(out[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, choices=range(1, 21), metavar="N")
    ap.add_argument("--neighbours", type=int, default=os.cpu_count() or 1, choices=range(1, 65), metavar="N",
                    help="busy processes beside the flight (default: one per core)")
    a = ap.parse_args()
    fly({})  # compile and cache the kernels once, untimed
    res = {(s, n): [] for s in SETTINGS for n in (False, True)}
    for k in range(a.runs):
        for neighbour in (False, True):
            busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    for _ in range(a.neighbours if neighbour else 0)]
            try:
                for name, extra in SETTINGS.items():
                    rt, mon = fly(extra)
                    res[(name, neighbour)].append(rt)
                    print(f"run {k + 1}, {f'beside {a.neighbours} busy' if neighbour else 'alone':16s} {name:24s} "
                          f"{rt:6.1f}x real time (monitors {mon:.2f} s)", flush=True)
            finally:
                for b in busy:
                    b.kill()
                    b.wait()
    print("\nmedian real-time factor (runs)")
    for name in SETTINGS:
        alone, beside = statistics.median(res[(name, False)]), statistics.median(res[(name, True)])
        print(f"  {name:24s} alone {alone:6.1f}x   beside the neighbours {beside:6.1f}x   ratio {beside / alone:.2f}")


if __name__ == "__main__":
    main()

"""Benchmark: what the patent's monitor buys on the runway-05 final, and what its landmark cap costs.

Usage::

    python benchmarks/bench_pixel_benefit.py [--trials 400] [--figure PATH]

1. For the two cells of ``approaches/campaigns/pixel-benefit.toml`` (the JSBSim-flown
   runway-05 final with the runway outline as landmarks, and with the patent's H and I
   ground markers as well; fault-free sorties started uniformly over a day), the same
   observations through GPS RAIM and the patent's PL rule with and without vision rows
   and H3 (:mod:`testbed.studies.pixel_benefit`): per-epoch availability, median / p95
   PLs, 95 % accuracy. ``--figure`` draws the markers cell's table (docs/img/readme-pixel-benefit.png).
2. On the markers cell (30 landmarks in view near the threshold), the pixel monitor with
   ``[monitor.pixel] max_landmarks`` = 6, 12 and 30: median epochs/s over alternating runs and APV-I
   availability (the cap's price in time and in availability).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from testbed.heap import keep_freed_memory

keep_freed_memory()
from testbed.studies.pixel_benefit import benefit_table, draw_benefit, format_table  # noqa: E402
from testbed.campaign.blocks import draw_block
from testbed.campaign.context import cell_context  # noqa: E402
from testbed.campaign.spec import expand_cells, load_spec  # noqa: E402
from testbed.integrity.pixel import pixel_monitor  # noqa: E402
from testbed.integrity.settings import PixelOptions  # noqa: E402

LEVELS = ("APV-I", "LPV-200", "APV-II")


def cap_sweep(loaded, cell_index: int, caps=(6, 12, 30), repeats: int = 3) -> list[str]:
    cell = expand_cells(loaded)[cell_index]
    ctx = cell_context(cell, loaded.spec)
    d = draw_block(ctx, loaded.spec, 0)
    n_ep = d.obs.gnss.pseudorange.shape[0] * d.obs.gnss.pseudorange.shape[1]
    lines = ["| max_landmarks | landmarks used (mean) | epochs/s (median) | APV-I available | "
             "APV-I available, no H3 |", "|---|---|---|---|---|"]
    runs = {}
    for _ in range(repeats):
        for cap in caps:
            st = ctx.setup.integrity.model_copy(update={"fde": False})
            t0 = time.perf_counter()
            out = pixel_monitor(d.obs.gnss, d.obs.vision, ctx.setup.frame, st, options=PixelOptions(max_landmarks=cap))
            runs.setdefault(cap, []).append(time.perf_counter() - t0)
            runs[cap, "out"] = out
    for cap in caps:
        out = runs[cap, "out"]
        st = ctx.setup.integrity.model_copy(update={"fde": False})
        no_h3 = pixel_monitor(d.obs.gnss, d.obs.vision, ctx.setup.frame, st,
                              options=PixelOptions(max_landmarks=cap, two_faults=False))
        lines.append(f"| {cap} | {np.mean(out.diagnostics.n_landmarks):.1f} | {n_ep / statistics.median(runs[cap]):,.0f} | "
                     f"{100 * np.mean(out.available[..., 0]):.1f} % | {100 * np.mean(no_h3.available[..., 0]):.1f} % |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=400, help="sorties per cell (default 400)")
    ap.add_argument("--figure", help="draw the markers cell's comparison here (PNG)")
    ap.add_argument("--cap-only", action="store_true", help="only the landmark-cap table")
    a = ap.parse_args(argv)
    loaded = load_spec("pixel-benefit", trials=a.trials)
    for k, cell in enumerate([] if a.cap_only else expand_cells(loaded)):
        t0 = time.perf_counter()
        rows = benefit_table(loaded, cell_index=k)
        print(f"\n{cell.params.get('approach', k)}: {a.trials} sorties ({time.perf_counter() - t0:.0f} s)\n")
        print(format_table(rows, LEVELS))
        if a.figure and k == 1:
            scene = (f"runway-05 final (JSBSim), H and I markers + runway outline, {a.trials} fault-free sorties "
                     f"started over a day, P_FA 1e-5")
            print(f"\nfigure: {draw_benefit(rows, 'APV-I', a.figure, scene)}")
    print("\nlandmark cap, markers cell, one block of sorties:\n")
    print("\n".join(cap_sweep(loaded, 1)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

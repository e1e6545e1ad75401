"""Benchmark: the pixel monitor's fault-free false-alarm rate at the default P_FA = 1e-5, over ~1e6 epochs.

Usage::

    python benchmarks/bench_pixel_fa.py [--trials 6700] [--cell 0]

Fault-free sorties of the runway-05 final (campaign ``pixel-benefit``: cell 0 the runway
outline, cell 1 the H/I markers), started uniformly over a day, through the shipped pixel
monitor (its defaults: dithering and attitude in the covariance, radial H1, 12 landmarks).
Prints solved epochs, alerts, the binomial 99 % interval of P_FA · epochs, and the epochs
whose error exceeds the protection level without an alert (misleading).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import stats

from testbed.heap import keep_freed_memory

keep_freed_memory()
from testbed.campaign.blocks import draw_block
from testbed.campaign.context import cell_context  # noqa: E402
from testbed.campaign.spec import expand_cells, load_spec  # noqa: E402
from testbed.integrity.pixel import pixel_monitor  # noqa: E402
from testbed.sim.evaluate import position_errors  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=6700)
    ap.add_argument("--cell", type=int, default=0)
    a = ap.parse_args(argv)
    loaded = load_spec("pixel-benefit", trials=a.trials)
    cell = expand_cells(loaded)[a.cell]
    ctx = cell_context(cell, loaded.spec)
    st = ctx.setup.integrity
    n_blocks = -(-loaded.spec.trials // loaded.spec.block_trials)
    solved = alerts = mi = 0
    t0 = time.perf_counter()
    for b in range(n_blocks):
        d = draw_block(ctx, loaded.spec, b)
        out = pixel_monitor(d.obs.gnss, d.obs.vision, ctx.setup.frame, st)
        ok = np.asarray(out.reason) == 0
        he, ve = position_errors(out, ctx.truth_cg_enu)
        solved += int(ok.sum())
        alerts += int(out.alert[ok].sum())
        with np.errstate(invalid="ignore"):
            mi += int((((he > out.hpl) | (ve > out.vpl)) & ok & ~out.alert).sum())
    wall = time.perf_counter() - t0
    lo, hi = stats.binom.interval(0.99, solved, st.p_fa)
    verdict = "inside" if lo <= alerts <= hi else "OUTSIDE"
    print(f"{cell.params.get('approach')}: {a.trials} sorties, {solved:,} solved epochs in {wall:.0f} s; "
          f"alerts {alerts} at P_FA = {st.p_fa:g} (binomial 99 % interval [{lo:.0f}, {hi:.0f}]: {verdict}); "
          f"misleading epochs {mi}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

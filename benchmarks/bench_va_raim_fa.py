"""Benchmark (statistics at the operating point): fault-free false alarms and HMI of VA-RAIM and
GPS RAIM at the default P_FA over millions of epochs.

Usage::

    python benchmarks/bench_va_raim_fa.py [--trials 100000] [--variants gated seed] [--out DIR]

Runs fault-free campaigns on the VA-RAIM paper's sortie at every camera resolution and detection
error of the reproduction (120/300/480/720 dpi x 1/2/4 px, 61 epochs per sortie: 6.1e6
epochs per setting at the default 1e5 sorties) and on the shipped approaches
(``zunz-rwy05-final``, ``zunz-rwy05-rnp``: sorties enough for >= 6e6 epochs), and prints per
setting and monitor: epochs, alert epochs, the per-epoch false-alarm rate, the binomial 99 %
interval of the count under P_FA, a verdict (inside / ABOVE / below), and HMI epochs.
Record a run with `python benchmarks/report.py run bench_va_raim_fa` (docs/performance.md). A full run takes about 20-25 minutes per variant
on 2 cores.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from scipy import stats

from testbed.campaign.runner import run_campaign
from testbed.campaign.spec import CampaignSpec, resolve_spec
from testbed.integrity.settings import DEFAULT_P_FA
from testbed.resources import campaigns_dir


def spec(name: str, approach: str, trials: int, variants: list[str], sweep: dict) -> CampaignSpec:
    return CampaignSpec.model_validate({
        "name": name, "approaches": [approach], "monitors": ["gps_raim", "va_raim"], "trials": trials,
        "block_trials": 100, "chunk_trials": 1000 if trials >= 1000 else 100, "base_seed": 2026,
        "per_epoch_trials": 0, "faults": [{"kind": "none"}], "sweep": {**sweep, "va_raim_variant": variants}})


def report(out: Path, p_fa: float) -> list[dict]:
    t = pq.read_table(out / "trials.parquet").to_pandas()
    c = pq.read_table(out / "cells.parquet").to_pandas()
    t = t.merge(c, on="cell")
    rows = []
    for (cell, mon), g in t.groupby(["cell", "monitor"]):
        n, k = int(g.epochs.sum()), int(g.alert_epochs.sum())
        lo, hi = stats.binom.interval(0.99, n, p_fa)
        verdict = "inside" if lo <= k <= hi else ("ABOVE" if k > hi else "below")
        r = g.iloc[0]
        rows.append({"approach": r.approach, "dpi": r.dpi, "sigma_px": r.sigma_px, "variant": r.va_raim_variant,
                     "monitor": mon, "epochs": n, "alerts": k, "rate": k / n, "lo": int(lo), "hi": int(hi),
                     "verdict": verdict, "hmi": int(g.hmi_epochs.sum())})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=100_000, help="sorties per seed-sortie setting")
    ap.add_argument("--variants", nargs="+", default=["gated"], choices=["gated", "seed"])
    ap.add_argument("--out", type=Path, help="keep the campaign folders here (default: a temporary folder)")
    ap.add_argument("--no-shipped", action="store_true", help="skip the shipped approaches")
    args = ap.parse_args()
    p_fa = DEFAULT_P_FA
    base = args.out or Path(tempfile.mkdtemp(prefix="bench-fa-"))
    jobs = [("seed-sortie", "va-raim-2015", args.trials,
             {"camera_dpi": [120.0, 300.0, 480.0, 720.0], "detection_sigma_px": [1.0, 2.0, 4.0]})]
    if not args.no_shipped:
        per = -(-6_000_000 // 150)  # the shipped finals are ~150 epochs long
        per = max(100, int(per * args.trials / 100_000))
        jobs += [(a, a, per, {}) for a in ("zunz-rwy05-final", "zunz-rwy05-rnp")]
    rows = []
    for name, approach, trials, sweep in jobs:
        t0 = time.perf_counter()
        loaded = resolve_spec(spec(name, approach, trials, args.variants, sweep), campaigns_dir() / f"{name}.toml")
        run_campaign(loaded, base / name, progress=False, restart=True)
        rows += report(base / name, p_fa)
        print(f"{name}: {time.perf_counter() - t0:.0f} s", flush=True)
    print(f"\nfault-free false alarms at P_FA = {p_fa:g} per epoch (binomial 99 % interval of the count), results in {base}")
    print(f"{'approach':18s} {'dpi':>5s} {'DE':>4s} {'variant':7s} {'monitor':9s} {'epochs':>9s} {'alerts':>7s} "
          f"{'rate':>9s} {'99 % interval':>14s} {'verdict':7s} {'HMI':>4s}")
    for r in rows:
        dpi = "-" if r["dpi"] != r["dpi"] else f"{r['dpi']:.0f}"
        print(f"{r['approach']:18s} {dpi:>5s} {r['sigma_px']:4.0f} {r['variant']:7s} {r['monitor']:9s} "
              f"{r['epochs']:9d} {r['alerts']:7d} {r['rate']:9.2e} {'[' + str(r['lo']) + ', ' + str(r['hi']) + ']':>14s} "
              f"{r['verdict']:7s} {r['hmi']:4d}")
    bad = [r for r in rows if r["verdict"] != "inside" or r["hmi"]]
    print(f"\n{len(rows) - len(bad)} of {len(rows)} (setting, monitor) rows inside the interval with zero HMI")
    if bad:
        print("outside or with HMI: " + "; ".join(f"{r['approach']} {r['dpi']}/{r['sigma_px']} {r['variant']} "
                                                  f"{r['monitor']}: {r['alerts']} ({r['verdict']}), HMI {r['hmi']}"
                                                  for r in bad))
    np.seterr(all="ignore")


if __name__ == "__main__":
    main()

"""Benchmark (statistics at the operating point): fault-free false alarms, misleading information and
protection levels of the Won et al. filter (``ekf``, default options) at the default P_FA over millions
of epochs.

Usage::

    python benchmarks/bench_ekf_fa.py [--epochs 1500000] [--approaches zunz-rwy05-ekf zunz-rwy05-final]

Per shipped approach, a fault-free campaign of the filter alone, its sorties' start times spread over a
day (so the satellites' geometry varies), enough sorties of the whole final (~150 epochs each) for
``--epochs``; then per approach: epochs, alert epochs (the union of the innovation, windowed and
solution-separation tests, each at P_FA/3), the per-epoch rate, the binomial 99 % interval of the
count under P_FA, a verdict (inside / ABOVE / below), the sorties with an alert (a test on filtered
states alerts in runs of epochs, so the count is over-dispersed against the binomial when that number
is much smaller than the count), MI and HMI epochs, the median and maximum of the
sorties' largest HPL and VPL, and the APV-I availability. Record a run with `python benchmarks/report.py run bench_ekf_fa` (docs/performance.md).
The union bound would keep the joint rate at or below P_FA for a filter whose statistics are exactly χ².
At 1.5e6 epochs zunz-rwy05-ekf took 63 minutes and zunz-rwy05-final (8 satellites) 97 minutes on 2 cores (shared with other work).
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


def spec(approach: str, trials: int) -> CampaignSpec:
    return CampaignSpec.model_validate({
        "name": f"ekf-fa-{approach}", "approaches": [approach], "monitors": ["ekf"], "trials": trials,
        "block_trials": 100, "chunk_trials": 1000 if trials >= 1000 else 100, "base_seed": 2013,
        "per_epoch_trials": 0, "faults": [{"kind": "none"}],
        "sorties": {"start": "uniform", "span_s": 86400.0, "window_s": 600.0, "sortie_s": 150.0}})


def main() -> None:
    from testbed.heap import keep_freed_memory

    keep_freed_memory()  # the process settings `testbed campaign` applies (run_campaign, a library call, does not)
    ap = argparse.ArgumentParser()
    ap.add_argument("--epochs", type=int, default=1_500_000, help="fault-free epochs per approach (at least)")
    ap.add_argument("--approaches", nargs="+", default=["zunz-rwy05-ekf", "zunz-rwy05-final"])
    ap.add_argument("--out", type=Path, help="keep the campaign folders here (default: a temporary folder)")
    args = ap.parse_args()
    p_fa = DEFAULT_P_FA
    base = args.out or Path(tempfile.mkdtemp(prefix="bench-ekf-fa-"))
    rows = []
    for approach in args.approaches:
        t0 = time.perf_counter()
        trials = max(100, -(-args.epochs // 150))
        trials = -(-trials // 100) * 100
        loaded = resolve_spec(spec(approach, trials), campaigns_dir() / f"ekf-fa-{approach}.toml")
        run_campaign(loaded, base / approach, progress=False, restart=True)
        t = pq.read_table(base / approach / "trials.parquet").to_pandas()
        n, k = int(t.epochs.sum()), int(t.alert_epochs.sum())
        lo, hi = stats.binom.interval(0.99, n, p_fa)
        rows.append({"approach": approach, "sorties": len(t), "epochs": n, "alerts": k, "rate": k / n,
                     "alerted": int((t.alert_epochs > 0).sum()),
                     "lo": int(lo), "hi": int(hi),
                     "verdict": "inside" if lo <= k <= hi else ("ABOVE" if k > hi else "below"),
                     "mi": int(t.mi_epochs.sum()), "hmi": int(t.hmi_epochs.sum()),
                     "hpl": (float(np.median(t.max_hpl)), float(t.max_hpl.max())),
                     "vpl": (float(np.median(t.max_vpl)), float(t.max_vpl.max())),
                     "apv1": float(np.average(t["avail_APV-I"], weights=t.epochs)),
                     "wall": time.perf_counter() - t0})
        print(f"{approach}: {rows[-1]['wall']:.0f} s ({n / rows[-1]['wall']:.0f} epochs/s)", flush=True)
    print(f"\nekf fault-free at P_FA = {p_fa:g} per epoch (binomial 99 % interval of the count); results in {base}")
    print(f"{'approach':18s} {'sorties':>7s} {'epochs':>9s} {'alerts':>6s} {'rate':>9s} {'99 % interval':>14s} "
          f"{'verdict':7s} {'in sorties':>10s} {'MI':>3s} {'HMI':>3s} {'max HPL med/max':>16s} {'max VPL med/max':>16s} {'APV-I':>6s}")
    for r in rows:
        print(f"{r['approach']:18s} {r['sorties']:7d} {r['epochs']:9d} {r['alerts']:6d} {r['rate']:9.2e} "
              f"{'[' + str(r['lo']) + ', ' + str(r['hi']) + ']':>14s} {r['verdict']:7s} {r['alerted']:10d} {r['mi']:3d} {r['hmi']:3d} "
              f"{r['hpl'][0]:7.1f}/{r['hpl'][1]:<8.1f} {r['vpl'][0]:7.1f}/{r['vpl'][1]:<8.1f} {100 * r['apv1']:5.1f}%")


if __name__ == "__main__":
    main()

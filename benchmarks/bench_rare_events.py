"""Benchmark: wall time to a 95 % upper bound below 10⁻⁷ per epoch on fault-free GPS RAIM (runway-05 final).

Usage::

    python benchmarks/bench_rare_events.py [--start 500] [--bound 1e-7]

Runs the shipped ``raim-hmi-fault-free`` campaign at the approach's own start time (one cell),
importance-sampled, with ``--start`` sorties, then twice as many, until the per-epoch P_HMI is
settled (:func:`testbed.campaign.sampling.weighted_rate`'s diagnostics pass) and the upper end of its
95 % interval is below ``--bound``. Prints each run's wall time, estimate and interval, and the
sorties plain sampling would need for a 95 % upper bound of ``--bound`` with no event
(``ln 0.05 / ln(1 − bound)`` epochs). Each run is a fresh process-level start (the flight is cached
after the first).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--start", type=int, default=500, help="sorties of the first run (doubled until done)")
    ap.add_argument("--bound", type=float, default=1e-7, help="the per-epoch upper bound to reach")
    args = ap.parse_args()

    from testbed.campaign.runner import run_campaign
    from testbed.campaign.sampling import weighted_rate
    from testbed.resources import campaigns_dir

    text = (campaigns_dir() / "raim-hmi-fault-free.toml").read_text()
    text = text[:text.index("[sweep]")] + text[text.index("[sampling]"):]  # the approach's own start time
    trials = args.start
    with tempfile.TemporaryDirectory() as tmp:
        while True:
            spec = Path(tmp) / f"hmi-{trials}.toml"
            spec.write_text(text.replace("trials = 20000", f"trials = {trials}")
                            .replace("chunk_trials = 2000", f"chunk_trials = {min(trials, 2000) // 100 * 100}"))
            t0 = time.perf_counter()
            res = run_campaign(spec, Path(tmp) / f"out-{trials}", progress=False)
            wall = time.perf_counter() - t0
            t = pq.read_table(res.out_dir / "trials.parquet").to_pydict()
            T = int(t["epochs"][0])
            r = weighted_rate(np.asarray(t["hmi_epochs"], float), T, np.asarray(t["log_weight"]), 0.95)
            print(f"{trials} sorties ({trials * T} sortie-epochs): {wall:.1f} s; P_HMI per epoch "
                  + (f"{r.estimate:.3g} [{r.lo:.3g}, {r.hi:.3g}], {r.ess_events:.0f} effective events"
                     if r.settled else r.text()))
            if r.settled and r.hi < args.bound:
                break
            trials *= 2
    plain = math.log(0.05) / math.log1p(-args.bound)
    print(f"plain sampling, no event: {plain:.3g} epochs = {plain / T:.3g} sorties of {T} epochs for a 95 % bound "
          f"of {args.bound:g} per epoch")


if __name__ == "__main__":
    main()

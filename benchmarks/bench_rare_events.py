"""Benchmark: wall time to a 95 % upper bound below 10⁻⁷ per epoch on fault-free GPS RAIM (runway-05 final), and
the DPE's K calibrated at a measured 10⁻⁷ tail.

Usage::

    python benchmarks/bench_rare_events.py [--start 500] [--bound 1e-7] [--sorties 480] [--workers 2] [--dpe-out K.json]
    python benchmarks/bench_rare_events.py --only raim|dpe

The DPE part runs ``testbed calibrate-dpe --method importance`` on ``zunz-rwy05-dpe`` (docs/design/dpe.md §6.8) with
``--sorties`` a set on ``--workers`` processes and prints its wall time beside the command's own estimate, the
machine's load average over it, K,
the measured tail's interval, the held-out check, the seconds a sortie took, and what brute force would take at
that rate: the full tail calibration of docs/design/dpe.md §6.7 (36 000 sorties a set, still extrapolated) and
plain sampling to the same relative standard error at 10⁻⁷ ((1 − P)/(P·rse²) epochs).

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
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq


def dpe(sorties: int, workers: int, out: str | None) -> None:
    """The DPE K at a measured tail: wall time, load, K and the brute-force comparison (module doc)."""
    from testbed.studies.budget import calibration_estimate
    from testbed.studies.dpe_measured import calibrate_dpe_measured

    estimate = calibration_estimate("zunz-rwy05-dpe", sorties, (), "importance", workers)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    rec = calibrate_dpe_measured("zunz-rwy05-dpe", sorties=sorties, workers=workers)  # the command's chunks
    wall = time.perf_counter() - t0
    load1 = os.getloadavg()
    if out:
        from testbed.studies.dpe_calibration import write_record

        write_record(rec, Path(out))
    per_sortie = wall * workers / (2 * sorties)  # process-seconds of wall a sortie, at this run's load
    print(f"DPE K at a measured tail: {2 * sorties} sorties ({rec['trials']} calibration epochs) on {workers} "
          f"processes in {wall / 60:.1f} min; load average {load0:.1f} at the start, {load1[0]:.1f} (1 min) and "
          f"{load1[1]:.1f} (5 min) at the end, on {os.cpu_count()} cores; the command's estimate "
          f"{estimate.wall_s / 60:.1f} min (measured / estimated {wall / estimate.wall_s:.2f})")
    for n, f in (rec["strata"] | {"all strata": rec["overall"]}).items():
        r = f["rate"]
        print(f"  {n}: " + (f"K {f['k']:.3f}, tail {r['estimate']:.3g} [{r['interval'][0]:.3g}, {r['interval'][1]:.3g}], "
                            f"{r['effective_events']:.0f} effective events" if f["k"] is not None else
                            f"not measured at P (deepest settled upper end {f['deepest_settled_upper']:.2g})"))
    for n, r in rec["validation"]["rates"].items():
        print(f"  held-out {n}: " + (f"{r['estimate']:.3g} [{r['interval'][0]:.3g}, {r['interval'][1]:.3g}]"
                                      if r["settled"] else "not settled: " + "; ".join(r["problems"])))
    if rec["k"] is None:
        print("no K: the tail is not measured at P = 1e-7 in every stratum (more sorties)")
    else:
        r = rec["strata"].get(rec["k_from"].removeprefix("stratum '").removesuffix("'"), rec["overall"])["rate"]
        print(f"K = {rec['k']:.3f} ({rec['k_from']}); tail there {r['estimate']:.3g} [{r['interval'][0]:.3g}, "
              f"{r['interval'][1]:.3g}], {r['effective_events']:.0f} effective events, held-out check "
              f"{'PASSED' if rec['validation']['passed'] else 'FAILED'}")
    r = rec["overall"]["rate"]
    if rec["overall"]["k"] is not None:  # the brute-force comparison at the all-strata precision
        lo, hi = r["interval"]
        rse = (hi - lo) / (2 * 1.96 * r["estimate"])
        p = rec["p_hmi"]
        plain = (1 - p) / (p * rse**2)
        epochs = rec["trials"] / sorties
        print(f"brute force at this run's pace ({per_sortie:.2f} s a sortie of {epochs:.0f} epochs per process, "
              f"{workers} processes, the load above): the full tail calibration (2 x 36 000 sorties, still "
              f"extrapolated) {72000 * per_sortie / 3600 / workers:.1f} h; plain sampling to the same relative "
              f"standard error ({100 * rse:.0f} %) at {p:g}: {plain:.2g} epochs, "
              f"{plain / epochs * per_sortie / 3600 / 24 / workers:.3g} days")


def main() -> None:
    from testbed.threads import sleep_idle_threads

    sleep_idle_threads()  # as the command sets it: idle OpenMP threads beside the other worker must not spin
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--start", type=int, default=500, help="sorties of the first run (doubled until done)")
    ap.add_argument("--bound", type=float, default=1e-7, help="the per-epoch upper bound to reach")
    ap.add_argument("--only", choices=("raim", "dpe"), help="run one part (default: both)")
    ap.add_argument("--sorties", type=int, default=480, help="DPE: sorties a set (480: the shipped record's)")
    ap.add_argument("--workers", type=int, default=2, help="DPE: processes")
    ap.add_argument("--dpe-out", help="DPE: write the K record here too")
    args = ap.parse_args()
    if args.only != "dpe":
        raim(args.start, args.bound)
    if args.only != "raim":
        dpe(args.sorties, args.workers, args.dpe_out)


def raim(start: int, bound: float) -> None:
    """GPS RAIM's P_HMI per epoch to a settled upper bound below ``bound`` (module doc)."""
    from testbed.campaign.runner import run_campaign
    from testbed.campaign.sampling import weighted_rate
    from testbed.resources import campaigns_dir

    text = (campaigns_dir() / "raim-hmi-fault-free.toml").read_text()
    text = text[:text.index("[sweep]")] + text[text.index("[sampling]"):]  # the approach's own start time
    trials = start
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
            if r.settled and r.hi < bound:
                break
            trials *= 2
    plain = math.log(0.05) / math.log1p(-bound)
    print(f"plain sampling, no event: {plain:.3g} epochs = {plain / T:.3g} sorties of {T} epochs for a 95 % bound "
          f"of {bound:g} per epoch")


if __name__ == "__main__":
    main()

"""Benchmark: the GNSS/vision/INS EKF core, batched over trials against the same code one trial at a time.

Usage::

    python benchmarks/bench_nav_filter.py [--trials 1000] [--repeats 3]

A 17-state filter step = one IMU predict (strapdown, Φ, Q, P ← ΦPΦᵀ + Q) at 120 Hz;
an aiding update = 7 pseudorange rows (Joseph form) at 1 Hz. Prints median trial-steps/s
for predict and for update, batched (B = --trials, one call per step) and per trial
(B = 1 in a Python loop over trials, the reference a first implementation would be),
and their ratio; and the compiled predict the filter runs (numba, 20 steps a call). docs/design/nav-filter.md
§13's target: ≥ 100k trial-steps/s for a 20-state step and ≥ 10× the per-trial loop. Last, the
50-state filter with unsurveyed features (:mod:`testbed.navigation.slam`).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_ekf import FRAME, NOISE, _state  # noqa: E402

from testbed.navigation.ekf import ClockNoise, N, predict, predict_compiled, pseudorange_rows, update  # noqa: E402


def _take(s, i):
    from dataclasses import fields, replace

    return replace(s, **{f.name: getattr(s, f.name)[i:i + 1] for f in fields(s)})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv)
    B = a.trials
    rng = np.random.default_rng(0)
    s = _state(rng, B)
    dt = 1 / 120
    dth = rng.normal(0, 0.05, (B, 3)) * dt
    dvl = (np.array([0.5, 0.0, -9.8]) + rng.normal(0, 0.5, (B, 3))) * dt
    sats = rng.normal(0, 1, (B, 7, 3)) * 2e7
    clock = ClockNoise()
    lever = np.zeros(3)
    h, H = pseudorange_rows(s, sats, lever)
    nu = rng.normal(0, 3.0, h.shape)
    R = np.broadcast_to(9.0 * np.eye(7), (B, 7, 7))
    mask = np.ones(h.shape, bool)
    n_ref = min(B, 50)
    res = {k: [] for k in ("pred_b", "pred_1", "comp_b", "comp_1", "upd_b", "upd_1")}
    predict_compiled(s, dth, dvl, dt, FRAME, NOISE, clock)  # compile (or load numba's cache)
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        for _ in range(20):
            predict(s, dth, dvl, dt, FRAME, NOISE, clock)
        res["pred_b"].append(20 * B / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        for i in range(n_ref):
            predict(_take(s, i), dth[i:i + 1], dvl[i:i + 1], dt, FRAME, NOISE, clock)
        res["pred_1"].append(n_ref / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        predict_compiled(s, np.repeat(dth[:, None], 20, 1), np.repeat(dvl[:, None], 20, 1), dt, FRAME, NOISE, clock)
        res["comp_b"].append(20 * B / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        for i in range(n_ref):
            predict_compiled(_take(s, i), np.repeat(dth[i:i + 1, None], 20, 1), np.repeat(dvl[i:i + 1, None], 20, 1),
                             dt, FRAME, NOISE, clock)
        res["comp_1"].append(20 * n_ref / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        for _ in range(5):
            update(s, nu, H, R, mask)
        res["upd_b"].append(5 * B / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        for i in range(n_ref):
            update(_take(s, i), nu[i:i + 1], H[i:i + 1], R[i:i + 1], mask[i:i + 1])
        res["upd_1"].append(n_ref / (time.perf_counter() - t0))
    med = {k: statistics.median(v) for k, v in res.items()}
    print(f"{N}-state EKF core, B = {B}:")
    print(f"  predict (IMU step):     batched {med['pred_b']:>10,.0f} trial-steps/s, per trial {med['pred_1']:>8,.0f}"
          f" ({med['pred_b'] / med['pred_1']:.0f}x)")
    print(f"  predict, compiled (the filter's): batched {med['comp_b']:>10,.0f} trial-steps/s, one trial "
          f"{med['comp_1']:>8,.0f} ({med['comp_b'] / med['pred_1']:.0f}x the numpy per-trial loop)")
    print(f"  update (7 pseudoranges): batched {med['upd_b']:>9,.0f} trial-updates/s, per trial {med['upd_1']:>8,.0f}"
          f" ({med['upd_b'] / med['upd_1']:.0f}x)")
    per_s = 1.0 / (120.0 / med["comp_b"] + 1.0 / med["upd_b"])
    print(f"  one simulated second per trial (120 predicts + 1 update): {per_s:,.0f} trial-seconds/s")
    _slam(s, dth, dvl, dt, clock, a.repeats)
    return 0


def _slam(s, dth, dvl, dt, clock, repeats: int) -> None:
    """The filter with unsurveyed features (slam.py: 7 feature slots and 2 clones, 50 states): the compiled core
    predict plus the static block's cross-covariance over a 12-step aiding interval (120 Hz IMU, 10 Hz vision)."""
    from testbed.navigation import slam

    cfg = slam.FeatureSettings()
    st = slam.start(s, cfg)
    B = s.p.shape[0]
    d12, v12 = np.repeat(dth[:, None], 12, 1), np.repeat(dvl[:, None], 12, 1)
    slam.predict_static(st, d12, v12, dt, FRAME, NOISE, clock)
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(5):
            slam.predict_static(st, d12, v12, dt, FRAME, NOISE, clock)
        rates.append(5 * 12 * B / (time.perf_counter() - t0))
    print(f"{cfg.size()}-state filter with features (static block), B = {B}: predict "
          f"{statistics.median(rates):>10,.0f} trial-steps/s (12-step aiding intervals)")


if __name__ == "__main__":
    raise SystemExit(main())

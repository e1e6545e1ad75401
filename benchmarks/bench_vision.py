"""Cost of the vision sensor and the in-view figures of the two reference scenarios.

Run: python benchmarks/bench_vision.py [--trials 1000] [--runs 3]

1. Seed scenario (the VA-RAIM paper §3.1, 60 s at 10 Hz, 3 landmarks, va-raim-2015 @ 720 dpi):
   median wall time of ``synthesize_vision`` for one flight and for ``--trials`` trials,
   without terrain and with the two-ridge terrain (TwoRidges).
2. ZUNZ runway-05 3° final from 13 km (24 runway points, approach-1080p): where the
   points come into view, with and without the apparent-size rule, with the
   synthetic LinZhi valley terrain when available.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from testbed.flight.kinematic import straight_truth
from testbed.frames import LocalFrame
from testbed.sensors.vision import VisionSettings, seed_triangle_settings, synthesize_vision, zunz_runway_settings
from testbed.world import airport


def seed_truth():
    fr = LocalFrame(*airport.VA_RAIM_CENTRE)
    a = fr.geodetic_to_enu(29.3065, 94.2539, 3650.0)
    b = fr.geodetic_to_enu(29.3065, 94.3144, 3150.0)
    return straight_truth(fr, a, b, 60.0, rate_hz=10.0)


def runway_truth(distance_m=13_000.0, tch_m=15.0, speed=72.0):
    fr = airport.runway_frame()
    c = math.radians(airport.RWY05_COURSE_DEG)
    along = np.array([math.sin(c), math.cos(c), 0.0])
    start = -distance_m * along + [0.0, 0.0, tch_m + distance_m * math.tan(math.radians(3.0))]
    end = np.array([0.0, 0.0, tch_m])
    return straight_truth(fr, start, end, float(np.linalg.norm(end - start)) / speed, rate_hz=10.0)


def timed(fn, runs):
    walls = []
    for _ in range(runs):
        t0 = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
    return statistics.median(walls), out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    try:
        from testbed.world.terrain import TwoRidges
        from testbed.world.valley import LinZhiSyntheticValley
    except ImportError:  # the terrain room is optional here
        TwoRidges = LinZhiSyntheticValley = None

    tr = seed_truth()
    s = VisionSettings(camera={"preset": "va-raim-2015", "dpi": 720})
    lms = seed_triangle_settings()
    for label, terrain in (("no terrain", None), ("TwoRidges", TwoRidges() if TwoRidges else None)):
        if label != "no terrain" and terrain is None:
            continue
        w1, (ep, _) = timed(lambda: synthesize_vision(tr, s, landmarks=lms, terrain=terrain,
                                                      rng=np.random.default_rng(0)), args.runs)
        wn, (epn, _) = timed(lambda: synthesize_vision(tr, s, landmarks=lms, terrain=terrain,
                                                       rng=np.random.default_rng(0), n_trials=args.trials), args.runs)
        cells = epn.detected.size
        print(f"seed, {label:10s}: 1 flight {w1 * 1e3:7.1f} ms; {args.trials} trials {wn:6.2f} s "
              f"({cells / wn / 1e6:.2f} M landmark-epochs/s); detected fraction {epn.detected.mean():.4f}")

    tr = runway_truth()
    dist = np.linalg.norm(tr.decimate(10.0).pos_enu[:, :2], axis=1)
    valley = LinZhiSyntheticValley() if LinZhiSyntheticValley else None
    for label, det, terrain in (("geometric (20 km max range)", {}, None),
                                ("size rule 5 m >= 2 px", {"min_size_px": 2.0}, None),
                                ("geometric + LinZhi valley", {}, valley)):
        if "valley" in label and terrain is None:
            continue
        w, (ep, vt) = timed(lambda: synthesize_vision(tr, VisionSettings(detection=det), landmarks=zunz_runway_settings(),
                                                      terrain=terrain, rng=np.random.default_rng(0)), 1)
        print(f"runway 05 final, {label} ({w * 1e3:.0f} ms):")
        for k, name in enumerate(ep.landmark_id):
            d = ep.detected[:, k]
            if not d.any():
                print(f"  {name:9s} never detected; reasons {sorted(set(ep.reason[:, k].tolist()))}")
                continue
            i, j = int(np.argmax(d)), len(d) - 1 - int(np.argmax(d[::-1]))
            print(f"  {name:9s} in view from {dist[i]:7.0f} m to threshold (slant range {vt.range_m[i, k]:7.0f} m)"
                  f" until {dist[j]:5.0f} m; detected {d.mean():.3f} of epochs")


if __name__ == "__main__":
    main()

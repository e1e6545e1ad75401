"""The ekf monitor with and without range-rate rows on zunz-rwy05-ekf over several seeds: the mean normalised
squared position error (e/σ)² per axis (E, N, U) and per satellite count (6, 3, 2, 1), and HPE95 per seed.

A consistent filter gives ~1 per axis (noisy: a few correlated flights). Run:
``python benchmarks/ekf_range_rate_seeds.py [--seeds 4]`` (~1 min).
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from testbed.api import load_approach, run_approach
from testbed.monitors import monitor_options


def main(seeds: int) -> None:
    for rr in (False, True):
        ap = load_approach("zunz-rwy05-ekf")
        ekf = monitor_options("ekf", ap.config.monitor).model_copy(update={"range_rate": rr})
        cfg = ap.config.model_copy(update={"monitor": {**ap.config.monitor, "ekf": ekf},
                                           "monitors": ["gps_raim", "ekf"]})
        z2, hpe = [], []
        for seed in range(seeds):
            r = run_approach(dataclasses.replace(ap, config=cfg), rrd_path=None, seed=seed)
            o = r.outputs["ekf"]
            d = o.pos_enu - r.loop.truth_at_gnss.pos_enu
            z2.append((d / o.diagnostics.sigma_enu) ** 2)
            hpe.append(r.summaries["ekf"].hpe95)
        z = np.mean(z2, 0)
        nvis = np.asarray(r.loop.gnss.visible).sum(-1)
        seg = {k: np.round(z[nvis == k].mean(0), 1).tolist() for k in (6, 3, 2, 1) if (nvis == k).any()}
        print(f"range-rate rows {'on ' if rr else 'off'}: mean (e/σ)² E,N,U by satellites in view {seg}; "
              f"HPE95 per seed {np.round(hpe, 2).tolist()} m")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4)
    main(ap.parse_args().seeds)

"""Benchmark: GNSS pseudoranges synthesised per second (trials × epochs × satellite slots).

Geometry (orbits, light time, visibility) is computed once per trajectory and
timed separately; the sampling step (noise, clock, faults, range rates) is the
part a campaign repeats. Run: ``/work/venv/bin/python benchmarks/bench_gnss.py``.
"""

from __future__ import annotations

import time

import numpy as np

from testbed.flight.kinematic import straight_truth
from testbed.records import Mount
from testbed.sensors.faults import GpsStep
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss
from testbed.world.airport import runway_frame


def main(n_trials: int = 1000, duration_s: float = 120.0) -> None:
    frame = runway_frame()
    truth = straight_truth(frame, [-9000.0, -6400.0, 650.0], [-1000.0, -700.0, 60.0], duration_s, rate_hz=1.0)
    s = GnssSettings(terrain_masking=False)
    t0 = time.perf_counter()
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc="2024-03-15T06:00:00Z")
    t_geom = time.perf_counter() - t0
    T, S = g.visible.shape
    for label, settings, faults in [
        ("white noise", s, []),
        ("Gauss-Markov multipath + URA/tropo", s.model_copy(update={"multipath_tau_s": 30.0, "ura_tropo_tau_s": 600.0}), []),
        ("white + 300 m step fault", s, [GpsStep(kind="gps_step", bias_m=300.0, onset_s=30.0, prn=int(g.prn[g.visible[0]][0]))]),
    ]:
        rng = np.random.default_rng(0)
        sample_gnss(g, settings, faults=faults, rng=rng, n_trials=10)  # warm-up
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            sample_gnss(g, settings, faults=faults, rng=rng, n_trials=n_trials)
            best = min(best, time.perf_counter() - t0)
        n = n_trials * T * S
        print(f"{label:40s}: {n_trials} trials × {T} epochs × {S} slots = {n:,} pseudoranges in {best:.3f} s "
              f"-> {n / best / 1e6:.1f} M/s ({n_trials * T * int(g.visible.sum(1).mean()) / best / 1e6:.1f} M/s visible)")
    print(f"geometry once: {T} epochs × {S} satellites in {t_geom * 1e3:.1f} ms")


if __name__ == "__main__":
    main()

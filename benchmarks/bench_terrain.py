"""Terrain query speed: scalar height, vectorised height, line of sight, sky visibility, horizon.

Run: ``/work/venv/bin/python benchmarks/bench_terrain.py [--rays 10000]``.
Rays start over the synthetic valley along the approach (along-track -14..+5 km,
+-1.5 km across, 30-1500 m above the terrain). Sky directions are uniform over the
upper hemisphere (and a low-elevation set, 0-15 deg, the expensive case); ground
targets are landmarks 2 m above the terrain 0.5-12 km away.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pymap3d.vincenty

from testbed.frames import R_ecef_to_enu, geodetic_to_ecef
from testbed.world import airport
from testbed.world.terrain import Flat, TwoRidges
from testbed.world.valley import LinZhiSyntheticValley, valley_centreline


def _best(fn, repeat: int = 3) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _origins(t, rng, n):
    a = rng.uniform(-14000, 5000, n)
    lat, lon = valley_centreline(a)
    side = rng.uniform(-1500, 1500, n)
    lat, lon = pymap3d.vincenty.vreckon(lat, lon, np.abs(side), np.where(side > 0, 144.65, 324.65))
    return geodetic_to_ecef(lat, lon, t.height(lat, lon) + rng.uniform(30, 1500, n)), lat, lon


def _dirs(lat, lon, az, el):
    d_enu = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    return np.einsum("...ji,...j->...i", R_ecef_to_enu(lat, lon), d_enu)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--rays", type=int, default=10_000)
    n = ap.parse_args().rays
    rng = np.random.default_rng(0)

    t0 = time.perf_counter()
    valley = LinZhiSyntheticValley()
    print(f"LinZhiSyntheticValley build: {time.perf_counter() - t0:.2f} s "
          f"(grid {valley._H.shape}, {valley._H.nbytes / 1e6:.0f} MB, step {valley.step_m:.1f} m)")

    for t in (valley, Flat(), TwoRidges()):
        k = 20_000
        dt = _best(lambda: [t.height(29.3, 94.33) for _ in range(k)])
        print(f"height scalar  {type(t).__name__:22s} {1e6 * dt / k:8.2f} us/call")
    lat = rng.uniform(29.1, 29.5, 1_000_000)
    lon = rng.uniform(94.1, 94.6, 1_000_000)
    dt = _best(lambda: valley.height(lat, lon))
    print(f"height vector  LinZhiSyntheticValley  {1e9 * dt / lat.size:8.1f} ns/point (1e6 points)")

    o, olat, olon = _origins(valley, rng, n)
    cases = {
        "sky_visible, hemisphere": _dirs(olat, olon, rng.uniform(0, 2 * np.pi, n),
                                         np.arcsin(rng.uniform(0, 1, n))),
        "sky_visible, el 0-15 deg": _dirs(olat, olon, rng.uniform(0, 2 * np.pi, n),
                                          np.radians(rng.uniform(0, 15, n))),
    }
    for label, d in cases.items():
        dt = _best(lambda: valley.sky_visible(o, d), repeat=2)
        vis = valley.sky_visible(o, d)
        print(f"{label:28s} {n / dt:10.0f} rays/s  ({1e3 * dt:.0f} ms for {n}; {vis.mean():.0%} visible)")
    tlat, tlon = pymap3d.vincenty.vreckon(olat, olon, rng.uniform(500, 12000, n), rng.uniform(0, 360, n))
    tgt = geodetic_to_ecef(tlat, tlon, valley.height(tlat, tlon) + 2.0)
    dt = _best(lambda: valley.line_of_sight(o, tgt), repeat=2)
    los = valley.line_of_sight(o, tgt)
    print(f"{'line_of_sight, landmarks':28s} {n / dt:10.0f} rays/s  ({1e3 * dt:.0f} ms for {n}; {los.mean():.0%} clear)")
    d = cases["sky_visible, hemisphere"]
    dt = _best(lambda: valley.sky_visible(o[0], d[0]), repeat=20)
    print(f"{'sky_visible, one ray':28s} {1e6 * dt:10.0f} us")

    la, lo = valley_centreline(-6000.0)
    h = valley.height(float(la), float(lo)) + 100.0
    az = np.radians(np.arange(0.0, 360.0, 1.0))
    dt = _best(lambda: valley.horizon(float(la), float(lo), h, az), repeat=2)
    print(f"horizon, 360 azimuths to 150 km: {1e3 * dt:.0f} ms")
    dt = _best(lambda: valley.mesh(airport.runway_frame(), 20e3, 100.0), repeat=2)
    v, f = valley.mesh(airport.runway_frame(), 20e3, 100.0)
    print(f"mesh 40x40 km at 100 m: {1e3 * dt:.0f} ms ({len(v)} vertices, {len(f)} triangles)")


if __name__ == "__main__":
    main()

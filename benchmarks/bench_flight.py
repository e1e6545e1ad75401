"""Real-time factor of the default approach, flight only, vs bare JSBSim stepping.

Run: python benchmarks/bench_flight.py [--runs 5]
Prints the median wall time and real-time factor of `fly()` on zunz-rwy05-final
(calm air, synthetic terrain fed to JSBSim at 10 Hz), and, measured side by side
in the same run, bare JSBSim steps/s with no guidance, to show what our Python
loop costs.
"""

from __future__ import annotations

import argparse
import statistics
import time

from testbed.api import fly_approach, load_approach, load_terrain_for
from testbed.flight.jsbsim_fdm import InitialCondition, JSBSimAircraft


def bare_steps_per_s(n: int = 20000) -> float:
    with JSBSimAircraft("737", 2) as ac:
        ac.trim(InitialCondition(29.25, 94.27, 3600.0, 54.65, 145.0, -3.0, 2949.0), 0.75, True, 0.0)
        t0 = time.perf_counter()
        for _ in range(n):
            ac.step()
        return n / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    approach = load_approach("zunz-rwy05-final")
    load_terrain_for(approach)  # warm caches
    walls, rtf, steps = [], [], 0
    for _ in range(args.runs):
        r = fly_approach(approach)
        walls.append(r.summary.wall_s)
        rtf.append(r.summary.realtime_factor)
        steps = r.summary.steps
    bare = statistics.median(bare_steps_per_s() for _ in range(3))
    loop = steps / statistics.median(walls)
    print(f"zunz-rwy05-final, {steps} steps of 1/120 s, {args.runs} runs")
    print(f"  fly(): median wall {statistics.median(walls):.3f} s, real-time factor {statistics.median(rtf):.0f}x "
          f"(min {min(rtf):.0f}x, max {max(rtf):.0f}x), {loop:,.0f} steps/s")
    print(f"  bare JSBSim 737: {bare:,.0f} steps/s = {bare / 120:.0f}x real time")
    print(f"  ratio closed loop / bare: {loop / bare:.2f}")


if __name__ == "__main__":
    main()

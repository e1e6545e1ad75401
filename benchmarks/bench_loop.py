"""End-to-end speed of `testbed fly` on the default approach: flight + sensors + all monitors + recording.

Run: python benchmarks/bench_loop.py [--runs 3] [--approach zunz-rwy05-final]
Prints, per run and as medians: the real-time factor of the loop (simulated
seconds / wall seconds of run_loop), the split between flight, sensors,
monitors (and per monitor) and logging, the set-up time (terrain, scene, recording start) kept
apart, and the recording size. Measured side by side with a flight-only run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from testbed.api import fly_approach, load_approach, load_terrain_for
from testbed.heap import keep_freed_memory
from testbed.sim.loop import run_loop
from testbed.sim.setup import build_scene, build_setup, prepare_monitors
from testbed.viz.rerun_sink import RerunSink

keep_freed_memory()  # as the CLI and campaigns do (off with TESTBED_SYSTEM_MALLOC=1)


def one_run(approach, tmp: Path, k: int, block_s: float) -> dict:
    t0 = time.perf_counter()
    setup = build_setup(approach, load_terrain_for(approach))
    prepare_monitors(setup)
    sink = RerunSink(tmp / f"bench{k}.rrd", recording_id=f"bench{k}")
    sink.start(build_scene(setup, setup.vision.camera.build()))
    t1 = time.perf_counter()
    res = run_loop(setup, seed=k, sinks=[sink], block_s=block_s)
    t2 = time.perf_counter()
    sink.close()
    t3 = time.perf_counter()
    sim = res.flight.summary.duration_s
    tm = res.timings.as_dict()
    tm["logging"] += t3 - t2  # flushing the file belongs to logging
    return {"setup_s": t1 - t0, "loop_s": t3 - t1, "rtf": sim / (t3 - t1), "sim_s": sim, **tm,
            **{f"monitor:{m}": v for m, v in res.timings.per_monitor.items()},
            "rrd_mb": os.path.getsize(tmp / f"bench{k}.rrd") / 2**20}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--approach", default="zunz-rwy05-final")
    ap.add_argument("--block", type=float, default=5.0, help="simulated seconds per live block")
    args = ap.parse_args()
    approach = load_approach(args.approach)
    load_terrain_for(approach)  # build the terrain once (cached per process), as a campaign would
    with tempfile.TemporaryDirectory() as d:
        runs = [one_run(approach, Path(d), k, args.block) for k in range(args.runs)]
    flight_only = statistics.median(fly_approach(approach).summary.realtime_factor for _ in range(args.runs))
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    print(f"{args.approach}: {med['sim_s']:.0f} s simulated, monitors {', '.join(approach.config.monitors)}, "
          f"{args.runs} runs (medians), blocks of {args.block:g} s")
    print(f"  loop with recording: {med['loop_s']:.2f} s wall = {med['rtf']:.0f}x real time "
          f"(flight only, same process: {flight_only:.0f}x)")
    tot = med["flight"] + med["sensors"] + med["monitors"] + med["logging"]
    for k in ("flight", "sensors", "monitors", "logging"):
        print(f"    {k:9s} {med[k]:.2f} s ({100 * med[k] / tot:.0f} %)")
    for k in sorted(k for k in med if k.startswith("monitor:")):
        print(f"      {k[8:]:9s} {med[k]:.2f} s")
    print(f"  set-up (terrain cached, scene mesh, recording start): {med['setup_s']:.2f} s")
    print(f"  recording size: {med['rrd_mb']:.1f} MiB")


if __name__ == "__main__":
    main()

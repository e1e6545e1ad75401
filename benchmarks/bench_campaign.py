"""Benchmark: campaign throughput in sortie-epochs per second (GPS RAIM + VA-RAIM).

Usage::

    /work/venv/bin/python benchmarks/bench_campaign.py [--trials 2000] [--block 100] [--chunk 1000]

Runs a fault-free + GPS-step campaign on the seed-000 sortie (approach
``va-raim-2015``, 61 epochs at 1 Hz, 720 dpi, DE 1 px) in-process, into a
temporary folder, and prints: wall time, trials/s, sortie-epochs/s (after the
one-off flight and geometry, which are timed separately), and the projected
time of ``testbed reproduce va-raim-2015 --full`` (1e5 sorties x 60 s = ~6e6
epochs per setting) per setting and for all its settings, on one process and on
this machine's cores.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

SPEC = """
name = "bench"
approaches = ["va-raim-2015"]
monitors = ["gps_raim", "va_raim"]
trials = {trials}
block_trials = {block}
chunk_trials = {chunk}
base_seed = 1
per_epoch_trials = 20

[[faults]]
kind = "gps_step"
magnitudes = [0.0, 50.0]
onset_s = 20.0

[sweep]
camera_dpi = [720.0]
"""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=2000, help="trials per cell (2 cells)")
    ap.add_argument("--block", type=int, default=100)
    ap.add_argument("--chunk", type=int, default=1000)
    args = ap.parse_args()

    from testbed.campaign.reproduce import FULL_TRIALS, experiments
    from testbed.campaign.runner import cell_context, run_campaign
    from testbed.campaign.spec import expand_cells, load_spec

    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "bench.toml"
        spec.write_text(SPEC.format(trials=args.trials, block=args.block, chunk=args.chunk))
        loaded = load_spec(spec)
        t0 = time.perf_counter()
        for c in expand_cells(loaded):
            cell_context(c)  # flight (JSBSim) + geometry, once
        setup_s = time.perf_counter() - t0
        res = run_campaign(loaded, Path(tmp) / "out", progress=False)
    n_trials = res.trials
    eps = res.epochs_per_s
    print(f"flight + geometry (once): {setup_s:.2f} s")
    print(f"{n_trials} sorties x 61 epochs (GPS RAIM + VA-RAIM) in {res.wall_s:.2f} s: "
          f"{n_trials / res.wall_s:,.0f} sorties/s, {eps:,.0f} sortie-epochs/s (one process)")
    per_setting = 6e6 / eps
    cores = os.cpu_count() or 1
    settings = sum(len(expand_cells_of(s)) for s in experiments(FULL_TRIALS).values())
    print(f"projected --full: {per_setting / 60:.1f} min per setting (6e6 epochs) on one process, "
          f"{per_setting / 60 / cores:.1f} min on {cores} cores;")
    print(f"  all {settings} settings of the reproduction: {settings * per_setting / 3600:.1f} h on one process, "
          f"{settings * per_setting / 3600 / cores:.1f} h on {cores} cores "
          f"(VA-RAIM-only settings are faster; a Dask cluster divides it further)")


def expand_cells_of(spec):
    from testbed.campaign.reproduce import loaded_experiments  # noqa: F401
    from testbed.campaign.spec import expand_cells, resolve_spec
    from testbed.config import approaches_dir

    return expand_cells(resolve_spec(spec, approaches_dir() / "campaigns" / "x.toml"))


if __name__ == "__main__":
    main()

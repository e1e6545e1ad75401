"""Benchmark: the resource estimate (testbed.sim.budget, testbed.campaign.budget) against measured runs.

Usage::

    python benchmarks/bench_budget.py            # predicted vs measured peak RSS and wall time of campaigns
    python benchmarks/bench_budget.py --fit      # the per-monitor constants: a draw block's traced bytes and time

Without ``--fit``: each case runs ``python -m testbed.cli campaign ... --workers 1 --no-report --quiet`` in a
fresh process (the driver's own process: its blocks on one thread per core), and prints the estimate the
command printed before it started beside the process's peak resident set size (``os.wait4``'s ru_maxrss)
and its wall time, and their ratios.

With ``--fit``: for each monitor alone on its shipped approach, a draw block of n1 and n2 trials
(:func:`testbed.campaign.blocks.run_block`, after a warm-up) is traced with ``tracemalloc`` (numpy reports its
allocations there) and timed on one thread; the slope per trial-epoch is the monitor's figure (the GNSS draw
and the camera frames included: testbed.sim.budget subtracts them).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's testbed, as the commands it runs (cwd ROOT) use

#: (label, spec name or TOML text, --trials)
CASES = [
    ("quick-look, 200 trials (block 100)", "quick-look", 200),
    ("GPS step sweep, blocks of 1000", """
name = "budget-big-blocks"
approaches = ["va-raim-2015"]
monitors = ["gps_raim", "va_raim"]
trials = 2000
block_trials = 1000
chunk_trials = 2000
per_epoch_trials = 10
[[faults]]
kind = "gps_step"
magnitudes = [0.0, 50.0]
""", None),
    ("pixel-benefit, 50 trials (block 50)", "pixel-benefit", 50),
    ("dpe-vs-raim, 4 trials", "dpe-vs-raim", 4),
]


def run_case(spec: str, trials: int | None, folder: Path) -> tuple[float, float, str]:
    """(peak RSS bytes, wall s, the estimate line) of one campaign command in a fresh process."""
    if "\n" in spec:
        path = folder / "spec.toml"
        path.write_text(spec.replace('approaches = ["va-raim-2015"]',
                                     f'approaches = ["{ROOT / "approaches" / "va-raim-2015.toml"}"]'))
        spec = str(path)
    argv = [sys.executable, "-m", "testbed.cli", "campaign", spec, "--out", str(folder / "out"), "--workers", "1",
            "--no-report", "--quiet", "--allow-large"] + (["--trials", str(trials)] if trials else [])
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{out}")
    line = next((ln for ln in out.splitlines() if ln.startswith("estimate for")), "")
    return usage.ru_maxrss * 1024.0, wall, line


def compare() -> None:
    from testbed.campaign.budget import campaign_estimate
    from testbed.campaign.spec import load_spec

    print(f"{'case':38s} {'predicted':>10s} {'measured':>10s} {'ratio':>6s}   {'predicted':>9s} {'measured':>9s} "
          f"{'ratio':>6s}")
    for label, spec, trials in CASES:
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            rss, wall, _ = run_case(spec, trials, folder)
            src = folder / "spec.toml" if "\n" in spec else spec
            est = campaign_estimate(load_spec(src, trials=trials), workers=1)
        print(f"{label:38s} {est.peak_bytes / 1e9:8.2f} GB {rss / 1e9:7.2f} GB {est.peak_bytes / rss:6.2f}   "
              f"{est.wall_s:7.1f} s {wall:7.1f} s {est.wall_s / wall:6.2f}", flush=True)
    print("memory: the estimate against the process's peak resident set; time: against the whole command's wall "
          "time (its start, the spec's checks and the store included)")


#: (approach, monitor, n1, n2, duration_s) of the --fit probes
FIT = [("va-raim-2015", "gps_raim", 20, 100, 60.0), ("va-raim-2015", "va_raim", 20, 100, 60.0),
       ("zunz-rwy05-markers", "va_raim", 1, 3, 10.0), ("va-raim-2015", "pixel", 20, 100, 60.0),
       ("zunz-rwy05-markers", "pixel", 5, 25, 60.0), ("zunz-rwy05-ekf", "ekf", 5, 20, 60.0),
       ("zunz-rwy05-slam", "ekf", 5, 20, 60.0), ("zunz-rwy05-dpe", "dpe", 2, 6, 60.0)]


def fit_one(approach: str, monitor: str, n1: int, n2: int, duration_s: float) -> dict:
    import numpy as np

    from testbed.campaign import blocks
    from testbed.campaign import context
    from testbed.campaign import plan
    from testbed.campaign.spec import CampaignSpec, resolve_spec
    from testbed.resources import campaigns_dir

    d = dict(name="fit", approaches=[approach], monitors=[monitor], trials=n2, block_trials=n2, chunk_trials=n2,
             per_epoch_trials=0, duration_s=duration_s)
    loaded = resolve_spec(CampaignSpec.model_validate(d), campaigns_dir() / "fit.toml")
    ctx = context.cell_context(plan.cells_of(loaded)[0], loaded.spec)
    T = ctx.t.size
    res = {}
    for n in (n1, n2):
        sp = loaded.spec.model_copy(update={"block_trials": n, "trials": n, "chunk_trials": n})
        blocks.run_block(ctx, sp, 0)  # warm (kernels, caches)
        tracemalloc.start()
        blocks.run_block(ctx, sp, 0)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        t0 = time.perf_counter()
        blocks.run_block(ctx, sp, 0)
        res[n] = (peak, time.perf_counter() - t0)
    (p1, t1), (p2, t2) = res[n1], res[n2]
    return {"approach": approach, "monitor": monitor, "epochs": T, "satellites": int(np.shape(ctx.g_geom.sat_pos_ecef)[-2]),
            "landmarks": 0 if ctx.landmarks is None else len(ctx.landmarks),
            "bytes_per_trial_epoch": round((p2 - p1) / ((n2 - n1) * T)),
            "bytes_per_block_beside": round(p1 - (p2 - p1) / (n2 - n1) * n1),
            "us_per_trial_epoch": round((t2 - t1) / ((n2 - n1) * T) * 1e6, 2)}


def fit() -> None:
    for case in FIT:  # each in its own process: no cache or memo of one probe helps the next
        out = subprocess.run([sys.executable, __file__, "--fit-one", json.dumps(case)], cwd=ROOT,
                             capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
        print(out.stdout.strip() or out.stderr[-2000:], flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fit", action="store_true", help="measure the per-monitor constants")
    ap.add_argument("--fit-one", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.fit_one:
        print(json.dumps(fit_one(*json.loads(args.fit_one))))
    elif args.fit:
        fit()
    else:
        compare()


if __name__ == "__main__":
    main()

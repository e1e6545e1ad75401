"""Benchmark: where a reproduction experiment's time goes, and the floor its compiled kernels set.

Usage::

    python benchmarks/bench_campaign_breakdown.py [--experiment where-vision-pays] [--sorties 300]

Runs chunk 0 (``--sorties`` sorties) of every setting of one experiment of
``testbed reproduce va-raim-2015`` as the driver does (one chunk row, block-major, shared
draws on), on one thread under :mod:`cProfile`, and splits its time into: the compiled
kernels (:mod:`testbed.integrity.kernels`, their own time), the monitors' numpy glue (the
rest of the monitors' time), the draws, the tables, and the rest. Prints milliseconds per
block-cell (100 sorties of one setting) and, for each part, the experiment's ``--full``
projection on two worker processes if that part were all that remained (the kernels' share is
the floor that only faster kernels lower). The profiler adds a few per cent to the Python
parts; the shares, not the absolute times, are the figures to read
(``benchmarks/bench_campaign.py`` times the projection itself).

Then, for an experiment whose faults start after the sortie does (a GPS step or pixel bias
from 20 s), the most that sharing the epochs before the onset across its fault magnitudes could
save (not built): chunk 1 again without the profiler, each cell with a fault of non-zero size
also monitored from the onset on only (its observations from there, cut once per record as the
cells share records), against the whole sortie. Under common random numbers those cells'
observations before the onset are the zero-size cell's, and the monitors are causal, so the
difference is an upper bound: it leaves out the few epochs a stateful monitor carries over
(VA-RAIM's calibration and last-fix epochs, which differ between the cameras of a sweep and so
also keep them from sharing VA-RAIM's step 1 after the onset) and joining the two parts of
each output.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import pstats

#: (label, functions whose cumulative time the part is) in the order they are subtracted
PARTS = (
    ("draws", ("draw_block",)),
    ("tables", ("_shared_tables", "_paired_columns", "_chunk_tables")),
    ("monitors", ("monitor_block",)),
)


def main() -> None:
    from testbed.campaign_cli import _positive_int  # argparse prints its message and exits 2
    from testbed.studies.reproduce import experiments

    ap = argparse.ArgumentParser()
    ap.add_argument("--experiment", default="where-vision-pays", choices=sorted(experiments(200)))
    ap.add_argument("--sorties", type=_positive_int, default=300,
                    help="sorties per setting (chunk 0; a multiple of the reproduction's 100-sortie blocks)")
    args = ap.parse_args()
    if args.sorties % 100:
        ap.error(f"--sorties: expected a multiple of 100, got {args.sorties}")

    from testbed import memo
    from testbed.studies.reproduce import FULL_TRIALS, loaded_experiments
    from testbed.campaign.context import cell_context
    from testbed.campaign.runner import run_chunk, run_chunk_row
    from testbed.campaign.spec import expand_cells
    from testbed.heap import keep_freed_memory

    keep_freed_memory()  # as the campaign driver runs
    le = loaded_experiments(2 * args.sorties)[args.experiment]
    le = dataclasses.replace(le, spec=le.spec.model_copy(update={"chunk_trials": args.sorties}))
    cells = expand_cells(le)
    for c in cells:
        cell_context(c, le.spec)
    run_chunk(le, 0, 1)  # compile and warm on blocks the timed chunk does not draw
    memo.clear()
    prof = cProfile.Profile()
    prof.enable()
    run_chunk_row(le, 0, list(range(len(cells))), threads=1)
    prof.disable()
    stats = pstats.Stats(prof).stats  # {(file, line, name): (cc, nc, tottime, cumtime, callers)}
    total = max(v[3] for v in stats.values())
    cum = {}
    for (_, _, fn), v in stats.items():
        cum[fn] = cum.get(fn, 0.0) + v[3]
    kernels = sum(v[2] for (f, _, _), v in stats.items() if "/integrity/kernels/" in f.replace("\\", "/"))
    parts = {label: sum(cum.get(fn, 0.0) for fn in fns) for label, fns in PARTS}
    parts["monitors"] -= kernels  # the monitors' own time beside their compiled kernels: the glue
    shares = {"compiled kernels": kernels, "monitor glue": parts["monitors"], "draws": parts["draws"],
              "tables": parts["tables"]}
    shares["rest"] = total - sum(shares.values())
    block_cells = len(cells) * args.sorties / le.spec.block_trials
    full_s = total * FULL_TRIALS / args.sorties / 2  # two worker processes: two chunk rows side by side
    print(f"{args.experiment}: {len(cells)} settings x {args.sorties} sorties, one thread under cProfile: "
          f"{total:.2f} s, {total / block_cells * 1e3:.1f} ms per block-cell")
    for label, s in shares.items():
        print(f"  {label:17s} {s / block_cells * 1e3:6.2f} ms per block-cell ({100 * s / total:4.1f} %) -> "
              f"--full {full_s * s / total / 60:5.1f} min on two workers if it were all that remained")
    floor = total - shares["monitor glue"] - shares["rest"]  # what fusing the glue into the kernels would leave
    print(f"  kernels + draws + tables together: {100 * floor / total:4.1f} % -> --full {full_s * floor / total / 60:5.1f} "
          "min: the floor while the kernels, draws and tables stay as they are")
    prefix_bound(le, cells)


def prefix_bound(le, cells) -> None:
    """Print the upper bound of sharing the epochs before the fault onset (module doc)."""
    import time

    import numpy as np

    from testbed import memo
    from testbed.campaign import blocks
    from testbed.campaign import context
    from testbed.campaign import runner
    from testbed.records import take_epochs

    ctxs = [context.cell_context(c, le.spec) for c in cells]
    onsets = {ctx.onset_s for ctx in ctxs if np.isfinite(ctx.onset_s)}
    if not onsets:
        print(f"  sharing the epochs before a fault onset: {le.spec.name} has no fault onset, nothing to share")
        return
    t = ctxs[0].t
    k0 = int(np.searchsorted(t, min(onsets) - 1e-9))
    acc = {"whole": 0.0, "faulty whole": 0.0, "faulty late": 0.0}
    cur = {}
    run_block, monitor_block = runner.run_block, blocks.monitor_block  # where run_chunk_row and run_block call them

    def block(ctx, spec, b):
        cur["faulty"] = ctx.cell.params.get("fault_size", 0.0) != 0.0
        return run_block(ctx, spec, b)

    def timed(mons, obs, correlators):
        t0 = time.perf_counter()
        out = monitor_block(mons, obs, correlators)
        return out, time.perf_counter() - t0

    def monitors(mons, obs, correlators=None):
        if cur["faulty"]:
            def cut(rec):
                return None if rec is None else memo.shared(("onset cut", id(rec), k0),
                                                            lambda: take_epochs(rec, slice(k0, None)), guard=rec)
            acc["faulty late"] += timed(mons, dataclasses.replace(obs, gnss=cut(obs.gnss), vision=cut(obs.vision)),
                                        correlators)[1]
        out, dt = timed(mons, obs, correlators)
        acc["whole"] += dt
        acc["faulty whole"] += dt if cur["faulty"] else 0.0
        return out

    runner.run_block, blocks.monitor_block = block, monitors
    try:
        memo.clear()
        t0 = time.perf_counter()
        runner.run_chunk_row(le, 1, list(range(len(cells))), threads=1)
        row = time.perf_counter() - t0 - acc["faulty late"]  # the row as it runs, without the extra runs
    finally:
        runner.run_block, blocks.monitor_block = run_block, monitor_block
    saved = acc["faulty whole"] - acc["faulty late"]
    print(f"  sharing the epochs before the onset ({k0} of {t.size}) across the fault magnitudes (not built; an upper "
          f"bound): the monitors of chunk 1 {acc['whole']:.2f} s on whole sorties, {acc['whole'] - saved:.2f} s with "
          f"the faulty cells monitored from the onset on ({100 * saved / acc['whole']:.0f} % less): "
          f"{100 * saved / row:.0f} % of the chunk row's {row:.2f} s")


if __name__ == "__main__":
    main()

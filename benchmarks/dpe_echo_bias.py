"""The ground echo's bias of the DPE's vertical error, per epoch (docs/design/dpe.md §6.8).

Usage::

    python benchmarks/dpe_echo_bias.py [--sortie 309] [--set-size 1440] [--seeds 30] [--survey 0]
    python benchmarks/dpe_echo_bias.py --held-out-stratum 4 --set-size 480 --k 5.375 [--workers 2]

Flies sortie ``--sortie`` of the importance calibration's set of ``--set-size`` sorties (its start time, C/N0 and
multipath, as ``testbed calibrate-dpe --method importance`` flies it) with ``--seeds`` seeds, each drawn plainly
(no tilt), regresses z = (e − m)/σ on the projection π of the draws per epoch over the seeds, and prints the slope
and intercept beside the bias b the DPE shows on the epoch's expected correlograms
(:func:`testbed.studies.dpe_measured.echo_bias`), then the distribution of |b| over the sortie's epochs and how
many copies :func:`~testbed.studies.dpe_measured.copies` draws. ``--survey N``: the same distribution over the
first N sorties of each ground-echo stratum of the set (the expected correlograms only; ~3 s a sortie).

``--held-out-stratum S``: flies the held-out set's sorties of stratum S (0-5: C/N0 offset index + 3 × echo) as
the importance calibration does, and prints its rate at ``--k`` with the diagnostics and the epochs that carry
most of it (their share, copies, echo bias, and their events' thresholds, projections and weights).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from scipy import stats

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))  # the working copy's testbed

from testbed.schema import arg_in_range  # noqa: E402


def _pilot(run, j: int, set_size: int):
    from testbed.studies import dpe_measured as dm
    from testbed.studies.dpe_calibration import _trajectory, sortie_plan

    traj = run.trajectories or (run.approach,)
    t, off, cn0, mp, stratum = sortie_plan(j, set_size, len(traj))
    ap, setup, truth_g, mon = _trajectory(run.approach, traj[t])
    g_gnss = np.random.SeedSequence(0, spawn_key=(dm.SET_KEYS["calibration"], j)).spawn(1)[0]  # the sortie's sky
    gs, g, gt = dm.sortie_sky(ap, setup, truth_g, off, cn0, mp, g_gnss)
    return dm.echo_bias(mon, g, gt, truth_g, gs, setup.frame), (ap, setup, truth_g, mon, off, cn0, mp, stratum)


def _quantiles(b: np.ndarray) -> str:
    from testbed.studies import dpe_measured as dm

    a = np.abs(b)
    q = np.quantile(a, [0.5, 0.9, 0.99])
    k = dm.COPY_K
    tail = stats.norm.sf(k - a) + stats.norm.sf(k + a)  # each epoch's expected tail at K = 5.3
    return (f"|b| median {q[0]:.3f}, 90 % {q[1]:.3f}, 99 % {q[2]:.3f}, max {a.max():.3f}; the {int((a > 0.6).sum())} "
            f"epochs with |b| > 0.6 carry {100 * tail[a > 0.6].sum() / tail.sum():.0f} % of the expected tail at K = {k:g}; "
            f"copies: mean {dm.copies(b).mean():.2f}, {int((dm.copies(b) > 1).sum())} of {a.size} epochs more than once")


def main(argv: list[str] | None = None) -> int:
    from testbed.threads import sleep_idle_threads

    sleep_idle_threads()  # as the commands set it: idle OpenMP threads beside the other worker must not spin
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sortie", type=arg_in_range(int, 0, 10**6), default=309)
    ap.add_argument("--set-size", type=arg_in_range(int, 6, 10**6 + 1), default=1440)
    ap.add_argument("--seeds", type=arg_in_range(int, 3, 10_001), default=30)
    ap.add_argument("--survey", type=arg_in_range(int, 0, 10**5), default=0)
    ap.add_argument("--held-out-stratum", type=arg_in_range(int, 0, 6), default=None)
    ap.add_argument("--k", type=arg_in_range(float, 1.0, 20.0), default=5.375)
    ap.add_argument("--workers", type=arg_in_range(int, 1, 65), default=2)
    args = ap.parse_args(argv)
    if args.held_out_stratum is not None:
        return held_out(args.set_size, args.held_out_stratum, args.k, args.workers)
    if args.sortie >= args.set_size:
        ap.error(f"--sortie {args.sortie}: expected a sortie of the set, 0..{args.set_size - 1}")
    from testbed.studies import dpe_measured as dm
    from testbed.studies.dpe_calibration import CN0_OFFSETS_DB, MULTIPATH, calibration_run

    run = calibration_run("zunz-rwy05-dpe", (), args.set_size, 0, 25, 1e-7)
    bias, (ap_, setup, truth_g, mon, off, cn0, mp, _) = _pilot(run, args.sortie, args.set_size)
    print(f"sortie {args.sortie} of {args.set_size}: C/N0 {cn0:+g} dB, multipath {mp}, start +{off:.0f} s")
    plain = 1.0 - 1e-12  # a defensive share that draws every epoch from the error model
    runs = [dm.sortie(ap_, setup, truth_g, mon, off, cn0, mp, (9, args.sortie), s, defensive=plain)
            for s in range(args.seeds)]
    pi_all = np.concatenate([r["pi"] for r in runs])  # an epoch's copies are draws of it too
    z_all, epoch = np.concatenate([r["z"] for r in runs]), np.concatenate([r["epoch"] for r in runs])
    print("epoch  slope  intercept  pilot b   (z = intercept + slope * pi over the seeds' draws)")
    for t in range(bias.size):
        pi, z = pi_all[epoch == t], z_all[epoch == t]
        if pi.size >= 3 and (abs(bias[t]) > 0.2 or t % 10 == 0):
            slope, icpt = np.polyfit(pi, z, 1)
            print(f"{t:5d}  {slope:5.3f}  {icpt:+9.3f}  {bias[t]:+7.3f}")
    print("this sortie:", _quantiles(bias))
    if args.survey:
        for s in (3, 4, 5):
            js = [j for j in range(args.set_size) if j % 3 == s % 3 and (j // 3) % 2 == 1][:args.survey]
            b = np.concatenate([_pilot(run, j, args.set_size)[0] for j in js])
            print(f"C/N0 {CN0_OFFSETS_DB[s % 3]:+g} dB, multipath {MULTIPATH[s // 3]}, {len(js)} sorties:", _quantiles(b))
    return 0


def _held_out_sortie(args):
    from testbed.studies import dpe_measured as dm
    from testbed.studies.dpe_calibration import _trajectory, calibration_run, sortie_plan

    set_size, j = args
    run = calibration_run("zunz-rwy05-dpe", (), set_size, 0, 25, 1e-7)
    traj = run.trajectories or (run.approach,)
    t, off, cn0, mp, _ = sortie_plan(j, set_size, len(traj), 0.5 * 86400.0 / set_size)  # the held-out start times
    ap, setup, truth_g, mon = _trajectory(run.approach, traj[t])
    return dm.sortie(ap, setup, truth_g, mon, off, cn0, mp, (dm.SET_KEYS["validation"], j), 0)


def held_out(set_size: int, stratum: int, k: float, workers: int) -> int:
    from testbed.pool import WorkerPool
    from testbed.studies import dpe_measured as dm
    from testbed.studies.dpe_calibration import sortie_plan

    js = [j for j in range(set_size) if sortie_plan(j, set_size, 1)[4] == stratum]
    with WorkerPool(workers) as pool:
        got = dict(pool.unordered(_held_out_sortie, [(i, ((set_size, j),)) for i, j in enumerate(js)]))
    rs = [got[i] for i in range(len(js))]
    ids = [np.concatenate([r[key] + i * dm.EPOCH_STRIDE for i, r in enumerate(rs)]) for key in ("epoch", "unsolved_epoch")]
    cat = {key: np.concatenate([r[key] for r in rs]) for key in rs[0]}
    t = (np.abs(cat["e"]) - np.abs(cat["m"])) / cat["sigma"]
    unit = dm.epoch_units(*ids)
    rate = dm.hmi_rate(t, cat["log_weight"], cat["unsolved_log_weight"], k, unit)
    print(f"held-out stratum {stratum}, {len(js)} sorties, K {k:g}: {rate.estimate:.4g} [{rate.lo:.4g}, {rate.hi:.4g}], "
          f"{rate.ess_events:.0f} effective events, largest share {rate.largest_share:.3f}, variance of the variance "
          f"{rate.vov:.3f} {list(rate.problems)}")
    w = np.exp(np.concatenate([cat["log_weight"], cat["unsolved_log_weight"]]))
    hit = np.concatenate([t > k, np.zeros(cat["unsolved_log_weight"].size, bool)])
    share = np.bincount(unit, w * hit, int(unit.max()) + 1)
    epochs = np.unique(np.concatenate(ids))
    for u in np.argsort(-share)[:8]:
        sel = ids[0] == epochs[u]
        ev = sel & (t > k)
        print(f"  sortie {js[epochs[u] // dm.EPOCH_STRIDE]} epoch {epochs[u] % dm.EPOCH_STRIDE}: share "
              f"{share[u] / share.sum():.3f}, {sel.sum()} copies, b {cat['bias'][sel][0]:+.3f}; events at t "
              f"{np.round(t[ev], 2).tolist()}, pi {np.round(cat['pi'][ev], 2).tolist()}, weights "
              f"{[float(f'{x:.3g}') for x in np.exp(cat['log_weight'][ev])]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""One draw block of a campaign: its trials' draws (one batch from the block's stream tree, through
:mod:`testbed.sim.pipeline`) and every monitor on them.

A **draw block** of ``block_trials`` trials draws the noise and faults of its trials in one ``n_trials`` batch from
the tree ``StreamTree.of_block(base_seed, cell, block)`` and runs the monitors on the batch. The block is the unit of
randomness *and* of computation, so results do not depend on how blocks are grouped into chunks or spread over
workers. One landmark survey is drawn per block (a surveyed scene serves many sorties; the monitors take one set of
landmark coordinates per call). What a sweep's cells draw alike is shared between them (:mod:`testbed.memo`).
"""

from __future__ import annotations

import contextlib
import functools
import json
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from testbed import memo
from testbed.campaign import sampling
from testbed.campaign.context import CellContext
from testbed.campaign.sorties import sky_windows, sortie_offsets
from testbed.campaign.tables import monitor_tables, paired_columns, weight_columns
from testbed.integrity.batching import map_trial_chunks
from testbed.integrity.monitor import Observations, provided_output
from testbed.records import MonitorOutput, map_epoch_arrays
from testbed.sensors.faults import GNSS_KINDS, IMU_KINDS, VISION_KINDS, imu_fault_epochs
from testbed.sensors.gnss.code_tracking import correlator_pseudoranges
from testbed.sensors.gnss.correlators import synthesize_correlators
from testbed.sim import pipeline
from testbed.sim.streams import StreamTree


# ----------------------------------------------------------------------------- one block

def block_streams(spec, cell_index: int, block: int) -> StreamTree:
    """The stream tree of one draw block (a pure function of its keys)."""
    return StreamTree.of_block(spec.base_seed, cell_index, block, spec.common_random_numbers)


@dataclass(frozen=True)
class BlockDraw:
    """The observations and truth of one draw block (n trials)."""

    trials: np.ndarray  # (n,) trial indices
    obs: Observations
    gnss_truth: object
    vision_truth: object | None
    fault_target: np.ndarray  # (n,) PRN of the faulty satellite / index of the faulty landmark / 0 the IMU, -1 none
    start_offset_s: np.ndarray  # (n,) the sortie's start, s after the approach's start time
    sky_window: np.ndarray  # (n,) int sky window whose geometry it flew in (-1: the fixed start)
    fault_present: np.ndarray  # (n, T) epochs whose observations carry the injected fault (all True: none)
    streams: StreamTree | None = None  # the block's stream tree (each trial's correlograms below it)
    #: the modelled observations the correlograms are synthesised from (their channel references); the
    #: monitors read ``obs.gnss``, which holds the correlograms' code delays when the approach says so
    correlator_gnss: object = None
    #: importance sampling (:mod:`.sampling`): each trial's log p/q and the proposal component it was drawn
    #: from (-1: the error model itself); None with plain sampling
    log_weight: np.ndarray | None = None
    component: np.ndarray | None = None
    #: (n,) RINEX name of the faulty satellite ("E11": PRNs alone repeat across systems), the system letter ("E")
    #: for a fault on every satellite of a system, "" where none
    fault_satellite: np.ndarray | None = None


def draw_block(ctx: CellContext, spec, block: int) -> BlockDraw:
    """Noise, faults and the landmark survey of one block's trials (:mod:`testbed.sim.pipeline`), the draws a sweep's
    cells have alike shared between them (:mod:`testbed.memo`)."""
    s, plan = ctx.setup, ctx.plan
    i0 = block * spec.block_trials
    n = min(spec.block_trials, spec.trials - i0)
    tree = block_streams(spec, ctx.cell.index, block)
    faults = list(s.faults)
    trials = np.arange(i0, i0 + n)
    offsets = sortie_offsets(spec, trials)
    windows = None if ctx.sky is None else sky_windows(offsets, spec.sorties.window_s, ctx.sky_repeat_s)
    sky_key = ("gnss_draw", ctx.gnss_draw_key, None if windows is None else memo.digest(windows))
    geom = functools.cache(lambda: ctx.gnss_geometry_of(windows))
    # the fault-free errors are shared by every GNSS fault of the sweep, the observations by its cells of one fault
    errors = lambda: memo.shared(sky_key + ("errors", memo.seed_key(tree.seed("gnss")), n),  # noqa: E731
                                 lambda: pipeline.gnss_errors(plan, geom(), tree, n))
    log_weight = component = tilted = None
    if spec.sampling.method == "importance":  # the errors from the cell's proposal: its observations its own
        tilted = sampling.tilted_draws(ctx, spec, errors(), windows, tree)
        errors = lambda: tilted.gnss  # noqa: E731
        sky_key = sky_key + ("importance", ctx.cell.index)
        component = tilted.component
    gnss, gtruth = _shared_draw(sky_key, faults, GNSS_KINDS, tree.seed("gnss"), n,
                                lambda: pipeline.gnss_observations(geom(), errors(), faults))
    vis = vtruth = None
    if ctx.v_geom is not None and tilted is not None and tilted.vision_tilt is not None:
        # the proposal moves the camera's draws too: the cell's own frames (the survey is the block's as ever)
        vis, vtruth = pipeline.draw_vision(plan, ctx.v_geom, tree, n, faults, share=memo.shared,
                                           tilt=tilted.vision_tilt)
    elif ctx.v_geom is not None:
        # the camera frames and the block's one survey, shared: the cells of one survey hand VA-RAIM one record
        vis, vtruth = _shared_draw(("vision_draw", ctx.vision_draw_key), faults, VISION_KINDS, tree.seed("vision"), n,
                                   lambda: pipeline.draw_vision(plan, ctx.v_geom, tree, n, faults, share=memo.shared))
    if tilted is not None:
        log_weight = tilted.log_weight()
    target = np.full(n, -1, np.int64)
    target_sat = np.full(n, "", "<U3")
    if gtruth.faulty.any():
        hit = gtruth.faulty.any(axis=-2)  # (n, S)
        target = np.where(hit.any(-1), np.asarray(gnss.prn)[hit.argmax(-1)], -1)
        first = hit.argmax(-1)  # a system-wide fault (several satellites hit): the system's letter alone
        target_sat = np.where(hit.sum(-1) > 1, np.asarray(gnss.system)[first], gnss.sat_id[first])
        target_sat = np.where(hit.any(-1), target_sat, "")
    elif vtruth is not None and np.asarray(vtruth.faulty).any():
        hit = np.asarray(vtruth.faulty).any(axis=-2)
        target = np.where(hit.any(-1), hit.argmax(-1), -1)
    model_gnss = gnss
    if s.gnss.correlator_pseudoranges:
        gnss, gtruth = _correlator_observations(ctx, gnss, gtruth, tree, trials)
    imu, init = _imu_draw(ctx, gtruth, tree, n) if ctx.imu_increments is not None else (None, None)
    tracks = None
    if ctx.feature_ids is not None:  # every trial's pixels under its own (dithered) camera
        tracks = pipeline.draw_features(plan, ctx.feature_ids, vtruth, tree, n_trials=n)
    present = _fault_present(gnss, gtruth, vis, vtruth, faulted=bool(faults))
    imu_hit = _imu_fault_epochs(ctx, faults)
    if imu_hit is not None:  # every trial's IMU carries the same fault: the IMU (0) is its target
        present = present | imu_hit
        target = np.where(imu_hit.any(), np.maximum(target, 0), target)
    return BlockDraw(trials, Observations(gnss, vis, imu, init, features=tracks), gtruth, vtruth, target, offsets,
                     np.full(n, -1, np.int64) if windows is None else windows, present, tree, model_gnss,
                     log_weight, component, target_sat)


def _shared_draw(key: tuple, faults: list, kinds: tuple, seed: np.random.SeedSequence, n: int, draw: Callable):
    """One sensor's draw of a block, shared by the cells whose draw key, faults of that sensor's kinds,
    seed (common random numbers) and trial count agree: a GPS-step sweep draws its camera frames
    once, a camera sweep its pseudoranges once (:mod:`testbed.memo`; off outside campaigns)."""
    own = json.dumps([f.model_dump(mode="json") for f in faults if f.kind in kinds], sort_keys=True)
    return memo.shared(key + (own, memo.seed_key(seed), n), draw)


def _imu_draw(ctx: CellContext, gtruth, tree: StreamTree, n: int):
    """The block's IMUs (one per trial, along the shared trajectory) and their alignments (each trial's
    receiver clock at the start), as the loop draws them for one flight."""
    stream = pipeline.imu_errors(ctx.plan, tree, n)
    imu = pipeline.imu_samples(ctx.plan, ctx.imu_increments, stream)
    cb = np.broadcast_to(np.asarray(gtruth.clock_bias, float), (n, len(ctx.t)))[:, 0]
    return imu, pipeline.alignment(ctx.plan, ctx.imu_start, cb, tree, n)


def _correlator_observations(ctx: "CellContext", gnss, gtruth, tree: StreamTree, trials: np.ndarray):
    """The block's pseudoranges from each trial's correlograms (``pseudorange_source = "correlator"``)."""

    parts = []
    for i, trial in enumerate(trials):
        g, gt = trial_of(gnss, i), trial_of(gtruth, i)
        corr, _ = synthesize_correlators(g, gt, ctx.truth_g, ctx.setup.gnss, pipeline.correlator_words(tree, trial))
        parts.append(correlator_pseudoranges(g, gt, corr, ctx.setup.gnss))
    fields = ("pseudorange", "sigma", "visible", "reason", "range_rate")
    gnss = replace(gnss, **{f: np.stack([np.broadcast_to(getattr(p[0], f), np.shape(p[0].pseudorange)) for p in parts])
                            for f in fields})
    return gnss, replace(gtruth, noise=np.stack([p[1].noise for p in parts]))


def trial_of(rec, i: int):
    """Trial ``i`` of a record with one trial axis (arrays shared by the trials are kept as they are)."""
    def take(a, meta):
        return a[i] if meta["batched"] and a.ndim == 2 + meta["tail"] else a

    return map_epoch_arrays(rec, take)


def _with_trial_axis(rec):
    return map_epoch_arrays(rec, lambda a, meta: a[None] if meta["batched"] else a)


def correlator_monitor(mon, ctx: "CellContext", d: "BlockDraw") -> MonitorOutput:
    """A monitor that reads correlators, trial by trial: each trial's correlograms are synthesised,
    monitored and dropped (a block's would be n·T·S·M floats); the outputs are stacked."""

    gnss = d.obs.gnss
    model = d.correlator_gnss if d.correlator_gnss is not None else gnss
    n, T = len(d.trials), len(gnss.t)

    def one(sl: slice) -> MonitorOutput:
        i = sl.start or 0
        gt = trial_of(d.gnss_truth, i)
        words = pipeline.correlator_words(d.streams, d.trials[i])
        corr, _ = synthesize_correlators(trial_of(model, i), gt, ctx.truth_g, ctx.setup.gnss, words)
        out, _ = mon.step(Observations(trial_of(gnss, i), correlators=corr), mon.initial_state())
        return _with_trial_axis(out)

    return map_trial_chunks(one, (n, T), threads=1, chunk_epochs=T)  # one trial a chunk


def monitor_block(monitors, obs: Observations, correlators: Callable | None = None) -> dict[str, MonitorOutput]:
    """Every monitor on one block (whole sorties: each from its initial state).

    A monitor that computes another on the way (VA-RAIM's step 1 is GPS RAIM) provides
    its output instead of a second solve (:func:`testbed.integrity.monitor.provided_output`);
    providers run first. A monitor reading correlators runs through ``correlators(mon)``.
    """
    order = sorted(monitors, key=lambda m: not m.provides_others)
    outs: dict[str, MonitorOutput] = {}
    for mon in order:
        if "correlators" in mon.inputs:
            outs[mon.name] = correlators(mon)
            continue
        for prov in order:
            if prov.name in outs:
                got = provided_output(prov, outs[prov.name], mon)
                if got is not None:
                    outs[mon.name] = got
                    break
        else:
            outs[mon.name], _ = mon.step(obs, mon.initial_state())
    return {m.name: outs[m.name] for m in monitors}


def _fault_present(gnss, gtruth, vis, vtruth, faulted: bool) -> np.ndarray:
    """(n, T) epochs whose observations carry an injected fault. A fault-free cell (``faulted`` False): every
    epoch, the denominator of its false-alarm rate. A faulted cell: the epochs where the fault reached an
    observation, none when it reached none (a satellite out of view, a landmark out of the image: the trial did
    not exercise its fault)."""
    gf = np.asarray(gtruth.faulty, bool)
    if not faulted:
        return np.ones(gf.shape[:-1], bool)
    present = (gf & np.asarray(gnss.visible, bool)).any(-1)
    if vtruth is not None:
        present |= (np.asarray(vtruth.faulty, bool) & np.asarray(vis.detected, bool)).any(-1)
    return present


def _imu_fault_epochs(ctx: CellContext, faults: list) -> np.ndarray | None:
    """(T,) the epochs whose IMU increments since the previous epoch carry an IMU fault of ``faults`` (None
    without one; none when no monitor reads the IMU: the run draws no IMU for the fault to reach)."""
    if not any(f.kind in IMU_KINDS for f in faults):
        return None
    if ctx.imu_increments is None:
        return np.zeros(ctx.t.size, bool)
    t_imu, _, _, dt = ctx.imu_increments
    return imu_fault_epochs(faults, ctx.t, t_imu, dt)


def run_block(ctx: CellContext, spec, block: int) -> dict[str, dict[str, np.ndarray]]:
    """Draw and monitor the trials of one block; per-trial, per-epoch and histogram columns.

    With common random numbers the sweep's other cells reuse this block's draws (:mod:`testbed.memo`; the
    same numbers either way); without, no two cells draw from one seed and nothing is shared."""
    with memo.sharing() if spec.common_random_numbers else contextlib.nullcontext():
        d = draw_block(ctx, spec, block)
        outs = monitor_block(ctx.setup.monitors, d.obs, lambda mon: correlator_monitor(mon, ctx, d))
        keep_ep = d.trials < spec.per_epoch_trials
        rows, ep, hist = {}, {}, {}
        for mon in ctx.setup.monitors:
            out = outs[mon.name]
            ref = pipeline.reference_enu(mon, ctx.truth_ant_enu, ctx.truth_cg_enu)
            own_rows, own_hist, own_ep = monitor_tables(ctx, d, out, ref, keep_ep)
            rows[mon.name] = {"cell": np.full(d.trials.size, ctx.cell.index, np.int32), **own_rows,
                              **paired_columns(ctx, d, out, outs), **weight_columns(d)}
            hist.update(own_hist)
            if own_ep is not None:
                ep[mon.name] = {"cell": np.full(own_ep["trial"].size, ctx.cell.index, np.int32), **own_ep}
    return {"trials": rows, "epochs": ep, "hist": hist}

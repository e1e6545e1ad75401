"""The batched campaign runner: fly once, sample many.

Work is split in three levels:

- a **cell context** (:func:`cell_context`) is computed once per cell and cached per
  process: the flight (cached by approach and wind/gust settings, so all cells on one
  trajectory share one JSBSim run), the GNSS geometry (per trajectory and start time)
  and the vision geometry (per trajectory, camera and landmark scene);
- a **draw block** of ``block_trials`` trials (:func:`run_block`) draws the noise and
  faults of its trials in one ``n_trials`` batch from generators seeded by
  ``SeedSequence(base_seed, spawn_key=(cell, block))`` and runs the monitors on the
  batch. The block is the unit of randomness *and* of computation, so results do not
  depend on how blocks are grouped into chunks or spread over workers;
- a **chunk** (:func:`run_chunk`, ``chunk_trials`` trials = whole blocks) is the unit of
  scheduling and storage: a pure function of (spec, cell, chunk) returning small
  tables (:data:`TABLES`), which the driver writes atomically (:mod:`.store`).

One landmark survey is drawn per block (the survey error is what VA-RAIM calibrates
away; a surveyed scene serves many sorties). The monitors need one set of landmark
coordinates per call, which a block provides.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import threading
import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Callable

import numpy as np
import pyarrow as pa

from testbed import memo
from testbed.campaign.sorties import sky_windows, sortie_offsets, window_offsets
from testbed.campaign.spec import CampaignSpec, Cell, LoadedSpec, expand_cells, resolve_spec
from testbed.integrity.batching import available_cores, map_trial_chunks, physical_memory_bytes
from testbed.integrity.monitor import ANTENNA, Observations, provided_output
from testbed.integrity.levels import service_level
from testbed.records import MonitorOutput, map_epoch_arrays
from testbed.schema import ConfigError
from testbed.sensors.faults import GNSS_KINDS, VISION_KINDS
from testbed.sim.evaluate import REGIONS, misleading, position_errors, stanford_regions

TABLES = ("trials", "epochs", "hist")

#: Stanford histogram bins: log10 of error and PL in metres, 0.01 m .. 10 km, 0.05 dex
HIST_LOG10_MIN, HIST_LOG10_MAX, HIST_BINS = -2.0, 4.0, 120


def hist_edges() -> np.ndarray:
    """(HIST_BINS + 1,) bin edges in metres of the Stanford histograms."""
    return 10.0 ** np.linspace(HIST_LOG10_MIN, HIST_LOG10_MAX, HIST_BINS + 1)


# ----------------------------------------------------------------------------- caches (per process)

_CACHE: OrderedDict[tuple, object] = OrderedDict()
_CACHE_MAX = 64
#: a Dask worker's threads build cell contexts side by side; reentrant: a ``make`` reads other entries
_CACHE_LOCK = threading.RLock()


def _cached(key: tuple, make: Callable[[], object]):
    """``make()`` once per key per process, least recently used out first: a chunk row touches every cell's
    entries, so with eviction by age the experiment's GNSS geometry (the first entry a row makes; 5 s for
    where-vision-pays' 1436 sky windows) was recomputed for every row once the row's cells held more than 64
    entries. Threads that want one key wait for the first to make it."""
    with _CACHE_LOCK:
        if key in _CACHE:
            _CACHE.move_to_end(key)
        else:
            value = make()
            if len(_CACHE) >= _CACHE_MAX:
                _CACHE.popitem(last=False)
            _CACHE[key] = value
        return _CACHE[key]


def clear_caches() -> None:
    with _CACHE_LOCK:
        _CACHE.clear()


def _flight_key(cell: Cell) -> tuple:
    c = cell.config
    d = c.model_dump(mode="json", include={"aircraft", "frame", "path", "vertical", "flight", "wind", "gusts",
                                          "terrain"})
    return ("flight", str(cell.approach.source), str(cell.approach.aircraft_source), json.dumps(d, sort_keys=True))


def _terrain(cell: Cell):
    from testbed.sim.setup import load_terrain_for

    c = cell.config
    key = ("terrain", str(cell.approach.source), json.dumps(c.terrain.model_dump(mode="json"), sort_keys=True))
    return _cached(key, lambda: load_terrain_for(cell.approach))


def flown_truth(cell: Cell):
    """The cell's trajectory flown by JSBSim (cached: one flight per distinct trajectory)."""
    from testbed.flight.fly import fly

    return _cached(_flight_key(cell), lambda: fly(cell.approach.flight_plan, _terrain(cell)).truth)


@dataclass(frozen=True)
class CellContext:
    """Everything a cell's trials share (no randomness)."""

    cell: Cell
    setup: object  # RunSetup
    t: np.ndarray  # (T,) GNSS (monitor) epochs
    g_geom: object
    v_geom: object | None
    landmarks: object | None  # Landmarks with lpe 0 (the survey is drawn per block)
    truth_cg_enu: np.ndarray  # (T, 3)
    truth_ant_enu: np.ndarray  # (T, 3)
    hal: float
    val: float
    levels: tuple[str, ...]
    onset_s: float  # nan without fault
    truth_g: object = None  # Truth at the GNSS epochs (the correlators' ground echo reads AGL and climb)
    sky: np.ndarray | None = None  # (W,) sorted sky windows of the sorties (g_geom stacked); None: fixed start
    #: the error-free IMU increments (t, Δθ, Δv, Δt) along the segment, and its first pose (C, v, p):
    #: only when a monitor reads the IMU (the Won et al. filter)
    imu_increments: tuple | None = None
    imu_start: tuple | None = None
    #: what fixes the cell's GNSS / vision draws besides seed, faults and sky windows (memo keys: a sweep's
    #: cells that share them share their draws, :func:`_shared_draw`)
    gnss_draw_key: tuple = ()
    vision_draw_key: tuple = ()
    #: the ground features the tracker follows at the GNSS epochs (T, W) and the tracker's camera: only when
    #: the approach's ``[vision.features]`` is enabled and a monitor reads them (the Won et al. filter)
    feature_ids: np.ndarray | None = None
    feature_camera: tuple | None = None

    def gnss_geometry_of(self, windows: np.ndarray | None):
        """The GNSS geometry of trials flying in sky ``windows`` (n,) (None: the fixed start)."""
        if self.sky is None:
            return self.g_geom
        return self.g_geom.windows(np.searchsorted(self.sky, windows))


#: Sidereal windows whose geometry is computed in one batched pass (bounds the temporaries).
_WINDOWS_PER_PASS = 128


def cell_context(cell: Cell, spec: CampaignSpec | None = None) -> CellContext:
    """The cached geometry of a cell: flight, GNSS geometry (per sky window of the
    sorties' start times, when ``spec.sorties`` spreads them), vision geometry."""
    from testbed.sensors.gnss.almanac import load_constellation
    from testbed.sensors.gnss.synth import concat_windows, gnss_geometry
    from testbed.sensors.gnss.timebase import utc_to_gps_seconds
    from testbed.sensors.vision import detect as vdetect
    from testbed.sim.setup import build_setup

    c = cell.config
    duration_s = None if spec is None else spec.duration_s
    segment = "first" if spec is None else spec.segment
    terrain = _terrain(cell)
    setup = build_setup(cell.approach, terrain, monitor_threads=1)  # blocks run side by side instead
    fkey = _flight_key(cell)
    sky = None
    if spec is not None and spec.sorties.start != "fixed":
        sky = np.unique(sky_windows(sortie_offsets(spec, np.arange(spec.trials)), spec.sorties.window_s))

    def truth_g():
        tr = flown_truth(cell).decimate(setup.gnss.rate_hz)
        return _segment(tr, duration_s, segment, _segment_start(tr.t, duration_s, segment))

    tkey = ("truth_g", fkey, setup.gnss.rate_hz, duration_s, segment)
    truth = _cached(tkey, truth_g)
    imu_inc = imu_start = None
    if any("imu" in m.inputs for m in setup.monitors):
        ikey = ("imu_truth", tkey, json.dumps(setup.imu.model_dump(mode="json"), sort_keys=True))
        imu_inc, imu_start = _cached(ikey, lambda: _imu_segment(flown_truth(cell), setup, duration_s, segment))
    gkey = ("gnss_geom", tkey, c.start_time_utc.isoformat(), json.dumps(c.gnss.model_dump(mode="json"), sort_keys=True),
            json.dumps(c.aircraft and cell.approach.aircraft.antenna_lever_arm_m),
            None if sky is None else (spec.sorties.window_s, sky.tobytes()))

    def ggeom():
        eph = load_constellation(setup.gnss.almanac_source, setup.gnss.almanac_path,
                                 utc_to_gps_seconds(c.start_time_utc), setup.gnss.almanac_week)
        if sky is None:
            return gnss_geometry(truth, setup.antenna, setup.gnss, start_utc=c.start_time_utc, terrain=terrain,
                                 constellation=eph)
        offsets = window_offsets(sky, spec.sorties.window_s)
        return concat_windows([gnss_geometry(truth, setup.antenna, setup.gnss, start_utc=c.start_time_utc,
                                             terrain=terrain, constellation=eph, offsets_s=offsets[i:i + _WINDOWS_PER_PASS])
                               for i in range(0, offsets.size, _WINDOWS_PER_PASS)])

    g_geom = _cached(gkey, ggeom)
    v_geom, lm = None, None
    if setup.uses_vision:
        lm = replace(setup.landmarks, lpe_sigma_m=0.0)
        vision_json = json.dumps(setup.vision.model_dump(mode="json"), sort_keys=True)
        landmarks_json = json.dumps(c.landmarks.model_dump(mode="json"), sort_keys=True)
        # keyed on the faults the geometry reads: a GPS-fault sweep's cells share one
        moved = vdetect.geometry_faults(list(setup.faults))
        vkey = ("vision_geom", tkey, vision_json, landmarks_json,
                json.dumps([f.model_dump(mode="json") for f in moved], sort_keys=True))
        v_geom = _cached(vkey, lambda: vdetect.vision_geometry(truth, setup.vision, landmarks=lm, terrain=terrain,
                                                               faults=moved))
    f_ids = f_cam = None
    if setup.features is not None:
        from testbed.sensors.vision.dithering import mount_from_settings
        from testbed.sensors.vision.features import scene_ids

        f_cam = (setup.vision.camera.build(), mount_from_settings(setup.vision.mount))
        fkey_ = ("feature_ids", tkey, json.dumps(setup.vision.model_dump(mode="json"), sort_keys=True),
                 setup.features.tobytes())
        f_ids = _cached(fkey_, lambda: scene_ids(truth, *f_cam, setup.features, setup.vision.features, terrain))
    levels = tuple(setup.integrity.service_levels)
    lv = [service_level(n) for n in levels]
    onset = min((f.onset_s for f in setup.faults), default=float("nan"))
    return CellContext(cell=cell, setup=setup, t=np.asarray(truth.t, float), g_geom=g_geom, v_geom=v_geom,
                       landmarks=lm, truth_cg_enu=setup.frame.ecef_to_enu(truth.pos_ecef),
                       truth_ant_enu=setup.frame.ecef_to_enu(g_geom.ant_pos_ecef),
                       hal=min(x.hal for x in lv), val=min(x.val for x in lv), levels=levels, onset_s=float(onset),
                       truth_g=truth, sky=sky, imu_increments=imu_inc, imu_start=imu_start, feature_ids=f_ids,
                       feature_camera=f_cam, gnss_draw_key=gkey,
                       vision_draw_key=() if v_geom is None else (tkey, vision_json, landmarks_json))


def _segment_start(t_gnss: np.ndarray, duration_s: float | None, segment: str) -> float:
    """Where the cell's segment starts on the flight's clock: its first GNSS epoch (0 but for ``"last"``)."""
    if duration_s is None or segment != "last":
        return 0.0
    return float(t_gnss[np.flatnonzero(t_gnss >= t_gnss[-1] - duration_s - 1e-9)[0]])


def _segment(tr, duration_s: float | None, segment: str, t0: float):
    """The part of a truth record (any rate) the cell flies: the first ``duration_s``, or from ``t0`` on
    (``"last"``) with its time from there, so GNSS-rate and full-rate records start at the same epoch."""
    if duration_s is None:
        return tr
    t = np.asarray(tr.t, float)
    if segment == "last":
        tr = tr.at_indices(np.flatnonzero(t >= t0 - 1e-9))
        return replace(tr, t=np.asarray(tr.t) - t0)
    return tr.at_indices(np.flatnonzero(t <= duration_s + 1e-9))


def _imu_segment(flown, setup, duration_s: float | None, segment: str):
    """The error-free IMU increments over the cell's segment (its time as the GNSS epochs') and the segment's
    first pose: the full-rate truth from the segment's first GNSS epoch on."""
    from testbed.inertial import body_to_world, local_to_world
    from testbed.sensors.imu import true_increments

    t0 = _segment_start(flown.decimate(setup.gnss.rate_hz).t, duration_s, segment)
    tr = _segment(flown, duration_s, segment, t0)
    inc = true_increments(tr, setup.imu)
    p0 = np.asarray(tr.pos_enu[0], float)
    start = (float(tr.t[0]), body_to_world(setup.frame, p0, np.asarray(tr.q_body_to_enu[0], float)),
             local_to_world(setup.frame, p0, np.asarray(tr.vel_enu[0], float)), p0)
    return inc, start


# ----------------------------------------------------------------------------- one block

def block_seed(base_seed: int, cell_index: int, block: int, common: bool) -> np.random.SeedSequence:
    """The SeedSequence of one draw block (a pure function of its keys)."""
    key = (block,) if common else (cell_index, block)
    return np.random.SeedSequence(base_seed, spawn_key=key)


@dataclass(frozen=True)
class BlockDraw:
    """The observations and truth of one draw block (n trials)."""

    trials: np.ndarray  # (n,) trial indices
    obs: Observations
    gnss_truth: object
    vision_truth: object | None
    fault_target: np.ndarray  # (n,) PRN of the faulty satellite / index of the faulty landmark, -1 none
    start_offset_s: np.ndarray  # (n,) the sortie's start, s after the approach's start time
    sky_window: np.ndarray  # (n,) int sky window whose geometry it flew in (-1: the fixed start)
    fault_present: np.ndarray  # (n, T) epochs whose observations carry the injected fault (all True: none)
    correlator_seed: np.random.SeedSequence | None = None  # the block's correlator draws (per trial below it)
    #: the modelled observations the correlograms are synthesised from (their channel references); the
    #: monitors read ``obs.gnss``, which holds the correlograms' code delays when the approach says so
    correlator_gnss: object = None


def draw_block(ctx: CellContext, spec, block: int) -> BlockDraw:
    """Noise, faults and (per block) the landmark survey of one block's trials."""
    from testbed.sensors.gnss.synth import apply_gnss_errors, draw_gnss_errors
    from testbed.sensors.vision import detect as vdetect

    s = ctx.setup
    i0 = block * spec.block_trials
    n = min(spec.block_trials, spec.trials - i0)
    # children 0-2 as before; children 3 (the correlators), 4 and 5 (IMU errors, alignment), 6 (the ground
    # features' tracking) leave them unchanged
    ss_g, ss_v, ss_s, ss_c, ss_i, ss_a, ss_f = block_seed(spec.base_seed, ctx.cell.index, block,
                                                          spec.common_random_numbers).spawn(7)
    faults = list(s.faults)
    trials = np.arange(i0, i0 + n)
    offsets = sortie_offsets(spec, trials)
    windows = None if ctx.sky is None else sky_windows(offsets, spec.sorties.window_s)
    sky_key = ("gnss_draw", ctx.gnss_draw_key, None if windows is None else memo.digest(windows))
    geom = functools.cache(lambda: ctx.gnss_geometry_of(windows))
    # the fault-free errors are shared by every GNSS fault of the sweep, the observations by its cells of one fault
    errors = lambda: memo.shared(sky_key + ("errors", memo.seed_key(ss_g), n),  # noqa: E731
                                 lambda: draw_gnss_errors(geom(), s.gnss, rng=np.random.default_rng(ss_g), n_trials=n))
    gnss, gtruth = _shared_draw(sky_key, faults, GNSS_KINDS, ss_g, n, lambda: apply_gnss_errors(geom(), errors(), faults))
    vis = vtruth = None
    if ctx.v_geom is not None:
        vis, vtruth = _shared_draw(
            ("vision_draw", ctx.vision_draw_key), faults, VISION_KINDS, ss_v, n,
            lambda: vdetect.sample_vision(ctx.v_geom, s.vision, landmarks=ctx.landmarks, faults=faults,
                                          rng=np.random.default_rng(ss_v), n_trials=n))
        # one survey per block: the monitor believes true + e, the landmarks stand at true (+ a fault's move);
        # shared like the frames, so the cells of one survey hand VA-RAIM one record (its vision step is shared)
        lpe, true_pos = s.landmarks.lpe_sigma_m, ctx.landmarks.pos_ecef
        frames = vis
        vis = memo.shared(
            ("landmark_survey", id(frames), memo.seed_key(ss_s), float(lpe), memo.digest(true_pos)),
            lambda: replace(frames, landmark_pos_ecef=true_pos
                            + np.random.default_rng(ss_s).standard_normal(true_pos.shape) * lpe), guard=frames)
    target = np.full(n, -1, np.int64)
    if gtruth.faulty.any():
        hit = gtruth.faulty.any(axis=-2)  # (n, S)
        target = np.where(hit.any(-1), np.asarray(gnss.prn)[hit.argmax(-1)], -1)
    elif vtruth is not None and np.asarray(vtruth.faulty).any():
        hit = np.asarray(vtruth.faulty).any(axis=-2)
        target = np.where(hit.any(-1), hit.argmax(-1), -1)
    model_gnss = gnss
    if s.gnss.correlator_pseudoranges:
        gnss, gtruth = _correlator_observations(ctx, gnss, gtruth, ss_c, trials)
    imu, init = _imu_draw(ctx, gtruth, ss_i, ss_a, n) if ctx.imu_increments is not None else (None, None)
    tracks = None
    if ctx.feature_ids is not None:  # every trial's pixels under its own (dithered) camera
        from testbed.sensors.vision.features import scene_tracks

        tracks = scene_tracks(ctx.feature_ids, vtruth, s.features, s.frame, *ctx.feature_camera, s.vision.features,
                              ss_f.generate_state(4), n_trials=n)
    return BlockDraw(trials, Observations(gnss, vis, imu, init, features=tracks), gtruth, vtruth, target, offsets,
                     np.full(n, -1, np.int64) if windows is None else windows, _fault_present(gnss, gtruth, vis, vtruth),
                     ss_c, model_gnss)


def _shared_draw(key: tuple, faults: list, kinds: tuple, seed: np.random.SeedSequence, n: int, draw: Callable):
    """One sensor's draw of a block, shared by the cells whose draw key, faults of that sensor's kinds,
    seed (common random numbers) and trial count agree: a GPS-step sweep draws its camera frames
    once, a camera sweep its pseudoranges once (:mod:`testbed.memo`; off outside campaigns)."""
    own = json.dumps([f.model_dump(mode="json") for f in faults if f.kind in kinds], sort_keys=True)
    return memo.shared(key + (own, memo.seed_key(seed), n), draw)


def _imu_draw(ctx: CellContext, gtruth, seed_imu: np.random.SeedSequence, seed_align: np.random.SeedSequence,
              n: int):
    """The block's IMUs (one per trial, along the shared trajectory) and their alignments (each trial's
    receiver clock at the start), as the loop draws them for one flight."""
    from testbed.records import ImuSamples
    from testbed.sensors.imu import ImuErrorStream, apply_errors
    from testbed.sensors.imu.alignment import align

    s = ctx.setup.imu
    t, dth, dvl, dt = ctx.imu_increments
    stream = ImuErrorStream(s, dt, np.random.default_rng(seed_imu), n)
    d_th, d_v = apply_errors(dth, dvl, stream, stream.draw(t.size))
    imu = ImuSamples(t=t, dtheta=d_th, dvel=d_v, dt=dt, lever_arm_body=np.asarray(s.lever_arm_body_m, float),
                     earth_rotation=s.earth_rotation, figures=s.figures())
    t0, C, v, p = ctx.imu_start
    cb = np.broadcast_to(np.asarray(gtruth.clock_bias, float), (n, len(ctx.t)))[:, 0]
    return imu, align(t0, C, v, p, cb, 0.0, s.figures(), np.random.default_rng(seed_align), n)


def trial_correlator_words(block_seed: np.random.SeedSequence, trial: int) -> np.ndarray:
    """Seed words of one trial's correlograms (child of the block's correlator seed, keyed by the trial)."""
    return np.random.SeedSequence(block_seed.entropy, spawn_key=block_seed.spawn_key + (int(trial),)).generate_state(4)


def _correlator_observations(ctx: "CellContext", gnss, gtruth, seed: np.random.SeedSequence, trials: np.ndarray):
    """The block's pseudoranges from each trial's correlograms (``pseudorange_source = "correlator"``)."""
    from testbed.sensors.gnss.code_tracking import correlator_pseudoranges
    from testbed.sensors.gnss.correlators import synthesize_correlators

    parts = []
    for i, trial in enumerate(trials):
        g, gt = _trial(gnss, i), _trial(gtruth, i)
        corr, _ = synthesize_correlators(g, gt, ctx.truth_g, ctx.setup.gnss, trial_correlator_words(seed, trial))
        parts.append(correlator_pseudoranges(g, gt, corr, ctx.setup.gnss))
    fields = ("pseudorange", "sigma", "visible", "reason", "range_rate")
    gnss = replace(gnss, **{f: np.stack([np.broadcast_to(getattr(p[0], f), np.shape(p[0].pseudorange)) for p in parts])
                            for f in fields})
    return gnss, replace(gtruth, noise=np.stack([p[1].noise for p in parts]))


def _trial(rec, i: int):
    """Trial ``i`` of a record with one trial axis (arrays shared by the trials are kept as they are)."""
    def take(a, meta):
        return a[i] if meta["batched"] and a.ndim == 2 + meta["tail"] else a

    return map_epoch_arrays(rec, take)


def _with_trial_axis(rec):
    return map_epoch_arrays(rec, lambda a, meta: a[None] if meta["batched"] else a)


def correlator_monitor(mon, ctx: "CellContext", d: "BlockDraw") -> MonitorOutput:
    """A monitor that reads correlators, trial by trial: each trial's correlograms are synthesised,
    monitored and dropped (a block's would be n·T·S·M floats); the outputs are stacked."""
    from testbed.sensors.gnss.correlators import synthesize_correlators

    gnss = d.obs.gnss
    model = d.correlator_gnss if d.correlator_gnss is not None else gnss
    n, T = len(d.trials), len(gnss.t)

    def one(sl: slice) -> MonitorOutput:
        i = sl.start or 0
        gt = _trial(d.gnss_truth, i)
        words = trial_correlator_words(d.correlator_seed, d.trials[i])
        corr, _ = synthesize_correlators(_trial(model, i), gt, ctx.truth_g, ctx.setup.gnss, words)
        out, _ = mon.step(Observations(_trial(gnss, i), correlators=corr), mon.initial_state())
        return _with_trial_axis(out)

    return map_trial_chunks(one, (n, T), threads=1, chunk_epochs=T)  # one trial a chunk


def monitor_block(monitors, obs: Observations, correlators: Callable | None = None) -> dict[str, MonitorOutput]:
    """Every monitor on one block (whole sorties: each from its initial state).

    A monitor that computes another on the way (VA-RAIM's step 1 is GPS RAIM) provides
    its output instead of a second solve (:func:`testbed.integrity.monitor.provided_output`);
    providers run first. A monitor reading correlators runs through ``correlators(mon)``.
    """
    order = sorted(monitors, key=lambda m: getattr(m, "provides", None) is None)
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
            ref = ctx.truth_ant_enu if mon.reference == ANTENNA else ctx.truth_cg_enu
            own_rows, own_hist, own_ep = _shared_tables(ctx, d, out, ref, keep_ep)
            rows[mon.name] = {"cell": np.full(d.trials.size, ctx.cell.index, np.int32), **own_rows,
                              **_paired_columns(ctx, d, out, outs)}
            hist.update(own_hist)
            if own_ep is not None:
                ep[mon.name] = {"cell": np.full(own_ep["trial"].size, ctx.cell.index, np.int32), **own_ep}
    return {"trials": rows, "epochs": ep, "hist": hist}


def _shared_tables(ctx: CellContext, d: BlockDraw, out: MonitorOutput, ref: np.ndarray, keep_ep: np.ndarray
                   ) -> tuple[dict, dict, dict | None]:
    """A monitor's own trial columns, Stanford counts and per-epoch records of one block (not its
    paired columns, nor the cell), computed once for the cells handing it the very same output
    fields (:mod:`testbed.memo`): GPS RAIM's, which VA-RAIM provides from its shared step 1, is
    one output across a camera sweep. Keyed on those fields' identity and on the content of
    everything else the tables read. An output that is not itself shared (an array of it the memo does
    not hold) is not kept either: no other cell can hand it in, and the entry would keep it alive."""
    own = tuple(getattr(out, f.name) for f in fields(out) if f.name != "name")
    extra = getattr(out.diagnostics, "trial_columns", None)

    def make() -> tuple[dict, dict, dict | None]:
        he, ve = position_errors(out, ref)  # (n, T)
        ep = _epoch_columns(ctx, d, np.flatnonzero(keep_ep), out, he, ve) if keep_ep.any() else None
        return _trial_columns(ctx, d, out, he, ve), _stanford_counts(out.name, out, he, ve), ep

    if not memo.active() or not all(memo.is_shared(v) for v in own if isinstance(v, np.ndarray)):
        return make()
    read = (ctx.t, ref, ctx.onset_s, ctx.hal, ctx.val, ctx.levels, keep_ep, d.trials, d.start_offset_s, d.sky_window,
            d.fault_target, d.fault_present)
    guard = own + ((d.vision_truth,) if extra is not None else ())
    return memo.shared(("monitor_tables", out.name, tuple(id(v) for v in guard), memo.digest(*read)), make, guard=guard)


def _trial_columns(ctx: CellContext, d: BlockDraw, out: MonitorOutput, he: np.ndarray, ve: np.ndarray) -> dict:
    """One row per trial: detection, time to alert, PL and error maxima, MI/HMI, availability, regions."""
    t, onset, n = ctx.t, ctx.onset_s, d.trials.size
    hpl, vpl = np.asarray(out.hpl, float), np.asarray(out.vpl, float)
    alert = np.asarray(out.alert, bool)
    avail = np.asarray(out.available, bool)  # (n, T, K)
    rh, rv = stanford_regions(he, hpl, ctx.hal, alert), stanford_regions(ve, vpl, ctx.val, alert)
    after = t >= onset - 1e-9 if np.isfinite(onset) else np.ones(t.size, bool)
    det = np.asarray(out.detected, bool) & after  # with FDE: an alert or an exclusion
    detected = det.any(-1)
    # per-epoch detection: alerted epochs / faulty epochs at which the monitor gives a solution, a
    # faulty epoch being one whose measurements carry the fault (the faulty satellite can set or
    # be masked, a faulty landmark leave the image); fault-free cells: every epoch with a solution,
    # so the ratio is the per-epoch false-alarm rate
    solved = (np.asarray(out.reason) == 0) & after & d.fault_present
    with np.errstate(all="ignore"):
        first_any = np.where(alert.any(-1), t[alert.argmax(-1)], np.nan)
        tta = np.where(detected, t[det.argmax(-1)] - (onset if np.isfinite(onset) else 0.0), np.nan)
        mi = misleading(he, ve, hpl, vpl, alert, out.dimensions)
        hmi = rh["hazardous"] | rv["hazardous"]  # alerted epochs are in their own region
        col = {
            "trial": d.trials.astype(np.int64),
            "monitor": out.name, "epochs": np.full(n, t.size, np.int32),
            "start_offset_s": d.start_offset_s, "sky_window": d.sky_window,
            "fault_target": d.fault_target, "detected": detected, "alert_epochs": alert.sum(-1).astype(np.int32),
            "excluded_epochs": (np.asarray(out.excluded) >= 0).sum(-1).astype(np.int32),
            "onset_epochs": solved.sum(-1).astype(np.int32), "onset_alerts": (det & solved).sum(-1).astype(np.int32),
            "first_alert_s": first_any, "time_to_alert_s": tta,
            "max_he": _nanmax(he), "max_ve": _nanmax(ve), "max_hpl": _nanmax(hpl), "max_vpl": _nanmax(vpl),
            "mi_epochs": mi.sum(-1).astype(np.int32), "hmi_epochs": hmi.sum(-1).astype(np.int32),
        }
        for k, lv in enumerate(ctx.levels):
            col[f"avail_{lv}"] = avail[..., k].mean(-1)
        for r in REGIONS:
            col[f"h_{r}"] = rh[r].sum(-1).astype(np.int32)
            col[f"v_{r}"] = rv[r].sum(-1).astype(np.int32)
        extra = getattr(out.diagnostics, "trial_columns", None)  # a monitor's own table columns
        if extra is not None:
            col.update(extra(d.vision_truth))
    return col


def _paired_columns(ctx: CellContext, d: BlockDraw, out: MonitorOutput, outs: dict[str, MonitorOutput]) -> dict:
    """Per trial, against every monitor of the run (the same epochs, the same signals): the epochs this one
    is available and the other not, per service level (``only_available_vs_<other>_<level>``; the report's
    McNemar test); and the epochs with exactly four satellites in use-able view, where snapshot RAIM has
    no redundancy (``four_sat_epochs``, ``four_sat_avail_<level>``)."""
    n_sat = np.asarray(d.obs.gnss.visible, bool).sum(-1)  # (n, T)
    four = n_sat == 4
    mine = np.asarray(out.available, bool)
    col = {"four_sat_epochs": four.sum(-1).astype(np.int32)}
    for k, lv in enumerate(ctx.levels):
        col[f"four_sat_avail_{lv}"] = (mine[..., k] & four).sum(-1).astype(np.int32)
        for name, other in outs.items():
            theirs = np.asarray(other.available, bool)[..., k]
            col[f"only_available_vs_{name}_{lv}"] = (mine[..., k] & ~theirs).sum(-1).astype(np.int32)
    return col


def _fault_present(gnss, gtruth, vis, vtruth) -> np.ndarray:
    """(n, T) epochs whose observations carry an injected fault (all True without a fault)."""
    gf = np.asarray(gtruth.faulty, bool)
    if not gf.any() and (vtruth is None or not np.asarray(vtruth.faulty).any()):
        return np.ones(gf.shape[:-1], bool)
    present = (gf & np.asarray(gnss.visible, bool)).any(-1)
    if vtruth is not None:
        present |= (np.asarray(vtruth.faulty, bool) & np.asarray(vis.detected, bool)).any(-1)
    return present


def _stanford_counts(name: str, out: MonitorOutput, he: np.ndarray, ve: np.ndarray) -> dict[str, list]:
    """Sparse Stanford histograms over the epochs the regions place (alerted ones are counted apart)."""
    edges_log = np.linspace(HIST_LOG10_MIN, HIST_LOG10_MAX, HIST_BINS + 1)
    alert = np.asarray(out.alert, bool)
    hist = {}
    for dim, e, p in (("H", he, np.asarray(out.hpl, float)), ("V", ve, np.asarray(out.vpl, float))):
        ok = np.isfinite(e) & np.isfinite(p) & ~alert
        le = np.clip(np.log10(np.maximum(e[ok], 1e-12)), HIST_LOG10_MIN, HIST_LOG10_MAX - 1e-9)
        lp = np.clip(np.log10(np.maximum(p[ok], 1e-12)), HIST_LOG10_MIN, HIST_LOG10_MAX - 1e-9)
        # np.histogram2d's binning (searchsorted on the edges, right side; the clip keeps the last edge out),
        # counted with one bincount instead of its general d-dimensional path (4x the time)
        cell = (np.searchsorted(edges_log, le, "right") - 1) * HIST_BINS + np.searchsorted(edges_log, lp, "right") - 1
        H = np.bincount(cell, minlength=HIST_BINS * HIST_BINS)
        nz = np.flatnonzero(H)
        hist[f"{name}/{dim}"] = [nz // HIST_BINS, nz % HIST_BINS, H[nz].astype(np.int64)]
    return hist


def _epoch_columns(ctx: CellContext, d: BlockDraw, k_idx: np.ndarray, out: MonitorOutput, he: np.ndarray,
                   ve: np.ndarray) -> dict:
    """Per-epoch records of the kept trials ``k_idx`` (block positions)."""
    trials = d.trials
    t, T, nk = ctx.t, ctx.t.size, k_idx.size
    avail = np.asarray(out.available, bool)
    e = {"trial": np.repeat(trials[k_idx], T),
         "monitor": out.name, "t": np.tile(t, nk),
         "he": he[k_idx].ravel(), "ve": ve[k_idx].ravel(), "hpl": np.asarray(out.hpl, float)[k_idx].ravel(),
         "vpl": np.asarray(out.vpl, float)[k_idx].ravel(), "test_stat": np.asarray(out.test_stat, float)[k_idx].ravel(),
         "threshold": np.asarray(out.threshold, float)[k_idx].ravel(),
         "alert": np.asarray(out.alert, bool)[k_idx].ravel(), "fault_present": d.fault_present[k_idx].ravel()}
    for k, lv in enumerate(ctx.levels):
        e[f"avail_{lv}"] = avail[k_idx, :, k].ravel()
    return e


def _nanmax(x: np.ndarray) -> np.ndarray:
    fin = np.isfinite(x)
    return np.where(fin.any(-1), np.max(np.where(fin, x, -np.inf), axis=-1), np.nan)


def _cat_cols(parts: list[dict[str, np.ndarray | str]]) -> pa.Table | None:
    """One table from column dicts of equal keys; a text value (a str, not an array) stands for that
    text on every row of its part (the monitor's name: 40x faster than a numpy object column)."""
    if not parts:
        return None

    def rows(p: dict) -> int:
        return next(len(v) for v in p.values() if not isinstance(v, str))

    def column(k: str):
        if isinstance(parts[0][k], str):
            return pa.concat_arrays([pa.repeat(pa.scalar(p[k], pa.string()), rows(p)) for p in parts])
        return np.concatenate([p[k] for p in parts])

    return pa.table({k: column(k) for k in parts[0]})


def _concat(tables: list) -> pa.Table | None:
    """Tables of different monitors (columns differ: nulls where a monitor has none)."""
    tables = [t for t in tables if t is not None]
    return pa.concat_tables(tables, promote_options="default") if tables else None


def run_chunk(loaded: LoadedSpec, cell_index: int, chunk: int, threads: int | None = None
              ) -> dict[str, pa.Table | None]:
    """A chunk's tables (pure function of spec, cell and chunk index, whatever ``threads``).

    threads : its draw blocks run on this many threads (None: one per core); each block's
    monitors run on one thread.
    """
    return run_chunk_row(loaded, chunk, [cell_index], threads)[cell_index]


def run_chunk_row(loaded: LoadedSpec, chunk: int, cells: list[int], threads: int | None = None
                  ) -> dict[int, dict[str, pa.Table | None]]:
    """Chunk ``chunk`` of each of ``cells``: ``{cell: tables}``, each what :func:`run_chunk` returns.

    Block-major: each draw block runs every cell in turn (blocks side by side on
    ``threads``), so what a sweep's cells draw alike for a block (:mod:`testbed.memo`) is
    drawn once and reused while it is still in the processor's cache: 0.98–1.36× the
    cell-by-cell order per experiment of the VA-RAIM reproduction (``benchmarks/bench_campaign.py``).
    """
    spec = loaded.spec
    ctxs = [cell_context(_cells(loaded)[c], spec) for c in cells]
    per_chunk = spec.chunk_trials // spec.block_trials
    n_blocks = -(-spec.trials // spec.block_trials)
    blocks = range(chunk * per_chunk, min((chunk + 1) * per_chunk, n_blocks))

    def every_cell(b: int) -> list[dict]:
        return [run_block(ctx, spec, b) for ctx in ctxs]

    n_threads = available_cores() if threads is None else int(threads)
    if n_threads > 1 and len(blocks) > 1:  # blocks are independent: sample and monitor them side by side
        with ThreadPoolExecutor(min(n_threads, len(blocks))) as pool:
            per_block = list(pool.map(every_cell, blocks))
    else:
        per_block = [every_cell(b) for b in blocks]
    throttle = float(os.environ.get("TESTBED_CAMPAIGN_THROTTLE_S", "0") or 0)  # test hook: slow chunks down
    if throttle > 0:
        time.sleep(throttle * len(cells))
    return {c: _chunk_tables(c, ctx, [r[i] for r in per_block]) for i, (c, ctx) in enumerate(zip(cells, ctxs))}


def _chunk_tables(cell_index: int, ctx: CellContext, res: list[dict]) -> dict[str, pa.Table | None]:
    """A cell's chunk tables from its blocks' columns (:func:`run_block`), in block order."""
    monitors = list(ctx.setup.monitor_names)
    trials = _concat([_cat_cols([r["trials"][m] for r in res]) for m in monitors])
    epochs = _concat([_cat_cols([r["epochs"][m] for r in res if m in r["epochs"]]) for m in monitors])
    # histogram: sum the blocks' sparse counts, bins in (error bin, PL bin) order
    hrows = []
    for m in monitors:
        for dim in ("H", "V"):
            parts = [r["hist"][f"{m}/{dim}"] for r in res]
            flat = np.concatenate([np.asarray(ei, np.int64) * HIST_BINS + pi for ei, pi, _ in parts])
            if flat.size == 0:
                continue
            bins, at = np.unique(flat, return_inverse=True)
            count = np.zeros(bins.size, np.int64)
            np.add.at(count, at, np.concatenate([np.asarray(c, np.int64) for _, _, c in parts]))
            hrows.append({"cell": np.full(bins.size, cell_index, np.int32), "monitor": m,
                          "dim": dim, "err_bin": (bins // HIST_BINS).astype(np.int16),
                          "pl_bin": (bins % HIST_BINS).astype(np.int16), "count": count})
    return {"trials": trials, "epochs": epochs, "hist": _cat_cols(hrows)}


def _cells(loaded: LoadedSpec) -> list[Cell]:
    return _cached(("cells", loaded.hash, str(loaded.source)), lambda: expand_cells(loaded))


def chunk_plan(loaded: LoadedSpec) -> list[tuple[int, int, int]]:
    """Every (cell, chunk, n_trials) task of a campaign, in order."""
    spec = loaded.spec
    n_chunks = -(-spec.trials // spec.chunk_trials)
    out = []
    for c in range(len(_cells(loaded))):
        for k in range(n_chunks):
            out.append((c, k, min(spec.chunk_trials, spec.trials - k * spec.chunk_trials)))
    return out


def chunk_rows(todo: list[tuple[int, int, int]]) -> list[tuple[int, list[tuple[int, int]]]]:
    """Tasks ``(cell, chunk, n)`` grouped by chunk: ``[(chunk, [(cell, n), ...]), ...]`` in chunk order
    (the unit :func:`run_chunk_row` runs)."""
    rows: dict[int, list[tuple[int, int]]] = {}
    for c, k, n in todo:
        rows.setdefault(k, []).append((c, n))
    return sorted(rows.items())


def worker_tasks(todo: list[tuple[int, int, int]], workers: int) -> list[tuple[int, list[tuple[int, int]]]]:
    """The tasks of ``todo`` for worker processes (Dask's or the local pool's): chunk rows (:func:`chunk_rows`), so a
    worker draws once what a row's cells share (:mod:`testbed.memo`; a task per cell would draw it once per cell:
    1.7-2.3x the work in the VA-RAIM reproduction). Rows are cut into runs of consecutive cells when there are fewer
    than two tasks per worker, so a campaign of few chunks still keeps every worker busy."""
    rows = chunk_rows(todo)
    want = 2 * max(int(workers), 1)
    if not rows or len(rows) >= want:
        return rows
    pieces = -(-want // len(rows))
    out = []
    for k, cells in rows:
        size = -(-len(cells) // pieces)
        out += [(k, cells[i:i + size]) for i in range(0, len(cells), size)]
    return out


#: The local pool's worker processes start in a few seconds (interpreter, imports, the kernels from numba's cache)
#: and each rebuilds the cells' flight and sky geometry (side by side, so no later than the driver would), then
#: compute faster than threads (docs/performance.md): measured end to end (``benchmarks/bench_dask.py``), gps-faults at 4000
#: sorties per setting (160 000 cell-sorties, ~35 s) took 40.4 s on the pool and 35.1 s in-process, so a pool
#: needs a few minutes of computing to pay for itself: below this many cell-sorties a campaign stays in-process.
POOL_MIN_CELL_SORTIES = 500_000


#: memory a local worker may take: one peaked at 1.2-2.5 GB resident on the reproduction's experiments (its cells'
#: contexts, the memo's 512 MiB, the blocks' arrays), so "auto" starts no more workers than the memory holds
WORKER_MEMORY_BYTES = 3 * 2**30


def local_workers(workers: int | str, todo: list[tuple[int, int, int]], cores: int,
                  memory_bytes: int | None = None) -> int:
    """How many local worker processes run ``todo`` (1: the driver's own process, blocks on threads).

    ``workers`` a number: that many, at most one per task (:func:`worker_tasks`). ``"auto"``: one per core, at most
    one per :data:`WORKER_MEMORY_BYTES` of ``memory_bytes`` (the machine's, when known), when there are at least
    two chunk rows and :data:`POOL_MIN_CELL_SORTIES` cell-sorties to run, else 1. Processes rather than threads
    because the monitors' numpy steps hold the interpreter lock: two worker processes run the reproduction's
    chunk rows faster than the same rows on two threads, side by side in ``benchmarks/bench_campaign.py``
    (its figures: docs/performance.md).
    """
    if workers == "auto":
        big = len(chunk_rows(todo)) >= 2 and sum(n for _, _, n in todo) >= POOL_MIN_CELL_SORTIES
        n = max(int(cores), 1)
        if memory_bytes is not None:
            n = min(n, max(int(memory_bytes // WORKER_MEMORY_BYTES), 1))
        return n if big else 1
    return max(min(int(workers), len(worker_tasks(todo, int(workers)))), 1)


def _worker_row(spec_json: str, source: str, chunk: int, cells: list[int]) -> dict:
    """Entry point on a worker process (Dask's or the local pool's): rebuild the spec from its JSON (cheap, cached
    per process) and run chunk ``chunk`` of ``cells`` (:func:`run_chunk_row`)."""
    from testbed.heap import keep_freed_memory
    from testbed.threads import sleep_idle_threads

    keep_freed_memory()  # a worker process runs nothing but campaign chunks
    sleep_idle_threads()  # beside the other workers (effective unless OpenMP started before the first row)
    return run_chunk_row(worker_spec(spec_json, source), chunk, cells, threads=1)  # the workers are the parallelism


def worker_spec(spec_json: str, source: str) -> LoadedSpec:
    """The spec a worker rebuilds from its JSON, cached per process."""
    from testbed.campaign.spec import CampaignSpec

    return _cached(("loaded", spec_json, source),
                   lambda: resolve_spec(CampaignSpec.model_validate_json(spec_json), Path(source)))


def _ignore_interrupts() -> None:
    """A local worker's initializer: Ctrl-C is the driver's to handle (it stops the workers, which print nothing)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _local_pool(workers: int):
    """``(submit, as_completed, workers)`` of a pool of ``workers`` local processes (spawned: a fresh interpreter
    each; a script calling :func:`run_campaign` with ``workers`` > 1 needs the usual ``if __name__ == "__main__":``
    guard). Interrupted, the pool stops at once: the rows in flight were not stored, and a resume runs them."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=_ignore_interrupts)
    try:
        yield (lambda fn, *a, key: pool.submit(fn, *a)), as_completed, workers
    except BaseException:
        stop = getattr(pool, "terminate_workers", None)  # Python >= 3.14
        if stop is not None:
            stop()
        else:  # before: the executor's own table of its processes
            for proc in list((getattr(pool, "_processes", None) or {}).values()):
                proc.terminate()
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown()


@contextlib.contextmanager
def _dask_pool(client, own: bool):
    """``(submit, as_completed, workers)`` of a Dask client (closed at the end if ``own``)."""
    try:
        from distributed import as_completed

        yield ((lambda fn, *a, key: client.submit(fn, *a, pure=False, key=key)), as_completed,
               sum(client.nthreads().values()))
    finally:
        if own:
            client.close()


# ----------------------------------------------------------------------------- driver

@dataclass
class CampaignResult:
    out_dir: Path
    cells: int
    trials: int
    chunks_run: int
    chunks_skipped: int
    wall_s: float
    epochs_run: int

    @property
    def epochs_per_s(self) -> float:
        return self.epochs_run / self.wall_s if self.wall_s > 0 else float("nan")


def run_campaign(spec: str | Path | LoadedSpec, out_dir: str | Path, *, resume: bool = False,
                 scheduler: str | object | None = None, progress: bool = True,
                 max_chunks: int | None = None, restart: bool = False, workers: int | str = 1) -> CampaignResult:
    """Run (or resume) a campaign into ``out_dir``.

    Parameters
    ----------
    spec : a spec file or a :class:`LoadedSpec` (validated before any work starts).
    out_dir : result folder (manifest, Parquet parts, consolidated tables).
    resume : continue a run in ``out_dir`` (same spec and inputs), skipping stored chunks.
    restart : discard a stored run in ``out_dir`` and start over.
    scheduler : None = on this machine (``workers``); a Dask scheduler address, or a
        ``distributed.Client`` / ``LocalCluster``, sends the same chunk tasks there.
    progress : show a rich progress bar (trials/s, ETA).
    max_chunks : stop after this many new chunks (tests; the run stays resumable).
    workers : without a scheduler: 1 = in this process (a chunk's draw blocks on one thread per
        core); N = chunk rows on N local worker processes; ``"auto"`` = one per core (no more than the
        memory holds) for a campaign big enough to repay their start (:func:`local_workers`). The tables
        are the same bit for bit.
    """
    from testbed.campaign.spec import load_spec
    from testbed.campaign.store import ResultStore
    from testbed.heap import keep_freed_memory

    keep_freed_memory()  # the driver owns its process: keep the blocks' freed arrays in the heap

    from testbed.sim.preflight import check_output_folder

    check_workers(workers, scheduler)
    loaded = spec if isinstance(spec, LoadedSpec) else load_spec(spec)
    check_output_folder(out_dir, "--out")
    from testbed.campaign.exercised import check_faults_exercised  # (it reads this module's cell contexts)

    check_faults_exercised(loaded)  # a fault no trial can exercise: refused before any chunk is drawn
    client, own = _client(scheduler) if scheduler is not None else (None, False)  # reachable before any work
    store = ResultStore(out_dir)
    cells = _cells(loaded)
    try:
        store.open(loaded, cells, resume=resume, restart=restart)
    except BaseException:
        if own:
            client.close()
        raise
    plan = chunk_plan(loaded)
    done = store.done_chunks()
    # chunk-major: a row (chunk k of every cell) runs block-major, so what the cells share (memo) is reused hot
    todo = sorted((p for p in plan if (p[0], p[1]) not in done), key=lambda p: (p[1], p[0]))
    if max_chunks is not None:
        todo = todo[:max_chunks]
    total_trials = sum(n for _, _, n in plan)
    done_trials = total_trials - sum(n for c, k, n in plan if (c, k) not in done)
    n_local = local_workers(workers, todo, available_cores(), physical_memory_bytes()) if client is None else 0
    wall0 = time.perf_counter()
    epochs_run = chunks_run = 0
    run_index = store.start_run()
    bar = _Progress(total_trials, done_trials, loaded.spec.name, enabled=progress)

    def stored(k: int, row: list[tuple[int, int]], tables: dict) -> None:
        nonlocal epochs_run, chunks_run
        for c, n in row:
            store.write_chunk(c, k, tables[c])
            epochs_run += n * _epochs_of(tables[c])
            chunks_run += 1
            bar.advance(n)
        store.update_run(run_index, time.perf_counter() - wall0, chunks_run, epochs_run)

    with bar:
        if n_local == 1:
            for k, row in chunk_rows(todo):
                stored(k, row, run_chunk_row(loaded, k, [c for c, _ in row]))
        else:
            sj, src = loaded.spec.model_dump_json(), str(loaded.source)
            with (_local_pool(n_local) if client is None else _dask_pool(client, own)) as (submit, completed, n):
                futs = {submit(_worker_row, sj, src, k, [c for c, _ in row],
                               key=f"campaign-{loaded.hash}-{k}-{row[0][0]}-{row[-1][0]}"): (k, row)
                        for k, row in worker_tasks(todo, n)}
                for fut in completed(list(futs)):
                    stored(*futs[fut], fut.result())
    if len(store.done_chunks()) == len(plan):
        store.finalize()
    wall = time.perf_counter() - wall0
    store.update_run(run_index, wall, chunks_run, epochs_run, finished=True)
    return CampaignResult(Path(out_dir), len(cells), total_trials, len(todo), len(done), wall, epochs_run)


def check_workers(workers: int | str, scheduler=None) -> None:
    """A ``workers`` value :func:`run_campaign` takes: a positive whole number or ``"auto"``, and only without a
    Dask scheduler (whose workers are the parallelism); else a :class:`ConfigError` before any work."""
    ok = workers == "auto" or (isinstance(workers, (int, np.integer)) and not isinstance(workers, bool)
                               and workers >= 1)
    if not ok:
        raise ConfigError("command line", [f"--workers {workers!r}: expected a positive whole number or 'auto'"])
    if scheduler is not None and workers not in (1, "auto"):
        raise ConfigError("command line", [f"--workers {workers!r} and --scheduler: the Dask scheduler's workers "
                                           "run the chunks; give one or the other"])


def _epochs_of(tables: dict) -> int:
    t = tables.get("trials")
    if t is None or t.num_rows == 0:
        return 0
    return int(t.column("epochs")[0].as_py())


def _client(scheduler):
    from distributed import Client

    if isinstance(scheduler, str):
        try:
            return Client(scheduler, timeout="10s"), True
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError("command line", [f"--scheduler {scheduler!r}: no Dask scheduler answered ({exc}); "
                                               "expected the address of a running scheduler, e.g. "
                                               "tcp://127.0.0.1:8786"]) from None
    if isinstance(scheduler, Client):
        return scheduler, False
    return Client(scheduler), True  # a cluster object


class _Progress:
    """A rich progress bar with trials/s and ETA (a no-op when disabled)."""

    def __init__(self, total: int, done: int, name: str, enabled: bool = True) -> None:
        self.enabled = enabled
        if enabled:
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TaskProgressColumn, TextColumn,
                                       TimeElapsedColumn, TimeRemainingColumn)

            self.p = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                              TaskProgressColumn(), TextColumn("{task.fields[rate]} trials/s"),
                              TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), transient=False)
            self.task = self.p.add_task(name, total=total, completed=done, rate="-")
            self.t0 = time.perf_counter()
            self.n = 0

    def __enter__(self):
        if self.enabled:
            self.p.__enter__()
        return self

    def __exit__(self, *exc):
        if self.enabled:
            self.p.__exit__(*exc)

    def advance(self, n: int) -> None:
        if self.enabled:
            self.n += n
            rate = self.n / max(time.perf_counter() - self.t0, 1e-9)
            self.p.update(self.task, advance=n, rate=f"{rate:,.0f}")

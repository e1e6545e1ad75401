"""A campaign cell's context: what its trials share, computed once per cell and cached per process.

The flight (cached by approach and wind/gust settings, so all cells on one trajectory share one JSBSim run), the
GNSS geometry (per trajectory and start time, per sky window of the sorties) and the vision geometry (per
trajectory, camera and landmark scene). No randomness here: the draws are :mod:`.blocks`'.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from testbed import memo
from testbed.campaign.sorties import sky_repeat_s, sky_windows, sortie_offsets, window_offsets
from testbed.campaign.spec import CampaignSpec, Cell
from testbed.flight.fly import fly
from testbed.inertial import body_to_world, local_to_world
from testbed.integrity.levels import strictest_limits
from testbed.sensors.gnss.synth import concat_windows, gnss_geometry
from testbed.sensors.imu import true_increments
from testbed.sensors.vision import detect as vdetect
from testbed.sim import pipeline
from testbed.sim.setup import build_setup, load_terrain_for


# ----------------------------------------------------------------------------- caches (per process)

_CACHE: OrderedDict[tuple, object] = OrderedDict()
_CACHE_MAX = 64
#: a Dask worker's threads build cell contexts side by side; reentrant: a ``make`` reads other entries
_CACHE_LOCK = threading.RLock()


def cached(key: tuple, make: Callable[[], object]):
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


def cell_terrain(cell: Cell):

    c = cell.config
    key = ("terrain", str(cell.approach.source), json.dumps(c.terrain.model_dump(mode="json"), sort_keys=True))
    return cached(key, lambda: load_terrain_for(cell.approach))


def flown_truth(cell: Cell):
    """The cell's trajectory flown by JSBSim (cached: one flight per distinct trajectory)."""

    return cached(_flight_key(cell), lambda: fly(cell.approach.flight_plan, cell_terrain(cell)).truth)


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
    #: the ground features the tracker follows at the GNSS epochs (T, W): only when the approach's
    #: ``[vision.features]`` is enabled and a monitor reads them (the Won et al. filter)
    feature_ids: np.ndarray | None = None
    #: the run's sensor plan (:func:`testbed.sim.pipeline.sensor_plan`)
    plan: object = None
    #: the period the sky windows are reduced modulo (:func:`~testbed.campaign.sorties.sky_repeat_s` of the
    #: constellations tracked)
    sky_repeat_s: float = sky_repeat_s()

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

    c = cell.config
    duration_s = None if spec is None else spec.duration_s
    segment = "first" if spec is None else spec.segment
    terrain = cell_terrain(cell)
    # blocks run side by side instead of a monitor's threads; what the cells of a sweep compute alike is shared
    setup = build_setup(cell.approach, terrain, monitor_threads=1, share=memo.shared)
    plan = pipeline.sensor_plan(setup)
    fkey = _flight_key(cell)
    sky = None
    repeat_s = sky_repeat_s(c.gnss.constellations)
    if spec is not None and spec.sorties.start != "fixed":
        sky = np.unique(sky_windows(sortie_offsets(spec, np.arange(spec.trials)), spec.sorties.window_s, repeat_s))

    def truth_g():
        tr = flown_truth(cell).decimate(setup.gnss.rate_hz)
        return _segment(tr, duration_s, segment, _segment_start(tr.t, duration_s, segment))

    tkey = ("truth_g", fkey, setup.gnss.rate_hz, duration_s, segment)
    truth = cached(tkey, truth_g)
    imu_inc = imu_start = None
    if any("imu" in m.inputs for m in setup.monitors):
        ikey = ("imu_truth", tkey, json.dumps(setup.imu.model_dump(mode="json"), sort_keys=True))
        imu_inc, imu_start = cached(ikey, lambda: _imu_segment(flown_truth(cell), setup, duration_s, segment))
    # the geometry is keyed on what it reads (the constellation set, almanac, masks, health, caps, schedule, rate,
    # the sky windows and their period); the draws on every GNSS setting (a sweep of the error model shares a sky)
    sky_id = None if sky is None else (spec.sorties.window_s, repeat_s, sky.tobytes())
    lever = json.dumps(c.aircraft and cell.approach.aircraft.antenna_lever_arm_m)
    geo_key = ("gnss_geom", tkey, c.start_time_utc.isoformat(), c.gnss.geometry_key(), lever, sky_id)
    gkey = ("gnss_draw", tkey, c.start_time_utc.isoformat(), json.dumps(c.gnss.model_dump(mode="json"), sort_keys=True),
            lever, sky_id)

    def ggeom():
        eph = plan.constellation
        if sky is None:
            return gnss_geometry(truth, setup.antenna, setup.gnss, start_utc=c.start_time_utc, terrain=terrain,
                                 constellation=eph)
        offsets = window_offsets(sky, spec.sorties.window_s)
        return concat_windows([gnss_geometry(truth, setup.antenna, setup.gnss, start_utc=c.start_time_utc,
                                             terrain=terrain, constellation=eph, offsets_s=offsets[i:i + _WINDOWS_PER_PASS])
                               for i in range(0, offsets.size, _WINDOWS_PER_PASS)])

    g_geom = cached(geo_key, ggeom)
    v_geom, lm = None, None
    if setup.uses_vision:
        lm = setup.landmarks
        vision_json = json.dumps(setup.vision.model_dump(mode="json"), sort_keys=True)
        landmarks_json = json.dumps(c.landmarks.model_dump(mode="json"), sort_keys=True)
        # keyed on the faults the geometry reads: a GPS-fault sweep's cells share one
        moved = vdetect.geometry_faults(list(setup.faults))
        vkey = ("vision_geom", tkey, vision_json, landmarks_json,
                json.dumps([f.model_dump(mode="json") for f in moved], sort_keys=True))
        v_geom = cached(vkey, lambda: vdetect.vision_geometry(truth, setup.vision, landmarks=lm, terrain=terrain,
                                                               faults=moved))
    f_ids = None
    if plan.uses_features:
        fkey_ = ("feature_ids", tkey, json.dumps(setup.vision.model_dump(mode="json"), sort_keys=True),
                 setup.features.tobytes())
        f_ids = cached(fkey_, lambda: pipeline.feature_ids(plan, truth, terrain))
    levels = tuple(setup.integrity.service_levels)
    hal, val = strictest_limits(levels)
    onset = min((f.onset_s for f in setup.faults), default=float("nan"))
    return CellContext(cell=cell, setup=setup, t=np.asarray(truth.t, float), g_geom=g_geom, v_geom=v_geom,
                       landmarks=lm, truth_cg_enu=setup.frame.ecef_to_enu(truth.pos_ecef),
                       truth_ant_enu=setup.frame.ecef_to_enu(g_geom.ant_pos_ecef),
                       hal=hal, val=val, levels=levels, onset_s=float(onset),
                       truth_g=truth, sky=sky, imu_increments=imu_inc, imu_start=imu_start, feature_ids=f_ids,
                       plan=plan, gnss_draw_key=gkey, sky_repeat_s=repeat_s,
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

    t0 = _segment_start(flown.decimate(setup.gnss.rate_hz).t, duration_s, segment)
    tr = _segment(flown, duration_s, segment, t0)
    inc = true_increments(tr, setup.imu)
    p0 = np.asarray(tr.pos_enu[0], float)
    start = (float(tr.t[0]), body_to_world(setup.frame, p0, np.asarray(tr.q_body_to_enu[0], float)),
             local_to_world(setup.frame, p0, np.asarray(tr.vel_enu[0], float)), p0)
    return inc, start

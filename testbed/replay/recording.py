"""The Rerun recording of a RINEX run: the flight's layout (integrity tabs, 3D view, alert log).

Without a reference trajectory there is no truth: ``world/aircraft`` and the
lines of sight are drawn at the preliminary receiver fix, and the protection
volumes (coloured by their Stanford region against the truth in a flight) are
not drawn. With a reference, the reference is the "truth" of the 3D view and
the volumes are coloured as in a flight.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from testbed.integrity.levels import strictest_limits
from testbed.records import take_epochs
from testbed.rinex.observables import hold_last_fix
from testbed.replay.run import RinexRun, geometry_enu
from testbed.sim.events import EventTracker
from testbed.sim.loop import LoopBlock
from testbed.sim.setup import Scene

#: epochs per logged block (the recording does not depend on it: columns are sent per block)
_LOG_EPOCHS = 600


@dataclass(frozen=True)
class _Track:
    """The few truth fields the sink draws the aircraft with (here: the reference or the fix)."""

    pos_enu: np.ndarray
    q_body_to_enu: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray


def _track(run: RinexRun, ant_enu: np.ndarray) -> _Track:
    """The drawn track: epochs without a fix hold the last one (the sink needs finite poses)."""
    ok = np.isfinite(ant_enu).all(-1)
    pos = hold_last_fix(ant_enu) if ok.any() else ant_enu
    lat, lon, _ = run.frame.enu_to_geodetic(pos)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (pos.shape[0], 1))
    return _Track(pos, q, np.asarray(lat), np.asarray(lon))


def write_recording(run: RinexRun, path: Path) -> Path:
    from testbed.viz.rerun_sink import RerunSink

    names = list(run.outputs)
    out0 = run.outputs[names[0]]
    limits = strictest_limits(out0.service_levels)
    ant, los = geometry_enu(run)
    track = _track(run, ant)
    planned = track.pos_enu[:: max(1, track.pos_enu.shape[0] // 2000)]
    scene = Scene(title=f"testbed monitor {run.obs.path.name}", monitors=tuple(names), planned_enu=planned,
                  terrain_mesh=None, runway_enu=None, landmarks_enu=None, landmark_ids=(), camera_K=None,
                  camera_resolution=(0, 0), alert_limits=limits)
    start_ns = int(round((float(run.obs.t_tag[0]) + 315_964_800.0) * 1e9))  # GPS epoch in Unix time (no leap s)
    sink = RerunSink(path, start_time_ns=start_ns)
    tracker = EventTracker(names)
    ok = False
    try:
        sink.start(scene)
        E = run.gnss.t.size
        for a in range(0, E, _LOG_EPOCHS):
            sl = slice(a, min(a + _LOG_EPOCHS, E))
            g = take_epochs(run.gnss, sl)
            tr = _Track(*(x[sl] for x in (track.pos_enu, track.q_body_to_enu, track.lat_deg, track.lon_deg)))
            block = LoopBlock(t=g.t, truth=tr, gnss=g, gnss_truth=None, los_enu=los[sl],
                              antenna_enu=track.pos_enu[sl], vision=None, vision_truth=None, camera_enu=None,
                              R_cam_to_world=None, outputs={m: take_epochs(o, sl) for m, o in run.outputs.items()},
                              events=[], alert_limits=limits)
            if run.reference_enu is not None:
                block.reference_enu = {m: run.reference_enu[sl] for m in names}
            tracker.add(block)
            sink.log_block(block)
        ok = True
    finally:
        sink.close(ok=ok)
    return path

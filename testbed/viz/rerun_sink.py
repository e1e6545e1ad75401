"""Rerun sink: a recording (``.rrd``) and optionally a live gRPC server on loopback.

The loop hands the sink one :class:`~testbed.sim.loop.LoopBlock` at a time (a
few sensor epochs); everything time-varying is sent column-wise with
``send_columns`` (one call per entity per block), which is far cheaper than
per-epoch ``log`` calls (docs/design/physics-notes.md §rerun-logging-cost: 40–170 µs per ``log``). Positions are
logged in the approach's local ENU world frame (Rerun stores float32).

Entity tree (timeline ``sim_time``):
- ``world/terrain`` mesh, ``world/runway``, ``world/landmarks`` (named; names shown on hover),
  ``world/path/planned``, ``world/path/flown``, ``world/aircraft`` (transform + box, and
  ``marker``: a labelled disc of constant screen size for the fixed view), ``world/follow``
  (a level frame at the aircraft along its ground track: the follow view's origin) with
  ``world/follow/stalk`` (a line down to the terrain), ``world/gnss/los`` (rays coloured
  visible / terrain-masked / airframe / faulty; visible GPS green, Galileo blue, BeiDou yellow
  when several constellations are tracked), ``world/gnss/faulty`` (the faulty
  satellite's ray, thick and labelled), ``world/camera`` (pinhole with the true pose),
  ``world/camera/detections`` (faulty ones red), ``world/camera/labels`` (the detections'
  names that do not overlap) and ``world/camera/scene/{frame, horizon, landmarks, runway}``
  (the image's outline, the level line, where the surveyed landmarks and the runway's edges
  fall in the image, true pose);
- ``world/integrity/<monitor>/protection``: the protection volume, an ellipsoid at the estimate
  with semi-axes HPL, HPL, VPL (wireframe), coloured by the worse Stanford region against the
  truth (:data:`REGION_COLOURS`, :data:`REGION_PRIORITY`), and ``.../name`` its label, stacked
  above the volumes (the follow view's);
- ``integrity/<monitor>/{horizontal/{hpl,hal,error}, vertical/{vpl,val,error},
  detection/{test_stat,threshold,ratio,limit}}`` with ``.../marks/<event>`` markers (fault onset,
  alert, alert cleared, excluded, (un)available), each kind in its own lane about the limit line
  (:data:`MARKS`); ``ratio`` is the test statistic over its threshold, the plotted one;
- ``sensors/{satellites_visible, satellites_used/<monitor>, landmarks_detected}``;
- ``alerts`` (TextLog), ``map/aircraft`` (GeoPoints).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from testbed.records import NotVisible
from testbed.viz import image_overlay as overlay
from testbed.viz.blueprint import AIRCRAFT_MARKER, FOLLOW_FRAME, monitor_label, scene_blueprint

if TYPE_CHECKING:  # pragma: no cover
    from testbed.sim.loop import LoopBlock, Scene

LOS_LENGTH_M = 4000.0  # drawn length of a satellite line of sight
COLOURS = {
    "visible": (60, 200, 90),
    "terrain": (230, 60, 50),
    "airframe": (240, 160, 40),
    "faulty": (220, 40, 220),
    "detection": (60, 220, 255),
    "detection_faulty": (255, 40, 40),
    "planned": (250, 250, 120),
    "flown": (80, 160, 255),
    "landmark": (255, 255, 255),
    "runway": (200, 200, 200),
    "feature": (255, 200, 60),
    "visible_galileo": (70, 130, 255),
    "visible_beidou": (250, 230, 70),
    "aircraft": (255, 69, 0),  # a marker that stands out on the terrain's greens and greys
    "horizon": (90, 170, 255),
    "frame": (150, 150, 150),
}
#: the aircraft marker's radius, ui points (constant on screen: the airframe is a pixel at valley scale)
AIRCRAFT_MARKER_PX = 12.0
#: vertical spacing of the monitors' labels above the protection volumes, m (a label is ~11 m
#: tall seen from the follow view's eye, 340 m away)
LABEL_STACK_M = 14.0
#: Stanford region -> colour of the 3D protection volume
REGION_COLOURS = {"normal": (60, 200, 90), "unavailable": (150, 150, 150), "misleading": (240, 160, 40),
                  "hazardous": (230, 30, 30), "unavailable_misleading": (200, 90, 40), "alerted": (220, 40, 220),
                  "no_solution": (90, 90, 90)}
#: events marked on every integrity plot -> (colour, marker, lane). A mark sits at
#: limit x (1 + lane x MARK_LANE) (HAL, VAL, or 1 on a test-over-threshold panel): the truth's
#: onset below the limit line, the monitor's decisions above it, so an alert at the onset epoch
#: is drawn beside the onset, not over it
MARKS = {"fault onset": ((220, 40, 220), "Diamond", -1), "alert": ((230, 30, 30), "Cross", 1),
         "alert cleared": ((40, 170, 70), "Plus", 1), "excluded": ((240, 140, 0), "Asterisk", 2),
         "unavailable": ((130, 130, 130), "Down", -2),
         "available": ((40, 170, 70), "Up", -2)}
MARK_LANE = 0.1
#: colours of the monitors' series in the sensors panel (Okabe & Ito's qualitative set: apart in
#: hue and lightness, on a light and a dark background)
MONITOR_PALETTE = ((0, 114, 178), (230, 159, 0), (204, 121, 167), (213, 94, 0), (86, 180, 233), (120, 80, 40))


def _slug(kind: str) -> str:
    return kind.replace(" ", "_")


#: the order in which a horizontal or vertical region decides the colour of the protection volume
REGION_PRIORITY = ("hazardous", "unavailable_misleading", "misleading", "alerted", "unavailable", "normal",
                   "no_solution")


def worse_region(rh: dict[str, np.ndarray], rv: dict[str, np.ndarray]) -> np.ndarray:
    """(...) index into REGION_PRIORITY of the worse of each epoch's H and V Stanford regions."""
    shape = rh["normal"].shape
    out = np.full(shape, len(REGION_PRIORITY) - 1)
    for k in range(len(REGION_PRIORITY) - 1, -1, -1):  # the worst written last
        r = REGION_PRIORITY[k]
        out[rh[r] | rv[r]] = k
    return out


def _worse_region_colours(rh: dict[str, np.ndarray], rv: dict[str, np.ndarray]) -> np.ndarray:
    palette = np.array([REGION_COLOURS[r] for r in REGION_PRIORITY], np.uint8)
    return palette[worse_region(rh, rv)]


SERIES = {  # entity suffix -> (colour, line name); "{hal}" / "{val}": the alert limit
    "horizontal/hpl": ((80, 160, 255), "HPL"), "horizontal/hal": ((230, 60, 50), "HAL{hal}"),
    "vertical/vpl": ((80, 160, 255), "VPL"), "vertical/val": ((230, 60, 50), "VAL{val}"),
    # the statistic and its threshold as computed (read by scripts), and the plotted ratio
    "detection/test_stat": ((80, 160, 255), "test statistic"), "detection/threshold": ((230, 60, 50), "threshold"),
    "detection/ratio": ((80, 160, 255), "test statistic / threshold"),
    "detection/limit": ((230, 60, 50), "threshold = 1"),
    # drawn when the truth (a flight) or a reference trajectory (a recorded file) is known
    "horizontal/error": ((225, 150, 0), "HPE: error vs truth"),
    "vertical/error": ((225, 150, 0), "VPE: error vs truth"),
}
#: a monitor with several tests (the Won et al. filter): each over its threshold, alert above 1
SEVERAL_TESTS_SERIES = {
    "tests/innovation": ((80, 160, 255), "innovation NIS / threshold"),
    "tests/windowed": ((40, 170, 70), "windowed NIS / threshold"),
    "tests/separation": ((240, 140, 0), "separation max |Δ| / T"), "tests/limit": ((230, 60, 50), "threshold = 1"),
}
#: a monitor that publishes the vertical error density its VPL bounds (DPE)
OVERBOUND_SERIES = {"overbound/sigma_ob": ((80, 160, 255), "σ_ob (overbound)"),
                    "overbound/median": ((230, 60, 50), "median")}


def _limit_text(x: float) -> str:
    return f" {x:g} m" if np.isfinite(x) else ""


def _mark_panels(several_tests: bool) -> tuple[str, ...]:
    """The panels of a monitor's tab that carry the marks (its test panel: one test's or several)."""
    return ("horizontal", "vertical", "tests" if several_tests else "detection")


class RerunSink:
    """Writes a recording and/or serves it live; one instance per flight.

    Parameters
    ----------
    rrd_path : file to write (None: no file).
    live : also serve a gRPC stream for a viewer.
    bind_ip, port : where the live server listens (loopback by default).
    recording_id : fixed id so the same run gives the same recording identity.
    """

    def __init__(self, rrd_path: Path | None, *, live: bool = False, bind_ip: str = "127.0.0.1",
                 port: int = 9876, recording_id: str = "testbed", memory_limit: str = "512MiB",
                 start_time_ns: int | None = None) -> None:
        self.rrd_path = Path(rrd_path) if rrd_path is not None else None
        # no automatic properties: they carry the wall-clock start; we send the simulated one
        self.rec = rr.RecordingStream("testbed", recording_id=recording_id, send_properties=False)
        self.rec.set_log_time_enabled(False)  # wall-clock stamps would make recordings irreproducible
        self._start_time_ns = start_time_ns
        sinks = []
        self._part = None
        if self.rrd_path is not None:
            self.rrd_path.parent.mkdir(parents=True, exist_ok=True)
            # write beside the target and rename on a clean close: a failed run never
            # destroys an earlier recording of the same name
            self._part = self.rrd_path.with_name(self.rrd_path.name + ".part")
            sinks.append(rr.FileSink(str(self._part)))
        self.live_url = None
        self._server = None
        if live:
            sinks.append(rr.GrpcServerSink(bind_ip=bind_ip, port=port, server_memory_limit=memory_limit))
            host = "127.0.0.1" if bind_ip in ("127.0.0.1", "0.0.0.0") else bind_ip
            self.live_url = f"rerun+http://{host}:{port}/proxy"
            self._server = (host, port)
        if not sinks:
            raise ValueError("RerunSink needs a file (rrd_path) or live=True")
        self.rec.set_sinks(*sinks)
        self.monitors: list[str] = []
        self._has_features = False
        self._several_tests: tuple[str, ...] = ()
        self._track_yaw = 0.0  # the follow frame's last heading (held while the aircraft hovers)
        self._volumes: dict[str, tuple] = {}  # this block's protection volumes: (t, centres, half sizes, colours)
        self._own_series: set[str] = set()  # monitors' own curves already named (Diagnostics.plot_series)

    # -- static ----------------------------------------------------------------
    def start(self, scene: "Scene") -> None:
        rec = self.rec
        rec.send_recording_name(scene.title)
        if self._start_time_ns is not None:
            rec.send_recording_start_time_nanos(int(self._start_time_ns))
        self.monitors = list(scene.monitors)
        self._scene_landmarks = scene.landmarks_enu
        self._landmark_ids = list(scene.landmark_ids)
        self._scene_runway = scene.runway_enu
        self._K, self._resolution = scene.camera_K, scene.camera_resolution
        self._has_features = scene.features_enu is not None
        self._several_tests = tuple(scene.several_tests)
        rec.send_blueprint(scene_blueprint(scene), make_active=True, make_default=True)
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if scene.terrain_mesh is not None:
            v, f = scene.terrain_mesh
            h = v[:, 2]
            shade = np.clip((h - h.min()) / max(np.ptp(h), 1.0), 0, 1)
            colours = np.stack([90 + 120 * shade, 110 + 90 * shade, 80 + 140 * shade], -1).astype(np.uint8)
            rec.log("world/terrain", rr.Mesh3D(vertex_positions=v, triangle_indices=f, vertex_colors=colours),
                    static=True)
        if scene.runway_enu is not None:
            ring = np.vstack([scene.runway_enu, scene.runway_enu[:1]])
            rec.log("world/runway", rr.LineStrips3D([ring], colors=[COLOURS["runway"]], radii=[-1.5]), static=True)
        if scene.features_enu is not None and len(scene.features_enu):
            rec.log("world/features", rr.Points3D(scene.features_enu, colors=[COLOURS["feature"]], radii=[-1.5]),
                    static=True)
        if scene.landmarks_enu is not None and len(scene.landmarks_enu):
            # named for hovering, not labelled: at approach ranges the runway's corners are pixels apart
            rec.log("world/landmarks", rr.Points3D(scene.landmarks_enu, labels=list(scene.landmark_ids),
                                                   colors=[COLOURS["landmark"]], radii=[-3.0], show_labels=False),
                    static=True)
        rec.log("world/path/planned", rr.LineStrips3D([scene.planned_enu], colors=[COLOURS["planned"]],
                                                      radii=[-1.5]), static=True)
        rec.log("world/aircraft/body", rr.Boxes3D(half_sizes=[[18.0, 3.0, 2.0]], colors=[COLOURS["aircraft"]],
                                                  fill_mode="solid"), static=True)
        rec.log(AIRCRAFT_MARKER, rr.Points3D([[0.0, 0.0, 0.0]], colors=[COLOURS["aircraft"]],
                                             radii=[-AIRCRAFT_MARKER_PX], labels=["aircraft"], show_labels=True),
                static=True)
        rec.log(f"{FOLLOW_FRAME}/stalk", rr.LineStrips3D.from_fields(colors=[COLOURS["aircraft"]], radii=[-1.0]),
                static=True)
        if scene.camera_K is not None:
            self._start_camera(scene)
        for m in self.monitors:
            self._start_monitor(m, tuple(scene.alert_limits), m in scene.several_tests, m in scene.vertical_only)
        self._start_sensors(scene)
        rec.set_time("sim_time", duration=0.0)
        rec.log("alerts", rr.TextLog(f"start: {scene.title}", level=rr.TextLogLevel.INFO))

    def _start_camera(self, scene: "Scene") -> None:
        rec = self.rec
        w, h = scene.camera_resolution
        # the landmark's slot as class id: hovering a detection names its landmark
        rec.log("world/camera/detections", rr.AnnotationContext(
            [rr.ClassDescription(info=(k, lid)) for k, lid in enumerate(scene.landmark_ids)]), static=True)
        rec.log("world/camera/detections", rr.Points2D.from_fields(radii=[5.0], show_labels=False), static=True)
        rec.log("world/camera/labels", rr.Points2D.from_fields(radii=[-1.0], show_labels=True), static=True)
        rec.log("world/camera/scene/frame", rr.LineStrips2D([[[0, 0], [w, 0], [w, h], [0, h], [0, 0]]],
                                                            colors=[COLOURS["frame"]], radii=[-1.0],
                                                            labels=[f"image {w} x {h} px"], show_labels=False),
                static=True)
        rec.log("world/camera/scene/horizon", rr.LineStrips2D.from_fields(colors=[COLOURS["horizon"]], radii=[-1.5]),
                static=True)
        rec.log("world/camera/scene/landmarks", rr.Points2D.from_fields(colors=[COLOURS["landmark"]], radii=[-4.0]),
                static=True)
        rec.log("world/camera/scene/runway", rr.LineStrips2D.from_fields(colors=[COLOURS["runway"]], radii=[-1.5]),
                static=True)
        rec.log("world/camera", rr.Pinhole(image_from_camera=scene.camera_K, resolution=[w, h],
                                           camera_xyz=rr.ViewCoordinates.RDF,
                                           image_plane_distance=12.0), static=True)  # a frame ahead of the nose

    def _start_monitor(self, m: str, alert_limits: tuple[float, float], several_tests: bool,
                       vertical_only: bool) -> None:
        """The names and colours of a monitor's series and marks (static: the legend's entries)."""
        rec = self.rec
        hal, val = (_limit_text(x) for x in alert_limits)
        series = dict(SERIES)
        series.update(SEVERAL_TESTS_SERIES if several_tests else {})
        series.update(OVERBOUND_SERIES if vertical_only else {})
        for suffix, (colour, name) in series.items():
            rec.log(f"integrity/{m}/{suffix}",
                    rr.SeriesLines(colors=[colour], names=[name.format(hal=hal, val=val)], widths=[2.0]), static=True)
        rec.log(f"world/integrity/{m}/protection", rr.Ellipsoids3D.from_fields(
            fill_mode="MajorWireframe", line_radii=[-1.5], labels=[m], show_labels=False), static=True)
        rec.log(monitor_label(m), rr.Points3D.from_fields(radii=[-2.0], labels=[m], show_labels=True), static=True)
        for panel in _mark_panels(several_tests):
            for kind, (colour, marker, _) in MARKS.items():
                rec.log(f"integrity/{m}/{panel}/marks/{_slug(kind)}",
                        rr.SeriesPoints(colors=[colour], names=[kind], markers=[marker], marker_sizes=[5.0]),
                        static=True)

    def _start_sensors(self, scene: "Scene") -> None:
        """Every sensors series in a colour of its own. The viewer draws series in the order of their
        entity paths: the monitors' satellites-used lines narrower in that order and the visible count
        thinnest, on top, so that equal counts show as nested stripes, none hidden."""
        rec = self.rec
        rec.log("sensors/satellites_visible", rr.SeriesLines(names=["satellites visible"], colors=[(110, 110, 110)],
                                                             widths=[1.5]), static=True)
        drawn = sorted(self.monitors)
        for k, m in enumerate(self.monitors):
            colour = MONITOR_PALETTE[k % len(MONITOR_PALETTE)]
            width = 1.5 + 1.5 * (len(drawn) - drawn.index(m))
            rec.log(f"sensors/satellites_used/{m}", rr.SeriesLines(
                names=[f"measurements used by {m}"], colors=[colour], widths=[width]), static=True)
            if self._has_features:
                rec.log(f"sensors/features_in_state/{m}", rr.SeriesLines(
                    names=[f"features in {m}'s state"], colors=[colour], widths=[1.0]), static=True)
        if scene.camera_K is not None:
            rec.log("sensors/landmarks_detected", rr.SeriesLines(names=["landmarks detected"], colors=[(0, 158, 115)],
                                                                 widths=[2.0]), static=True)
        if self._has_features:
            rec.log("sensors/features_tracked", rr.SeriesLines(names=["ground features tracked"],
                                                               colors=[(150, 90, 40)], widths=[2.0]), static=True)

    # -- per block -------------------------------------------------------------
    def log_block(self, block: "LoopBlock") -> None:
        rec = self.rec
        t = block.t
        if t.size == 0:
            return
        times = [rr.TimeColumn("sim_time", duration=t)]
        tr = block.truth
        # aircraft pose (the truth record's local ENU attitude ~ world ENU near the field)
        rec.send_columns("world/aircraft", indexes=times,
                         columns=rr.Transform3D.columns(translation=tr.pos_enu, quaternion=tr.q_body_to_enu))
        self._log_follow_frame(times, t, tr)
        # flown trail: the whole trail up to each epoch would be O(T^2); log the new points
        rec.send_columns("world/path/flown", indexes=times,
                         columns=rr.Points3D.columns(positions=tr.pos_enu, colors=np.tile(COLOURS["flown"], (t.size, 1)),
                                                     radii=np.full(t.size, -2.5)).partition(np.ones(t.size, int)))
        lat, lon = tr.lat_deg, tr.lon_deg
        rec.send_columns("map/aircraft", indexes=times,
                         columns=rr.GeoPoints.columns(positions=np.column_stack([lat, lon])).partition(np.ones(t.size, int)))
        if block.gnss is not None:
            self._log_gnss(block, times)
        if block.vision is not None:
            self._log_vision(block)
        if block.features is not None:
            self._log_features(block.features)
        for name, out in block.outputs.items():
            self._log_monitor(name, out, block, times)
            self._log_errors(name, out, block)
            self._log_protection_in_3d(name, out, block)
        self._log_monitor_labels(block)
        self._log_marks(block)
        for t_ev, level, text in block.events:
            rec.set_time("sim_time", duration=t_ev)
            rec.log("alerts", rr.TextLog(text, level=level))

    def _log_follow_frame(self, times, t: np.ndarray, tr) -> None:
        """The follow view's frame: at the aircraft, x along its ground track, z up; and the stalk
        from the aircraft down to the terrain (when the truth knows the height above it)."""
        yaw = self._ground_track(np.asarray(t, float), np.asarray(tr.pos_enu, float), getattr(tr, "vel_enu", None))
        half = 0.5 * yaw
        q = np.column_stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)])  # xyzw about z
        self.rec.send_columns(FOLLOW_FRAME, indexes=times,
                              columns=rr.Transform3D.columns(translation=tr.pos_enu, quaternion=q))
        agl = getattr(tr, "agl", None)
        if agl is not None:
            n = len(yaw)
            strips = np.zeros((n, 2, 3))
            strips[:, 1, 2] = -np.maximum(np.asarray(agl, float), 0.0)
            self.rec.send_columns(f"{FOLLOW_FRAME}/stalk", indexes=times,
                                  columns=rr.LineStrips3D.columns(strips=strips).partition(np.ones(n, int)))

    def _ground_track(self, t: np.ndarray, pos_enu: np.ndarray, vel_enu) -> np.ndarray:
        """(T,) rad, the direction of horizontal motion anticlockwise from east: from the velocity
        when the truth has one, else from the positions' differences (a recorded file); held at its
        last value below 1 m/s (a static receiver, a hover), 0 (east) before any motion."""
        if vel_enu is not None:
            v = np.asarray(vel_enu, float)[:, :2]
        elif len(t) > 1:
            v = np.gradient(pos_enu[:, :2], t, axis=0)
        else:
            v = np.zeros((len(t), 2))
        moving = np.hypot(v[:, 0], v[:, 1]) >= 1.0
        raw = np.arctan2(v[:, 1], v[:, 0])
        last = np.maximum.accumulate(np.where(moving, np.arange(len(t)), -1)) if len(t) else np.zeros(0, int)
        yaw = np.where(last >= 0, raw[np.maximum(last, 0)], self._track_yaw)
        if moving.any():
            self._track_yaw = float(raw[np.flatnonzero(moving)[-1]])
        return yaw

    def _log_gnss(self, block: "LoopBlock", times) -> None:
        g, gt = block.gnss, block.gnss_truth
        los_enu = block.los_enu  # (T, S, 3) unit vectors in the world frame
        reason = np.asarray(g.reason)
        faulty = np.asarray(gt.faulty) if gt is not None else np.zeros(reason.shape, bool)
        draw = (reason != NotVisible.BELOW_MASK) & np.isfinite(los_enu).all(-1)  # a recorded file: no orbit, no ray
        start = np.broadcast_to(block.antenna_enu[:, None, :], los_enu.shape)
        end = start + LOS_LENGTH_M * los_enu
        colour = np.empty(reason.shape + (3,), np.uint8)
        colour[:] = COLOURS["visible"]
        system = np.broadcast_to(np.asarray(g.system), reason.shape)
        mixed = bool((system != "G").any())  # several constellations: a visible ray has its system's colour
        colour[system == "E"] = COLOURS["visible_galileo"]
        colour[system == "C"] = COLOURS["visible_beidou"]
        colour[reason == NotVisible.TERRAIN] = COLOURS["terrain"]
        colour[reason == NotVisible.AIRFRAME] = COLOURS["airframe"]
        colour[faulty & (reason == NotVisible.VISIBLE)] = COLOURS["faulty"]
        strips = np.stack([start[draw], end[draw]], 1)  # (K, 2, 3)
        lengths = draw.sum(axis=1)
        self.rec.send_columns(
            "world/gnss/los", indexes=times,
            columns=rr.LineStrips3D.columns(strips=strips, colors=colour[draw],
                                            radii=np.full(len(strips), -1.0)).partition(lengths))
        # the faulty satellite's ray again, thick and labelled (empty where none is faulty and in view)
        bad = faulty & (reason == NotVisible.VISIBLE)
        prn = np.broadcast_to(np.asarray(g.prn), reason.shape)
        self.rec.send_columns(
            "world/gnss/faulty", indexes=times,
            columns=rr.LineStrips3D.columns(strips=np.stack([start[bad], end[bad]], 1),
                                            colors=np.tile(COLOURS["faulty"], (int(bad.sum()), 1)),
                                            radii=np.full(int(bad.sum()), -4.0),
                                            labels=[f"faulty {c}{p:02d}" if mixed else f"faulty PRN {p}"
                                                    for c, p in zip(system[bad], prn[bad])]).partition(bad.sum(axis=1)))
        self.rec.send_columns("sensors/satellites_visible", indexes=times,
                              columns=rr.Scalars.columns(scalars=np.asarray(g.visible).sum(axis=-1).astype(float)))

    def _log_vision(self, block: "LoopBlock") -> None:
        v, vt = block.vision, block.vision_truth
        tv = [rr.TimeColumn("sim_time", duration=v.t)]
        rec = self.rec
        rec.send_columns("world/camera", indexes=tv,
                         columns=rr.Transform3D.columns(translation=block.camera_enu, mat3x3=block.R_cam_to_world))
        det = np.asarray(v.detected)
        uv = np.asarray(v.pixel_uv)[det]
        faulty = np.asarray(vt.faulty)[det] if vt is not None else np.zeros(len(uv), bool)
        colours = np.where(faulty[:, None], COLOURS["detection_faulty"], COLOURS["detection"]).astype(np.uint8)
        # the landmark's slot as class id: hovering names it (ints are cheap)
        slot = np.broadcast_to(np.arange(det.shape[-1]), det.shape)[det]
        rec.send_columns("world/camera/detections", indexes=tv,
                         columns=rr.Points2D.columns(positions=uv, colors=colours, class_ids=slot).partition(
                             det.sum(axis=1)))
        rec.send_columns("sensors/landmarks_detected", indexes=tv,
                         columns=rr.Scalars.columns(scalars=det.sum(axis=1).astype(float)))
        self._log_detection_labels(tv, det, np.asarray(v.pixel_uv), np.asarray(vt.faulty) if vt is not None else None)
        self._log_scene_in_camera(tv, block.camera_enu, block.R_cam_to_world)

    def _log_detection_labels(self, tv, det: np.ndarray, pixel_uv: np.ndarray, faulty) -> None:
        """The detections' names where they do not overlap (:func:`image_overlay.declutter`, the
        faulty ones first): far from the runway its landmarks fall a few pixels apart."""
        w, h = self._resolution
        box = (overlay.LABEL_BOX[0] * w, overlay.LABEL_BOX[1] * h)
        pos, text, colour, counts = [], [], [], []
        for k in range(det.shape[0]):
            idx = np.flatnonzero(det[k])
            bad = np.zeros(len(idx), bool) if faulty is None else np.asarray(faulty[k])[idx]
            keep = overlay.declutter(pixel_uv[k, idx], box, order=np.argsort(~bad, kind="stable"))
            pos += list(pixel_uv[k, idx[keep]])
            text += [self._landmark_ids[i] for i in idx[keep]]
            colour += [COLOURS["detection_faulty"] if b else COLOURS["detection"] for b in bad[keep]]
            counts.append(int(keep.sum()))
        self.rec.send_columns("world/camera/labels", indexes=tv, columns=rr.Points2D.columns(
            positions=np.array(pos, float).reshape(-1, 2), labels=text,
            colors=np.array(colour, np.uint8).reshape(-1, 3)).partition(counts))

    def _log_features(self, tracks) -> None:
        """The tracked ground features' pixels (the tracker's report) and how many it follows, per GNSS epoch."""
        tm = [rr.TimeColumn("sim_time", duration=tracks.t)]
        seen = np.asarray(tracks.ids) >= 0
        uv = np.asarray(tracks.uv)[0][seen]
        self.rec.send_columns("world/camera/features", indexes=tm,
                              columns=rr.Points2D.columns(positions=uv, colors=np.tile(COLOURS["feature"], (len(uv), 1)),
                                                          radii=np.full(len(uv), 2.5)).partition(seen.sum(axis=1)))
        self.rec.send_columns("sensors/features_tracked", indexes=tm,
                              columns=rr.Scalars.columns(scalars=seen.sum(axis=1).astype(float)))

    def _log_scene_in_camera(self, tv, cam_enu: np.ndarray, R_c2w: np.ndarray) -> None:
        """What the camera sees, drawn from the true pose every vision epoch: the level line
        (horizon), where the surveyed landmarks fall inside the image, and the runway's edges, each
        clipped to the part in front of the camera and inside the image."""
        if self._K is None:
            return
        w, h = self._resolution
        K = np.asarray(self._K, float)
        ends, ok = overlay.level_line(K, w, h, R_c2w)
        self.rec.send_columns("world/camera/scene/horizon", indexes=tv, columns=rr.LineStrips2D.columns(
            strips=ends[ok]).partition(ok.astype(int)))
        if self._scene_landmarks is not None and len(self._scene_landmarks):
            Xc = overlay.to_camera(np.asarray(self._scene_landmarks, float)[None], cam_enu[:, None, :], R_c2w)
            front = Xc[..., 2] > overlay.NEAR_M
            with np.errstate(divide="ignore", invalid="ignore"):
                uv = overlay.project(K, Xc)
            inside = front & (uv[..., 0] >= 0) & (uv[..., 0] <= w) & (uv[..., 1] >= 0) & (uv[..., 1] <= h)
            self.rec.send_columns("world/camera/scene/landmarks", indexes=tv,
                                  columns=rr.Points2D.columns(positions=uv[inside]).partition(inside.sum(axis=1)))
        if self._scene_runway is not None:
            ring = np.asarray(self._scene_runway, float)
            edges = np.stack([ring, np.roll(ring, -1, axis=0)], axis=1)  # (4, 2, 3) world
            edges_c = overlay.to_camera(edges[None].reshape(1, 8, 3), cam_enu[:, None, :], R_c2w).reshape(-1, 4, 2, 3)
            ends, ok = overlay.segments_in_image(K, w, h, edges_c)  # (Tv, 4, 2, 2), (Tv, 4)
            self.rec.send_columns("world/camera/scene/runway", indexes=tv, columns=rr.LineStrips2D.columns(
                strips=ends[ok]).partition(ok.sum(axis=1)))

    def _log_monitor(self, name: str, out, block: "LoopBlock", times) -> None:
        tm = [rr.TimeColumn("sim_time", duration=out.t)]
        hal, val = block.alert_limits
        n = out.t.size
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.asarray(out.test_stat, float) / np.asarray(out.threshold, float)
        vals = {
            "horizontal/hpl": out.hpl, "horizontal/hal": np.full(n, hal),
            "vertical/vpl": out.vpl, "vertical/val": np.full(n, val),
            "detection/test_stat": out.test_stat, "detection/threshold": out.threshold,
            "detection/ratio": ratio, "detection/limit": np.ones(n),
        }
        for suffix, x in vals.items():
            self.rec.send_columns(f"integrity/{name}/{suffix}", indexes=tm,
                                  columns=rr.Scalars.columns(scalars=np.asarray(x, float)))
        self.rec.send_columns(f"sensors/satellites_used/{name}", indexes=tm,
                              columns=rr.Scalars.columns(scalars=np.asarray(out.n_used, float)))
        self._log_normalised_tests(name, out)
        self._log_vertical_density(name, out)
        d = out.diagnostics
        for suffix, (x, label) in ({} if d is None else d.plot_series()).items():  # a monitor's own curves
            entity = f"integrity/{name}/{suffix}"
            if entity not in self._own_series:
                self.rec.log(entity, rr.SeriesLines(names=[label], widths=[1.5]), static=True)
                self._own_series.add(entity)
            self.rec.send_columns(entity, indexes=tm, columns=rr.Scalars.columns(scalars=np.asarray(x, float)))
        if getattr(d, "n_features", None) is not None and self._has_features:  # the filter's SLAM states
            self.rec.send_columns(f"sensors/features_in_state/{name}", indexes=tm,
                                  columns=rr.Scalars.columns(scalars=np.asarray(d.n_features, float)))

    def _log_normalised_tests(self, name: str, out) -> None:
        """A monitor with several tests (diagnostics with ``window_stat``, ``window_threshold``, ``ss_ratio``:
        the Won et al. filter): each statistic over its threshold on one panel, the alert line at 1."""
        d = out.diagnostics
        if not all(hasattr(d, f) for f in ("window_stat", "window_threshold", "ss_ratio")):
            return
        tm = [rr.TimeColumn("sim_time", duration=out.t)]
        with np.errstate(invalid="ignore", divide="ignore"):
            vals = {"tests/innovation": np.asarray(out.test_stat, float) / np.asarray(out.threshold, float),
                    "tests/windowed": np.asarray(d.window_stat, float) / np.asarray(d.window_threshold, float),
                    "tests/separation": np.asarray(d.ss_ratio, float), "tests/limit": np.ones(out.t.size)}
        for suffix, x in vals.items():
            self.rec.send_columns(f"integrity/{name}/{suffix}", indexes=tm, columns=rr.Scalars.columns(scalars=x))

    def _log_errors(self, name: str, out, block: "LoopBlock") -> None:
        """The monitor's horizontal and vertical position errors beside its PLs (when a truth is known)."""
        from testbed.sim.evaluate import position_errors

        ref = block.reference_enu.get(name)
        if ref is None:
            return
        he, ve = position_errors(out, ref)
        tm = [rr.TimeColumn("sim_time", duration=out.t)]
        for suffix, x in (("horizontal/error", he), ("vertical/error", ve)):
            self.rec.send_columns(f"integrity/{name}/{suffix}", indexes=tm,
                                  columns=rr.Scalars.columns(scalars=np.asarray(x, float)))

    def _log_vertical_density(self, name: str, out) -> None:
        """A monitor that publishes the vertical error distribution its PL bounds (diagnostics with
        ``marginal``, ``marginal_offsets``, ``sigma_ob``, ``median_m``: DPE): its overbound over
        time and, per epoch, the density as a bar chart (m on the abscissa)."""
        d = out.diagnostics
        if not all(hasattr(d, f) for f in ("marginal", "marginal_offsets", "sigma_ob", "median_m")):
            return
        tm = [rr.TimeColumn("sim_time", duration=out.t)]
        for suffix, x in (("overbound/sigma_ob", d.sigma_ob), ("overbound/median", d.median_m)):
            self.rec.send_columns(f"integrity/{name}/{suffix}", indexes=tm,
                                  columns=rr.Scalars.columns(scalars=np.asarray(x, float)))
        for i, t in enumerate(np.asarray(out.t, float)):
            off, mass = np.asarray(d.marginal_offsets[i], float), np.asarray(d.marginal[i], float)
            if not np.isfinite(mass).all():
                continue
            width = float(off[1] - off[0])
            keep = mass > 1e-6 * mass.max()  # the bars that show
            self.rec.set_time("sim_time", duration=float(t))
            self.rec.log(f"integrity/{name}/vertical_error_density",
                         rr.BarChart(mass[keep] / width, abscissa=off[keep], widths=np.full(int(keep.sum()), width)))

    def _log_marks(self, block: "LoopBlock") -> None:
        """Fault onset, alerts and availability changes as markers on each monitor's three panels, on
        the limit line (HAL, VAL, 1 on the test panel: in range whatever the curves do), each kind in
        its lane (:data:`MARKS`). Sent as columns, one call per marker series, so the recording's
        chunks do not depend on timing."""
        hal, val = block.alert_limits
        series: dict[str, tuple[list, list]] = {}
        for t_m, who, kind in block.marks:
            lane = 1.0 + MARK_LANE * MARKS[kind][2]
            for m in ([who] if who else list(block.outputs)):
                if m not in block.outputs:
                    continue
                panels = _mark_panels(m in self._several_tests)
                for panel, limit in zip(panels, (hal, val, 1.0)):
                    ts, ys = series.setdefault(f"integrity/{m}/{panel}/marks/{_slug(kind)}", ([], []))
                    ts.append(t_m)
                    ys.append(limit * lane)
        for entity, (ts, ys) in series.items():
            self.rec.send_columns(entity, indexes=[rr.TimeColumn("sim_time", duration=np.asarray(ts))],
                                  columns=rr.Scalars.columns(scalars=np.asarray(ys, float)))

    def _log_monitor_labels(self, block: "LoopBlock") -> None:
        """Each monitor's name above the protection volumes, in its volume's colour, stacked
        :data:`LABEL_STACK_M` apart over the highest volume top of the epoch so that none covers
        another (the volumes of monitors that agree coincide)."""
        drawn = {m: self._volumes.get(m) for m in self.monitors}
        drawn = {m: v for m, v in drawn.items() if v is not None}
        if not drawn:
            return
        t_all = np.unique(np.concatenate([v[0] for v in drawn.values()]))
        top = np.full(t_all.size, -np.inf)
        for t, centre, half, _ in drawn.values():
            np.maximum.at(top, np.searchsorted(t_all, t), centre[:, 2] + half[:, 2])
        for k, (m, (t, centre, _, colour)) in enumerate(drawn.items()):
            pos = centre.copy()
            pos[:, 2] = top[np.searchsorted(t_all, t)] + LABEL_STACK_M * (k + 1)
            self.rec.send_columns(monitor_label(m), indexes=[rr.TimeColumn("sim_time", duration=t)],
                                  columns=rr.Points3D.columns(positions=pos, colors=colour).partition(
                                      np.ones(t.size, int)))
        self._volumes = {}

    def _log_protection_in_3d(self, name: str, out, block: "LoopBlock") -> None:
        """The monitor's protection volume: an ellipsoid at its estimate with horizontal semi-axes
        HPL and vertical semi-axis VPL (wireframe: the HPL circle and the ±VPL meridians), coloured
        by the worse of its horizontal and vertical Stanford regions against the truth at its
        reference point (hazardous > misleading > alerted > unavailable > normal)."""
        from testbed.sim.evaluate import position_errors, stanford_regions

        ref = block.reference_enu.get(name)
        if ref is None:
            return
        hal, val = block.alert_limits
        pos, hpl, vpl = np.asarray(out.pos_enu, float), np.asarray(out.hpl, float), np.asarray(out.vpl, float)
        ok = np.isfinite(pos).all(-1) & np.isfinite(hpl) & np.isfinite(vpl)
        if not ok.any():
            return
        he, ve = position_errors(out, ref)
        alert = np.asarray(out.alert, bool)
        colour = _worse_region_colours(stanford_regions(he, hpl, hal, alert), stanford_regions(ve, vpl, val, alert))[ok]
        t = out.t[ok]
        half = np.column_stack([hpl[ok], hpl[ok], vpl[ok]])
        self.rec.send_columns(f"world/integrity/{name}/protection", indexes=[rr.TimeColumn("sim_time", duration=t)],
                              columns=rr.Ellipsoids3D.columns(centers=pos[ok], half_sizes=half,
                                                              colors=colour).partition(np.ones(t.size, int)))
        self._volumes[name] = (t, pos[ok], half, colour)  # where its label goes (_log_monitor_labels)

    def commit(self) -> None:
        """Flush and move the recording into place (atomically); a live server stays up."""
        self.rec.flush()
        if self._part is not None and self._part.exists():
            self._part.replace(self.rrd_path)
            self._part = None

    def close(self, ok: bool = True) -> None:
        """Flush, commit (with ``ok``) and stop every sink, the live server included.

        Without ``ok`` the partial ``.part`` file is removed and ``rrd_path`` is untouched.
        """
        if ok:
            self.commit()
        self.rec.flush()
        self.rec.disconnect()
        if self._server is not None:
            _wait_until_closed(*self._server)
            self._server = None
        if self._part is not None and self._part.exists():
            self._part.unlink()
            self._part = None


def _wait_until_closed(host: str, port: int, timeout_s: float = 10.0) -> None:
    """Block until the live server stops accepting connections.

    Rerun stops its gRPC server on a background thread after ``disconnect``; without
    this wait a caller that returns from a live run could still find the port taken
    (a second live run on the same port would then be refused by its preflight).
    """
    import socket
    import time

    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket(family) as s:
            s.settimeout(0.5)
            if s.connect_ex((host, port)) != 0:
                return
        time.sleep(0.02)

"""Rerun sink: a recording (``.rrd``) and optionally a live gRPC server on loopback.

The loop hands the sink one :class:`~testbed.sim.loop.LoopBlock` at a time (a
few sensor epochs); everything time-varying is sent column-wise with
``send_columns`` (one call per entity per block), which is far cheaper than
per-epoch ``log`` calls (docs/design/physics-notes.md §rerun-logging-cost: 40–170 µs per ``log``). Positions are
logged in the approach's local ENU world frame (Rerun stores float32).

Entity tree (timeline ``sim_time``):
- ``world/terrain`` mesh, ``world/runway``, ``world/landmarks``, ``world/path/planned``,
  ``world/path/flown``, ``world/aircraft`` (transform + box), ``world/gnss/los`` (rays
  coloured visible / terrain-masked / airframe / faulty), ``world/gnss/faulty`` (the faulty
  satellite's ray, thick and labelled), ``world/camera`` (pinhole with the true pose),
  ``world/camera/detections`` (faulty ones red) and ``world/camera/scene/{landmarks, runway}``
  (where the surveyed landmarks and the runway outline fall in the image, true pose);
- ``world/integrity/<monitor>/protection``: the protection volume, an ellipsoid at the estimate
  with semi-axes HPL, HPL, VPL (wireframe), coloured by the worse Stanford region against the
  truth (:data:`REGION_COLOURS`, :data:`REGION_PRIORITY`);
- ``integrity/<monitor>/{horizontal/{hpl,hal}, vertical/{vpl,val}, detection/{test_stat,threshold}}``
  with ``.../marks/<event>`` markers (fault onset, alert, alert cleared, (un)available);
- ``sensors/{satellites_visible, satellites_used/<monitor>, landmarks_detected}``;
- ``alerts`` (TextLog), ``map/aircraft`` (GeoPoints).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from testbed.records import NotVisible
from testbed.viz.blueprint import approach_eye, default_blueprint

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
}
#: Stanford region -> colour of the 3D protection volume
REGION_COLOURS = {"normal": (60, 200, 90), "unavailable": (150, 150, 150), "misleading": (240, 160, 40),
                  "hazardous": (230, 30, 30), "unavailable_misleading": (200, 90, 40), "alerted": (220, 40, 220),
                  "no_solution": (90, 90, 90)}
#: events marked on every integrity plot -> (colour, marker)
MARKS = {"fault onset": ((220, 40, 220), "Diamond"), "alert": ((230, 30, 30), "Cross"),
         "alert cleared": ((60, 200, 90), "Plus"), "excluded": ((240, 160, 40), "Asterisk"),
         "unavailable": ((150, 150, 150), "Down"),
         "available": ((60, 200, 90), "Up")}
PANELS = ("horizontal", "vertical", "detection")


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


SERIES = {  # entity suffix -> (colour, line name)
    "horizontal/hpl": ((80, 160, 255), "HPL"), "horizontal/hal": ((230, 60, 50), "HAL"),
    "vertical/vpl": ((80, 160, 255), "VPL"), "vertical/val": ((230, 60, 50), "VAL"),
    "detection/test_stat": ((80, 160, 255), "test statistic"), "detection/threshold": ((230, 60, 50), "threshold"),
    # drawn when the truth (a flight) or a reference trajectory (a recorded file) is known
    "horizontal/error": ((250, 200, 40), "HPE (error vs truth)"), "vertical/error": ((250, 200, 40), "VPE (error vs truth)"),
    # a monitor with several tests (the Won et al. filter): each over its threshold, alert above 1
    "tests/innovation": ((80, 160, 255), "innovation NIS / threshold"),
    "tests/windowed": ((60, 200, 120), "windowed NIS / threshold"),
    "tests/separation": ((250, 150, 40), "separation max |Δ|/T"), "tests/limit": ((230, 60, 50), "alert limit 1"),
}


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
        self._trail_len = 0

    # -- static ----------------------------------------------------------------
    def start(self, scene: "Scene") -> None:
        rec = self.rec
        rec.send_recording_name(scene.title)
        if self._start_time_ns is not None:
            rec.send_recording_start_time_nanos(int(self._start_time_ns))
        self.monitors = list(scene.monitors)
        self._scene_landmarks = scene.landmarks_enu
        self._scene_runway = scene.runway_enu
        self._K, self._resolution = scene.camera_K, scene.camera_resolution
        self._has_features = scene.features_enu is not None
        rec.send_blueprint(default_blueprint(self.monitors, approach_eye(scene.planned_enu), tuple(scene.alert_limits),
                                             vertical_only=tuple(scene.vertical_only),
                                             several_tests=tuple(scene.several_tests),
                                             camera_view=scene.camera_K is not None),
                           make_active=True, make_default=True)
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
            rec.log("sensors/features_tracked", rr.SeriesLines(names=["ground features tracked"]), static=True)
        if scene.landmarks_enu is not None and len(scene.landmarks_enu):
            rec.log("world/landmarks", rr.Points3D(scene.landmarks_enu, labels=list(scene.landmark_ids),
                                                   colors=[COLOURS["landmark"]], radii=[-3.0]), static=True)
        rec.log("world/path/planned", rr.LineStrips3D([scene.planned_enu], colors=[COLOURS["planned"]],
                                                      radii=[-1.5]), static=True)
        rec.log("world/aircraft/body", rr.Boxes3D(half_sizes=[[18.0, 3.0, 2.0]], colors=[(255, 255, 255)]),
                static=True)
        if scene.camera_K is not None:
            rec.log("world/camera/detections", rr.AnnotationContext(
                [rr.ClassDescription(info=(k, lid)) for k, lid in enumerate(scene.landmark_ids)]), static=True)
            rec.log("world/camera/detections", rr.Points2D.from_fields(radii=[4.0], show_labels=True), static=True)
            rec.log("world/camera/scene/landmarks", rr.Points2D.from_fields(colors=[COLOURS["landmark"]], radii=[7.0]),
                    static=True)
            rec.log("world/camera/scene/runway", rr.LineStrips2D.from_fields(colors=[COLOURS["runway"]], radii=[1.5]),
                    static=True)
            w, h = scene.camera_resolution
            rec.log("world/camera", rr.Pinhole(image_from_camera=scene.camera_K, resolution=[w, h],
                                               camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=60.0),
                    static=True)
        for m in self.monitors:
            for suffix, (colour, name) in SERIES.items():
                rec.log(f"integrity/{m}/{suffix}", rr.SeriesLines(colors=[colour], names=[name], widths=[2.0]),
                        static=True)
            rec.log(f"world/integrity/{m}/protection", rr.Ellipsoids3D.from_fields(
                fill_mode="MajorWireframe", line_radii=[-1.5], labels=[m], show_labels=True), static=True)
            for panel in PANELS:
                for kind, (colour, marker) in MARKS.items():
                    rec.log(f"integrity/{m}/{panel}/marks/{_slug(kind)}",
                            rr.SeriesPoints(colors=[colour], names=[kind], markers=[marker], marker_sizes=[6.0]),
                            static=True)
        rec.log("sensors/satellites_visible", rr.SeriesLines(names=["satellites visible"]), static=True)
        rec.log("sensors/landmarks_detected", rr.SeriesLines(names=["landmarks detected"]), static=True)
        rec.set_time("sim_time", duration=0.0)
        rec.log("alerts", rr.TextLog(f"start: {scene.title}", level=rr.TextLogLevel.INFO))

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
        self._log_marks(block)
        for t_ev, level, text in block.events:
            rec.set_time("sim_time", duration=t_ev)
            rec.log("alerts", rr.TextLog(text, level=level))

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
                                            labels=[f"faulty PRN {p}" for p in prn[bad]]).partition(bad.sum(axis=1)))
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
        # the landmark's slot as class id: its label comes from the annotation context (ints are cheap)
        slot = np.broadcast_to(np.arange(det.shape[-1]), det.shape)[det]
        rec.send_columns("world/camera/detections", indexes=tv,
                         columns=rr.Points2D.columns(positions=uv, colors=colours, class_ids=slot).partition(
                             det.sum(axis=1)))
        rec.send_columns("sensors/landmarks_detected", indexes=tv,
                         columns=rr.Scalars.columns(scalars=det.sum(axis=1).astype(float)))
        self._log_scene_in_camera(tv, block.camera_enu, block.R_cam_to_world)

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
        """Where the surveyed landmarks and the runway outline fall in the image (true pose, no
        noise), every vision epoch they are in front of the camera and inside the image: the
        camera view shows the scene while it is in view, beside the detections."""
        if self._K is None:
            return
        w, h = self._resolution

        def project(X):  # (T, N, 3) world -> (T, N, 2) px, and in front of the camera
            c = np.einsum("tji,tnj->tni", R_c2w, X[None] - cam_enu[:, None, :])  # R_c2wᵀ (X − c), RDF
            z = c[..., 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                uv = np.stack([c[..., 0] / z, c[..., 1] / z, np.ones_like(z)], -1) @ self._K.T
            return uv[..., :2], z > 1.0

        if self._scene_landmarks is not None and len(self._scene_landmarks):
            uv, front = project(np.asarray(self._scene_landmarks, float))
            inside = front & (uv[..., 0] >= 0) & (uv[..., 0] < w) & (uv[..., 1] >= 0) & (uv[..., 1] < h)
            self.rec.send_columns("world/camera/scene/landmarks", indexes=tv,
                                  columns=rr.Points2D.columns(positions=uv[inside]).partition(inside.sum(axis=1)))
        if self._scene_runway is not None:
            uv, front = project(np.asarray(self._scene_runway, float))
            whole = front.all(-1)  # an outline partly behind the camera does not project to a polygon
            rings = np.concatenate([uv[whole], uv[whole][:, :1]], axis=1)  # an ndarray: 30x faster than a list
            self.rec.send_columns("world/camera/scene/runway", indexes=tv,
                                  columns=rr.LineStrips2D.columns(strips=rings).partition(whole.astype(int)))

    def _log_monitor(self, name: str, out, block: "LoopBlock", times) -> None:
        tm = [rr.TimeColumn("sim_time", duration=out.t)]
        hal, val = block.alert_limits
        n = out.t.size
        vals = {
            "horizontal/hpl": out.hpl, "horizontal/hal": np.full(n, hal),
            "vertical/vpl": out.vpl, "vertical/val": np.full(n, val),
            "detection/test_stat": out.test_stat, "detection/threshold": out.threshold,
        }
        for suffix, x in vals.items():
            self.rec.send_columns(f"integrity/{name}/{suffix}", indexes=tm,
                                  columns=rr.Scalars.columns(scalars=np.asarray(x, float)))
        self.rec.send_columns(f"sensors/satellites_used/{name}", indexes=tm,
                              columns=rr.Scalars.columns(scalars=np.asarray(out.n_used, float)))
        self._log_normalised_tests(name, out)
        self._log_vertical_density(name, out)
        d = out.diagnostics
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
        """Fault onset, alerts and availability changes as markers on each monitor's three panels
        (on the alert-limit / threshold line, so they are in range whatever the PLs do). Sent as
        columns, one call per marker series, so the recording's chunks do not depend on timing."""
        hal, val = block.alert_limits
        series: dict[str, tuple[list, list]] = {}
        for t_m, who, kind in block.marks:
            for m in ([who] if who else list(block.outputs)):
                out = block.outputs.get(m)
                if out is None:
                    continue
                thr = np.asarray(out.threshold, float)
                fin = np.isfinite(thr)
                y_det = float(np.interp(t_m, out.t[fin], thr[fin])) if fin.any() else 0.0
                for panel, y in (("horizontal", hal), ("vertical", val), ("detection", y_det)):
                    ts, ys = series.setdefault(f"integrity/{m}/{panel}/marks/{_slug(kind)}", ([], []))
                    ts.append(t_m)
                    ys.append(y)
        for entity, (ts, ys) in series.items():
            self.rec.send_columns(entity, indexes=[rr.TimeColumn("sim_time", duration=np.asarray(ts))],
                                  columns=rr.Scalars.columns(scalars=np.asarray(ys, float)))

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
        self.rec.send_columns(f"world/integrity/{name}/protection", indexes=[rr.TimeColumn("sim_time", duration=t)],
                              columns=rr.Ellipsoids3D.columns(
                                  centers=pos[ok], half_sizes=np.column_stack([hpl[ok], hpl[ok], vpl[ok]]),
                                  colors=colour).partition(np.ones(t.size, int)))

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

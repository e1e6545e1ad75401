"""The .rrd recording: layout entities, stored blueprint, PL series = monitor outputs, alert timing, verify."""

import dataclasses
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from testbed.api import load_approach, run_approach
from testbed.sensors.faults import GpsStep
from testbed.viz import readback

FAULT_ONSET_S = 30.0
MAX_RRD_MB = 8.0


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    ap = load_approach("va-raim-2015")
    cfg = ap.config.model_copy(update={"faults": [GpsStep(kind="gps_step", prn="random", bias_m=100.0,
                                                          onset_s=FAULT_ONSET_S)]})
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    return run_approach(dataclasses.replace(ap, config=cfg), seed=4, rrd_path=path)


def test_layout_entities_and_blueprint(run):
    paths = readback.entity_paths(run.rrd_path)
    expected = {"/world/terrain", "/world/runway", "/world/landmarks", "/world/path/planned", "/world/path/flown",
                "/world/aircraft", "/world/gnss/los", "/world/camera", "/world/camera/detections", "/alerts",
                "/map/aircraft", "/sensors/satellites_visible"}
    for m in ("gps_raim", "va_raim", "pixel"):
        expected |= {f"/integrity/{m}/horizontal/hpl", f"/integrity/{m}/vertical/vpl",
                     f"/integrity/{m}/horizontal/hal", f"/integrity/{m}/detection/test_stat",
                     f"/integrity/{m}/detection/threshold"}
    assert expected <= paths, sorted(expected - paths)
    assert readback.has_blueprint(run.rrd_path)


@pytest.mark.parametrize("monitor", ["gps_raim", "va_raim", "pixel"])
def test_pl_series_equal_monitor_outputs(run, monitor):
    out = run.outputs[monitor]
    for entity, values in [("horizontal/hpl", out.hpl), ("vertical/vpl", out.vpl),
                           ("detection/test_stat", out.test_stat)]:
        t, v = readback.scalar_series(run.rrd_path, f"integrity/{monitor}/{entity}")
        np.testing.assert_allclose(t, out.t, atol=1e-9)
        np.testing.assert_array_equal(v, np.asarray(values, float))  # float64 series, bit for bit


def test_step_fault_alert_logged_at_the_right_time(run):
    out = run.outputs["gps_raim"]
    first = float(out.t[np.flatnonzero(out.alert)[0]])
    assert first == pytest.approx(FAULT_ONSET_S)  # 100 m on a visible satellite, 8 in view: immediate
    log = readback.text_log(run.rrd_path)
    alerts = [e for e in log if e[1] == "ERROR" and e[2].startswith("gps_raim: ALERT")]
    assert alerts and alerts[0][0] == pytest.approx(first)
    assert any("[truth] fault injected: gps_step" in e[2] and e[0] == pytest.approx(FAULT_ONSET_S) for e in log)
    assert run.summaries["gps_raim"].time_to_alert_s == pytest.approx(0.0)


def test_rrd_verify_and_size(run):
    rerun_cli = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    res = subprocess.run([rerun_cli, "rrd", "verify", str(run.rrd_path)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert os.path.getsize(run.rrd_path) < MAX_RRD_MB * 2**20


def _listening(port: int) -> list[str]:
    """Local addresses (hex, as in /proc/net/tcp) listening on ``port``."""
    out = []
    for f in ("/proc/net/tcp", "/proc/net/tcp6"):
        if not os.path.exists(f):
            continue
        for line in open(f).read().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            addr, p = local.rsplit(":", 1)
            if state == "0A" and int(p, 16) == port:
                out.append(addr)
    return out


def test_live_sink_binds_loopback_and_flight_completes_without_viewer(tmp_path):
    from testbed.viz.rerun_sink import RerunSink

    port = 19876
    sink = RerunSink(None, live=True, port=port, recording_id="live-test")
    try:
        addrs = _listening(port)
        assert addrs and all(a == "0100007F" for a in addrs), addrs  # 127.0.0.1 only
        assert sink.live_url == f"rerun+http://127.0.0.1:{port}/proxy"
    finally:
        sink.close()
    res = run_approach("va-raim-2015", seed=1, rrd_path=None, live=True, port=port + 1,
                       monitors=["gps_raim"])
    assert res.flight.summary.reached_end and res.live_url is not None


def test_failed_run_keeps_the_earlier_recording(tmp_path, monkeypatch):
    import testbed.sim.loop as loop_mod

    path = tmp_path / "keep.rrd"
    path.write_bytes(b"an earlier recording")

    def boom(*a, **k):
        raise RuntimeError("simulated failure mid-run")

    monkeypatch.setattr(loop_mod, "fly", boom)
    with pytest.raises(RuntimeError):
        run_approach("va-raim-2015", rrd_path=path, monitors=["gps_raim"])
    assert path.read_bytes() == b"an earlier recording"


def test_same_seed_recordings_hold_the_same_content(tmp_path):
    """Same seed, same recording: every entity, timeline, component and value equal, and the
    recording's start time is the simulated one. What differs is stated in the README: the
    per-write ids (TUIDs) Rerun gives chunks and rows, hence the compressed bytes."""
    from testbed.api import run_approach
    from testbed.viz.readback import content_digest

    paths = [tmp_path / f"r{k}.rrd" for k in range(3)]
    for p, seed in zip(paths, (4, 4, 5)):
        run_approach("va-raim-2015", seed=seed, rrd_path=p, block_s=10.0)
    assert content_digest(paths[0]) == content_digest(paths[1])
    assert content_digest(paths[0]) != content_digest(paths[2])  # the digest sees a different noise draw
    import rerun.chunk as rrc

    starts = [rb.column(rb.schema.names.index("RecordingInfo:start_time")).to_pylist()
              for ch in rrc.RrdReader(str(paths[0])).stream() if ch.entity_path == "/__properties"
              for rb in [ch.to_record_batch()] if "RecordingInfo:start_time" in rb.schema.names]
    assert starts and starts[0][0][0] == 1772337600 * 10**9  # 2026-03-01T04:00:00Z, the approach's start


def test_linger_keeps_the_live_server_up_after_landing(tmp_path):
    """``--linger``: the recording is in place and the server still accepts a viewer after landing."""
    import socket

    from testbed.api import run_approach

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    seen = {}

    def landed(result):
        seen["rrd"] = result.rrd_path.exists()
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            seen["connected"] = True

    run_approach("va-raim-2015", seed=1, rrd_path=tmp_path / "l.rrd", live=True, port=port, linger_s=0.5,
                 block_s=20.0, on_landed=landed)
    assert seen == {"rrd": True, "connected": True}
    with socket.socket() as s:  # closed after the linger
        assert s.connect_ex(("127.0.0.1", port)) != 0


def test_series_views_show_the_whole_flight(tmp_path):
    """Every time-series view of the stored layout (each monitor's HPL, VPL and test statistic, and
    the sensors in use) spans the whole flight, not the seconds before the cursor."""
    from testbed.api import run_approach
    from testbed.viz.readback import view_time_ranges

    rrd = tmp_path / "bp.rrd"
    run_approach("va-raim-2015", seed=1, rrd_path=rrd, block_s=30.0, monitors=["gps_raim", "va_raim"])
    ranges = view_time_ranges(rrd)
    assert len(ranges) == 2 * 3 + 1
    for r in ranges:
        assert r == [{"timeline": "sim_time", "range": {"start": None, "end": None}}]


def test_events_are_marked_on_every_integrity_plot(run):
    """Fault onset and each monitor's first alert as markers on its HPL, VPL and test-statistic
    plots, at the epochs the alert log gives (the alert a tenth of the limit above the HAL / VAL /
    threshold line, the onset a tenth below)."""
    log = readback.text_log(run.rrd_path)
    for m in ("gps_raim", "va_raim", "pixel"):
        t, v = readback.scalar_series(run.rrd_path, f"integrity/{m}/horizontal/marks/fault_onset")
        assert list(t) == [pytest.approx(FAULT_ONSET_S)]
        out = run.outputs[m]
        if out.alert.any():
            first = float(out.t[np.flatnonzero(out.alert)[0]])
            ta, va = readback.scalar_series(run.rrd_path, f"integrity/{m}/detection/marks/alert")
            assert ta[0] == pytest.approx(first)
            assert any(e[0] == pytest.approx(first) and e[2].startswith(f"{m}: ALERT") for e in log)
            assert va[0] == pytest.approx(1.1)  # just above the threshold line (the ratio's 1)
            th, vh = readback.scalar_series(run.rrd_path, f"integrity/{m}/horizontal/marks/alert")
            assert th[0] == pytest.approx(first) and np.all(vh == pytest.approx(1.1 * 40.0))  # above the HAL line
        _, vo = readback.scalar_series(run.rrd_path, f"integrity/{m}/vertical/marks/fault_onset")
        assert vo[0] == pytest.approx(0.9 * 20.0)  # just below the VAL line


def test_protection_volumes_and_the_faulty_ray_in_3d(run):
    """Each monitor's protection volume: an ellipsoid at its estimate with semi-axes HPL, HPL, VPL,
    coloured by the worse Stanford region; the faulty satellite's ray labelled from the onset."""
    from testbed.integrity.monitor import ANTENNA
    from testbed.integrity.pixel import PixelMonitor
    from testbed.integrity.raim import GpsRaimMonitor
    from testbed.integrity.va_raim import VaRaimMonitor
    from testbed.sim.evaluate import position_errors, stanford_regions
    from testbed.sim.setup import approach_geometry
    from testbed.viz.rerun_sink import REGION_COLOURS, REGION_PRIORITY, worse_region

    MONITOR_CLASSES = {"gps_raim": GpsRaimMonitor, "va_raim": VaRaimMonitor, "pixel": PixelMonitor}
    frame, _ = approach_geometry(load_approach("va-raim-2015").flight_plan)
    hal, val = 40.0, 20.0  # APV-II, the most demanding default level
    for m in ("gps_raim", "va_raim", "pixel"):
        out = run.outputs[m]
        t, half = readback.component_rows(run.rrd_path, f"world/integrity/{m}/protection", "Ellipsoids3D:half_sizes")
        _, centres = readback.component_rows(run.rrd_path, f"world/integrity/{m}/protection", "Ellipsoids3D:centers")
        _, colours = readback.component_rows(run.rrd_path, f"world/integrity/{m}/protection", "Ellipsoids3D:colors")
        ok = np.isfinite(out.hpl) & np.isfinite(out.vpl) & np.isfinite(out.pos_enu).all(-1)
        np.testing.assert_allclose(t, out.t[ok], atol=1e-9)
        half = np.array([h[0] for h in half])
        np.testing.assert_allclose(half, np.column_stack([out.hpl[ok], out.hpl[ok], out.vpl[ok]]), rtol=1e-6)
        np.testing.assert_allclose(np.array([c[0] for c in centres]), out.pos_enu[ok], atol=0.01)  # float32
        at_antenna = MONITOR_CLASSES[m].reference == ANTENNA
        truth = frame.ecef_to_enu(run.loop.gnss_truth.antenna_pos_ecef if at_antenna else run.loop.truth_at_gnss.pos_ecef)
        he, ve = position_errors(out, truth)
        want = worse_region(stanford_regions(he, out.hpl, hal, out.alert), stanford_regions(ve, out.vpl, val, out.alert))
        rgba = [np.uint32(c[0]) for c in colours]
        got = [((int(x) >> 24) & 255, (int(x) >> 16) & 255, (int(x) >> 8) & 255) for x in rgba]
        assert got == [REGION_COLOURS[REGION_PRIORITY[k]] for k in want[ok]]
    t, labels = readback.component_rows(run.rrd_path, "world/gnss/faulty", "LineStrips3D:labels")
    prn = run.loop.gnss.prn[np.asarray(run.loop.gnss_truth.faulty).any(0)][0]
    marked = [lb for lb in labels if lb]
    assert t[[bool(lb) for lb in labels]].min() == pytest.approx(FAULT_ONSET_S)
    assert marked and all(lb == [f"faulty PRN {prn}"] for lb in marked)


def test_blueprint_has_a_view_that_follows_the_aircraft_and_names_the_alert_limits(run):
    vs = {(v["class"], v["name"], v["origin"]) for v in readback.views(run.rrd_path)}
    assert ("3D", "follow the aircraft", "/world/follow") in vs and ("3D", "world", "/world") in vs
    for entity, name in (("horizontal/hal", "HAL 40 m"), ("vertical/val", "VAL 20 m")):  # in the legends
        assert readback.static_components(run.rrd_path, f"/integrity/gps_raim/{entity}")["SeriesLines:names"] == [name]


def test_camera_view_shows_where_the_landmarks_are_beside_the_detections(run):
    """The surveyed landmarks projected with the true camera pose land on their detections (to the
    detection noise), at every vision epoch they are in the image."""
    t_s, scene = readback.component_rows(run.rrd_path, "world/camera/scene/landmarks", "Points2D:positions")
    t_d, det = readback.component_rows(run.rrd_path, "world/camera/detections", "Points2D:positions")
    assert len(t_s) == len(t_d) > 50  # the seed sortie: vision at 1 Hz, 61 epochs
    gaps = []
    for a, b in zip(scene, det):
        if a and b:
            a, b = np.array(a), np.array(b)
            gaps.append(np.min(np.linalg.norm(a[:, None] - b[None], axis=-1), axis=0))  # each detection's nearest
    gaps = np.concatenate(gaps)
    assert gaps.size > 100 and np.median(gaps) < 3.0  # 1 px detection noise, sub-pixel dithering


def test_an_exclusion_is_logged_and_marked(tmp_path):
    """FDE on, a 100 m step: GPS RAIM excludes the faulty satellite from the first faulty epoch on; the
    log names its PRN and the plots carry the exclusion mark there (no alert mark: it was cleared)."""
    ap = load_approach("va-raim-2015")
    cfg = ap.config.model_copy(update={
        "faults": [GpsStep(kind="gps_step", prn="random", bias_m=100.0, onset_s=FAULT_ONSET_S)],
        "integrity": ap.config.integrity.model_copy(update={"fde": True}), "monitors": ["gps_raim"]})
    res = run_approach(dataclasses.replace(ap, config=cfg), seed=4, rrd_path=tmp_path / "fde.rrd")
    out = res.outputs["gps_raim"]
    first = float(out.t[np.flatnonzero(out.excluded >= 0)[0]])
    assert first == pytest.approx(FAULT_ONSET_S) and not out.alert.any()
    faulty = np.asarray(res.loop.gnss_truth.faulty)[np.flatnonzero(out.t == first)[0]]
    prn = int(np.asarray(res.loop.gnss.prn)[np.flatnonzero(faulty)[0]])
    log = readback.text_log(res.rrd_path)
    hits = [e for e in log if "EXCLUDED" in e[2]]
    assert hits and hits[0][0] == pytest.approx(first) and f"PRN {prn} EXCLUDED" in hits[0][2]
    t, _ = readback.scalar_series(res.rrd_path, "integrity/gps_raim/detection/marks/excluded")
    assert t[0] == pytest.approx(first)
    assert res.summaries["gps_raim"].excluded_epochs == int((out.excluded >= 0).sum()) > 0
    assert res.summaries["gps_raim"].time_to_alert_s == pytest.approx(0.0)  # a detection, though no alert


def _listening_sockets_of_this_process() -> set[str]:
    """Inodes of the TCP sockets this process has listening (Linux /proc)."""
    mine = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            mine.add(target[8:-1])
    listening = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        if os.path.exists(table):
            for line in open(table).read().splitlines()[1:]:
                f = line.split()
                if f[3] == "0A":  # LISTEN
                    listening.add(f[9])
    return mine & listening


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs Linux's /proc")
def test_no_listener_is_opened_without_live(tmp_path, monkeypatch):
    """README: 'no listener is opened without --live'. A recorded flight never builds Rerun's server sink,
    and this process has no more listening sockets during the flight than before it."""
    import rerun as rr

    def refuse(*a, **k):
        raise AssertionError("a live server was started without --live")

    for name in ("GrpcServerSink", "serve_grpc", "serve_web_viewer", "start_web_viewer_server", "spawn"):
        monkeypatch.setattr(rr, name, refuse)
    before = _listening_sockets_of_this_process()
    seen = []
    res = run_approach("va-raim-2015", seed=1, rrd_path=tmp_path / "r.rrd", monitors=["gps_raim"],
                       on_landed=lambda r: seen.append(_listening_sockets_of_this_process()))
    assert res.live_url is None and (tmp_path / "r.rrd").is_file()
    assert seen and seen[0] <= before


# ---- the layout as a user reads it (issue 49): each test reads the STORED blueprint and recording back

def _view(rrd, name):
    found = [v for v in readback.views(rrd) if v["name"] == name]
    assert len(found) == 1, [v["name"] for v in readback.views(rrd)]
    return found[0]


def _rotation_xyzw(q) -> np.ndarray:
    """The rotation matrix of a unit quaternion (x, y, z, w), written out (not Rerun's code, not ours)."""
    x, y, z, w = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_the_follow_view_rides_behind_and_above_the_aircraft(run):
    """The follow view's origin is a level frame at the aircraft along its ground track (the truth's
    position and velocity), its stored eye behind and above the aircraft looking at it, close enough
    for the 36 m airframe to span more than 4°; the fixed view marks the aircraft with a labelled
    disc of constant screen size."""
    rrd = run.rrd_path
    follow = _view(rrd, "follow the aircraft")
    eye = follow["properties"]["EyeControls3D"]
    e, target, up = (np.asarray(eye[k], float) for k in ("position", "look_target", "eye_up"))
    np.testing.assert_allclose(target, 0.0, atol=1e-6)  # the aircraft, at the frame's origin
    np.testing.assert_allclose(up, [0.0, 0.0, 1.0])
    assert np.linalg.norm(e) < 18.0 / np.tan(np.radians(2.0))
    t, trans = readback.component_rows(rrd, follow["origin"], "Transform3D:translation")
    _, quat = readback.component_rows(rrd, follow["origin"], "Transform3D:quaternion")
    truth = run.loop.truth_at_gnss
    np.testing.assert_allclose(t, truth.t, atol=1e-9)
    np.testing.assert_allclose(np.array([x[0] for x in trans]), truth.pos_enu, atol=0.01)
    v_h = truth.vel_enu * np.array([1.0, 1.0, 0.0])
    v_h /= np.linalg.norm(v_h, axis=1, keepdims=True)
    for k, q in enumerate(quat):
        R = _rotation_xyzw(q[0])
        np.testing.assert_allclose(R @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=1e-6)  # level
        assert R[:, 0] @ v_h[k] > 0.9999  # x along the ground track
        eye_world = truth.pos_enu[k] + R @ e
        behind = (truth.pos_enu[k] - eye_world) @ v_h[k]
        assert 150.0 < behind < 600.0 and 30.0 < eye_world[2] - truth.pos_enu[k][2] < 300.0
    world = _view(rrd, "world")
    marker = "/world/aircraft/marker"
    assert marker in readback.view_entities(rrd, world) and marker not in readback.view_entities(rrd, follow)
    comps = readback.static_components(rrd, marker)
    assert comps["Points3D:radii"][0] <= -8.0  # negative: ui points, the same size at any range
    assert comps["Points3D:labels"] == ["aircraft"] and comps["Points3D:show_labels"] == [True]


def test_every_plot_names_every_curve_in_its_legend(run):
    """Every time-series view of the stored layout shows its legend, and every series it plots names
    itself (distinct names: the legend merges equal ones); titles stay short enough not to be cut."""
    rrd = run.rrd_path
    series = readback.scalar_entities(rrd)
    plots = [v for v in readback.views(rrd) if v["class"] == "TimeSeries"]
    assert len(plots) == 3 * 3 + 1
    for v in plots:
        assert len(v["name"]) <= 60, v["name"]
        assert v["properties"]["PlotLegend"]["visible"] is True, v["name"]
        shown = readback.view_entities(rrd, v) & series
        assert shown, v["name"]
        names = []
        for entity in shown:
            comps = readback.static_components(rrd, entity)
            name = comps.get("SeriesLines:names") or comps.get("SeriesPoints:names")
            assert name and name[0].strip(), entity
            names.append(name[0])
        assert len(set(names)) == len(names), (v["name"], names)
    names = readback.static_components(rrd, "/integrity/gps_raim/horizontal/error")["SeriesLines:names"]
    assert "error vs truth" in names[0]


def test_plot_ranges_keep_the_limits_and_their_numbers_in_view(run):
    """The PL plots span 0 to at least 1.2 x the alert limit in at most 9 decade steps (the viewer labels
    the y axis at decade steps and drops all but 0 when there are too many); the test panel plots
    the statistic over its threshold (alert above 1) on 0..2, not the raw statistic whose post-fault
    ~1000 flattened the threshold."""
    rrd = run.rrd_path
    for m in ("gps_raim", "va_raim", "pixel"):
        for panel, limit in (("horizontal", 40.0), ("vertical", 20.0)):
            v = next(v for v in readback.views(rrd) if v["origin"] == f"/integrity/{m}/{panel}")
            lo, hi = v["properties"]["ScalarAxis"]["range"]
            assert lo == 0.0 and hi >= 1.2 * limit
            assert hi / 10 ** np.floor(np.log10(hi)) <= 9
        v = next(v for v in readback.views(rrd) if v["origin"] == f"/integrity/{m}/detection")
        assert v["properties"]["ScalarAxis"]["range"] == [0.0, 2.0]
        plotted = readback.view_entities(rrd, v) & readback.scalar_entities(rrd)
        assert f"/integrity/{m}/detection/test_stat" not in plotted
        out = run.outputs[m]
        _, ratio = readback.scalar_series(rrd, f"integrity/{m}/detection/ratio")
        np.testing.assert_allclose(ratio, out.test_stat / out.threshold, rtol=1e-12)
        assert f"/integrity/{m}/detection/ratio" in plotted and f"/integrity/{m}/detection/limit" in plotted


def test_an_alert_at_the_onset_epoch_is_drawn_beside_the_onset(run):
    """GPS RAIM alerts at the fault's onset epoch: on each of its three plots the two marks are apart
    (by a tenth of the limit or more), and every kind of mark has its own shape and colour."""
    rrd = run.rrd_path
    for panel, limit in (("horizontal", 40.0), ("vertical", 20.0), ("detection", 1.0)):
        t_on, y_on = readback.scalar_series(rrd, f"integrity/gps_raim/{panel}/marks/fault_onset")
        t_al, y_al = readback.scalar_series(rrd, f"integrity/gps_raim/{panel}/marks/alert")
        assert t_on[0] == t_al[0] == pytest.approx(FAULT_ONSET_S)
        assert abs(y_al[0] - y_on[0]) >= 0.1 * limit - 1e-9
    styles = [readback.static_components(rrd, f"/integrity/gps_raim/detection/marks/{k}")
              for k in ("fault_onset", "alert", "alert_cleared", "excluded", "unavailable", "available")]
    pairs = {(s["SeriesPoints:markers"][0], s["SeriesPoints:colors"][0]) for s in styles}
    assert len(pairs) == len(styles)


def test_the_camera_view_shows_the_image_frame_horizon_and_runway(run):
    """The camera view is framed on the image (its outline drawn, a dark background); the horizon is
    where level directions project with the pose and intrinsics read back from the recording (to
    0.5 px); the runway's drawn segments lie inside the image on the projected runway's edges."""
    rrd = run.rrd_path
    cam = readback.static_components(rrd, "/world/camera")
    K = np.asarray(cam["Pinhole:image_from_camera"], float).reshape(3, 3).T  # stored column-major
    w, h = cam["Pinhole:resolution"][0]
    view = next(v for v in readback.views(rrd) if v["origin"] == "/world/camera")
    xr, yr = (view["properties"]["VisualBounds2D"]["range"][k] for k in ("x_range", "y_range"))
    assert xr[0] <= 0 and xr[1] >= w and yr[0] <= 0 and yr[1] >= h and xr[1] - xr[0] < 1.1 * w
    assert sum(readback.rgba(view["properties"]["Background"]["color"])[:3]) < 3 * 60  # dark
    frame = np.asarray(readback.static_components(rrd, "/world/camera/scene/frame")["LineStrips2D:strips"][0])
    assert {tuple(p) for p in frame} == {(0, 0), (w, 0), (w, h), (0, h)}
    t, trans = readback.component_rows(rrd, "/world/camera", "Transform3D:translation")
    _, mats = readback.component_rows(rrd, "/world/camera", "Transform3D:mat3x3")
    t_h, horizons = readback.component_rows(rrd, "/world/camera/scene/horizon", "LineStrips2D:strips")
    t_r, runways = readback.component_rows(rrd, "/world/camera/scene/runway", "LineStrips2D:strips")
    np.testing.assert_allclose(t_h, t)
    np.testing.assert_allclose(t_r, t)
    ring = np.asarray(readback.static_components(rrd, "/world/runway")["LineStrips3D:strips"][0], float)[:4]
    truth = run.loop.truth_at_gnss
    drawn = 0
    for k in range(len(t)):
        R = np.asarray(mats[k][0], float).reshape(3, 3).T  # camera axes in the world, stored column-major
        c = np.asarray(trans[k][0], float)
        v = truth.vel_enu[np.argmin(np.abs(truth.t - t[k]))]
        assert R[:, 2] @ v / np.linalg.norm(v) > np.cos(np.radians(25))  # the optical axis looks ahead
        # level directions across the view: their pixels, straight from K and the pose
        fwd = R[:, 2] * [1.0, 1.0, 0.0]
        fwd /= np.linalg.norm(fwd)
        side = np.cross([0.0, 0.0, 1.0], fwd)
        px = []
        for a in np.radians(np.linspace(-20, 20, 9)):
            d_cam = R.T @ (np.cos(a) * fwd + np.sin(a) * side)
            p = K @ d_cam
            px.append(p[:2] / p[2])
        px = np.array(px)
        seg = np.asarray(horizons[k][0], float)
        assert seg.shape == (2, 2) and np.all((seg >= -1e-3) & (seg <= [w + 1e-3, h + 1e-3]))
        normal = np.array([-(seg[1] - seg[0])[1], (seg[1] - seg[0])[0]]) / np.linalg.norm(seg[1] - seg[0])
        inside = (px[:, 0] >= 0) & (px[:, 0] <= w) & (px[:, 1] >= 0) & (px[:, 1] <= h)
        assert inside.any() and np.all(np.abs((px[inside] - seg[0]) @ normal) < 0.5)
        # the runway's edges, projected where all four corners are in front of the camera
        Xc = (ring - c) @ R
        uv = (Xc @ K.T)[:, :2] / Xc[:, 2:3]
        edges = [(uv[i], uv[(i + 1) % 4]) for i in range(4)]
        for s in np.asarray(runways[k], float).reshape(-1, 2, 2):
            drawn += 1
            assert np.all((s >= -1e-3) & (s <= [w + 1e-3, h + 1e-3]))
            off = [max(abs((b - a)[0] * (p - a)[1] - (b - a)[1] * (p - a)[0]) / np.linalg.norm(b - a) for p in s)
                   for a, b in edges]  # each end's distance from the edge's line
            assert (Xc[:, 2] > 0).all() and min(off) < 0.5
    assert drawn > 0


def test_labels_do_not_pile_up(run):
    """In the camera view a detection's name is drawn only where it overlaps no other drawn name (a
    faulty detection's always); in the fixed 3D view only the aircraft and the faulty ray carry
    visible labels (the runway's landmarks and the protection volumes, a few pixels apart at valley
    scale, are named on hover); in the follow view the monitors' names are stacked apart."""
    from testbed.viz.image_overlay import LABEL_BOX

    rrd = run.rrd_path
    w, h = readback.static_components(rrd, "/world/camera")["Pinhole:resolution"][0]
    bw, bh = LABEL_BOX[0] * w, LABEL_BOX[1] * h
    t_l, label_pos = readback.component_rows(rrd, "/world/camera/labels", "Points2D:positions")
    _, label_text = readback.component_rows(rrd, "/world/camera/labels", "Points2D:labels")
    t_d, det_pos = readback.component_rows(rrd, "/world/camera/detections", "Points2D:positions")
    np.testing.assert_allclose(t_l, t_d)
    labelled = 0
    for pos, text, det in zip(label_pos, label_text, det_pos):
        pos, det = np.asarray(pos or [], float).reshape(-1, 2), np.asarray(det or [], float).reshape(-1, 2)
        assert len(text or []) == len(pos) and (len(pos) > 0) == (len(det) > 0)
        for i in range(len(pos)):
            assert np.min(np.linalg.norm(det - pos[i], axis=1)) < 1e-3  # on a detection
            for j in range(i):
                assert abs(pos[i, 0] - pos[j, 0]) >= bw or abs(pos[i, 1] - pos[j, 1]) >= bh
        labelled += len(pos)
    assert labelled > 0
    world = _view(rrd, "world")
    for entity in readback.view_entities(rrd, world):
        comps = readback.static_components(rrd, entity)
        kinds = {k.split(":")[0] for k in comps if k.endswith(":labels")}
        for kind in kinds:
            if entity != "/world/aircraft/marker":
                assert comps.get(f"{kind}:show_labels") == [False], entity
    follow = _view(rrd, "follow the aircraft")
    tops = []
    for m in ("gps_raim", "va_raim", "pixel"):
        entity = f"/world/integrity/{m}/name"
        assert entity in readback.view_entities(rrd, follow) and entity not in readback.view_entities(rrd, world)
        assert readback.static_components(rrd, entity)["Points3D:labels"] == [m]
        _, pos = readback.component_rows(rrd, entity, "Points3D:positions")
        tops.append(np.array([p[0][2] for p in pos]))
    tops = np.array(tops)
    assert np.all(np.abs(np.diff(np.sort(tops, axis=0), axis=0)) >= 10.0)


def _lab(rgb) -> np.ndarray:
    """CIE L*a*b* (D65) of an sRGB colour, from the standard formulas."""
    c = np.asarray(rgb, float) / 255.0
    c = np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]) @ c
    f = xyz / np.array([0.95047, 1.0, 1.08883])
    f = np.where(f > (6 / 29) ** 3, np.cbrt(f), f / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def test_the_sensors_series_have_distinct_colours(run):
    """Satellites visible, used by each monitor and landmarks detected: each in its own colour, far
    apart (ΔE*76 > 25; two greens looked alike), and the panel's legend names each."""
    rrd = run.rrd_path
    v = next(v for v in readback.views(rrd) if v["origin"] == "/sensors")
    shown = sorted(readback.view_entities(rrd, v) & readback.scalar_entities(rrd))
    assert len(shown) == 5
    colours = [_lab(readback.rgba(readback.static_components(rrd, e)["SeriesLines:colors"][0])[:3]) for e in shown]
    gaps = [np.linalg.norm(a - b) for i, a in enumerate(colours) for b in colours[:i]]
    assert min(gaps) > 25.0

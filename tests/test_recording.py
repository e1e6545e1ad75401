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
    plots, at the epochs the alert log gives (on the HAL / VAL / threshold line)."""
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
            k = int(np.flatnonzero(out.t == first)[0])
            assert va[0] == pytest.approx(out.threshold[k])  # on the threshold line
            th, vh = readback.scalar_series(run.rrd_path, f"integrity/{m}/horizontal/marks/alert")
            assert th[0] == pytest.approx(first) and np.all(vh == vh[0])  # on the HAL line


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


def test_blueprint_has_a_view_that_follows_the_aircraft_and_titles_with_alert_limits(run):
    vs = readback.views(run.rrd_path)
    assert {"class": "3D", "name": "follow the aircraft", "origin": "/world/aircraft"} in vs
    assert {"class": "3D", "name": "world", "origin": "/world"} in vs
    names = [v["name"] for v in vs]
    assert any(n.startswith("gps_raim: HPL (blue) vs HAL 40 m (red), m.") for n in names), names
    assert any(n.startswith("gps_raim: VPL (blue) vs VAL 20 m (red), m.") for n in names), names


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

"""Regenerate the README pictures (a tool, not part of the test suite).

Needs Chromium (a Debian package) and Playwright to drive it::

    apt-get install -y chromium && pip install playwright     # no browser download: the system Chromium is used
    python benchmarks/readme_pictures.py [--at 110] [--out testbed/data] [--skip-campaign]

1. flies the runway-05 final with a 60 m GPS step on a random visible satellite at 100 s
   (seed 0) into a temporary recording;
2. crops the recording at ``--at`` s (the viewer opens a recording at its last epoch, so the
   picture shows that moment: by default 10 s after the fault onset);
3. hosts the web viewer (``rerun --serve-web``) and the file on loopback and screenshots the
   viewer in headless Chromium (software rendering) -> ``readme-recording.png``;
4. unless ``--skip-campaign``: runs the quick reproduction's where-vision-pays experiment and
   copies its break-even figure -> ``readme-break-even.png``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def crop_recording(src: Path, dst: Path, t_end_s: float, monitors: list[str], approach,
                   vertical_only: tuple[str, ...] = (), active: str | None = None) -> None:
    """Copy ``src`` to ``dst`` keeping static data and the rows up to ``t_end_s`` on ``sim_time``."""
    import pyarrow.compute as pc
    import rerun as rr
    import rerun.chunk as rrc

    from testbed.viz.blueprint import approach_eye, default_blueprint

    rec = rr.RecordingStream("testbed", recording_id="readme", send_properties=False)
    rec.set_log_time_enabled(False)
    rec.set_sinks(rr.FileSink(str(dst)))
    # the layout first: a viewer reading the file applies it from the start
    rec.send_blueprint(default_blueprint(monitors, approach_eye(approach[0]), approach[1], play_state="following",
                                         vertical_only=vertical_only, active_monitor=active),
                       make_active=True, make_default=True)
    limit = int(round(t_end_s * 1e9))
    for ch in rrc.RrdReader(str(src)).stream():
        if ch.is_static or "sim_time" not in ch.timeline_names:
            rec.send_chunks(ch)
            continue
        rb = ch.to_record_batch()
        t = rb.column(rb.schema.names.index("sim_time")).cast("int64")
        keep = rb.filter(pc.less_equal(t, limit))
        if keep.num_rows:
            rec.send_chunks(rrc.Chunk.from_record_batch(keep))
    rec.flush()
    rec.disconnect()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def screenshot(rrd: Path, png: Path, wait_s: float = 120.0, size: tuple[int, int] = (1800, 1100)) -> None:
    """Host the web viewer (``rerun --serve-web``) and the file (an HTTP server) on loopback, open
    the viewer on the file's URL in headless Chromium (the file loads whole, the cursor at its
    end), wait, screenshot."""
    from playwright.sync_api import sync_playwright

    grpc, web, files = free_port(), free_port(), free_port()
    # its own process group: `rerun` is a wrapper that starts the viewer binary as a child
    viewer = subprocess.Popen([shutil.which("rerun") or "rerun", "--serve-web", "--bind", "127.0.0.1",
                               "--port", str(grpc), "--web-viewer-port", str(web)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    http = _file_server(rrd.parent, files)
    try:
        time.sleep(4.0)
        url = f"http://127.0.0.1:{web}?url=http%3A%2F%2F127.0.0.1%3A{files}%2F{rrd.name}"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=shutil.which("chromium") or "/usr/bin/chromium",
                                        args=["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                                              "--ignore-gpu-blocklist"])
            page = browser.new_page(viewport={"width": size[0], "height": size[1]})
            page.goto(url)
            time.sleep(wait_s)  # wasm load, the file, software rendering
            page.screenshot(path=str(png))
            browser.close()
    finally:
        http.shutdown()
        os.killpg(viewer.pid, signal.SIGTERM)  # the wrapper and the viewer it started
        viewer.wait(timeout=10)


def _file_server(folder: Path, port: int):
    """A loopback HTTP server for ``folder`` in a thread, with the CORS header the viewer's fetch needs."""
    import functools
    import threading
    from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

    class Handler(SimpleHTTPRequestHandler):
        def end_headers(self):
            self.send_header("Access-Control-Allow-Origin", "*")
            super().end_headers()

        def log_message(self, *args):  # quiet
            pass

    server = ThreadingHTTPServer(("127.0.0.1", port), functools.partial(Handler, directory=str(folder)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--at", type=float, default=110.0, help="moment of the recording picture, s (fault at 100 s)")
    ap.add_argument("--out", type=Path, default=ROOT / "testbed" / "data")
    ap.add_argument("--skip-campaign", action="store_true")
    ap.add_argument("--dpe-only", action="store_true", help="only the DPE picture (zunz-rwy05-dpe, 40 m step at 100 s)")
    args = ap.parse_args()
    if shutil.which("chromium") is None:
        sys.exit("chromium not found: apt-get install -y chromium (and pip install playwright)")

    from testbed.api import load_approach, run_approach
    from testbed.sensors.faults import GpsStep
    from testbed.sim.setup import build_setup, build_scene, load_terrain_for

    def picture(name: str, bias_m: float, png: str, active: str | None = None) -> None:
        approach = load_approach(name)
        cfg = approach.config.model_copy(update={"faults": [GpsStep(kind="gps_step", prn="random", bias_m=bias_m,
                                                                    onset_s=100.0)]})
        approach = dataclasses.replace(approach, config=cfg)
        with tempfile.TemporaryDirectory() as tmp:
            full, cut = Path(tmp) / "full.rrd", Path(tmp) / "cut.rrd"
            run_approach(approach, seed=0, rrd_path=full)
            setup = build_setup(approach, load_terrain_for(approach))
            scene = build_scene(setup)
            crop_recording(full, cut, args.at, list(setup.monitor_names), (scene.planned_enu, tuple(setup.alert_limits)),
                           tuple(scene.vertical_only), active)
            screenshot(cut, args.out / png)
        print(f"wrote {args.out / png} ({name} at t = {args.at:g} s)")

    # the DPE's tab 10 s after a 40 m step: GPS RAIM alerts, the DPE (no detection) is misled
    picture("zunz-rwy05-dpe", 40.0, "readme-recording-dpe.png", active="dpe")
    if args.dpe_only:
        return
    picture("zunz-rwy05-final", 60.0, "readme-recording.png")
    if not args.skip_campaign:
        from testbed.campaign.reproduce import QUICK_TRIALS, loaded_experiments, write_summary
        from testbed.campaign.runner import run_campaign

        with tempfile.TemporaryDirectory() as tmp:
            le = loaded_experiments(QUICK_TRIALS)["where-vision-pays"]
            run_campaign(le, Path(tmp) / "where-vision-pays", progress=False)
            write_summary(Path(tmp), QUICK_TRIALS, {"where-vision-pays": 0.0})
            shutil.copy(Path(tmp) / "where-vision-pays" / "break_even.png", args.out / "readme-break-even.png")
        print(f"wrote {args.out / 'readme-break-even.png'}")


if __name__ == "__main__":
    main()

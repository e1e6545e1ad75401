"""Regenerate the documentation pictures in ``docs/img/`` (a tool, not part of the test suite).

Every picture in ``docs/img/`` is made here, and :data:`PICTURES` says how: a screenshot of a
recording in the Rerun web viewer, or a figure that a ``testbed`` command (a campaign, a
reproduction, a RINEX run) draws, copied. ``tests/test_pictures.py`` checks that this table and
the folder agree.

Usage::

    python benchmarks/pictures.py --list                  # the table: name, what makes it, minutes
    python benchmarks/pictures.py                         # every picture but the long ones
    python benchmarks/pictures.py --only dpe-vs-raim      # one picture, readme-dpe-vs-raim.png (repeat --only
                                                          # for more; readme- and .png may be left off)
    python benchmarks/pictures.py --long                  # every picture, long ones too
    python benchmarks/pictures.py --work DIR              # keep the campaigns' results in DIR and
                                                          # redraw from them on the next run

A long picture (``long`` in the table: its run takes more than 10 minutes on 2 cores) is made
only with ``--long`` or when named with ``--only``.

The recording screenshots need Chromium (a Debian package) and Playwright to drive it::

    apt-get install -y chromium && pip install playwright     # no browser download: the system Chromium is used

A recording picture flies the approach with a GPS step on a random visible satellite at 100 s
(seed 0) into a temporary recording, crops it at ``--at`` s (the viewer opens a recording at its
last epoch, so the picture shows that moment: by default 10 s after the fault onset), hosts the
web viewer (``rerun --serve-web``) and the file on loopback and screenshots the viewer in
headless Chromium (software rendering) once the picture stops changing (the viewer takes the file in
progressively: minutes on a busy machine). The layout is the recording's without its map view (the
map's tiles come from the internet).
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
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "img"


@dataclasses.dataclass(frozen=True)
class Picture:
    """How one picture of ``docs/img/`` is made."""

    name: str  #: file name in docs/img/
    kind: str  #: "recording" (a Chromium screenshot) or "figure" (drawn by a testbed command, copied)
    command: str  #: what makes it: the testbed command (a recording: the flight and the moment shown)
    source: str  #: which file of the command's output is copied ("" for a screenshot)
    minutes: float  #: rough wall time on 2 cores (the long ones: more than 10)
    make: Callable[[argparse.Namespace, Path, Path], None]  #: (options, work folder, destination)

    @property
    def long(self) -> bool:
        return self.minutes > 10


# ---- the recording screenshots

def crop_recording(src: Path, dst: Path, t_end_s: float, scene, active: str | None = None,
                   follow: bool = False) -> None:
    """Copy ``src`` to ``dst`` keeping static data and the rows up to ``t_end_s`` on ``sim_time``, under
    the layout a flight of ``scene`` stores without the map view (its tiles come from the internet,
    which the screenshot does not reach: an empty map tab would be the same as none), ``follow``:
    with the follow view's tab open."""
    import pyarrow.compute as pc
    import rerun as rr
    import rerun.chunk as rrc

    from testbed.viz.blueprint import scene_blueprint

    rec = rr.RecordingStream("testbed", recording_id="pictures", send_properties=False)
    rec.set_log_time_enabled(False)
    rec.set_sinks(rr.FileSink(str(dst)))
    # the layout first: a viewer reading the file applies it from the start
    rec.send_blueprint(scene_blueprint(scene, play_state="following", active_monitor=active, map_view=False,
                                       follow_open=follow), make_active=True, make_default=True)
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


def _rerun() -> str:
    """The ``rerun`` command: beside this Python (a virtual environment not activated), else on the PATH."""
    here = Path(sys.executable).parent / "rerun"
    return str(here) if here.exists() else (shutil.which("rerun") or "rerun")


def _screenshot_tools() -> None:
    """Fail before any flight when a screenshot could not be taken."""
    import importlib.util

    missing = [what for what, ok in (
        ("chromium (apt-get install -y chromium)", shutil.which("chromium") is not None),
        ("playwright (pip install playwright; no browser download)", importlib.util.find_spec("playwright") is not None),
        ("rerun (the rerun-sdk package)", Path(_rerun()).exists() or shutil.which("rerun") is not None),
    ) if not ok]
    if missing:
        raise SystemExit("a recording picture needs " + ", ".join(missing))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def screenshot(rrd: Path, png: Path, wait_s: float = 900.0, size: tuple[int, int] = (1800, 1100),
               settle_s: float = 60.0, every_s: float = 20.0) -> None:
    """Host the web viewer (``rerun --serve-web``) and the file (an HTTP server) on loopback, open
    the viewer on the file's URL in headless Chromium, and screenshot it once the picture has
    stopped changing: the viewer takes in a file progressively (minutes for a few MB with software
    rendering on a busy machine), the cursor following the newest data, so a fixed wait could
    catch it half-loaded. After ``settle_s``, a shot every ``every_s`` until two in a row are the
    same; none within ``wait_s`` fails."""
    from playwright.sync_api import sync_playwright

    grpc, web, files = free_port(), free_port(), free_port()
    # its own process group: `rerun` is a wrapper that starts the viewer binary as a child
    viewer = subprocess.Popen([_rerun(), "--serve-web", "--bind", "127.0.0.1",
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
            t0 = time.monotonic()
            time.sleep(settle_s)  # wasm load, the first data, software rendering
            shot = page.screenshot()
            while True:
                if time.monotonic() - t0 > wait_s:
                    raise RuntimeError(f"{rrd.name}: the viewer's picture still changed after {wait_s:.0f} s")
                time.sleep(every_s)
                again = page.screenshot()
                if again == shot:
                    break
                shot = again
            png.write_bytes(shot)
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


def recording(approach_name: str, bias_m: float, active: str | None = None, follow: bool = False):
    """A maker: fly ``approach_name`` with a ``bias_m`` GPS step on a random visible satellite at 100 s
    (seed 0), crop the recording at ``--at`` s, screenshot it (the ``active`` monitor's tab open; with
    ``follow``, the follow view's)."""

    def make(args: argparse.Namespace, work: Path, dst: Path) -> None:
        _screenshot_tools()
        from testbed.api import load_approach, run_approach
        from testbed.sensors.faults import GpsStep
        from testbed.sim.setup import build_scene, build_setup, load_terrain_for

        approach = load_approach(approach_name)
        cfg = approach.config.model_copy(update={"faults": [GpsStep(kind="gps_step", prn="random", bias_m=bias_m,
                                                                    onset_s=100.0)]})
        approach = dataclasses.replace(approach, config=cfg)
        with tempfile.TemporaryDirectory() as tmp:
            full, cut = Path(tmp) / "full.rrd", Path(tmp) / "cut.rrd"
            run_approach(approach, seed=0, rrd_path=full)
            setup = build_setup(approach, load_terrain_for(approach))
            scene = build_scene(setup, setup.vision.camera.build())  # as the flight draws it (api.run_approach)
            crop_recording(full, cut, args.at, scene, active, follow)
            screenshot(cut, dst)

    return make


# ---- the figures drawn by testbed commands

def _testbed(*argv: str) -> None:
    """Run the ``testbed`` command line in a child process (its own memory; fails loudly)."""
    cmd = [sys.executable, "-m", "testbed.cli", *argv]
    print("  $ testbed " + " ".join(argv), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)


def _stored(out: Path, spec_hash: str) -> bool:
    """A complete run of the campaign whose spec hashes to ``spec_hash`` is stored in ``out``."""
    from testbed.campaign.store import ResultStore

    store = ResultStore(out)
    return (out / "manifest.json").exists() and store.manifest()["spec_hash"] == spec_hash and store.complete()


def campaign_figure(spec: str, trials: int, figure: str):
    """A maker: run campaign ``spec`` at ``trials`` sorties per cell into the work folder (completing a
    run stored there; a complete one of the same spec is only redrawn, ``testbed report``) and copy
    ``figures/<figure>``."""

    def make(args: argparse.Namespace, work: Path, dst: Path) -> None:
        from testbed.campaign.spec import load_spec

        out = work / spec
        if _stored(out, load_spec(spec, trials=trials).hash):
            _testbed("report", str(out))
        else:
            again = ["--resume"] if (out / "manifest.json").exists() else []
            _testbed("campaign", spec, "--trials", str(trials), "--out", str(out), "--quiet", *again)
        shutil.copy(out / "figures" / figure, dst)

    return make


def where_vision_pays(trials: int):
    """A maker: the va-raim-2015 reproduction's where-vision-pays experiment alone at ``trials`` sorties
    per setting (the same campaign ``testbed reproduce va-raim-2015`` runs), and its break-even figure."""

    def make(args: argparse.Namespace, work: Path, dst: Path) -> None:
        from testbed.studies.reproduce import loaded_experiments, write_summary
        from testbed.campaign.runner import run_campaign
        from testbed.campaign.store import ResultStore

        root = work / f"va-raim-2015-{trials}"
        d = root / "where-vision-pays"
        loaded = loaded_experiments(trials)["where-vision-pays"]
        if not _stored(d, loaded.hash):
            run_campaign(loaded, d, resume=(d / "manifest.json").exists(), progress=False, workers="auto")
        write_summary(root, trials, {"where-vision-pays": ResultStore(d).wall_s()})
        shutil.copy(d / "break_even.png", dst)

    return make


def pixel_benefit(trials: int):
    """A maker: the markers cell of campaign ``pixel-benefit`` through GPS RAIM and the patent's rule with
    and without vision rows and H3 (what ``benchmarks/bench_pixel_benefit.py --figure`` draws)."""

    def make(args: argparse.Namespace, work: Path, dst: Path) -> None:
        from testbed.studies.pixel_benefit import benefit_table, draw_benefit
        from testbed.campaign.spec import load_spec

        rows = benefit_table(load_spec("pixel-benefit", trials=trials), cell_index=1)
        scene = (f"runway-05 final (JSBSim), H and I markers + runway outline, {trials} fault-free sorties "
                 f"started over a day, P_FA 1e-5")
        draw_benefit(rows, "APV-I", dst, scene)

    return make


def rinex_gsi(args: argparse.Namespace, work: Path, dst: Path) -> None:
    """GPS RAIM over the GSI station's RINEX file against its surveyed marker."""
    out = work / "rinex-gsi"
    rinex = "tests/references/rinex/07590920.05"
    _testbed("monitor", rinex + "o", rinex + "n", "--reference", "marker", "--out", str(out))
    shutil.copy(out / "stanford-gps_raim.png", dst)


def stanford_pair(spec: str, trials: int, monitors: tuple[str, ...], cells: tuple[int, ...]):
    """A maker: run campaign ``spec`` at ``trials`` sorties per cell into the work folder (a complete stored run
    of it is reused) and draw the Stanford diagrams of ``monitors`` side by side over ``cells``."""

    def make(args: argparse.Namespace, work: Path, dst: Path) -> None:
        from testbed.campaign.spec import load_spec

        out = work / spec
        if not _stored(out, load_spec(spec, trials=trials).hash):
            again = ["--resume"] if (out / "manifest.json").exists() else []
            _testbed("campaign", spec, "--trials", str(trials), "--out", str(out), "--quiet", "--no-report", *again)
        subprocess.run([sys.executable, "-m", "testbed.studies.stanford_pair", str(out), str(dst), "--monitors",
                        *monitors, "--cells", *map(str, cells)], cwd=ROOT, check=True)

    return make


def constellation_sky(args: argparse.Namespace, work: Path, dst: Path) -> None:
    """Satellites in view, VDOP and RAIM redundancy along the final over a day, per constellation set."""
    subprocess.run([sys.executable, "-m", "testbed.studies.constellation_sky", str(dst)], cwd=ROOT, check=True)


def won_2013(args: argparse.Namespace, work: Path, dst: Path) -> None:
    """The won-2013 reproduction at 200 runs per case."""
    out = work / "won-2013-full"
    _testbed("reproduce", "won-2013", "--full", "--out", str(out), "--quiet")
    shutil.copy(out / "won2013_errors.png", dst)


#: every picture of docs/img/ and how it is made
PICTURES: dict[str, Picture] = {p.name: p for p in (
    Picture("readme-recording.png", "recording",
            "testbed fly zunz-rwy05-final, 60 m GPS step on a random visible satellite at 100 s, seed 0; "
            "the recording cut at --at (110 s) in the web viewer", "", 3,
            recording("zunz-rwy05-final", 60.0)),
    Picture("readme-recording-follow.png", "recording",
            "testbed fly zunz-rwy05-final, 60 m GPS step on a random visible satellite at 100 s, seed 0; "
            "the recording cut at --at (110 s) in the web viewer, the follow view open", "", 3,
            recording("zunz-rwy05-final", 60.0, follow=True)),
    Picture("readme-recording-dpe.png", "recording",
            "testbed fly zunz-rwy05-dpe, 40 m GPS step on a random visible satellite at 100 s, seed 0; "
            "the recording cut at --at (110 s) in the web viewer, the dpe tab open", "", 3,
            recording("zunz-rwy05-dpe", 40.0, active="dpe")),
    Picture("readme-break-even.png", "figure",
            "testbed reproduce va-raim-2015 (its where-vision-pays experiment alone, 200 sorties per setting)",
            "where-vision-pays/break_even.png", 1, where_vision_pays(200)),
    Picture("readme-break-even-full.png", "figure",
            "testbed reproduce va-raim-2015 --full (its where-vision-pays experiment alone, 1e5 sorties per setting)",
            "where-vision-pays/break_even.png", 102, where_vision_pays(100_000)),  # the whole --full run: 1 h 42 min
    Picture("readme-dpe-vs-raim.png", "figure", "testbed campaign dpe-vs-raim --trials 100",
            "figures/stanford_dpe.png", 10, campaign_figure("dpe-vs-raim", 100, "stanford_dpe.png")),
    Picture("readme-pixel-benefit.png", "figure",
            "python benchmarks/bench_pixel_benefit.py --figure PATH (its markers cell alone, 400 sorties)",
            "the --figure PNG", 3, pixel_benefit(400)),
    Picture("readme-rinex-gsi.png", "figure",
            "testbed monitor tests/references/rinex/07590920.05o tests/references/rinex/07590920.05n "
            "--reference marker --out DIR", "DIR/stanford-gps_raim.png", 0.5, rinex_gsi),
    Picture("readme-won2013.png", "figure", "testbed reproduce won-2013 --full", "won2013_errors.png", 19, won_2013),
    Picture("constellation-sky.png", "figure", "python -m testbed.studies.constellation_sky PATH",
            "PATH", 1, constellation_sky),
    Picture("araim-availability-day.png", "figure", "testbed campaign araim-constellations",
            "figures/availability_over_day.png", 5,
            campaign_figure("araim-constellations", 96, "availability_over_day.png")),
    Picture("araim-stanford.png", "figure",
            "testbed campaign araim-constellation-fault --out DIR; python -m testbed.studies.stanford_pair DIR PATH "
            "--monitors gps_raim araim --cells 1 2 3 4 5", "PATH", 5,
            stanford_pair("araim-constellation-fault", 200, ("gps_raim", "araim"), (1, 2, 3, 4, 5))),
)}


def _name(text: str) -> str:
    """A picture's file name from what ``--only`` was given: the name, or it without ``readme-`` / ``.png``."""
    name = text if text.endswith(".png") else text + ".png"
    name = name if name in PICTURES else "readme-" + name
    if name not in PICTURES:
        raise SystemExit(f"no picture {text!r}: one of {', '.join(sorted(PICTURES))}")
    return name


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", action="append", metavar="NAME", help="make this picture only (repeatable; "
                    "readme- and .png may be left off); a long one is made when named")
    ap.add_argument("--long", action="store_true", help="make the long pictures too (each > 10 min on 2 cores)")
    ap.add_argument("--list", action="store_true", help="print the table of pictures and exit")
    ap.add_argument("--out", type=Path, default=OUT, help="output folder (default docs/img)")
    ap.add_argument("--work", type=Path, help="keep the campaigns' results here and reuse them "
                    "(default: a temporary folder)")
    ap.add_argument("--at", type=float, default=110.0, help="moment of the recording pictures, s (fault at 100 s)")
    args = ap.parse_args(argv)

    if args.list:
        for p in PICTURES.values():
            src = f" -> {p.source}" if p.source else ""
            print(f"{p.name:22s} {p.kind:9s} ~{p.minutes:g} min{' (long)' if p.long else ''}\n    {p.command}{src}")
        return 0
    names = [_name(n) for n in args.only] if args.only else [n for n, p in PICTURES.items() if args.long or not p.long]
    skipped = [n for n in PICTURES if n not in names and not args.only]
    if any(PICTURES[n].kind == "recording" for n in names):
        _screenshot_tools()  # before hours of campaigns, not after
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for n in names:
            p = PICTURES[n]
            print(f"{n}: {p.command}", flush=True)
            t0 = time.perf_counter()
            p.make(args, work.resolve(), args.out / n)
            print(f"  wrote {args.out / n} ({time.perf_counter() - t0:.0f} s)", flush=True)
    if skipped:
        print("not made (long: --long or --only NAME): " + ", ".join(skipped))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

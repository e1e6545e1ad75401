"""Benchmark: reading and monitoring a 24 h, 1 Hz RINEX file, side by side with RTKLIB ``rnx2rtkp``.

A 24 h export (static-ish receiver at ZUNZ, the DO-229 constellation: 6-12
satellites in view, drifting receiver clock) is read (observation + navigation
file), formed into pseudoranges, and monitored by GPS RAIM with FDE; RTKLIB's
single-point solution of the same files (its whole run: reading + solving +
writing) is timed on the same machine in the same run. georinex, the reader the
issue names, is timed on the first hour of the same file (it is too slow for the
whole day; the per-epoch rate is what is compared).

Run: ``python benchmarks/bench_rinex.py [--hours H] [--repeats N]``. Medians of N runs.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from testbed.flight.kinematic import straight_truth
from testbed.records import Mount
from testbed.rinex.obs import read_obs
from testbed.rinex.observables import form_epochs
from testbed.replay.run import monitor_rinex
from testbed.rinex.settings import MonitorFileConfig
from testbed.sensors.gnss.navfile import read_nav
from testbed.sensors.gnss.rinex import write_rinex
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss
from testbed.world.airport import runway_frame

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import median_time  # noqa: E402


def export(folder: Path, hours: float) -> tuple[Path, Path, int, float]:
    frame = runway_frame()
    truth = straight_truth(frame, [-3000.0, -2000.0, 300.0], [3000.0, 2000.0, 300.0], hours * 3600.0, rate_hz=1.0)
    s = GnssSettings(terrain_masking=False, clock_drift0_sigma_m_s=10.0)
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc="2024-03-15T00:00:00Z")
    ep, tr = sample_gnss(g, s, rng=np.random.default_rng(1))
    obs, nav = write_rinex(ep, g, folder, name="day", clock_bias_m=tr.clock_bias)
    return obs, nav, g.t.size, float(g.visible.sum(1).mean())


def first_lines(src: Path, dst: Path, epochs: int) -> Path:
    """The header and the first ``epochs`` epochs of a RINEX 3 observation file."""
    out, n = [], -1
    with src.open() as fh:
        for ln in fh:
            if ln.startswith(">"):
                n += 1
                if n == epochs:
                    break
            out.append(ln)
    dst.write_text("".join(out))
    return dst




def main(hours: float = 24.0, repeats: int = 3) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        obs, nav, E, vis = export(d, hours)
        print(f"{obs.name}: {E} epochs ({hours:g} h at 1 Hz), {vis:.1f} satellites in view on average, "
              f"{obs.stat().st_size / 1e6:.0f} MB")
        t_read = median_time(lambda: (read_obs(obs), read_nav(nav)), repeats)
        o, n = read_obs(obs), read_nav(nav)
        cfg = MonitorFileConfig()
        t_form = median_time(lambda: form_epochs(o, n, cfg.rinex), repeats)
        run = monitor_rinex(obs, nav, config=cfg)
        t_mon = statistics.median([monitor_rinex(obs, nav, config=cfg).timings["monitors"] for _ in range(repeats)])
        print(f"testbed read (obs + nav):        {t_read:7.2f} s  {E / t_read:10,.0f} epochs/s")
        print(f"testbed form pseudoranges:       {t_form:7.2f} s  {E / t_form:10,.0f} epochs/s")
        print(f"testbed GPS RAIM + FDE + PLs:    {t_mon:7.2f} s  {E / t_mon:10,.0f} epochs/s "
              f"({int(np.isfinite(run.outputs['gps_raim'].hpl).sum())} epochs with PLs)")
        if shutil.which("rnx2rtkp"):
            conf = d / "r.conf"
            conf.write_text("pos1-posmode =single\npos1-elmask =5\npos1-ionoopt =off\npos1-tropopt =off\n"
                            "pos1-navsys =1\nout-solformat =xyz\n")
            t_rtk = median_time(lambda: subprocess.run(["rnx2rtkp", "-k", str(conf), "-o", str(d / "r.pos"), str(obs),
                                                  str(nav)], check=True, capture_output=True), repeats)
            print(f"RTKLIB rnx2rtkp whole run:       {t_rtk:7.2f} s  {E / t_rtk:10,.0f} epochs/s")
            print(f"ratios: RTKLIB whole run / testbed monitoring = {t_rtk / t_mon:.1f} (target ≥ 10); "
                  f"RTKLIB whole run / testbed reading = {t_rtk / t_read:.1f} (target ≥ 1: reading no slower); "
                  f"RTKLIB whole run / testbed read + form + monitor = {t_rtk / (t_read + t_form + t_mon):.1f}")
        else:
            print("RTKLIB rnx2rtkp not on PATH: no side-by-side (apt-get install rtklib)")
        try:
            import georinex
        except ImportError:
            print("georinex not installed: not timed (pip install georinex)")
            return
        hour = first_lines(obs, d / "hour.obs", 3600)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t_gr = median_time(lambda: georinex.load(hour, use="G"), 1)
        t_ours = median_time(lambda: read_obs(hour), repeats)
        print(f"georinex, first hour (3600 epochs): {t_gr:7.2f} s  {3600 / t_gr:8,.0f} epochs/s; testbed on the same "
              f"hour {t_ours:.2f} s ({t_gr / t_ours:.0f}× faster)")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    main(a.hours, a.repeats)

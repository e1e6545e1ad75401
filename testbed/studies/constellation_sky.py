"""Satellites in view, VDOP and snapshot-RAIM redundancy along a final over a day, per constellation set,
in open sky and in the valley (docs/design/gnss.md §1).

The approach is flown once (JSBSim); its GNSS geometry is computed at start times ``step_s`` apart over
``span_s`` (one stacked pass per constellation set and terrain setting, :func:`gnss_geometry` with
``offsets_s``). Per epoch of every sortie: the satellites in view after the masks (and the terrain in the
valley), the unweighted VDOP with one clock per constellation present, and whether snapshot RAIM can test
(at least one measurement more than the 3 + K unknowns).

    python -m testbed.studies.constellation_sky sky.png   # the figure and the table (stdout)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from testbed.campaign.report import _figure, _save
from testbed.config import load_approach
from testbed.flight.fly import approach_geometry, fly
from testbed.integrity.multi_clock import geometry_dops, system_codes
from testbed.markdown import table as markdown_table
from testbed.records import Mount
from testbed.sensors.gnss.synth import gnss_geometry
from testbed.sim.setup import load_terrain_for

#: the constellation sets compared, with their labels
SETS = (("GPS", ["gps"]), ("GPS+Galileo", ["gps", "galileo"]), ("GPS+Galileo+BeiDou", ["gps", "galileo", "beidou"]))


def sky_along_final(approach_name: str = "zunz-rwy05-final", span_s: float = 86400.0, step_s: float = 600.0,
                    rate_hz: float = 0.2) -> list[dict]:
    """One row per (constellation set, open sky / valley): per-epoch arrays over (start time, epoch) and their
    summary (``n_min``, ``n_median``, ``n_max``, ``vdop_median``, ``raim_fraction``)."""
    approach = load_approach(approach_name)
    terrain = load_terrain_for(approach)
    frame, _ = approach_geometry(approach.flight_plan)
    truth = fly(approach.flight_plan, terrain).truth.decimate(rate_hz)
    offsets = np.arange(0.0, span_s, step_s)
    rows = []
    for label, cons in SETS:
        for valley in (False, True):
            s = approach.config.gnss.model_copy(update={"constellations": cons, "terrain_masking": valley})
            g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc=approach.config.start_time_utc,
                              terrain=terrain, offsets_s=offsets)
            vis = np.asarray(g.visible)  # (W, T, S)
            d = g.sat_pos_ecef - g.ant_pos_ecef[None, :, None, :]
            los_enu = np.einsum("ij,wtsj->wtsi", frame.R, d / np.linalg.norm(d, axis=-1, keepdims=True))
            code, letters = system_codes(g.system)
            vdop = geometry_dops(los_enu, vis, code, len(letters))["vdop"]
            n = vis.sum(-1)
            present = np.stack([(vis & (code == k)).any(-1) for k in range(len(letters))]).sum(0)
            rows.append({"set": label, "valley": valley, "t_day_h": offsets / 3600.0, "n": n, "vdop": vdop,
                         "n_min": int(n.min()), "n_median": float(np.median(n)), "n_max": int(n.max()),
                         "vdop_median": float(np.nanmedian(vdop)),
                         "raim_fraction": float(np.mean(n >= 3 + present + 1))})
    return rows


def table(rows: list[dict]) -> str:
    """The summary as a Markdown table."""
    return "\n".join(markdown_table(
        ["constellations", "sky", "satellites in view (min / median / max)", "median VDOP", "RAIM can test"],
        [[r["set"], "valley" if r["valley"] else "open sky", f"{r['n_min']} / {r['n_median']:g} / {r['n_max']}",
          f"{r['vdop_median']:.2f}", f"{100 * r['raim_fraction']:.1f} %"] for r in rows]))


def draw(rows: list[dict], path: Path) -> None:
    """Satellites in view and VDOP (median along the final) against the start time of day; one colour per
    constellation set, solid in the valley, dashed in open sky."""
    fig, (ax_n, ax_v) = _figure(2, 1, figsize=(8, 6), sharex=True)
    colours = dict(zip((label for label, _ in SETS), ("tab:green", "tab:blue", "tab:orange")))
    for r in rows:
        style = dict(color=colours[r["set"]], ls="-" if r["valley"] else "--",
                     label=f"{r['set']}, {'valley' if r['valley'] else 'open sky'}")
        ax_n.plot(r["t_day_h"], np.median(r["n"], axis=1), **style)
        with np.errstate(all="ignore"):
            ax_v.plot(r["t_day_h"], np.nanmedian(np.where(np.isfinite(r["vdop"]), r["vdop"], np.nan), axis=1),
                      **style)
    ax_n.set_ylabel("satellites in view")
    ax_v.set_ylabel("VDOP (one clock per constellation)")
    ax_v.set_yscale("log")
    ax_v.set_xlabel("start time of the final (h after the approach's start time)")
    ax_n.set_title("Along the final, median over its epochs")
    ax_n.legend(fontsize=7, ncol=2)
    _save(fig, path)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1 or not args[0].endswith(".png"):
        print("usage: python -m testbed.studies.constellation_sky FIGURE.png", file=sys.stderr)
        return 2
    rows = sky_along_final()
    draw(rows, Path(args[0]))
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

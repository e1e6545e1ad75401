"""Stanford diagrams of a campaign's monitors side by side, on the same signals: one row per monitor, its
horizontal and vertical diagrams, from the campaign's stored histograms (``stanford_hist.parquet``) and region
counts (``trials.parquet``) over the cells chosen (all by default). The monitors of one campaign saw the same
sorties, noise and faults, so the rows differ by the monitor alone.

    python -m testbed.studies.stanford_pair RESULT_DIR FIGURE.png [--monitors gps_raim araim] [--cells 1 2 3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from testbed.campaign.report import ReportInputs, _cols, _save, report_inputs
from testbed.schema import ConfigError
from testbed.sim.evaluate import REGIONS
from testbed.viz.stanford import hist_edges, stanford_panel


def monitor_panels(inp: ReportInputs, monitor: str, cells: list[int]) -> list[tuple[str, np.ndarray, dict, int, float]]:
    """``monitor``'s (dim, histogram [error bin, PL bin], region counts, epochs, alert limit) over ``cells``."""
    tc, edges = inp.tc, hist_edges()
    sel = (np.asarray(tc["monitor"]) == monitor) & np.isin(np.asarray(tc["cell"]), cells)
    hc = None if inp.hist is None else _cols(inp.hist)
    panels = []
    for dim, al in (("H", inp.hal), ("V", inp.val)):
        counts = {r: int(np.asarray(tc[f"{dim.lower()}_{r}"])[sel].sum()) for r in REGIONS}
        H = np.zeros((edges.size - 1, edges.size - 1))
        if hc is not None:
            hs = (hc["monitor"] == monitor) & (hc["dim"] == dim) & np.isin(hc["cell"], cells)
            np.add.at(H, (hc["err_bin"][hs].astype(np.int64), hc["pl_bin"][hs].astype(np.int64)), hc["count"][hs])
        panels.append((dim, H, counts, int(np.asarray(tc["epochs"])[sel].sum()), al))
    return panels


def _cell_text(inp: ReportInputs, cells: list[int]) -> str:
    """What the chosen cells hold, e.g. 'constellation_orbit 10, 25, 50 m'."""
    rows = [c for c in inp.cells if c["cell"] in cells]
    kinds = sorted({c.get("fault_sweep_kind") or c["fault_kind"] for c in rows})
    sizes = ", ".join(f"{c['fault_size']:g}" for c in rows if c["fault_kind"] != "none")
    unit = rows[0].get("fault_unit", "") if rows else ""
    free = sum(c["fault_kind"] == "none" for c in rows)
    parts = [f"{'/'.join(k for k in kinds if k != 'none')} {sizes} {unit}".strip()] if sizes else []
    return ", ".join(parts + ([f"{free} fault-free cell(s)"] if free else []))


def draw(inp: ReportInputs, monitors: list[str], cells: list[int], path: Path) -> None:
    """The figure: one row of H and V diagrams per monitor."""
    from matplotlib.figure import Figure

    edges = hist_edges()
    fig = Figure(figsize=(11.0, 4.8 * len(monitors) + 0.6))
    axs = np.atleast_2d(fig.subplots(len(monitors), 2))
    for row, m in zip(axs, monitors):
        for ax, (dim, H, counts, total, al) in zip(row, monitor_panels(inp, m, cells)):
            stanford_panel(fig, ax, H, edges, counts, total, m, dim, al)
    sorties = int(np.isin(np.asarray(inp.tc["cell"]), cells).sum() // max(len(monitors), 1))
    fig.suptitle(f"{inp.man['spec']['name']}: {' beside '.join(monitors)} on the same signals — "
                 f"{_cell_text(inp, cells)}; {sorties} sorties, per epoch")
    _save(fig, path)


def problems(inp: ReportInputs, monitors: list[str], cells: list[int]) -> list[str]:
    """What makes the request impossible (monitors or cells the campaign does not have)."""
    have_m = sorted(set(np.asarray(inp.tc["monitor"]).tolist()))
    have_c = sorted(c["cell"] for c in inp.cells)
    out = [f"--monitors {m!r}: not in the campaign (it ran {have_m})" for m in monitors if m not in have_m]
    out += [f"--cells {c}: not a cell of the campaign (cells {have_c})" for c in cells if c not in have_c]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m testbed.studies.stanford_pair", description=__doc__.splitlines()[0])
    ap.add_argument("result", type=Path, help="a finished campaign's result folder (testbed campaign --out)")
    ap.add_argument("figure", type=Path, help="the PNG to write")
    ap.add_argument("--monitors", nargs="+", help="the monitors, one row each, in this order (default: all)")
    ap.add_argument("--cells", nargs="+", type=int, help="the cells pooled (default: all)")
    args = ap.parse_args(argv)
    try:
        if args.figure.suffix != ".png":
            raise ConfigError(args.figure, ["expected a .png file to write"])
        inp = report_inputs(args.result)
        monitors = args.monitors or sorted(set(np.asarray(inp.tc["monitor"]).tolist()))
        cells = args.cells if args.cells is not None else [c["cell"] for c in inp.cells]
        bad = problems(inp, monitors, cells)
        if bad:
            raise ConfigError(args.result, bad)
        draw(inp, monitors, cells, args.figure)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

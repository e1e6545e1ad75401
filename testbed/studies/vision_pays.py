"""Where vision pays: VA-RAIM against GPS RAIM across camera precision and landmark baseline.

From a campaign that sweeps ``camera_focal_px`` (angular precision σ_px / f at a fixed field
of view) and ``landmark_sets`` (the baseline), with fault-free and GPS-step cells and common
random numbers (so both monitors see the same GPS draws):

* :func:`ratio_table` – per (landmark set, focal length): VA-RAIM / GPS RAIM ratios of the
  median per-sortie maximum HPL and VPL (fault-free cells) and of the per-epoch minimal
  detectable bias at the report's power (GPS-step cells). Where either MDB is only a bracket
  of swept steps (:mod:`testbed.campaign.detection`: not resolved, or not reached), the ratio
  is its upper bound, VA-RAIM's largest possible MDB over GPS RAIM's smallest, and
  ``ratio_mdb_bound`` says so: a bound below 1 is a win for certain, one above is no win;
* :func:`break_even` – the smallest focal length from which VA-RAIM beats GPS RAIM on all
  three (every ratio < 1 there and at every larger swept focal length), interpolated in
  log f between the last swept focal length that fails and the first that holds;
* :func:`draw_break_even` – the figure: the three ratios against f, one line per baseline,
  the break-even marked.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from testbed.campaign.detection import detection_table, minimal_detectable_bias
from testbed.campaign.report import _cols, _figure, fit_titles

RATIOS = (("hpl", "median max HPL"), ("vpl", "median max VPL"), ("mdb", "per-epoch MDB"))


def ratio_table(cells: list[dict], trials, power: float = 0.99, det: list[dict] | None = None) -> list[dict]:
    """One row per (landmark_set, focal_px): the three VA-RAIM / GPS RAIM ratios and their parts
    (``det``: the campaign's detection table, when the caller has it already)."""
    tc = _cols(trials, ["cell", "monitor", "max_hpl", "max_vpl"])
    det = detection_table(cells, trials) if det is None else det
    rows = []
    for key in sorted({(c["landmark_set"], c["focal_px"]) for c in cells}):
        group = [c for c in cells if (c["landmark_set"], c["focal_px"]) == key]
        free = [c["cell"] for c in group if c["fault_size"] == 0]
        row = {"landmark_set": key[0], "focal_px": key[1]}
        for m in ("gps_raim", "va_raim"):
            sel = np.isin(tc["cell"], free) & (tc["monitor"] == m)
            for k in ("hpl", "vpl"):
                x = np.asarray(tc[f"max_{k}"][sel], float)
                row[f"{m}_{k}"] = float(np.median(x[np.isfinite(x)])) if np.isfinite(x).any() else float("nan")
            d = [r for r in det if r["monitor"] == m and r["cell"] in {c["cell"] for c in group}
                 and r["fault_kind"] == "gps_step"]
            row[f"{m}_mdb"] = minimal_detectable_bias(*(np.array([r[k] for r in d], float) for k in (
                "fault_size", "rate_ep")), power, *(np.array([r[k] for r in d], float) for k in ("lo_ep", "hi_ep")))
        for k in ("hpl", "vpl"):
            row[f"ratio_{k}"] = row[f"va_raim_{k}"] / row[f"gps_raim_{k}"]
        va, gps = row["va_raim_mdb"], row["gps_raim_mdb"]
        row["ratio_mdb_bound"] = not (va.resolved and gps.resolved)
        with np.errstate(divide="ignore", invalid="ignore"):
            row["ratio_mdb"] = float(np.float64(va.upper) / gps.lower) if va.measured and gps.measured else float("nan")
        rows.append(row)
    return rows


def break_even(focal_px: np.ndarray, worst_ratio: np.ndarray) -> tuple[float, str]:
    """Smallest focal length from which ``worst_ratio`` (the largest VA/GPS ratio) stays < 1.

    Returns (f, text). f is interpolated in log f between the last swept focal length at
    which the ratio is ≥ 1 (or NaN: not measurable) and the next; NaN when VA-RAIM does not
    beat GPS RAIM at the largest swept f (text: "never below f = …"); the smallest swept f
    when it beats it everywhere (text: "≤ …").
    """
    o = np.argsort(focal_px)
    f, r = np.asarray(focal_px, float)[o], np.asarray(worst_ratio, float)[o]
    good = r < 1.0  # NaN (an MDB out of the swept range) is not a win
    if not good[-1]:
        return float("nan"), f"VA-RAIM never beats GPS RAIM below f = {f[-1]:.0f} px"
    fails = np.flatnonzero(~good)
    if fails.size == 0:
        return float(f[0]), f"≤ {f[0]:.0f} px (beats GPS RAIM at every swept focal length)"
    i = fails[-1]  # last failure; from i + 1 on every swept f wins
    r0, r1 = r[i], r[i + 1]
    if np.isfinite(r0) and r0 > r1:
        t = (r0 - 1.0) / (r0 - r1)
        fb = float(np.exp(np.log(f[i]) + t * (np.log(f[i + 1]) - np.log(f[i]))))
    else:  # the losing side is not a number: no interpolation, the first winning f
        fb = float(f[i + 1])
    return fb, f"{fb:.0f} px"


def draw_break_even(rows: list[dict], set_names: dict[int, str], path: Path, sorties: int) -> dict[int, tuple]:
    """The figure (three panels of VA/GPS ratio against f, a line per baseline, the break-even
    marked); returns {landmark_set: break_even(...)}."""
    fig, axs = _figure(1, 3, figsize=(14, 4.4), sharex=True)
    result = {}
    for ls in sorted({r["landmark_set"] for r in rows}):
        rs = sorted((r for r in rows if r["landmark_set"] == ls), key=lambda r: r["focal_px"])
        f = np.array([r["focal_px"] for r in rs])
        ratios = np.array([[r[f"ratio_{k}"] for r in rs] for k, _ in RATIOS])
        worst = np.where(np.isnan(ratios).any(0), np.nan, ratios.max(0))
        result[ls] = break_even(f, worst)
        for ax, (k, title), y in zip(axs, RATIOS, ratios):
            line, = ax.plot(f, y, "o-", label=set_names.get(ls, f"set {ls}"))
            if np.isfinite(result[ls][0]):
                ax.axvline(result[ls][0], color=line.get_color(), ls=":", lw=1)
    for ax, (k, title) in zip(axs, RATIOS):
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_xlabel("focal length f (px) at σ = 1 px (angular precision 1/f rad)")
        ax.set_ylabel(f"VA-RAIM / GPS RAIM, {title}")
        ax.set_title(f"{title} ratio (< 1: vision pays)")
    handles, labels = axs[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=9,
               title="landmark baseline (dotted line: its break-even)")
    fig.suptitle(f"Where vision pays: {sorties} sorties per setting over the sky's repeat, fault-free cells for "
                 f"the PLs, GPS-step cells for the per-epoch MDB")
    fit_titles(fig)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    fig.savefig(path, dpi=110)
    return result

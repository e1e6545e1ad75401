"""A campaign's tables: per trial, per epoch (the first trials) and the Stanford histograms, from one block's
monitor outputs against the truth (:mod:`testbed.sim.evaluate`), joined per chunk.
"""

from __future__ import annotations

from dataclasses import fields
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa

from testbed import memo
from testbed.records import MonitorOutput
from testbed.sim.evaluate import REGIONS, misleading, position_errors, stanford_regions
from testbed.viz.stanford import HIST_BINS, HIST_LOG10_MAX, HIST_LOG10_MIN

if TYPE_CHECKING:  # annotations only: the blocks import the tables
    from testbed.campaign.blocks import BlockDraw
    from testbed.campaign.context import CellContext


TABLES = ("trials", "epochs", "hist")

def monitor_tables(ctx: CellContext, d: BlockDraw, out: MonitorOutput, ref: np.ndarray, keep_ep: np.ndarray
                   ) -> tuple[dict, dict, dict | None]:
    """A monitor's own trial columns, Stanford counts and per-epoch records of one block (not its
    paired columns, nor the cell), computed once for the cells handing it the very same output
    fields (:mod:`testbed.memo`): GPS RAIM's, which VA-RAIM provides from its shared step 1, is
    one output across a camera sweep. Keyed on those fields' identity and on the content of
    everything else the tables read. An output that is not itself shared (an array of it the memo does
    not hold) is not kept either: no other cell can hand it in, and the entry would keep it alive."""
    own = tuple(getattr(out, f.name) for f in fields(out) if f.name != "name")

    def make() -> tuple[dict, dict, dict | None]:
        he, ve = position_errors(out, ref)  # (n, T)
        ep = _epoch_columns(ctx, d, np.flatnonzero(keep_ep), out, he, ve) if keep_ep.any() else None
        return _trial_columns(ctx, d, out, he, ve), _stanford_counts(out.name, out, he, ve), ep

    if not memo.active() or not all(memo.is_shared(v) for v in own if isinstance(v, np.ndarray)):
        return make()
    read = (ctx.t, ref, ctx.onset_s, ctx.hal, ctx.val, ctx.levels, keep_ep, d.trials, d.start_offset_s, d.sky_window,
            d.fault_target, d.fault_satellite, d.fault_present)
    guard = own + ((d.vision_truth,) if out.diagnostics is not None and out.diagnostics.reads_vision_truth else ())
    return memo.shared(("monitor_tables", out.name, tuple(id(v) for v in guard), memo.digest(*read)), make, guard=guard)


def _trial_columns(ctx: CellContext, d: BlockDraw, out: MonitorOutput, he: np.ndarray, ve: np.ndarray) -> dict:
    """One row per trial: detection, time to alert, PL and error maxima, MI/HMI, availability, regions."""
    t, onset, n = ctx.t, ctx.onset_s, d.trials.size
    hpl, vpl = np.asarray(out.hpl, float), np.asarray(out.vpl, float)
    alert = np.asarray(out.alert, bool)
    avail = np.asarray(out.available, bool)  # (n, T, K)
    rh, rv = stanford_regions(he, hpl, ctx.hal, alert), stanford_regions(ve, vpl, ctx.val, alert)
    after = t >= onset - 1e-9 if np.isfinite(onset) else np.ones(t.size, bool)
    det = np.asarray(out.detected, bool) & after  # with FDE: an alert or an exclusion
    detected = det.any(-1)
    # per-epoch detection: alerted epochs / faulty epochs at which the monitor gives a solution, a
    # faulty epoch being one whose measurements carry the fault (the faulty satellite can set or
    # be masked, a faulty landmark leave the image); fault-free cells: every epoch with a solution,
    # so the ratio is the per-epoch false-alarm rate
    solved = (np.asarray(out.reason) == 0) & after & d.fault_present
    with np.errstate(all="ignore"):
        first_any = np.where(alert.any(-1), t[alert.argmax(-1)], np.nan)
        tta = np.where(detected, t[det.argmax(-1)] - (onset if np.isfinite(onset) else 0.0), np.nan)
        mi = misleading(he, ve, hpl, vpl, alert, out.dimensions)
        hmi = rh["hazardous"] | rv["hazardous"]  # alerted epochs are in their own region
        col = {
            "trial": d.trials.astype(np.int64),
            "monitor": out.name, "epochs": np.full(n, t.size, np.int32),
            "start_offset_s": d.start_offset_s, "sky_window": d.sky_window,
            "fault_target": d.fault_target, "fault_satellite": d.fault_satellite,
            "detected": detected, "alert_epochs": alert.sum(-1).astype(np.int32),
            "excluded_epochs": (np.asarray(out.excluded) >= 0).sum(-1).astype(np.int32),
            "onset_epochs": solved.sum(-1).astype(np.int32), "onset_alerts": (det & solved).sum(-1).astype(np.int32),
            "first_alert_s": first_any, "time_to_alert_s": tta,
            "max_he": _nanmax(he), "max_ve": _nanmax(ve), "max_hpl": _nanmax(hpl), "max_vpl": _nanmax(vpl),
            "mi_epochs": mi.sum(-1).astype(np.int32), "hmi_epochs": hmi.sum(-1).astype(np.int32),
        }
        for k, lv in enumerate(ctx.levels):
            col[f"avail_{lv}"] = avail[..., k].mean(-1)
        for r in REGIONS:
            col[f"h_{r}"] = rh[r].sum(-1).astype(np.int32)
            col[f"v_{r}"] = rv[r].sum(-1).astype(np.int32)
        if out.diagnostics is not None:  # a monitor's own table columns
            col.update(out.diagnostics.trial_columns(d.vision_truth))
    return col


def paired_columns(ctx: CellContext, d: BlockDraw, out: MonitorOutput, outs: dict[str, MonitorOutput]) -> dict:
    """Per trial, against every monitor of the run (the same epochs, the same signals): the epochs this one
    is available and the other not, per service level (``only_available_vs_<other>_<level>``; the report's
    McNemar test); and the epochs with exactly four satellites in use-able view, where snapshot RAIM has
    no redundancy (``four_sat_epochs``, ``four_sat_avail_<level>``)."""
    n_sat = np.asarray(d.obs.gnss.visible, bool).sum(-1)  # (n, T)
    four = n_sat == 4
    mine = np.asarray(out.available, bool)
    col = {"four_sat_epochs": four.sum(-1).astype(np.int32)}
    for k, lv in enumerate(ctx.levels):
        col[f"four_sat_avail_{lv}"] = (mine[..., k] & four).sum(-1).astype(np.int32)
        for name, other in outs.items():
            theirs = np.asarray(other.available, bool)[..., k]
            col[f"only_available_vs_{name}_{lv}"] = (mine[..., k] & ~theirs).sum(-1).astype(np.int32)
    return col


def weight_columns(d: BlockDraw) -> dict:
    """Per trial, with importance sampling (:mod:`.sampling`): its ``log_weight`` (log p/q: the weight every
    rate of the trial carries) and the ``proposal_component`` it was drawn from (-1: the error model itself);
    none with plain sampling (the tables as they were)."""
    if d.log_weight is None:
        return {}
    return {"log_weight": np.asarray(d.log_weight, np.float64),
            "proposal_component": np.asarray(d.component, np.int32)}


def _stanford_counts(name: str, out: MonitorOutput, he: np.ndarray, ve: np.ndarray) -> dict[str, list]:
    """Sparse Stanford histograms over the epochs the regions place (alerted ones are counted apart)."""
    edges_log = np.linspace(HIST_LOG10_MIN, HIST_LOG10_MAX, HIST_BINS + 1)
    alert = np.asarray(out.alert, bool)
    hist = {}
    for dim, e, p in (("H", he, np.asarray(out.hpl, float)), ("V", ve, np.asarray(out.vpl, float))):
        ok = np.isfinite(e) & np.isfinite(p) & ~alert
        le = np.clip(np.log10(np.maximum(e[ok], 1e-12)), HIST_LOG10_MIN, HIST_LOG10_MAX - 1e-9)
        lp = np.clip(np.log10(np.maximum(p[ok], 1e-12)), HIST_LOG10_MIN, HIST_LOG10_MAX - 1e-9)
        # np.histogram2d's binning (searchsorted on the edges, right side; the clip keeps the last edge out),
        # counted with one bincount instead of its general d-dimensional path (4x the time)
        cell = (np.searchsorted(edges_log, le, "right") - 1) * HIST_BINS + np.searchsorted(edges_log, lp, "right") - 1
        H = np.bincount(cell, minlength=HIST_BINS * HIST_BINS)
        nz = np.flatnonzero(H)
        hist[f"{name}/{dim}"] = [nz // HIST_BINS, nz % HIST_BINS, H[nz].astype(np.int64)]
    return hist


def _epoch_columns(ctx: CellContext, d: BlockDraw, k_idx: np.ndarray, out: MonitorOutput, he: np.ndarray,
                   ve: np.ndarray) -> dict:
    """Per-epoch records of the kept trials ``k_idx`` (block positions): the contract's columns, then the
    monitor's own (:meth:`~testbed.records.MonitorOutput.own_epoch_columns`)."""
    trials = d.trials
    t, T, nk = ctx.t, ctx.t.size, k_idx.size
    avail = np.asarray(out.available, bool)
    e = {"trial": np.repeat(trials[k_idx], T),
         "monitor": out.name, "t": np.tile(t, nk),
         "he": he[k_idx].ravel(), "ve": ve[k_idx].ravel(), "hpl": np.asarray(out.hpl, float)[k_idx].ravel(),
         "vpl": np.asarray(out.vpl, float)[k_idx].ravel(), "test_stat": np.asarray(out.test_stat, float)[k_idx].ravel(),
         "threshold": np.asarray(out.threshold, float)[k_idx].ravel(),
         "alert": np.asarray(out.alert, bool)[k_idx].ravel(), "fault_present": d.fault_present[k_idx].ravel()}
    for k, lv in enumerate(ctx.levels):
        e[f"avail_{lv}"] = avail[k_idx, :, k].ravel()
    for k, v in out.own_epoch_columns(e).items():  # the monitor's own: ARAIM's EMT, fault modes, ...
        e[k] = np.broadcast_to(v, (trials.size, T))[k_idx].ravel()
    return e


def _nanmax(x: np.ndarray) -> np.ndarray:
    fin = np.isfinite(x)
    return np.where(fin.any(-1), np.max(np.where(fin, x, -np.inf), axis=-1), np.nan)


def _cat_cols(parts: list[dict[str, np.ndarray | str]]) -> pa.Table | None:
    """One table from column dicts; a text value (a str, not an array) stands for that text on every row of
    its part (the monitor's name: 40x faster than a numpy object column). A numeric column some parts lack
    (a monitor's own column for a system one block never used) is NaN on their rows."""
    if not parts:
        return None

    def rows(p: dict) -> int:
        return next(len(v) for v in p.values() if not isinstance(v, str))

    def column(k: str):
        if isinstance(next(p[k] for p in parts if k in p), str):
            return pa.concat_arrays([pa.repeat(pa.scalar(p[k], pa.string()), rows(p)) for p in parts])
        return np.concatenate([p[k] if k in p else np.full(rows(p), np.nan) for p in parts])

    keys = list(dict.fromkeys(k for p in parts for k in p))
    return pa.table({k: column(k) for k in keys})


def _concat(tables: list) -> pa.Table | None:
    """Tables of different monitors (columns differ: nulls where a monitor has none)."""
    tables = [t for t in tables if t is not None]
    return pa.concat_tables(tables, promote_options="default") if tables else None


def chunk_tables(cell_index: int, ctx: CellContext, res: list[dict]) -> dict[str, pa.Table | None]:
    """A cell's chunk tables from its blocks' columns (:func:`run_block`), in block order."""
    monitors = list(ctx.setup.monitor_names)
    trials = _concat([_cat_cols([r["trials"][m] for r in res]) for m in monitors])
    epochs = _concat([_cat_cols([r["epochs"][m] for r in res if m in r["epochs"]]) for m in monitors])
    # histogram: sum the blocks' sparse counts, bins in (error bin, PL bin) order
    hrows = []
    for m in monitors:
        for dim in ("H", "V"):
            parts = [r["hist"][f"{m}/{dim}"] for r in res]
            flat = np.concatenate([np.asarray(ei, np.int64) * HIST_BINS + pi for ei, pi, _ in parts])
            if flat.size == 0:
                continue
            bins, at = np.unique(flat, return_inverse=True)
            count = np.zeros(bins.size, np.int64)
            np.add.at(count, at, np.concatenate([np.asarray(c, np.int64) for _, _, c in parts]))
            hrows.append({"cell": np.full(bins.size, cell_index, np.int32), "monitor": m,
                          "dim": dim, "err_bin": (bins // HIST_BINS).astype(np.int16),
                          "pl_bin": (bins % HIST_BINS).astype(np.int16), "count": count})
    return {"trials": trials, "epochs": epochs, "hist": _cat_cols(hrows)}

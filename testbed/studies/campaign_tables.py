"""A finished campaign's tables as the reproductions read them: cells, trial columns, histograms, and the
figures drawn from them (a cell by its parameters, a per-trial statistic, the 95 % accuracy, detection rates,
the per-epoch MDB)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from testbed.campaign.detection import detection_table, minimal_detectable_bias
from testbed.campaign.report import _cols, hist_quantile
from testbed.campaign.store import ResultStore, read_columns


#: the trials columns the summary reads (at the paper's scale an experiment's trials are up to 1.8e7 rows)
SUMMARY_COLUMNS = ["cell", "trial", "monitor", "epochs", "detected", "onset_epochs", "onset_alerts", "alert_epochs", "max_hpl",
                   "max_vpl", "avail_APV-I", "avail_LPV-200"] + \
    [f"vre_{tag}_{x}" for tag in ("raw", "cal") for x in ("n", "sum", "sumsq")] + \
    ["vf_epochs", "vf_gate_dropped", "vf_rows_used"]


def tables(d: Path) -> dict | None:
    """A finished experiment's cells (list of dicts), trials (numpy columns :data:`SUMMARY_COLUMNS`) and
    Stanford histogram table, or None."""
    if not (d / "trials.parquet").exists():
        return None
    hist = pq.read_table(d / "stanford_hist.parquet") if (d / "stanford_hist.parquet").exists() else None
    return {"cells": pq.read_table(d / "cells.parquet").to_pylist(),
            "trials": read_columns(d / "trials.parquet", SUMMARY_COLUMNS), "hist": hist,
            "block_trials": ResultStore(d).manifest()["spec"]["block_trials"]}


def find_cell(tb: dict | None, **want) -> dict | None:
    if tb is None:
        return None
    for c in tb["cells"]:
        if all(c.get(k) == v or (isinstance(v, float) and abs(float(c.get(k, float("nan"))) - v) < 1e-9)
               for k, v in want.items()):
            return c
    return None


def trial_stat(tb: dict, cell: dict, monitor: str, col: str, how: str) -> float:
    cols = tb["trials"]
    sel = (cols["cell"] == cell["cell"]) & (cols["monitor"] == monitor)
    x = np.asarray(cols[col], float)[sel]
    x = x[np.isfinite(x)]
    if not x.size:
        return float("nan")
    return float(np.median(x) if how == "median" else np.mean(x))


def accuracy95(tb: dict, cell: dict, monitor: str, dim: str) -> float:
    if tb.get("hist") is None:
        return float("nan")
    hc = _cols(tb["hist"])
    return hist_quantile(hc, (hc["cell"] == cell["cell"]) & (hc["monitor"] == monitor) & (hc["dim"] == dim), 0.95)


def detection_rows(tb: dict) -> list[dict]:
    """The experiment's detection table, computed once (at the paper's scale its trials are 1.8e7 rows)."""
    if "detection" not in tb:
        tb["detection"] = detection_table(tb["cells"], tb["trials"])
    return tb["detection"]


def rates(tb: dict, cells: list[dict], monitor: str) -> dict[float, dict]:
    ids = {c["cell"] for c in cells}
    return {r["fault_size"]: r for r in detection_rows(tb) if r["monitor"] == monitor and r["cell"] in ids}


def mdb(rates: dict[float, dict]):
    """The per-epoch MDB at 99 % of a setting's faulty sizes (:class:`~testbed.campaign.detection.MDB`)."""
    sizes = sorted(k for k in rates if k > 0)
    col = lambda key: np.array([rates[k][key] for k in sizes], float)  # noqa: E731
    return minimal_detectable_bias(np.array(sizes, float), col("rate_ep"), 0.99, col("lo_ep"), col("hi_ep"))


def survey_biases(tb: dict, cell: dict, monitor: str = "va_raim") -> dict[str, np.ndarray]:
    """Each landmark survey's mean vision-range error in a cell, raw and calibrated (m; NaN where a survey has
    no such epoch): a campaign draws one survey per block of ``block_trials`` sorties, and the mean over the
    survey's epochs and landmarks is its bias, the paper's "mean error" of its one survey. Keys ``survey``
    (block index), ``raw``, ``cal``, ``raw_n``, ``cal_n``."""
    t = tb["trials"]
    sel = (np.asarray(t["cell"]) == cell["cell"]) & (np.asarray(t["monitor"]) == monitor)
    block = np.asarray(t["trial"], np.int64)[sel] // int(tb["block_trials"])
    ids, inv = np.unique(block, return_inverse=True)
    out: dict[str, np.ndarray] = {"survey": ids}
    for tag in ("raw", "cal"):
        n = np.bincount(inv, np.nan_to_num(np.asarray(t[f"vre_{tag}_n"], float)[sel]), ids.size)
        total = np.bincount(inv, np.nan_to_num(np.asarray(t[f"vre_{tag}_sum"], float)[sel]), ids.size)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[tag] = np.where(n > 0, total / n, np.nan)
        out[f"{tag}_n"] = n
    return out

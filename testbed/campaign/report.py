"""Figures and the index page (``report.md``) of a campaign, drawn from its stored tables.

:func:`write_report` reads ``cells.parquet``, ``trials.parquet``, ``epochs.parquet``
and ``stanford_hist.parquet`` of a result folder and writes ``figures/*.png`` and
``report.md``; it never re-runs anything (``testbed report DIR``). The report and its
figures are moved into place together (:mod:`testbed.outputs`): a failure or a Ctrl-C
while drawing leaves the earlier report as it was.

Statistics (:mod:`testbed.campaign.detection`):
- detection rate per cell = detected trials / trials that exercised the fault, with a
  binomial confidence band (Clopper-Pearson exact, or Wilson score; ``[report]`` of the
  spec); the trials that never exercised it are counted apart ("not exercised"), never
  as missed detections;
- minimal detectable bias (MDB) at power P = the smallest fault size at which the
  detection rate reaches P: its bracket of measured sizes, interpolated inside it only
  where the bracket resolves it, and the bracket the rates' confidence bounds support;
- pooled 95 % accuracy = 95th percentile of all epochs' errors, read from the
  Stanford histogram (0.05-decade bins: about ±6 % resolution).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from testbed.campaign.detection import MDB, binomial_interval, detection_table, minimal_detectable_bias
from testbed.campaign.sampling import MAX_LARGEST_SHARE, MAX_VOV, MIN_EFFECTIVE_EVENTS, coverage, weighted_rate
from testbed.campaign.store import read_columns
from testbed.monitors import monitor_inputs
from testbed.markdown import table as md_table
from testbed.outputs import OutputSet
from testbed.viz.stanford import hist_edges, stanford_figure
from testbed.schema import ConfigError
from testbed.sim.evaluate import REGIONS

AXES = ("approach", "start_time_utc", "dpi", "focal_px", "sigma_px", "lpe_sigma_m", "landmark_set", "calibration",
        "va_raim_variant", "dpe_variant", "multipath_echo_db", "max_satellites", "ground_features", "constellations",
        "terrain_masking")
AXIS_LABEL = {"approach": "approach", "start_time_utc": "start", "dpi": "dpi", "focal_px": "f px", "sigma_px": "DE px",
              "lpe_sigma_m": "LPE m", "landmark_set": "landmark set", "calibration": "cal",
              "va_raim_variant": "VA-RAIM variant", "dpe_variant": "DPE variant", "multipath_echo_db": "echo dB (nan: off)",
              "max_satellites": "satellites (-1: the approach's)", "ground_features": "ground features",
              "constellations": "constellations", "terrain_masking": "terrain masking"}


#: the two definitions of detection: (tag, title, rate, lower, upper key of detection_table rows)
DETECTION_DEFINITIONS = (("sortie", "per sortie (any alert from the onset on)", "rate", "lo", "hi"),
                         ("epoch", "per faulty epoch (alerted / faulty epochs with a solution)", "rate_ep", "lo_ep", "hi_ep"))


def _load(out_dir: Path):
    """The stored tables of a finished campaign; a ConfigError naming what is missing or unreadable."""
    from testbed.campaign.store import ResultStore

    if not out_dir.is_dir():
        raise ConfigError(out_dir, ["not a folder: expected a campaign result folder (testbed campaign --out)"])
    man = ResultStore(out_dir).manifest()
    missing = [n for n in ("cells.parquet", "trials.parquet") if not (out_dir / n).exists()]
    if missing:
        raise ConfigError(out_dir, [f"{n}: missing (the campaign is incomplete: complete it with testbed campaign "
                                    f"SPEC --out {out_dir} --resume)" for n in missing])

    def readable(path: Path, read):
        try:
            return read(path)
        except (OSError, pa.ArrowException) as exc:
            raise ConfigError(path, [f"not a readable Parquet table ({exc}); run the campaign again with --resume: "
                                     "its stored chunks are consolidated again"]) from None

    def table(name: str):
        p = out_dir / name
        return readable(p, pq.read_table) if p.exists() else None

    cells = table("cells.parquet").to_pylist()
    trials = readable(out_dir / "trials.parquet", read_columns)  # numpy columns, one at a time: ~10⁷ rows at paper scale
    return man, cells, trials, table("epochs.parquet"), table("stanford_hist.parquet")


def _names(t) -> list[str]:
    """Column names of a table: a pyarrow Table or a dict of numpy columns."""
    return list(t) if isinstance(t, dict) else t.column_names


def _cols(t, names=None) -> dict[str, np.ndarray]:
    """Numpy columns ``names`` (default all) of a pyarrow Table, or of a dict of numpy columns (as they are)."""
    names = names or _names(t)
    if isinstance(t, dict):
        return {n: t[n] for n in names}
    out = {}
    for n in names:
        c = t.column(n)
        try:
            out[n] = c.to_numpy(zero_copy_only=False)
        except Exception:  # pragma: no cover
            out[n] = np.asarray(c.to_pylist())
    return out


def headlines(source: str | Path | ReportInputs, limit: int = 8) -> list[str]:
    """A finished campaign's result in a few console lines: per cell and monitor, the sorties alerted
    (fault-free: false alarms; faulty: detections among the sorties that exercised the fault, the others
    counted apart) with their interval, and the sorties with HMI. ``source``: a result folder, or the
    :func:`report_inputs` already read from it (the detection table is then not computed again)."""
    inp = source if isinstance(source, ReportInputs) else report_inputs(source)
    if inp.weighted:
        return weighted_headlines(inp, limit)
    rows, conf, varying = inp.det_rows, inp.conf, inp.varying
    tc = inp.tc if "hmi_epochs" in inp.tc else None
    lines = []
    for r in rows[:limit]:
        free = r["fault_kind"] == "none"
        what = "fault-free" if free else f"{r['fault_sweep_kind']} {r['fault_size']:g} {r['fault_unit']}"
        where = _label(r, varying) if varying else ""
        hmi = ""
        if tc is not None:
            sel = (tc["cell"] == r["cell"]) & (tc["monitor"] == r["monitor"])
            hmi = f"; HMI in {int((tc['hmi_epochs'][sel] > 0).sum())}"
        head = f"{r['monitor']}, {what}{', ' + where if where else ''}: "
        if r["n_ex"] == 0:
            lines.append(head + f"not exercised in any of its {r['n']} sorties (no epoch carried the fault while the "
                                f"monitor gave a solution): no detection rate{hmi}")
            continue
        rate = (f"({100 * r['rate']:.1f} %, {100 * conf:g} % interval {100 * r['lo']:.1f}-{100 * r['hi']:.1f} %)")
        if free:
            lines.append(head + f"false alarm in {r['k']} of {r['n']} sorties {rate}{hmi}")
        elif r["not_exercised"]:
            lines.append(head + f"detected in {r['k']} of the {r['n_ex']} sorties that exercised the fault {rate}; "
                                f"{r['not_exercised']} of {r['n']} not exercised{hmi}")
        else:
            lines.append(head + f"detected in {r['k']} of {r['n']} sorties {rate}{hmi}")
    if len(rows) > limit:
        lines.append(f"... and {len(rows) - limit} more cell-monitor rows in report.md")
    return lines


def _varying(cells: list[dict]) -> list[str]:
    return [a for a in AXES if len({str(c.get(a)) for c in cells}) > 1]


def _label(row: dict, axes: list[str]) -> str:
    parts = [row["monitor"]]
    for a in axes:
        v = row[a]
        parts.append(f"{AXIS_LABEL[a]} {v:g}" if isinstance(v, float) else f"{AXIS_LABEL[a]} {v}")
    return ", ".join(parts)


@dataclass(frozen=True)
class ReportInputs:
    """What every report section reads: the stored tables, the report settings and the detection table
    (computed once, for the report and the console's headlines alike)."""

    out_dir: Path
    man: dict
    cells: list[dict]
    trials: object
    epochs: object
    hist: object
    tc: dict
    varying: list[str]
    det_rows: list[dict]
    power: float
    conf: float
    method: str
    hal: float
    val: float
    figdir: Path  # where the figures are drawn (staged until the report is committed)

    @property
    def weighted(self) -> bool:
        """The trials were drawn by importance sampling: every rate is a weighted estimate (:mod:`.sampling`)."""
        return "log_weight" in self.tc

    @property
    def calibration(self) -> str:
        """The VA-RAIM calibration modes of the cells, as the spec sets them (``gps``, ``none`` or both)."""
        return ", ".join(sorted({str(c.get("calibration", "gps")) for c in self.cells}))


#: what a report writes into its campaign folder (a folder ends in "/")
REPORT_ENTRIES = ("report.md", "figures/")


def report_inputs(out_dir: str | Path, *, power: float | None = None) -> ReportInputs:
    """Read a finished campaign's tables and settings once (a ConfigError naming what is missing or
    unreadable); ``power`` overrides the spec's ``[report] power``."""
    out_dir = Path(out_dir)
    man, cells, trials, epochs, hist = _load(out_dir)
    rep = man["spec"].get("report", {})
    power = power if power is not None else rep.get("power", 0.99)
    conf, method = rep.get("confidence", 0.95), rep.get("interval", "clopper-pearson")
    return ReportInputs(out_dir=out_dir, man=man, cells=cells, trials=trials, epochs=epochs, hist=hist,
                        tc=_cols(trials), varying=_varying(cells), det_rows=detection_table(cells, trials, conf, method),
                        power=power, conf=conf, method=method, hal=min(c["hal"] for c in cells),
                        val=min(c["val"] for c in cells), figdir=out_dir / "figures")


def write_report(out_dir: str | Path, *, power: float | None = None, inputs: ReportInputs | None = None,
                 outputs: OutputSet | None = None) -> Path:
    """Draw every figure of a finished campaign and write ``report.md``; returns its path.

    ``inputs``: the campaign's :func:`report_inputs`, when the caller has read them already.
    Figures are drawn on :class:`matplotlib.figure.Figure` objects (no pyplot, no backend
    switch): the caller's matplotlib state is left as it was. The report and its figures are
    staged and committed together: before this returns, or with the caller's ``outputs``
    (:class:`~testbed.outputs.OutputSet`) at its commit.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():  # before trying to write in it: a missing folder is no campaign
        _load(out_dir)
    with OutputSet.using(outputs) as outs:  # the outputs tried first, then the tables read
        if not outs.declares(out_dir):
            outs.folder(out_dir, "DIR", entries=REPORT_ENTRIES, complete=True)
        inp = inputs if inputs is not None else report_inputs(out_dir, power=power)
        return _write_report(replace(inp, figdir=outs.staged_folder(out_dir / "figures")), outs)


def _write_report(inp: ReportInputs, outs: OutputSet) -> Path:
    man, cells = inp.man, inp.cells
    md = [f"# Campaign `{man['name']}`", "",
          f"{man['spec'].get('description', '')}".strip(), "",
          f"- spec hash `{man['spec_hash']}`, {len(cells)} cells x {man['spec']['trials']} trials, "
          f"monitors {', '.join(man['spec']['monitors'])}, base seed {man['spec']['base_seed']}",
          f"- tables: `cells.parquet`, `trials.parquet` (per trial and monitor), `epochs.parquet` "
          f"(first {man['spec']['per_epoch_trials']} trials per cell), `stanford_hist.parquet`", ""]
    md += _exercise_lines(inp)
    figures: list[tuple[str, str]] = []
    sections = (_detection_section, _stanford_section, _misleading_section, _pl_and_availability_section,
                _availability_over_day_section, _paired_section, _pl_time_section, _vision_range_section)
    if inp.weighted:  # counts under the proposal are no rates of the error model: the weighted estimates instead
        sections = (_weighted_section, _pl_and_availability_section, _pl_time_section)
    for section in sections:
        lines, figs = section(inp)
        md += lines
        figures += figs
    md += _index_lines(inp, figures)
    idx = inp.out_dir / "report.md"
    outs.staged(idx).write_text("\n".join(md) + "\n")
    return idx


#: the rates of an importance-sampled campaign: (name, per, numerator, denominator, which cells), from the
#: trials table's columns (``den`` None: an indicator per sortie, among the trials ``den_sortie`` selects)
WEIGHTED_RATES = (
    ("P_FA", "epoch", "free"), ("P_FA", "sortie", "free"),
    ("P_MD", "epoch", "faulty"), ("P_MD", "sortie", "faulty"),
    ("P_MI", "epoch", "all"), ("P_MI", "sortie", "all"),
    ("P_HMI", "epoch", "all"), ("P_HMI", "sortie", "all"),
)


def _rate_terms(tc: dict, sel: np.ndarray, rate: str, per: str) -> tuple[np.ndarray, np.ndarray]:
    """The numerator and denominator per trial of one rate (:data:`WEIGHTED_RATES`) on the rows ``sel``.
    Per epoch: false alarms among the epochs with a solution, missed detections among the faulty epochs with
    one, MI and HMI among all epochs; per sortie: an indicator (MD: among the sorties that exercised the fault)."""
    col = lambda k: np.asarray(tc[k][sel], float)  # noqa: E731
    if rate == "P_FA":
        return (col("onset_alerts"), col("onset_epochs")) if per == "epoch" else (col("detected"), np.ones(sel.sum()))
    if rate == "P_MD":
        if per == "epoch":
            return col("onset_epochs") - col("onset_alerts"), col("onset_epochs")
        ex = col("onset_epochs") > 0
        return (ex & (col("detected") == 0)).astype(float), ex.astype(float)
    k = "mi_epochs" if rate == "P_MI" else "hmi_epochs"
    return (col(k), col("epochs")) if per == "epoch" else ((col(k) > 0).astype(float), np.ones(sel.sum()))


def weighted_rates(inp: ReportInputs) -> list[dict]:
    """Every rate of :data:`WEIGHTED_RATES` per cell and monitor, as :func:`~.sampling.weighted_rate` estimates it
    from the trials' log-weights (rows: cell, monitor, fault, rate, per, and the :class:`~.sampling.Rate`)."""
    tc = inp.tc
    lw = np.asarray(tc["log_weight"], float)
    samp, aimed = inp.man["spec"].get("sampling", {}), _aimed_monitor(inp.man["spec"])
    out = []
    for c in inp.cells:
        free = c["fault_kind"] == "none"
        for m in sorted(set(tc["monitor"][tc["cell"] == c["cell"]].tolist())):
            sel = (tc["cell"] == c["cell"]) & (tc["monitor"] == m)
            for rate, per, which in WEIGHTED_RATES:
                if (which == "free" and not free) or (which == "faulty" and free):
                    continue
                num, den = _rate_terms(tc, sel, rate, per)
                status, why = coverage(m, rate, aimed, samp.get("proposal", "shift"), samp.get("event", "misleading"))
                out.append({"cell": int(c["cell"]), "monitor": m, "fault": "fault-free" if free else
                            f"{c['fault_sweep_kind']} {c['fault_size']:g} {c['fault_unit']}", "rate": rate,
                            "per": per, "est": weighted_rate(num, den, lw[sel], inp.conf), "coverage": status,
                            "why": why})
    return out


def verdict(row: dict) -> str:
    """A weighted rate's verdict: settled, or why no rate is printed; a rate the proposal does not reach says
    so first (its "no event" is no bound: the proposal never went where its events are)."""
    e = row["est"]
    if e.settled:
        return "settled"
    if row["coverage"] in ("not reached", "not aimed"):
        return f"{row['coverage']} by the proposal ({row['why']}): " + "; ".join(e.problems)
    return "; ".join(e.problems)


def weighted_headlines(inp: ReportInputs, limit: int = 8) -> list[str]:
    """:func:`headlines` of an importance-sampled campaign: the per-epoch HMI and MI rates of each cell and
    monitor with their intervals, or why there is no rate."""
    rows = [r for r in weighted_rates(inp) if r["per"] == "epoch" and r["rate"] in ("P_HMI", "P_MI")]
    lines = [f"{r['monitor']}, cell {r['cell']} ({r['fault']}): {r['rate']} per epoch "
             + (f"{r['est'].estimate:.3g}, {100 * inp.conf:g} % interval [{r['est'].lo:.3g}, {r['est'].hi:.3g}] "
                f"({r['est'].ess_events:.0f} effective events in {r['est'].trials} sorties)" if r["est"].settled
                else "no rate: " + verdict(r)) for r in rows[:limit]]
    if len(rows) > limit:
        lines.append(f"... and {len(rows) - limit} more rows in report.md")
    return lines


def _aimed_monitor(spec: dict) -> str:
    """The monitor an importance plan was aimed from (:func:`~.sampling.sampling_monitor`), from a stored spec."""
    samp = spec.get("sampling", {})
    return samp.get("monitor") or next((m for m in spec["monitors"] if monitor_inputs(m) == frozenset({"gnss"})),
                                       "?")


def _weighted_section(inp: ReportInputs) -> tuple[list[str], list[tuple[str, str]]]:
    """Section: the weighted estimates of every rate, with their diagnostics."""
    samp = inp.man["spec"].get("sampling", {})
    aim = (f"the `{samp.get('event')}` event" if samp.get("proposal", "shift") == "shift"
           else "the tests' tails (false alerts)")  # scale, separation: `event` is not read
    md = ["## Rates by importance sampling", "",
          f"The trials were drawn from a proposal (`[sampling]`: proposal `{samp.get('proposal')}` aimed at "
          f"{aim} of `{_aimed_monitor(inp.man['spec'])}`, defensive "
          f"share {samp.get('defensive')}), each carrying its log-likelihood ratio (`log_weight` in "
          "`trials.parquet`). Every rate is the weighted mean over the trials with its standard error and "
          f"{100 * inp.conf:g} % normal interval (the upper end: the {100 * (1 + inp.conf) / 2:g} % upper bound). "
          "Counts under the proposal are not rates of the error model, so the count-based sections (detection, "
          "Stanford regions, misleading information) are left out. A rate whose weights have not settled (fewer "
          f"than {MIN_EFFECTIVE_EVENTS:g} effective events, one trial carrying more than "
          f"{100 * MAX_LARGEST_SHARE:g} % of it, or a variance of the variance above {MAX_VOV:g}) or whose event no "
          "trial reached is not printed: the reason is. Per epoch: false alarms among the epochs with a solution, "
          "missed detections among the faulty epochs with one, MI and HMI among all epochs; per sortie: a sortie "
          "with at least one.", ""]
    rates = weighted_rates(inp)
    md += _coverage_lines(inp, rates)
    rows = []
    for r in rates:
        e = r["est"]
        rows.append([r["cell"], r["monitor"], r["fault"], r["rate"], r["per"],
                     f"{e.estimate:.3e}" if e.settled else "-", f"{e.se:.2e}" if e.settled else "-",
                     f"[{e.lo:.3e}, {e.hi:.3e}]" if e.settled else "-", e.trials, e.events,
                     _f(e.ess_events, "{:.1f}"), _f(e.largest_share, "{:.3f}"), _f(e.vov, "{:.3f}"),
                     r["coverage"], verdict(r)])
    md += md_table(["cell", "monitor", "fault", "rate", "per", "estimate", "standard error",
                    f"{100 * inp.conf:g} % interval", "trials", "trials with the event", "effective events",
                    "largest share", "VOV", "proposal", "verdict"], rows)
    md += ["", "The sections below count the trials as drawn, unweighted: the proposal moves one epoch of a sortie, so "
           "their protection levels and availability are the error model's to within that epoch, their accuracy "
           "and figures are the proposal's.", ""]
    return md, []


def _coverage_lines(inp: ReportInputs, rates: list[dict]) -> list[str]:
    """Which monitor's rates the proposal aims at, and which it does not reach (:func:`~.sampling.coverage`), one
    row per monitor: the "proposal" column of the rates table, explained."""
    per_monitor: dict[str, dict[str, list[str]]] = {}
    whys: dict[tuple[str, str], str] = {}
    for r in rates:
        names = per_monitor.setdefault(r["monitor"], {})
        if r["rate"] not in names.setdefault(r["coverage"], []):
            names[r["coverage"]].append(r["rate"])
        whys[r["monitor"], r["coverage"]] = r["why"]
    rows = [[m, sorted(monitor_inputs_or_unknown(m)), "; ".join(f"{', '.join(rs)}: {status} ({whys[m, status]})"
                                                                for status, rs in by.items())]
            for m, by in per_monitor.items()]
    return (["Where the proposal goes: a rate is **aimed** at (efficient), **moved** (every input of another "
             "monitor moved: efficient where its failure region is near the aimed one's), **not aimed** at (a rate "
             "the proposal does not seek) or **not reached** (the monitor reads errors the proposal leaves as "
             "drawn). Every weighted estimate is unbiased, but one the proposal does not aim at or reach gets the "
             "precision of plain sampling at best; with no event it is no bound, and none is printed.", ""]
            + md_table(["monitor", "reads", "its rates"], rows) + [""])


def monitor_inputs_or_unknown(name: str) -> frozenset[str]:
    """What a stored run's monitor reads, or "unknown" when it is not registered in this process."""
    try:
        return monitor_inputs(name)
    except KeyError:
        return frozenset({"unknown"})


def _exercise_lines(inp: ReportInputs) -> list[str]:
    """A warning near the top when some faulty trials never exercised their fault (they are out of every
    detection rate; the MDB and per-cell tables count them)."""
    faulty = [r for r in inp.det_rows if r["fault_kind"] != "none"]
    ne = sum(r["not_exercised"] for r in faulty)
    if not ne:
        return []
    dead = sorted({(r["cell"], r["monitor"]) for r in faulty if r["n_ex"] == 0})
    return [f"**Faults not exercised**: in {ne} of {sum(r['n'] for r in faulty)} faulty sortie-monitor pairs no epoch "
            "carried the fault while the monitor gave a solution (the satellite never in view, the landmark never "
            "detected, or no solution then). They are left out of the detection rates and counted apart, never as "
            "missed detections"
            + (f"; no sortie exercised the fault at all for {len(dead)} cell-monitor pair(s) "
               f"({', '.join(f'cell {c} {m}' for c, m in dead[:8])}{' ...' if len(dead) > 8 else ''})" if dead else "")
            + ".", ""]


def _figure(nrows: int = 1, ncols: int = 1, **kw):
    """A figure and its axes without pyplot (no global state)."""
    from matplotlib.figure import Figure

    figsize = kw.pop("figsize", None)
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kw)


def _save(fig, path: Path) -> None:
    """Lay a figure out with every title inside it and write it."""
    fit_titles(fig)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def fit_titles(fig) -> None:
    """Wrap the figure's own texts (its suptitle) to the figure's width and each axes title to its axes'
    width, at word boundaries: a title wider than its room was clipped at both ends (``pl_time.png``'s
    over one panel). Drawn on an Agg canvas to measure (no pyplot, no backend switch)."""
    import textwrap

    from matplotlib.backends.backend_agg import FigureCanvasAgg

    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    renderer = fig.canvas.get_renderer()
    rooms = [(t, 0.96 * fig.bbox.width) for t in fig.texts]
    rooms += [(ax.title, 1.05 * ax.get_window_extent(renderer).width) for ax in fig.axes]
    for text, room in rooms:
        paragraphs = text.get_text().split("\n")  # the title's own line breaks stay
        chars = max(map(len, paragraphs))
        for _ in range(6):  # a fill can still come out wide (long words): narrower until it fits
            width = text.get_window_extent(renderer).width
            if not text.get_text() or width <= room or chars <= 12:
                break
            chars = max(12, int(chars * min(room / width, 0.95)))
            text.set_text("\n".join(textwrap.fill(p, chars) for p in paragraphs))


def _detection_section(inp: ReportInputs) -> tuple[list[str], list[tuple[str, str]]]:
    """Section: detection rate vs fault size per fault family, per sortie and per epoch, and the MDB of each."""
    md: list[str] = []
    figures: list[tuple[str, str]] = []
    cells, varying, figdir = inp.cells, inp.varying, inp.figdir
    det_rows, power, conf, method = inp.det_rows, inp.power, inp.conf, inp.method
    fams = sorted({(c["fault_family"], c["fault_sweep_kind"], c["fault_unit"]) for c in cells})
    mdb_rows = []
    for fam, kind, unit in fams:
        if kind == "none":
            continue
        rows = [r for r in det_rows if r["fault_family"] == fam]
        groups: dict[str, list[dict]] = {}
        for r in rows:
            groups.setdefault(_label(r, varying), []).append(r)
        for rs in groups.values():
            rs.sort(key=lambda r: r["fault_size"])
        mdbs = {lab: group_mdbs(rs, power) for lab, rs in groups.items()}
        for lab, rs in sorted(groups.items()):
            faulty = [r for r in rs if r["fault_kind"] != "none"]
            free = [r for r in rs if r["fault_kind"] == "none"]
            mdb_rows.append({"fault": kind, "unit": unit, "group": lab, "n": rs[0]["n"],
                             "not_exercised": f"{sum(r['not_exercised'] for r in faulty)} of {sum(r['n'] for r in faulty)}",
                             "fa_sortie": free[0]["rate"] if free else float("nan"),
                             "fa_epoch": free[0]["rate_ep"] if free else float("nan"), **mdbs[lab]})
        per_cell = {r["cell"]: r["n"] for r in rows}  # sorties of each cell (every monitor flies them all)
        fig = detection_figure(f"{kind} size ({unit})", groups, mdbs, power,
                               f"{kind}: {sum(per_cell.values())} sorties in {len(per_cell)} cells; points: the "
                               f"measured rates with their {method} {100 * conf:g} % intervals")
        name = f"detection_{fam}_{kind}.png"
        _save(fig, figdir / name)
        figures.append((f"Detection rate vs {kind} size, per sortie and per epoch", name))
    if mdb_rows:
        band = f"{100 * conf:g} % bracket"
        md += [f"## Minimal detectable bias at {100 * power:g} % power", "",
               "Per sortie: any alert from the onset on, among the sorties that exercised the fault (an epoch "
               "carried it while the monitor gave a solution; the others are counted in \"not exercised\", never "
               "as missed); per epoch: alerted epochs among the epochs from the onset that carried the fault and "
               "at which the monitor gives a solution (size 0: the per-epoch false-alarm rate).", "",
               "The MDB is the smallest size whose measured rate reaches the power. It lies between the measured "
               "size before it and that size, and is interpolated between the two only when they are adjacent in "
               "the sweep and the rate at the lower one is at least 1/2 (there a detection curve is concave, so "
               "the interpolation errs on the large side); otherwise the bracket is the answer. The "
               f"{band}: sizes whose rate's {method} interval lies wholly below the power (the MDB is above) or "
               "wholly at or above it (the MDB is at most that), read size by size.", ""]
        md += md_table(["fault", "group", "sorties/cell", "not exercised", "false alarms per sortie",
                        "MDB per sortie", band, "false alarms per epoch", "MDB per epoch", band],
                       [[r["fault"], r["group"], r["n"], r["not_exercised"], _f(r["fa_sortie"], "{:.4f}"),
                         r["sortie"].text(r["unit"]), r["sortie"].ci_text(r["unit"]), _f(r["fa_epoch"], "{:.2e}"),
                         r["epoch"].text(r["unit"]), r["epoch"].ci_text(r["unit"])] for r in mdb_rows])
        md.append("")
    return md, figures


def group_mdbs(rows: list[dict], power: float) -> dict[str, MDB]:
    """The MDB of a group of detection-table rows (one setting, every size), per detection definition."""
    def col(k: str) -> np.ndarray:
        return np.array([r[k] for r in rows], float)

    return {tag: minimal_detectable_bias(col("fault_size"), col(key), power, col(klo), col(khi))
            for tag, _, key, klo, khi in DETECTION_DEFINITIONS}


def detection_figure(xlabel: str, groups: dict[str, list[dict]], mdbs: dict[str, dict[str, MDB]], power: float,
                     title: str):
    """Detection rate vs fault size, per sortie and per epoch side by side, a colour per group.

    Only what was measured is drawn: each size's rate as a point with its interval, a thin dotted line
    joining sizes adjacent in the sweep (a size whose fault was not exercised breaks it, and is marked x on
    the axis), and on the power line each group's MDB: its bracket of measured sizes as a thick segment and,
    where the bracket resolves it, the interpolated value as a tick (``>`` at the largest size: not reached).
    """
    fig, axs = _figure(1, 2, figsize=(12, 5.2), sharey=True)
    unexercised = False
    for g, (lab, rs) in enumerate(sorted(groups.items())):
        colour = f"C{g % 10}"
        x = np.array([r["fault_size"] for r in rs], float)
        for ax, (tag, _, key, klo, khi) in zip(axs, DETECTION_DEFINITIONS):
            y, lo, hi = (np.array([r[k] for r in rs], float) for k in (key, klo, khi))
            m = np.isfinite(y)
            ax.errorbar(x[m], y[m], yerr=[y[m] - lo[m], hi[m] - y[m]], fmt="o", ms=4, capsize=2, color=colour,
                        label=lab)
            ax.plot(x, y, ls=":", lw=0.9, color=colour)  # NaN (not exercised) breaks the line
            if (~m).any():
                ax.plot(x[~m], np.zeros((~m).sum()), "x", ms=7, mew=1.5, color="0.45")
                unexercised = True
            _mark_mdb(ax, mdbs[lab][tag], power, colour)
    for ax, (tag, title_, *_) in zip(axs, DETECTION_DEFINITIONS):
        ax.axhline(power, color="k", ls=":", lw=0.8)
        ax.set_xlabel(xlabel)
        ax.set_ylim(-0.03, 1.03)
        ax.set_title(f"detection rate {title_}", fontsize=9)
        ax.grid(alpha=0.3)
    axs[0].set_ylabel("detection rate")
    axs[1].legend(fontsize=7, loc="lower right")
    fig.suptitle(f"{title}\ndotted: power {power:g}, joins between adjacent measured sizes; on the power line the MDB: "
                 "thick its bracket, | its interpolation where resolved, > not reached"
                 + ("; x: fault not exercised" if unexercised else ""), fontsize=9)
    return fig


def _mark_mdb(ax, mdb: MDB, power: float, colour: str) -> None:
    """The MDB on the power line: its bracket (a thick segment), its value (a tick) or ``>`` / ``<``."""
    if not mdb.measured:
        return
    if mdb.reached and np.isfinite(mdb.low):
        ax.plot([mdb.low, mdb.high], [power, power], lw=6, alpha=0.35, color=colour, solid_capstyle="butt")
    if mdb.resolved:
        ax.plot([mdb.value], [power], marker="|", ms=14, mew=2.5, color=colour)
    elif not mdb.reached:
        ax.plot([mdb.low], [power], marker=">", ms=8, color=colour)
    elif np.isnan(mdb.low):
        ax.plot([mdb.high], [power], marker="<", ms=8, color=colour)


def _stanford_section(inp: ReportInputs) -> tuple[list[str], list[tuple[str, str]]]:
    """Section: Stanford diagrams, region counts and pooled 95 % accuracy per monitor."""
    md: list[str] = []
    figures: list[tuple[str, str]] = []
    figdir = inp.figdir
    tc, hist, hal, val = inp.tc, inp.hist, inp.hal, inp.val
    # ---- Stanford diagrams and region counts

    monitors = sorted(set(tc["monitor"].tolist()))

    edges = hist_edges()
    region_rows = []
    acc_rows = []
    for m in monitors:
        sel = tc["monitor"] == m
        panels = []
        for dim, al in (("H", hal), ("V", val)):
            counts = {r: int(tc[f"{dim.lower()}_{r}"][sel].sum()) for r in REGIONS}
            total = int(tc["epochs"][sel].sum())
            region_rows.append({"monitor": m, "dim": dim, **counts, "epochs": total})
            H = np.zeros((len(edges) - 1, len(edges) - 1))
            if hist is not None:
                hc = _cols(hist)
                hs = (hc["monitor"] == m) & (hc["dim"] == dim)
                np.add.at(H, (hc["err_bin"][hs], hc["pl_bin"][hs]), hc["count"][hs])
            hc = None if hist is None else _cols(hist)
            e95 = hist_quantile(hc, None if hc is None else (hc["monitor"] == m) & (hc["dim"] == dim), 0.95)
            acc_rows.append({"monitor": m, "dim": dim, "e95": e95})
            panels.append((dim, H, counts, total, al))
        name = f"stanford_{m}.png"
        _save(stanford_figure(m, panels, edges), figdir / name)
        figures.append((f"Stanford diagrams, {m}", name))
    md += ["## Integrity regions (all cells, all epochs; most demanding service level)", ""]
    md += md_table(["monitor", "dim", *REGIONS, "epochs"],
                   [[r["monitor"], r["dim"], *(r[k] for k in REGIONS), r["epochs"]] for r in region_rows])
    md += ["", "## 95 % accuracy (pooled over all cells and epochs, from the Stanford histograms)", ""]
    e95 = {(a["monitor"], a["dim"]): a["e95"] for a in acc_rows}
    md += md_table(["monitor", "HPE95 (m)", "VPE95 (m)"],
                   [[m, _f(e95[m, "H"], "{:.2f}"), _f(e95[m, "V"], "{:.2f}")] for m in monitors])
    md.append("")
    return md, figures


def hist_quantile(hist: dict[str, np.ndarray] | None, select: np.ndarray | None, q: float) -> float:
    """The q-quantile of the position errors counted in Stanford-histogram rows ``select``.

    Rows are (err_bin, pl_bin, count) on :func:`testbed.viz.stanford.hist_edges` (0.05-dex bins); the
    quantile is interpolated log-linearly inside its bin (resolution about 12 %, exact at
    bin edges). NaN with no counts.
    """

    if hist is None:
        return float("nan")
    edges = hist_edges()
    sel = np.ones(hist["count"].shape, bool) if select is None else select
    per_bin = np.bincount(hist["err_bin"][sel].astype(np.int64), weights=hist["count"][sel],
                          minlength=len(edges) - 1)[: len(edges) - 1]
    total = per_bin.sum()
    if total <= 0:
        return float("nan")
    cum = np.cumsum(per_bin)
    k = int(np.searchsorted(cum, q * total))
    below = cum[k - 1] if k > 0 else 0.0
    frac = (q * total - below) / per_bin[k]
    lo, hi = np.log10(edges[k]), np.log10(edges[k + 1])
    return float(10 ** (lo + frac * (hi - lo)))


def _setting_label(cell: dict, varying: list[str]) -> str:
    """The sweep setting of a cell (every varying axis but the start time), e.g. 'dpi 720, DE px 1'."""
    parts = [f"{AXIS_LABEL[a]} {cell[a]:g}" if isinstance(cell[a], float) else f"{AXIS_LABEL[a]} {cell[a]}"
             for a in varying if a != "start_time_utc"]
    return ", ".join(parts) or "all cells"


def _pl_and_availability_section(inp: ReportInputs) -> tuple[list[str], list[tuple[str, str]]]:
    """Section: PL statistics across sorties and per-epoch availability per service level, one table
    (settings x monitors as rows, statistics and levels as columns)."""
    cells, varying, tc = inp.cells, inp.varying, inp.tc
    levels = [c[len("avail_"):] for c in tc if c.startswith("avail_")]
    setting = np.array([_setting_label(cells[i], varying) for i in tc["cell"]])
    cell_setting = {int(c["cell"]): _setting_label(c, varying) for c in cells}
    hc = None if inp.hist is None else _cols(inp.hist)
    md = ["## Protection levels, accuracy and availability across sorties", "",
          "Per setting and monitor, pooled over its sorties (and start times): the median, 95th percentile and "
          "maximum of each sortie's largest HPL / VPL; the 95 % horizontal / vertical accuracy (95th percentile "
          "of the position error over its epochs with a protection level and no alert, from the 0.05-dex "
          "error histogram: ±6 %); the fraction of epochs available per service level.", ""]
    rows = []
    for g in sorted(set(setting.tolist())):
        in_setting = None if hc is None else np.isin(hc["cell"], [k for k, v in cell_setting.items() if v == g])
        for m in sorted(set(tc["monitor"][setting == g].tolist())):
            sel = (setting == g) & (tc["monitor"] == m)
            stats3 = [" / ".join(_f(x, "{:.1f}") for x in _median_p95_max(tc[k][sel])) for k in ("max_hpl", "max_vpl")]
            acc = [hist_quantile(hc, None if hc is None else in_setting & (hc["monitor"] == m) & (hc["dim"] == d), 0.95)
                   for d in ("H", "V")]
            rows.append([g, m, int(sel.sum()), stats3[0], stats3[1], f"{_f(acc[0], '{:.2f}')} / {_f(acc[1], '{:.2f}')}",
                         *(f"{100 * float(np.mean(tc[f'avail_{lv}'][sel])):.1f} %" for lv in levels)])
    md += md_table(["setting", "monitor", "sorties", "max HPL: median / p95 / max (m)",
                    "max VPL: median / p95 / max (m)", "H / V accuracy 95 % (m)", *levels], rows)
    md.append("")
    return md, []


#: sorties whose start times span at least this long get the availability-over-the-day section
DAY_SECTION_MIN_SPAN_H = 6.0


def hour_of_day(cells: list[dict], cell: np.ndarray, start_offset_s: np.ndarray) -> np.ndarray:
    """UTC hour of day [0, 24) at which each sortie starts: its cell's approach start time plus its offset."""
    start_h = {int(c["cell"]): (lambda t: t.hour + t.minute / 60.0 + t.second / 3600.0)(
        dt.datetime.fromisoformat(c["start_time_utc"])) for c in cells}
    return np.mod(np.array([start_h[int(k)] for k in cell]) + np.asarray(start_offset_s, float) / 3600.0, 24.0)


def _availability_over_day_section(inp: ReportInputs) -> tuple[list[str], list[tuple[str, str]]]:
    """Section (sorties spread over at least :data:`DAY_SECTION_MIN_SPAN_H` hours): the first service level's
    availability (fraction of epochs) against the UTC hour the sortie started, one panel a setting and a line a
    monitor (fault-free cells), and a compact table: the day's availability and its worst hour."""
    cells, varying, tc = inp.cells, inp.varying, inp.tc
    levels = [c[len("avail_"):] for c in tc if c.startswith("avail_")]
    offsets = np.asarray(tc.get("start_offset_s", np.zeros(0)), float)
    if not levels or offsets.size == 0 or np.ptp(offsets) < DAY_SECTION_MIN_SPAN_H * 3600.0:
        return [], []
    level = "LPV-200" if "LPV-200" in levels else levels[0]
    nofault = {int(c["cell"]) for c in cells if c["fault_kind"] == "none"}
    use = np.isin(tc["cell"], list(nofault)) if nofault else np.ones(offsets.size, bool)
    hour = hour_of_day(cells, tc["cell"], offsets)
    setting = np.array([_setting_label(cells[i], varying) for i in tc["cell"]])
    groups = list(dict.fromkeys(setting[use][np.argsort(tc["cell"][use], kind="stable")].tolist()))  # cell order
    monitors = sorted(set(tc["monitor"][use].tolist()), key=lambda m: (m != "gps_raim", m))
    edges = np.arange(0.0, 24.0 + 1e-9, 1.0)
    mid = 0.5 * (edges[:-1] + edges[1:])
    rows, figures = [], []
    ncols = min(len(groups), 3)
    nrows = -(-len(groups) // ncols)
    fig, axs = _figure(nrows, ncols, figsize=(3.6 * ncols + 1.0, 2.8 * nrows + 0.8), sharex=True, sharey=True,
                       squeeze=False)
    for j, g in enumerate(groups):
        ax = axs[j // ncols][j % ncols]
        for k, m in enumerate(monitors):
            sel = use & (setting == g) & (tc["monitor"] == m)
            if not sel.any():
                continue
            a = np.asarray(tc[f"avail_{level}"], float)[sel]
            b = np.clip(np.digitize(hour[sel], edges) - 1, 0, edges.size - 2)
            n_bin = np.bincount(b, minlength=mid.size)
            per_hour = np.bincount(b, weights=a, minlength=mid.size) / np.maximum(n_bin, 1)
            per_hour = np.where(n_bin > 0, per_hour, np.nan)
            ax.step(mid, 100.0 * per_hour, where="mid", color=f"C{k}", lw=1.3, ls="--" if k == 0 else "-", label=m)
            worst = int(np.nanargmin(per_hour))
            when = ("every hour" if np.nanmax(per_hour) == per_hour[worst]
                    else f"{edges[worst]:02.0f}–{edges[worst + 1]:02.0f} h")
            rows.append([g, m, int(sel.sum()), f"{100.0 * float(a.mean()):.1f} %",
                         f"{100.0 * per_hour[worst]:.1f} % ({when})"])
        ax.set_title(g, fontsize=8)
        ax.set_ylim(-3, 103)
        ax.set_xlim(0, 24)
        ax.set_xticks(np.arange(0, 25, 6))
        ax.grid(alpha=0.3)
        if j % ncols == 0:
            ax.set_ylabel(f"{level} available (% of epochs)")
        if j // ncols == nrows - 1:
            ax.set_xlabel("sortie start, UTC hour of day")
    for j in range(len(groups), nrows * ncols):
        axs[j // ncols][j % ncols].set_visible(False)
    axs[0][0].legend(fontsize=7, loc="lower left")
    fig.suptitle(f"{level} availability over the day, mean per 1-h bin of sortie starts"
                 + (" (fault-free cells)" if nofault else ""), fontsize=10)
    name = "availability_over_day.png"
    _save(fig, inp.figdir / name)
    figures.append((f"{level} availability over the day", name))
    md = ["## Availability over the day", "",
          f"Per setting and monitor, the fraction of epochs {level}-available over every sortie"
          + (" of the fault-free cells" if nofault else "") + ", and the worst 1-hour bin of sortie start "
          f"times (UTC): figure `figures/{name}`.", ""]
    md += md_table(["setting", "monitor", "sorties", f"{level} over the day", "worst hour"], rows)
    md.append("")
    return md, figures


def _misleading_section(inp: ReportInputs) -> tuple[list[str], list[tuple[str, str]]]:
    """Section: misleading and hazardously misleading epochs per cell and monitor, with the per-epoch
    HMI rate's binomial interval (a monitor without detection, such as the DPE, shows its faults here)."""
    tc, cells = inp.tc, {int(c["cell"]): c for c in inp.cells}
    md = ["## Misleading information per cell", "",
          "Epochs whose error exceeds the protection level without an alert (MI), and those whose error also "
          "exceeds the alert limit while the PL is within it (HMI), on the dimensions each monitor bounds "
          f"(a vertical-only monitor on V); HMI rate per epoch with its {100 * inp.conf:g} % {inp.method} interval.",
          ""]
    rows = []
    for cell in sorted(set(tc["cell"].tolist())):
        c = cells[int(cell)]
        for m in sorted(set(tc["monitor"][tc["cell"] == cell].tolist())):
            sel = (tc["cell"] == cell) & (tc["monitor"] == m)
            n, mi, hmi = (int(tc[k][sel].sum()) for k in ("epochs", "mi_epochs", "hmi_epochs"))
            lo, hi = binomial_interval(np.array([hmi]), np.array([n]), inp.conf, inp.method)
            rows.append([cell, c["fault_sweep_kind"], f"{c['fault_size']:g} {c['fault_unit']}", m, n, mi, hmi,
                         f"{hmi / max(n, 1):.2e}", f"[{float(lo[0]):.2e}, {float(hi[0]):.2e}]"])
    md += md_table(["cell", "fault", "size", "monitor", "epochs", "MI", "HMI", "HMI per epoch", "interval"], rows)
    md.append("")
    return md, []


def mcnemar_p(a_only: int, b_only: int) -> float:
    """Exact two-sided McNemar p-value: the discordant counts against Binomial(a_only + b_only, 1/2)."""
    from scipy import stats

    n = a_only + b_only
    return 1.0 if n == 0 else float(min(1.0, 2.0 * stats.binom.cdf(min(a_only, b_only), n, 0.5)))


def _paired_section(inp: ReportInputs) -> tuple[list[str], list[tuple[str, str]]]:
    """Section: the monitors paired on the same epochs — availability (McNemar over epochs, and a sign test
    over sorties, which are independent where epochs are not), the VPL ratio, and the epochs with exactly
    four satellites (no redundancy for snapshot RAIM) counted apart."""
    tc = inp.tc
    monitors = sorted(set(tc["monitor"].tolist()))
    levels = [c[len("only_available_vs_" + monitors[0] + "_"):] for c in tc if c.startswith(f"only_available_vs_{monitors[0]}_")]
    if len(monitors) < 2 or not levels:
        return [], []
    md = ["## The monitors paired on the same epochs", "",
          "Availability at the same epochs and signals: epochs where only one is available, the exact McNemar "
          "test on them (epochs within a sortie are correlated, so its p is optimistic), and a sign test over "
          "sorties (independent: the sorties where one is available more often than the other); then the "
          "epochs with exactly four satellites, where snapshot RAIM has no redundancy, counted apart.", ""]
    pairs = [(a, b) for i, a in enumerate(monitors) for b in monitors[i + 1:]]
    md += md_table(["level", "monitor A", "monitor B", "epochs", "A only", "B only", "McNemar p", "sorties A > B",
                    "A < B", "sign test p", "4-satellite epochs", "A available there", "B available there"],
                   [_paired_row(tc, level, a, b) for level in levels for a, b in pairs])
    md.append("")
    ep = inp.epochs
    if ep is not None and ep.num_rows:
        e = _cols(ep, ["cell", "trial", "t", "monitor", "vpl"])
        md += ["VPL ratio on the per-epoch trials' epochs where both give a VPL:", ""]
        rows = []
        for i, a in enumerate(monitors):
            for b in monitors[i + 1:]:
                va = _keyed(e, a)
                vb = _keyed(e, b)
                keys = sorted(set(va) & set(vb))
                r = np.array([va[k] / vb[k] for k in keys])
                r = r[np.isfinite(r)]
                if r.size:
                    q = np.percentile(r, [50, 5, 95])
                    rows.append([a, b, r.size, f"{q[0]:.3f}", f"{q[1]:.3f}", f"{q[2]:.3f}"])
        md += md_table(["monitor A", "monitor B", "epochs", "VPL_A / VPL_B median", "5 %", "95 %"], rows)
        md.append("")
    return md, []


def _paired_row(tc: dict, level: str, a: str, b: str) -> list:
    """One row of the paired table: monitors ``a`` and ``b`` at ``level`` (trials matched by cell and trial)."""
    sa, sb = tc["monitor"] == a, tc["monitor"] == b
    ka = np.lexsort((tc["trial"][sa], tc["cell"][sa]))
    kb = np.lexsort((tc["trial"][sb], tc["cell"][sb]))
    a_only = tc[f"only_available_vs_{b}_{level}"][sa][ka]
    b_only = tc[f"only_available_vs_{a}_{level}"][sb][kb]
    more, less = int((a_only > b_only).sum()), int((a_only < b_only).sum())
    fa, fb = int(tc[f"four_sat_avail_{level}"][sa].sum()), int(tc[f"four_sat_avail_{level}"][sb].sum())
    return [level, a, b, int(tc["epochs"][sa].sum()), int(a_only.sum()), int(b_only.sum()),
            f"{mcnemar_p(int(a_only.sum()), int(b_only.sum())):.2g}", more, less, f"{mcnemar_p(more, less):.2g}",
            int(tc["four_sat_epochs"][sa].sum()), fa, fb]


def _keyed(e: dict, monitor: str) -> dict:
    sel = e["monitor"] == monitor
    return {(int(c), int(tr), round(float(t), 6)): float(v)
            for c, tr, t, v in zip(e["cell"][sel], e["trial"][sel], e["t"][sel], e["vpl"][sel])}


def _median_p95_max(x: np.ndarray) -> tuple[float, float, float]:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if not x.size:
        return float("nan"), float("nan"), float("nan")
    return float(np.median(x)), float(np.percentile(x, 95)), float(x.max())


MAX_PANELS = 4  # settings per PL-over-time figure (more settings: more figures)


def _pl_time_section(inp: ReportInputs) -> tuple[list[str], list[tuple[str, str]]]:
    """Section: HPL/VPL over time, median and 5-95 % across trials; small multiples, one column per
    setting, every monitor of it in the panel (GPS RAIM the reference), the alert limit dashed."""
    figures: list[tuple[str, str]] = []
    cells, varying, figdir = inp.cells, inp.varying, inp.figdir
    epochs, hal, val = inp.epochs, inp.hal, inp.val
    if epochs is None or not epochs.num_rows:
        return [], figures
    ec = _cols(epochs)
    nofault = {c["cell"] for c in cells if c["fault_kind"] == "none"}
    use = np.isin(ec["cell"], list(nofault)) if nofault else np.ones(len(ec["cell"]), bool)
    setting = np.array([_setting_label(cells[i], varying) for i in ec["cell"]])
    groups = sorted(set(setting[use].tolist()))
    monitors = sorted(set(ec["monitor"][use].tolist()), key=lambda m: (m != "gps_raim", m))
    colours = {m: f"C{k}" for k, m in enumerate(monitors)}
    for part in range(0, len(groups), MAX_PANELS):
        gs = groups[part:part + MAX_PANELS]
        fig, axs = _figure(2, len(gs), figsize=(3.2 * len(gs) + 1.5, 6.4), sharex=True, sharey="row", squeeze=False)
        for j, g in enumerate(gs):
            for row, (key, al) in enumerate((("hpl", hal), ("vpl", val))):
                ax = axs[row][j]
                for m in monitors:
                    s = use & (setting == g) & (ec["monitor"] == m)
                    if not s.any():
                        continue
                    tt, q = _quantiles_over_time(ec["t"][s], ec[key][s])
                    ax.plot(tt, q[:, 1], lw=1.2, color=colours[m], label=m)
                    ax.fill_between(tt, q[:, 0], q[:, 2], color=colours[m], alpha=0.18, lw=0)
                ax.axhline(al, color="r", lw=0.8, ls="--")
                ax.grid(alpha=0.3)
                if j == 0:
                    ax.set_ylabel(f"{key.upper()} (m); {key[0].upper()}AL {al:g} m dashed")
                if row == 0:
                    n_tr = len({(c, t) for c, t in zip(ec["cell"][use & (setting == g)], ec["trial"][use & (setting == g)])})
                    ax.set_title(f"{g}\n({n_tr} sorties)", fontsize=8)
                else:
                    ax.set_xlabel("time since approach start (s)")
        axs[0][-1].legend(fontsize=7, loc="upper right")
        fig.suptitle("HPL / VPL over time: median and 5-95 % across the stored sorties"
                     + (" (fault-free cells)" if nofault else ""), fontsize=10)
        name = "pl_time.png" if part == 0 else f"pl_time_{part // MAX_PANELS + 1}.png"
        _save(fig, figdir / name)
        figures.append(("HPL/VPL over time" + ("" if part == 0 else f" ({part // MAX_PANELS + 1})"), name))
    return [], figures


def _quantiles_over_time(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(epochs, (T, 3) 5/50/95 % of the finite values at each epoch)."""
    tt = np.unique(t)
    q = np.full((tt.size, 3), np.nan)
    for i, ti in enumerate(tt):
        x = v[t == ti]
        x = x[np.isfinite(x)]
        if x.size:
            q[i] = np.percentile(x, [5, 50, 95])
    return tt, q


def _vision_range_section(inp: ReportInputs) -> tuple[list[str], list[tuple[str, str]]]:
    """Section: vision-range error, raw and calibrated."""
    md: list[str] = []
    figures: list[tuple[str, str]] = []
    cells, figdir = inp.cells, inp.figdir
    tc, trials = inp.tc, inp.trials
    # ---- vision-range error
    if "vre_raw_n" in tc:
        bt = int(inp.man["spec"].get("block_trials") or 0) or None
        vr = vision_range_error_table(cells, trials, bt)
        if vr:
            _save(vision_range_figure(vr), figdir / "vision_range_error.png")
            figures.append(("Vision-range error", "vision_range_error.png"))
            md += ["## Vision-range error (VA-RAIM; error = estimated - true camera-landmark range)", ""]

            def mean_se(r: dict, tag: str) -> str:
                se = r.get(f"{tag}_se", float("nan"))
                return _f(r[f"{tag}_mean"], "{:.3f}") + ("" if not np.isfinite(se) else f" ± {se:.3f}")

            md += md_table(["cell", "dpi", "DE px", "LPE m", "cal mode", "raw mean ± se", "raw sd", "calibrated mean ± se",
                            "calibrated sd", "surveys"],
                           [[r["cell"], f"{r['dpi']:g}", f"{r['sigma_px']:g}", f"{r['lpe_sigma_m']:g}", r["calibration"],
                             mean_se(r, "raw"), _f(r["raw_std"], "{:.3f}"), mean_se(r, "cal"), _f(r["cal_std"], "{:.3f}"),
                             r.get("raw_surveys", "")] for r in vr])
            md += ["", "se: standard error of the mean with the landmark surveys as the independent units (one survey "
                   f"per block of {bt} sorties: every epoch of a block carries its survey's bias, so the epochs' "
                   "sd/√N would understate it; `report.clustered_mean_se`). sd: the spread of single errors.", ""]
    return md, figures


#: the axes a vision-range figure may plot against (the first is the default with none swept)
VISION_RANGE_AXES = ("lpe_sigma_m", "dpi", "sigma_px")


def vision_range_figure(vr: list[dict]):
    """The vision-range error's mean ± 1 sd per cell of :func:`vision_range_error_table`, a panel per swept
    axis (LPE, dpi, detection error), a series per setting of the others.

    The fault-free cells when there are some (a fault moves the errors it is about), else every cell. Each
    series says what the spec made of it: ``raw ranges (before GPS calibration)`` and ``after GPS
    calibration`` where the cells calibrate (with a note where no epoch was calibrated), ``raw ranges
    (uncalibrated: calibration = none)`` where they do not. A panel whose axis takes one value places its
    settings side by side as categories, named on the axis, instead of a window of a few thousandths
    around one point."""
    free = [r for r in vr if r.get("fault_kind") == "none"]
    rows = free or vr
    vary = lambda a: len({r[a] for r in rows}) > 1  # noqa: E731
    vaxes = [a for a in VISION_RANGE_AXES if vary(a)] or [VISION_RANGE_AXES[0]]
    fig, axs = _figure(1, len(vaxes), figsize=(5.6 * len(vaxes), 4.6), squeeze=False)
    for ax, a in zip(axs[0], vaxes):
        others = [b for b in (*VISION_RANGE_AXES, "calibration") if b != a and vary(b)]
        grp: dict[str, list] = {}
        for r in rows:
            grp.setdefault(", ".join(f"{AXIS_LABEL[b]} {r[b]:g}" if isinstance(r[b], float) else f"{AXIS_LABEL[b]} {r[b]}"
                                     for b in others), []).append(r)
        values = sorted({r[a] for r in rows})
        categorical = len(values) == 1
        # the series side by side around each x (common random numbers make some coincide): a small dodge,
        # raw and calibrated about each category, or every series about each swept value
        n_series = 2 if categorical else 2 * len(grp)
        dodge = (0.25 if categorical else 0.06 * (values[-1] - values[0])) / n_series
        uncalibrated = []
        for k, (g, rs) in enumerate(sorted(grp.items())):
            rs = sorted(rs, key=lambda r: r[a])
            x = np.array([k if categorical else r[a] for r in rs], float)
            modes = {r["calibration"] for r in rs}
            raw = ("raw ranges (before GPS calibration)" if modes == {"gps"} else
                   "raw ranges (uncalibrated: calibration = none)" if modes == {"none"} else "raw ranges")
            for j, (tag, mk, label) in enumerate((("raw", "o--", raw), ("cal", "s-", "after GPS calibration"))):
                mu = np.array([r[f"{tag}_mean"] for r in rs], float)
                sd = np.array([r[f"{tag}_std"] for r in rs], float)
                shift = ((j if categorical else 2 * k + j) - (n_series - 1) / 2) * dodge
                if np.isfinite(mu).any():
                    ax.errorbar(x + shift, mu, yerr=sd, fmt=mk, ms=4, capsize=3, label=f"{label}{', ' + g if g else ''}")
                elif tag == "cal" and "gps" in modes:
                    uncalibrated.append(g or "every cell")
        if uncalibrated:
            ax.text(0.02, 0.02, "GPS calibration set, but no epoch was calibrated: " + "; ".join(uncalibrated),
                    transform=ax.transAxes, fontsize=7, va="bottom", wrap=True)
        if categorical:
            ax.set_xticks(range(len(grp)), [g or "all cells" for g in sorted(grp)], fontsize=7)
            ax.set_xlim(-0.6, len(grp) - 0.4)
            ax.set_xlabel(f"{AXIS_LABEL[a]} = {values[0]:g} (one value)")
        else:
            ax.set_xlabel(AXIS_LABEL[a])
        ax.set_ylabel("vision-range error (m): mean ± 1 sd")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:  # (no vision ranges at all: nothing to label)
            ax.legend(fontsize=6)
    fig.suptitle("vision-range error (VA-RAIM) vs " + ", ".join(AXIS_LABEL[a] for a in vaxes)
                 + (", fault-free cells" if free else ""))
    return fig


def _index_lines(inp: ReportInputs, figures: list[tuple[str, str]]) -> list[str]:
    """The figure index and the per-cell detection table."""
    varying, det_rows = inp.varying, inp.det_rows
    md: list[str] = []
    md += ["## Figures", ""]
    for title, name in figures:
        md += [f"### {title}", "", f"![{title}](figures/{name})", ""]
    if inp.weighted:  # the per-cell counts are the proposal's, not rates
        return md
    md += ["## Detection rates per cell", "",
           "Per sortie: detected among the sorties that exercised the fault; \"not exercised\": sorties in which no "
           "epoch carried the fault while the monitor gave a solution (out of the rate, not missed).", ""]
    md += md_table(["cell", "monitor", "fault", "size", *(AXIS_LABEL[a] for a in varying), "trials", "not exercised",
                    "detected", "rate", "interval"],
                   [[r["cell"], r["monitor"], r["fault_sweep_kind"], f"{r['fault_size']:g} {r['fault_unit']}",
                     *(r[a] for a in varying), r["n"], r["not_exercised"], r["k"], _f(r["rate"], "{:.4f}"),
                     f"[{r['lo']:.4f}, {r['hi']:.4f}]" if r["n_ex"] else "not exercised"] for r in det_rows])
    return md




def vision_range_error_table(cells: list[dict], trials, block_trials: int | None = None) -> list[dict]:
    """Pooled vision-range error per cell (rows of monitors that report it): mean and sd, raw and calibrated.

    With ``block_trials`` also the mean's standard error with the landmark surveys as the independent
    units (``{tag}_se``, ``{tag}_surveys``): a campaign draws one survey per block, and every epoch of a
    block carries that survey's bias, so epochs are not independent draws of the mean —
    :func:`clustered_mean_se`.
    """
    tc = _cols(trials, ["cell", "trial"] + [f"vre_{tag}_{x}" for tag in ("raw", "cal") for x in ("n", "sum", "sumsq")])
    sel = np.isfinite(np.asarray(tc["vre_raw_n"], float))
    out = []
    for c in cells:
        s = sel & (tc["cell"] == c["cell"])
        if not s.any():
            continue
        row = dict(c)
        for tag in ("raw", "cal"):
            n_t = np.nan_to_num(tc[f"vre_{tag}_n"][s].astype(float))
            sum_t = np.nan_to_num(tc[f"vre_{tag}_sum"][s].astype(float))
            n, sm = n_t.sum(), sum_t.sum()
            sq = np.nansum(tc[f"vre_{tag}_sumsq"][s].astype(float))
            mu = sm / n if n > 0 else float("nan")
            row[f"{tag}_mean"] = mu
            row[f"{tag}_std"] = float(np.sqrt(max(sq / n - mu**2, 0.0))) if n > 0 else float("nan")
            row[f"{tag}_n"] = int(n)
            if block_trials:
                row[f"{tag}_se"], row[f"{tag}_surveys"] = clustered_mean_se(
                    np.asarray(tc["trial"][s], np.int64) // block_trials, n_t, sum_t)
        out.append(row)
    return out


def clustered_mean_se(cluster: np.ndarray, n: np.ndarray, total: np.ndarray) -> tuple[float, int]:
    """Standard error of the pooled mean Σtotal/Σn with clusters (here landmark surveys) as the independent
    units, and the number of clusters with data: the ratio estimator's sandwich variance
    ``G/(G−1) · Σ_g (t_g − m·n_g)² / (Σn)²`` over the G clusters (NaN with fewer than two).

    Pooled epochs are not independent when each cluster shares an error (a survey's bias): the
    naive sd/√N then understates the error of the mean by √(1 + (N/G − 1)·ρ)."""
    _, inv = np.unique(cluster, return_inverse=True)
    n_g, t_g = np.bincount(inv, weights=n), np.bincount(inv, weights=total)
    keep = n_g > 0
    n_g, t_g = n_g[keep], t_g[keep]
    G, N = int(n_g.size), float(n_g.sum())
    if G < 2:
        return float("nan"), G
    m = t_g.sum() / N
    return float(np.sqrt(G / (G - 1) * np.sum((t_g - m * n_g) ** 2)) / N), G


def _f(x: float, fmt: str) -> str:
    return "-" if x is None or x != x else fmt.format(x)

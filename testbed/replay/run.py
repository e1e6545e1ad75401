"""``testbed monitor OBS NAV``: the integrity monitors on a recorded RINEX file.

:func:`monitor_rinex` checks every input and output before any work, reads
the files, forms the pseudoranges (:mod:`testbed.rinex.observables`), runs
GPS RAIM (with FDE by default) over every epoch in blocks, and writes what a
flight writes: a per-epoch table, a summary, a Rerun recording with the
flight's layout and, when a reference trajectory is given, the position
errors, the Stanford regions and Stanford diagrams. Nothing is written
unless asked for; what is asked for (``--out``'s files and ``--rrd``) is
committed together at the end (:mod:`testbed.outputs`).
"""

from __future__ import annotations

import json
import time
import warnings
from typing import Any, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from testbed.config import read_toml, validate
from testbed.frames import C_LIGHT, LocalFrame, ecef_to_geodetic
from testbed.integrity.monitor import MonitorContext, Observations
from testbed.monitors import build_monitor, monitor_inputs, monitor_names, options_tables
from testbed.outputs import OutputSet
from testbed.records import GnssEpochs, MonitorOutput, NotVisible, concat_epochs, take_epochs
from testbed.rinex.obs import RinexObs, read_obs
from testbed.rinex.observables import Formation, form_epochs
from testbed.rinex.settings import MonitorFileConfig
from testbed.schema import ConfigError
from testbed.sensors.gnss.navfile import read_nav
from testbed.sensors.gnss.orbits import SYSTEM_NAMES
from testbed.sensors.gnss.timebase import SECONDS_PER_WEEK, gps_seconds_to_calendar
from testbed.sim.evaluate import MonitorSummary, summarise_monitor
from testbed.viz.stanford import hist_edges, stanford_figure

TABLE_SUFFIXES = (".parquet", ".csv")
REFERENCE_SUFFIXES = (".csv", ".parquet", ".npz")
#: epochs per monitor block: bounds the memory of a day-long file (the monitors are batched)
BLOCK_EPOCHS = 3600


@dataclass
class RinexRun:
    """What ``testbed monitor`` computed (the Python API's result)."""

    obs: RinexObs
    gnss: GnssEpochs
    formation: Formation
    frame: LocalFrame
    outputs: dict[str, MonitorOutput]
    summaries: dict[str, MonitorSummary] = field(default_factory=dict)  # with a reference only
    reference_enu: np.ndarray | None = None  # (E, 3) reference antenna position at the epochs
    timings: dict[str, float] = field(default_factory=dict)
    written: list[Path] = field(default_factory=list)


def load_config(path: str | Path | None) -> MonitorFileConfig:
    if path is None:
        return MonitorFileConfig()
    p = Path(path)
    cfg = validate(MonitorFileConfig, read_toml(p), p)
    validate(options_tables(), cfg.monitor, p, prefix="monitor.")  # each monitor's table, by its own model
    return cfg


def read_reference(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A reference trajectory: ``t_gps`` (s since the GPS epoch) and ``pos_ecef_x/y/z`` (m) columns.

    ``testbed export-rinex`` writes one beside its files (the true antenna positions). CSV (header row),
    Parquet or .npz.
    """
    p = Path(path)
    try:
        if p.suffix.lower() == ".npz":
            with np.load(p) as z:
                cols = {k: np.asarray(z[k], float) for k in z.files}
        elif p.suffix.lower() == ".parquet":
            import pyarrow.parquet as pq

            t = pq.read_table(p)
            cols = {k: t[k].to_numpy().astype(float) for k in t.column_names}
        else:
            with p.open() as fh:
                names = fh.readline().strip().split(",")
            with warnings.catch_warnings():  # a header alone: said below, as the other problems are
                warnings.simplefilter("ignore", UserWarning)
                data = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
            if data.size == 0 or data.shape[1] != len(names):
                raise ConfigError(p, [f"--reference: {data.shape[0] if data.size else 0} data rows of "
                                      f"{data.shape[1] if data.size else 0} columns under a header of {len(names)} "
                                      f"({', '.join(names)}); expected at least 2 rows, one value per column"])
            cols = {n: data[:, k] for k, n in enumerate(names)}
    except ConfigError:  # said above, as it is (a ConfigError is a ValueError too)
        raise
    except (OSError, ValueError) as exc:
        raise ConfigError(p, [f"--reference: cannot read the reference trajectory ({exc})"]) from None
    need = ("t_gps", "pos_ecef_x", "pos_ecef_y", "pos_ecef_z")
    missing = [n for n in need if n not in cols]
    if missing:
        raise ConfigError(p, [f"--reference: columns {missing} missing; expected {list(need)} (got {sorted(cols)})"])
    t = cols["t_gps"]
    pos = np.column_stack([cols[n] for n in need[1:]])
    problems = trajectory_problems(t, pos, need)
    if problems:
        raise ConfigError(p, ["--reference: " + q for q in problems])
    return t, pos


#: where a receiver on or above the Earth can be, m from its centre: the polar radius less the deepest dry
#: land (6356.75 km − 0.43 km) to the equatorial radius plus 100 km (the highest [rinex] origin)
ECEF_RADIUS_RANGE_M = (6.35e6, 6.48e6)


def _rows(bad: np.ndarray) -> str:
    """'row 7' or 'rows 7, 9 and 3 more' (1-based data rows, the header not counted)."""
    k = np.flatnonzero(bad) + 1
    head = ", ".join(str(int(r)) for r in k[:2])
    return f"row{'s' if k.size > 1 else ''} {head}" + (f" and {k.size - 2} more" if k.size > 2 else "")


def trajectory_problems(t: np.ndarray, pos: np.ndarray, names: tuple[str, str, str, str]) -> list[str]:
    """What makes (t, pos) not a trajectory: fewer than 2 rows, a time or a coordinate that is not a finite
    number, times that do not increase, positions not on or near the Earth; each names the column, the rows
    and the first value. Empty when it is one."""
    if t.size < 2:
        return [f"{t.size} row(s): expected at least 2 (a trajectory is interpolated between its rows)"]
    out = []
    for k, name in enumerate(names):
        col = t if k == 0 else pos[:, k - 1]
        bad = ~np.isfinite(col)
        if bad.any():
            out.append(f"{name} at {_rows(bad)} is {float(col[bad][0])!r}: expected a finite number in every row")
    dt = np.diff(t)
    back = np.concatenate([[False], np.isfinite(dt) & (dt <= 0)])
    if back.any():
        k = int(np.flatnonzero(back)[0])
        out.append(f"{names[0]} does not increase at {_rows(back)} ({float(t[k])!r} after {float(t[k - 1])!r}): "
                   f"expected strictly increasing times, one row per time")
    far = _off_earth(pos)
    if far.any():
        out.append(f"position at {_rows(far)} {_off_earth_text(pos[far][0])}")
    return out


def _off_earth(pos: np.ndarray) -> np.ndarray:
    """(N,) bool: finite ECEF positions (N, 3) outside :data:`ECEF_RADIUS_RANGE_M`."""
    r = np.linalg.norm(pos, axis=-1)
    return np.isfinite(r) & ((r < ECEF_RADIUS_RANGE_M[0]) | (r > ECEF_RADIUS_RANGE_M[1]))


def _off_earth_text(p: np.ndarray) -> str:
    lo, hi = ECEF_RADIUS_RANGE_M
    return (f"is {np.linalg.norm(p):.6g} m from the Earth's centre: expected ECEF metres of a point on or above the "
            f"Earth ({lo:.4g} to {hi:.4g} m from its centre; degrees, or a local frame?)")


#: ``--reference marker``: the header's APPROX POSITION XYZ as a static reference (a surveyed station)
MARKER = "marker"


def _marker_reference(obs: RinexObs) -> tuple[np.ndarray, np.ndarray]:
    if not np.any(obs.approx_pos_ecef):
        raise ConfigError(obs.path, ["--reference marker: the header has no APPROX POSITION XYZ (or it is 0 0 0); "
                                     "expected a surveyed marker position, or give a reference trajectory file"])
    t = np.array([obs.t_tag[0] - 1.0, obs.t_tag[-1] + 1.0])
    if _off_earth(obs.approx_pos_ecef[None]).any():
        raise ConfigError(obs.path, [f"--reference marker: the header's APPROX POSITION XYZ "
                                     f"{_off_earth_text(obs.approx_pos_ecef)}"])
    return t, np.tile(obs.approx_pos_ecef, (2, 1))


def _reference_at(t_ref: np.ndarray, pos_ref: np.ndarray, t_true: np.ndarray, path) -> np.ndarray:
    """The reference interpolated (linearly) to the epochs' true GPS times; an error if it does not cover them."""
    if t_true.min() < t_ref[0] - 1e-3 or t_true.max() > t_ref[-1] + 1e-3:
        raise ConfigError(path, [f"--reference: covers t_gps {t_ref[0]:.1f} .. {t_ref[-1]:.1f}, the observations "
                                 f"{t_true.min():.1f} .. {t_true.max():.1f}; expected a reference spanning them"])
    return np.column_stack([np.interp(t_true, t_ref, pos_ref[:, k]) for k in range(3)])


def out_entries(monitors: tuple[str, ...], table_format: str, reference: bool) -> tuple[str, ...]:
    """The files ``--out`` receives."""
    return (*(f"epochs-{m}.{table_format}" for m in monitors), "summary.json",
            *((f"stanford-{m}.png" for m in monitors) if reference else ()))


def check_monitors(monitors: tuple[str, ...], options: Mapping[str, Any] | None = None) -> None:
    """``--monitors``: registered monitors, each named once, each reading nothing but GNSS observations with its
    options from ``options`` (a RINEX file has no images, IMU or correlators); ConfigError naming the option
    otherwise."""
    problems = []
    if not monitors:
        problems.append("no monitor named; expected at least one")
    for name in monitors:
        if name not in monitor_names():
            problems.append(f"unknown monitor {name!r}; expected one of {list(monitor_names())}")
        elif monitor_inputs(name, options) != frozenset({"gnss"}):
            problems.append(f"{name!r} reads {sorted(monitor_inputs(name, options))} with its [monitor.{name}] "
                            f"options; a RINEX file has GNSS observations only (expected a monitor reading 'gnss' "
                            f"alone, e.g. gps_raim, araim without vision)")
    twice = sorted({m for m in monitors if monitors.count(m) > 1})
    if twice:
        problems.append(f"{twice} named more than once; expected each monitor once")
    if problems:
        raise ConfigError("--monitors", problems)


def _declare_outputs(outs: OutputSet, out_dir, rrd_path, table_format: str, monitors: tuple[str, ...],
                     reference: bool, options: Mapping[str, Any]) -> None:
    """Every output tried and compared before any work (ConfigError naming the option)."""
    check_monitors(monitors, options)
    if table_format not in ("parquet", "csv"):
        raise ConfigError("--format", [f"--format {table_format!r}: expected 'parquet' or 'csv'"])
    if out_dir is not None:
        outs.folder(out_dir, "--out", entries=out_entries(monitors, table_format, reference), complete=True)
    if rrd_path is not None:
        outs.file(rrd_path, "--rrd", (".rrd",))


def monitor_rinex(obs_path: str | Path, nav_path: str | Path, *, config: str | Path | MonitorFileConfig | None = None,
                  out_dir: str | Path | None = None, rrd_path: str | Path | None = None,
                  reference: str | Path | None = None, table_format: str = "parquet",
                  monitors: tuple[str, ...] = ("gps_raim",), outputs: OutputSet | None = None) -> RinexRun:
    """Run the monitors over a RINEX observation file (see the module doc). Raises ConfigError on bad input.

    outputs : the caller's :class:`~testbed.outputs.OutputSet` (the caller commits); by default the
        files are committed before this returns.
    """
    cfg = config if isinstance(config, MonitorFileConfig) else load_config(config)
    with OutputSet.using(outputs) as outs:
        _declare_outputs(outs, out_dir, rrd_path, table_format, monitors, reference is not None, cfg.monitor)
        return _monitor(obs_path, nav_path, cfg, out_dir, rrd_path, reference, table_format, monitors, outs)


def _monitor(obs_path, nav_path, cfg: MonitorFileConfig, out_dir, rrd_path, reference, table_format: str,
             monitors: tuple[str, ...], outs: OutputSet) -> RinexRun:
    marker = reference is not None and str(reference) == MARKER
    ref = read_reference(reference) if reference is not None and not marker else None
    tm: dict[str, float] = {}
    t0 = time.perf_counter()
    obs = read_obs(obs_path)
    if marker:
        ref = _marker_reference(obs)
    if ref is not None:  # before any work: the reference must cover the file's time tags
        _reference_at(*ref, obs.t_tag[[0, -1]], reference)
    nav = read_nav(nav_path)
    tm["read"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    gnss, formation = form_epochs(obs, nav, cfg.rinex)
    tm["form"] = time.perf_counter() - t1
    frame = LocalFrame(*formation.origin_lat_lon_h)
    ctx = MonitorContext(frame=frame, integrity=cfg.integrity, options=cfg.monitor)
    built = [build_monitor(m, ctx) for m in monitors]
    t2 = time.perf_counter()
    outputs = {}
    for mon in built:
        state, parts = mon.initial_state(), []
        for a in range(0, gnss.t.size, BLOCK_EPOCHS):
            blk = take_epochs(gnss, slice(a, a + BLOCK_EPOCHS))
            out, state = mon.step(Observations(blk, None, None, None, None), state)
            parts.append(out)
        outputs[mon.name] = concat_epochs(parts)
    tm["monitors"] = time.perf_counter() - t2
    run = RinexRun(obs=obs, gnss=gnss, formation=formation, frame=frame, outputs=outputs, timings=tm)
    if ref is not None:
        clock_m = outputs[built[0].name].clock  # the receiver clock: tag = true time + clock / c
        clk = np.where(np.isfinite(clock_m), clock_m, 0.0)
        run.reference_enu = frame.ecef_to_enu(_reference_at(*ref, obs.t_tag - clk / C_LIGHT, reference))
        run.summaries = {m: summarise_monitor(o, run.reference_enu, reference="antenna")
                         for m, o in outputs.items()}
    if out_dir is not None:
        run.written += write_outputs(run, Path(out_dir), table_format, outs)
    if rrd_path is not None:
        from testbed.replay.recording import write_recording

        write_recording(run, outs.staged(rrd_path))
        run.written.append(Path(rrd_path))
    return run


def epoch_table(run: RinexRun, name: str) -> dict[str, np.ndarray]:
    """Per-epoch columns of one monitor's output (position in the run's frame and geodetic)."""
    out, g = run.outputs[name], run.gnss
    week = np.floor(g.t_gps / SECONDS_PER_WEEK)
    ecef = run.frame.enu_to_ecef(out.pos_enu)
    lat, lon, h = ecef_to_geodetic(ecef)
    ex = np.asarray(out.excluded)
    cols = {"t_gps": g.t_gps, "gps_week": week, "tow_s": g.t_gps - week * SECONDS_PER_WEEK,
            "satellites_observed": (np.asarray(g.reason) != NotVisible.NOT_OBSERVED).sum(-1),
            "satellites_usable": np.asarray(g.visible).sum(-1), "n_used": out.n_used,
            "lat_deg": lat, "lon_deg": lon, "h_m": h, "e_m": out.pos_enu[:, 0], "n_m": out.pos_enu[:, 1],
            "u_m": out.pos_enu[:, 2], "clock_m": out.clock, "hpl_m": out.hpl, "vpl_m": out.vpl,
            "test_stat": out.test_stat, "threshold": out.threshold, "alert": out.alert,
            "excluded_prn": np.where(ex >= 0, np.asarray(g.prn)[np.clip(ex, 0, None)], -1), "reason": out.reason}
    if run.formation.systems != ("G",):  # a PRN names a satellite only with its system
        system = np.asarray(run.obs.system)
        cols["excluded_system"] = np.where(ex >= 0, system[np.clip(ex, 0, None)], "")
    for k, lv in enumerate(out.service_levels):
        cols[f"available_{lv}"] = out.available[:, k]
    cols.update(out.own_epoch_columns(cols))
    if run.reference_enu is not None:
        d = out.pos_enu - run.reference_enu
        cols.update({"err_e_m": d[:, 0], "err_n_m": d[:, 1], "err_u_m": d[:, 2]})
    return cols


def _write_table(cols: dict[str, np.ndarray], path: Path) -> Path:
    if path.suffix == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        pq.write_table(pa.table({k: np.asarray(v) for k, v in cols.items()}), path)
    elif all(np.asarray(v).dtype.kind != "U" for v in cols.values()):
        names = list(cols)
        np.savetxt(path, np.column_stack([np.asarray(cols[n], float) for n in names]), delimiter=",",
                   header=",".join(names), comments="", fmt="%.12g")
    else:  # text columns (a satellite's system letter) beside the numbers
        names = list(cols)
        text = [np.asarray(cols[n]) if np.asarray(cols[n]).dtype.kind == "U"
                else np.char.mod("%.12g", np.asarray(cols[n], float)) for n in names]
        path.write_text(",".join(names) + "\n" + "".join(",".join(r) + "\n" for r in zip(*text)))
    return path


def summary_record(run: RinexRun) -> dict:
    """The summary as plain data (what ``summary.json`` holds and the console prints)."""
    f, o = run.formation, run.obs
    rec = {"observation_file": str(o.path), "rinex_version": o.version, "epochs": o.epochs,
           "first_epoch": f"{gps_seconds_to_calendar(float(o.t_tag[0])):%Y-%m-%d %H:%M:%S} GPST",
           "last_epoch": f"{gps_seconds_to_calendar(float(o.t_tag[-1])):%Y-%m-%d %H:%M:%S} GPST",
           "gps_satellites": int(o.prn.size), "l1_code": f.l1_code, "second_code": f.second_code,
           "ionosphere": f.ionosphere, "troposphere": f.troposphere, "error_model": f.error_model,
           "measurements": f.counts, "skipped": o.skipped, "notes": list(f.notes),
           "frame_origin_lat_lon_h": list(f.origin_lat_lon_h), "timings_s": run.timings, "monitors": {}}
    if o.systems != ("G",):  # a file with Galileo / BeiDou satellites: which systems were used, which not and why
        rec["gps_satellites"] = int((o.system == "G").sum())
        rec.update({"systems_used": list(f.systems), "systems_skipped": f.skipped_systems,
                    "satellites": {x: int((o.system == x).sum()) for x in o.systems}, "codes": f.codes,
                    "second_codes": f.second_codes})
    for name, out in run.outputs.items():
        m = {"availability": {lv: float(np.mean(out.available[:, k])) for k, lv in enumerate(out.service_levels)},
             "alert_epochs": int(np.sum(out.alert)), "excluded_epochs": int(np.sum(np.asarray(out.excluded) >= 0)),
             "no_solution_epochs": int(np.sum(~np.isfinite(out.hpl))),
             "reasons": {out.reasons[k]: int(np.sum(out.reason == k)) for k in np.unique(out.reason)},
             "reason_codes": list(out.reasons)}  # the epochs table's reason column: an index into these
        own = out.diagnostics.summary_rows() if out.diagnostics is not None else {}
        if own:  # a monitor's own rows (ARAIM's EMT, σ_acc,v and fault modes over the file)
            m["own"] = own
        for pl in ("hpl", "vpl"):
            x = np.asarray(getattr(out, pl), float)
            x = x[np.isfinite(x)]
            m[pl] = ({"median": float(np.median(x)), "p95": float(np.percentile(x, 95)), "max": float(x.max())}
                     if x.size else None)
        s = run.summaries.get(name)
        if s is not None:
            m.update({"hpe95_m": s.hpe95, "vpe95_m": s.vpe95, "mi_epochs": s.mi_epochs, "hmi_epochs": s.hmi_epochs,
                      "regions_h": s.regions_h, "regions_v": s.regions_v})
        rec["monitors"][name] = m
    return rec


def write_outputs(run: RinexRun, out_dir: Path, table_format: str, outs: OutputSet) -> list[Path]:
    """``--out``'s files, staged in ``outs`` (which declares ``out_dir``); returns their final paths."""
    written = []
    for name in run.outputs:
        p = out_dir / f"epochs-{name}.{table_format}"
        _write_table(epoch_table(run, name), outs.staged(p))
        written.append(p)
    js = out_dir / "summary.json"
    outs.staged(js).write_text(json.dumps(summary_record(run), indent=1, default=float))
    written.append(js)
    if run.reference_enu is not None:
        written += stanford_figures(run, out_dir, outs)
    return written


def stanford_figures(run: RinexRun, out_dir: Path, outs: OutputSet) -> list[Path]:
    """Horizontal and vertical Stanford diagrams per monitor against the reference (most demanding level)."""
    from testbed.integrity.levels import strictest_limits
    from testbed.sim.evaluate import position_errors, stanford_regions

    edges = hist_edges()
    paths = []
    for name, out in run.outputs.items():
        hal, val = strictest_limits(out.service_levels)
        he, ve = position_errors(out, run.reference_enu)
        panels = []
        for dim, e, pl, al in (("H", he, out.hpl, hal), ("V", ve, out.vpl, val)):
            reg = stanford_regions(e, pl, al, out.alert)
            counts = {k: int(v.sum()) for k, v in reg.items()}
            keep = np.isfinite(e) & np.isfinite(pl) & ~np.asarray(out.alert, bool)
            H, _, _ = np.histogram2d(np.clip(e[keep], edges[0], edges[-1] * 0.999),
                                     np.clip(np.asarray(pl)[keep], edges[0], edges[-1] * 0.999), bins=[edges, edges])
            panels.append((dim, H, counts, int(e.size), al))
        fig = stanford_figure(name, panels, edges, f"{run.obs.path.name}: {name} against the reference (per epoch)")
        fig.tight_layout()
        p = out_dir / f"stanford-{name}.png"
        fig.savefig(outs.staged(p), dpi=110)
        paths.append(p)
    return paths


def print_summary(run: RinexRun) -> None:
    from rich.console import Console
    from rich.table import Table

    rec = summary_record(run)
    t = Table(title=f"{run.obs.path.name}: {rec['epochs']} epochs, {rec['first_epoch']} .. {rec['last_epoch']}",
              show_header=False)
    t.add_row("pseudoranges", f"{rec['l1_code']}{' + ' + rec['second_code'] + ' (iono-free)' if rec['second_code'] else ''}"
                              f", ionosphere {rec['ionosphere']}, troposphere {rec['troposphere']}, σ model "
                              f"{rec['error_model']}")
    if "systems_used" in rec:
        used = ", ".join(f"{SYSTEM_NAMES[x]} ({rec['satellites'][x]} satellites, {rec['codes'][x]}"
                         f"{' + ' + rec['second_codes'][x] if x in rec['second_codes'] else ''})"
                         for x in rec["systems_used"])
        t.add_row("systems used", used + (", one receiver clock per system" if len(rec["systems_used"]) > 1 else ""))
        for x, why in rec["systems_skipped"].items():
            t.add_row(f"{SYSTEM_NAMES[x]} skipped", why)
    t.add_row("measurements", ", ".join(f"{k.lower().replace('_', ' ')} {v}" for k, v in rec["measurements"].items()))
    if rec["skipped"]:
        t.add_row("skipped", ", ".join(f"{k} {v}" for k, v in rec["skipped"].items()))
    for n in rec["notes"]:
        t.add_row("note", n)
    tm = rec["timings_s"]
    t.add_row("time", f"read {tm['read']:.2f} s, form {tm['form']:.2f} s, monitors {tm['monitors']:.2f} s")
    for name, m in rec["monitors"].items():
        av = ", ".join(f"{k} {100 * v:.1f} %" for k, v in m["availability"].items())
        t.add_row(f"{name} availability", av)
        pls = "; ".join(f"{pl.upper()} median {m[pl]['median']:.1f} / 95 % {m[pl]['p95']:.1f} / max {m[pl]['max']:.1f} m"
                        for pl in ("hpl", "vpl") if m[pl])
        t.add_row(f"{name} PLs", pls or "none (no epoch had a solution)")
        t.add_row(f"{name} detection", f"{m['alert_epochs']} alert epochs, {m['excluded_epochs']} with an exclusion, "
                                       f"{m['no_solution_epochs']} without PLs")
        for label, text in m.get("own", {}).items():
            t.add_row(f"{name} {label}", text)
        if "hpe95_m" in m:
            t.add_row(f"{name} vs reference", f"HPE95 {m['hpe95_m']:.2f} m, VPE95 {m['vpe95_m']:.2f} m, MI "
                                              f"{m['mi_epochs']}, HMI {m['hmi_epochs']}")
    Console().print(t)
    for p in run.written:
        print(f"wrote {p}")


def geometry_enu(run: RinexRun) -> tuple[np.ndarray, np.ndarray]:
    """(antenna (E, 3), unit lines of sight (E, S, 3)) in the run's frame, from the reference when given,
    else from the preliminary fix (for the recording's 3D view)."""
    ant = run.reference_enu if run.reference_enu is not None else run.frame.ecef_to_enu(run.formation.fix_ecef)
    sat = run.frame.ecef_to_enu(run.gnss.sat_pos_ecef)
    los = sat - ant[:, None, :]
    with np.errstate(invalid="ignore"):
        los = los / np.linalg.norm(los, axis=-1, keepdims=True)
    return ant, los


__all__ = ["RinexRun", "epoch_table", "load_config", "monitor_rinex", "print_summary", "read_reference",
           "summary_record"]

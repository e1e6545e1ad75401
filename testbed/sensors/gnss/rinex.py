"""RINEX 3 export of a synthesized flight, and an RTKLIB single-point check.

:func:`write_rinex` writes an observation file and a matching navigation file
whose broadcast records reproduce the orbits the synthesis used (the
constellation re-referenced to toe = toc on a 2-hour grid so that every epoch
is within RTKLIB's ±2 h validity; the rebasing is exact for the IS-GPS-200
model, see :meth:`Ephemeris.rebased`). A GPS-only flight gives RINEX 3.04 GPS
files (C1C, D1C, S1C), unchanged; a flight with Galileo or BeiDou satellites
gives RINEX 3.05 mixed files: Galileo E1 (``C1C D1C S1C``, the E1-C pilot),
BeiDou B1C (``C1P D1P S1P``, the B1C pilot; ``beidou_signal="B1I"`` writes
``C2I D2I S2I``), with Galileo (E) and BeiDou (C) broadcast records in their
own conventions and time scales (GST = GPST, BDT = GPST − 14 s; BeiDou GEO
satellites in the ICD's GEO form): :mod:`testbed.sensors.gnss.broadcast`.
The codes of every signal, the dual-frequency ones (L5 ``5Q``, E5a ``5Q``,
B2a ``5P``) included, are in :mod:`testbed.sensors.gnss.signals`.

What the observation file holds (and why):

* ``C1C`` = synthesized pseudorange − c·dtsv (a receiver measures
  c·(receiver clock time − satellite clock time), ρ = r + c·δt_rx − c·dtsv).
  Our pseudoranges are
  *iono-free-equivalent* residual ranges (seed eq. 27: geometric range +
  receiver clock + iono-free residual error); a real L1 receiver would also
  see the ionosphere and troposphere. So the export is the iono-free-equivalent
  range, and RTKLIB must run with ionosphere and troposphere models OFF
  (``pos1-ionoopt=off``, ``pos1-tropopt=off``, ``-sys G``): otherwise it would
  "correct" delays that are not there. The satellite clock (incl. the
  relativistic term) is put back because RTKLIB removes it using the nav
  file (zero for DO-229; TGD written 0).
* ``D1C`` = −(range rate − c·dṫsv)/λ_L1 (Hz; positive when approaching).
* ``S1C`` = C/N0 (dB-Hz) rising linearly in sin(elevation) between
  ``cn0_horizon_dbhz`` and ``cn0_zenith_dbhz``: a display/weighting value only.
* Epoch time tags are the *receiver's* clock time, true GPS time + δt_rx (as an
  unsteered receiver writes them; ``clock_bias_m`` = c·δt_rx): RTKLIB (and any
  reader) forms the transmit time as tag − C1C/c − Δt_sv, which is then the true
  one. (Tags without the clock put the transmit time off by δt_rx, which
  drifts to ~1 ms over hours: metres of satellite motion, issue 19.) The
  7-decimal tag (0.1 µs) moves a satellite by < 0.2 mm.
* Satellite clocks: the almanac's af0/af1 when any is non-zero; the DO-229
  almanac's are all zero, and then each satellite gets a fixed, realistic
  clock (af0 uniform in ±0.5 ms, af1 normal with σ 5e-12 s/s, drawn from a
  generator keyed by the PRN only, so every export of a constellation writes the
  same clocks). All-zero clocks trip RTKLIB 2.4.3 into de-weighting the first
  satellite of each epoch (issue 19).
* No phase observations, so no SYS / PHASE SHIFT or GLONASS header records.
* Galileo records: SISA 3.12 m, data sources 517 (I/NAV E1-B and E5b, clock for
  E5b/E1), both BGDs = TGD (0 for the nominal constellations). BeiDou records:
  URA 2 m, TGD1 = TGD, TGD2 = 0; AODE/AODC and IODnav count the records.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from testbed.correlation import L1_WAVELENGTH_M
from testbed.frames import C_LIGHT
from testbed.records import GnssEpochs
from testbed.sensors.gnss.broadcast import TIME_OFFSET_S, geo_record, is_bds_geo, to_broadcast
from testbed.sensors.gnss.orbits import SYSTEM_NAMES, Ephemeris, concat_ephemerides
from testbed.sensors.gnss.signals import FIRST_SIGNAL, SIGNALS, Signal
from testbed.sensors.gnss.synth import GnssGeometry
from testbed.sensors.gnss.timebase import SECONDS_PER_WEEK, gps_seconds_to_calendar, gps_seconds_to_utc, leap_seconds

LAMBDA_L1 = L1_WAVELENGTH_M
_TOE_GRID_S = 7200.0


def _hl(content: str, label: str) -> str:
    return f"{content:<60.60}{label:<20}\n"


def _pgm_line() -> str:
    now = datetime.now(timezone.utc).strftime("%Y%m%d %H%M%S UTC")
    return _hl(f"{'testbed':<20}{'testbed':<20}{now:<20}", "PGM / RUN BY / DATE")


def _d19(x: float) -> str:
    return f"{x:19.12E}"


def cn0_from_elevation(elevation: NDArray, horizon_dbhz: float = 35.0, zenith_dbhz: float = 50.0) -> NDArray:
    """C/N0 (dB-Hz) linear in sin(elevation): horizon value at 0°, zenith value at 90°."""
    return horizon_dbhz + (zenith_dbhz - horizon_dbhz) * np.clip(np.sin(elevation), 0.0, 1.0)


def _pick(a: NDArray, trial: int, ndim: int) -> NDArray:
    a = np.asarray(a)
    return a[trial] if a.ndim > ndim else a


#: a GEO-form record this close to a grid point is written as it is (within every reader's validity)
_GEO_AS_IS_S = 3600.0


def _records_at(eph: Ephemeris, toe_grid: float) -> Ephemeris:
    """``eph`` re-referenced to toe = toc on the grid point ``toe_grid`` of each system's own time scale
    (a BeiDou toe a whole BDT hour), BeiDou GEO satellites as GEO-form records; slot order kept. A GEO-form
    record (a navigation file's) within an hour of the grid point is written as it is: a re-fit would drop
    its harmonic terms."""
    geo = is_bds_geo(eph.system, eph.prn)
    toe = toe_grid - np.array([TIME_OFFSET_S[x] for x in eph.system])
    as_is = geo & eph.bds_geo & (np.abs(eph.toe_gps - toe) <= _GEO_AS_IS_S)
    parts, order = [], []
    for letter in sorted(set(eph.system.tolist())):
        for sel, build in ((~geo, lambda e, t: e.rebased(t)), (geo & ~as_is, geo_record), (as_is, lambda e, t: e)):
            idx = np.flatnonzero((eph.system == letter) & sel)
            if idx.size:
                parts.append(build(eph.take(idx), float(toe[idx[0]])))
                order.append(idx)
    out = concat_ephemerides(parts, source=eph.source)
    return out.take(np.argsort(np.concatenate(order), kind="stable"))


def _nav_rows(system: str, b: dict, g, k: int) -> list[list[float]]:
    """The 7 broadcast-orbit lines of one record (RINEX 3.05 §A.8: GPS Table A6, Galileo A8, BeiDou A14)."""
    if system == "G":
        iod = int(k % 256)
        return [[iod, g("crs"), b["delta_n"], g("m0")], [g("cuc"), g("e"), g("cus"), g("sqrt_a")],
                [b["toe_s"], g("cic"), b["omega0"], g("cis")], [g("i0"), g("crc"), g("w"), b["omega_dot"]],
                [g("idot"), 1.0, b["week_s"], 0.0],
                [2.0, g("health"), g("tgd"), iod],  # SV accuracy 2 m (URA index 0)
                [b["toe_s"], 4.0]]
    if system == "E":
        iod = int(k % 1024)
        return [[iod, g("crs"), b["delta_n"], g("m0")], [g("cuc"), g("e"), g("cus"), g("sqrt_a")],
                [b["toe_s"], g("cic"), b["omega0"], g("cis")], [g("i0"), g("crc"), g("w"), b["omega_dot"]],
                [g("idot"), 517.0, b["week_s"], 0.0],  # data sources: I/NAV E1-B + E5b, clock for E5b/E1
                [3.12, g("health"), g("tgd"), g("tgd")],  # SISA 3.12 m, BGD E5a/E1, BGD E5b/E1
                [b["toe_s"]]]
    iod = int(k % 32)
    return [[iod, g("crs"), b["delta_n"], g("m0")], [g("cuc"), g("e"), g("cus"), g("sqrt_a")],
            [b["toe_s"], g("cic"), b["omega0"], g("cis")], [g("i0"), g("crc"), g("w"), b["omega_dot"]],
            [g("idot"), 0.0, b["week_s"], 0.0],
            [2.0, g("health"), g("tgd"), 0.0],  # URA 2 m, SatH1, TGD1 (B1I/B3I), TGD2
            [b["toe_s"], iod]]  # transmission time, AODC


def write_nav(eph: Ephemeris, t_gps_span: tuple[float, float], path: str | Path) -> Path:
    """RINEX navigation file covering ``t_gps_span`` (records every 2 h per satellite).

    GPS only: RINEX 3.04 ``G``. With Galileo or BeiDou slots: RINEX 3.05 ``M`` (mixed), each record
    in its system's format and time scale (module doc).
    """
    t0, t1 = float(t_gps_span[0]), float(t_gps_span[1])
    toes = np.arange(np.round(t0 / _TOE_GRID_S), np.round(t1 / _TOE_GRID_S) + 1) * _TOE_GRID_S
    mixed = bool(np.any(eph.system != "G"))
    out = [_hl(f"{'3.05' if mixed else '3.04':>9}{'':11}{'N: GNSS NAV DATA':<20}"
               f"{'M: MIXED' if mixed else 'G: GPS':<20}", "RINEX VERSION / TYPE"),
           _pgm_line()]
    if mixed:
        week0 = int(toes[0] // SECONDS_PER_WEEK)
        sow0 = int(toes[0] - week0 * SECONDS_PER_WEEK)
        out += [_hl(f"GPGA{0.0:18.10E}{0.0:16.9E}{sow0:7d}{week0:5d}", "TIME SYSTEM CORR"),
                _hl("testbed: GST = GPST, BDT = GPST - 14 s exactly", "COMMENT")]
    out += [_hl(f"{leap_seconds(gps_seconds_to_utc(t0)):6d}", "LEAP SECONDS"), _hl("", "END OF HEADER")]
    for k, toe in enumerate(toes):
        e = _records_at(eph, toe) if mixed else eph.rebased(toe)
        bc = to_broadcast(e)
        for s in range(len(e)):
            g = lambda name: float(np.asarray(getattr(e, name))[s])  # noqa: E731
            b = {key: float(v[s]) for key, v in bc.items()}
            c = gps_seconds_to_calendar(b["toc_sys"])
            system = str(e.system[s])
            out.append(f"{system}{int(e.prn[s]):02d} {c.year:04d} {c.month:02d} {c.day:02d} {c.hour:02d} "
                       f"{c.minute:02d} {c.second:02d}{_d19(g('af0'))}{_d19(g('af1'))}{_d19(g('af2'))}\n")
            out += ["    " + "".join(_d19(v) for v in r) + "\n" for r in _nav_rows(system, b, g, k)]
    path = Path(path)
    path.write_text("".join(out))
    return path


#: seed words of the satellite clocks given to a constellation whose almanac has none
_SAT_CLOCK_WORDS = (0x5A7C10C5, 19)


def satellite_clocks(eph: Ephemeris) -> Ephemeris:
    """``eph`` with realistic satellite clocks when its af0/af1 are all zero (see the module doc), else itself.
    Each satellite's clock is drawn from a generator keyed by its system and PRN (GPS: by the PRN, as before)."""
    if np.any(np.asarray(eph.af0) != 0) or np.any(np.asarray(eph.af1) != 0):
        return eph
    def words(letter: str, p: int, *more: int) -> list[int]:  # GPS keeps its words of before: same clocks
        return [*_SAT_CLOCK_WORDS, int(p), *more] + ([] if letter == "G" else [2, ord(letter)])

    sats = list(zip(eph.system.tolist(), np.asarray(eph.prn, np.int64).tolist()))
    af0 = np.array([np.random.default_rng(words(x, p)).uniform(-5e-4, 5e-4) for x, p in sats])
    af1 = np.array([np.random.default_rng(words(x, p, 1)).normal(0.0, 5e-12) for x, p in sats])
    return replace(eph, af0=af0, af1=af1)


def export_signals(systems, beidou_signal: str = "B1C") -> dict[str, Signal]:
    """The signal written for each system letter in ``systems``: GPS L1, Galileo E1, BeiDou ``beidou_signal``."""
    if beidou_signal not in ("B1C", "B1I"):
        raise ValueError(f"beidou_signal: expected 'B1C' or 'B1I', got {beidou_signal!r}")
    first = {**FIRST_SIGNAL, "C": beidou_signal}
    return {x: SIGNALS[first[x]] for x in systems}


def write_rinex(gnss: GnssEpochs, geometry: GnssGeometry, out_dir: str | Path, *, clock_bias_m: NDArray,
                name: str = "testbed", trial: int = 0, cn0_horizon_dbhz: float = 35.0,
                cn0_zenith_dbhz: float = 50.0, beidou_signal: str = "B1C") -> tuple[Path, Path]:
    """Write ``<name>.obs`` (RINEX 3 observations) and ``<name>.nav`` into ``out_dir``.

    Parameters
    ----------
    gnss : synthesized observations (one trial is exported: ``trial`` of a batch).
    geometry : the :class:`GnssGeometry` they were drawn on (constellation, satellite
        clocks, elevations for C/N0) — the truth-side inputs of the export; its
        ``eph.system`` names each slot's system.
    clock_bias_m : (T,) or (B, T) the receiver clock c·δt_rx inside the ranges
        (``GnssTruth.clock_bias``): it goes into the time tags.
    beidou_signal : 'B1C' (``C1P``, the default: the single-frequency BeiDou-3 signal of the
        sensor layer) or 'B1I' (``C2I``): the label and the Doppler's wavelength.

    Returns
    -------
    (obs_path, nav_path)
    """
    out_dir = Path(out_dir)
    if gnss.pseudorange.ndim not in (2, 3):
        raise ValueError(f"gnss.pseudorange: expected shape (T, S) or (B, T, S), got {gnss.pseudorange.shape}")
    if gnss.pseudorange.ndim == 3 and not 0 <= trial < gnss.pseudorange.shape[0]:
        raise ValueError(f"trial: expected 0..{gnss.pseudorange.shape[0] - 1}, got {trial}")
    system = np.asarray(geometry.eph.system)
    if system.shape != np.shape(gnss.prn):
        raise ValueError(f"geometry.eph: {system.size} slots, the observations {np.size(gnss.prn)}; expected the "
                         f"geometry the observations were drawn on")
    present = [x for x in SYSTEM_NAMES if (system == x).any()]
    signals = export_signals(present, beidou_signal)
    out_dir.mkdir(parents=True, exist_ok=True)
    pr = _pick(gnss.pseudorange, trial, 2)
    rr = _pick(gnss.range_rate, trial, 2)
    vis = _pick(gnss.visible, trial, 2) & np.isfinite(pr)
    bias = _pick(clock_bias_m, trial, 1)
    if np.shape(bias) != pr.shape[:1] or not np.isfinite(bias).all():
        raise ValueError(f"clock_bias_m: expected {pr.shape[0]} finite values (one per epoch), got shape "
                         f"{np.shape(bias)}")
    eph = satellite_clocks(geometry.eph)
    # the drawn clocks on top of the geometry's (which hold the relativistic term) at each transmit time
    t_tx = np.asarray(geometry.t_gps, float)[:, None] - geometry.geometric_range / C_LIGHT
    extra = (np.asarray(eph.af0) - np.asarray(geometry.eph.af0)) + (
        np.asarray(eph.af1) - np.asarray(geometry.eph.af1)) * (t_tx - eph.toc_gps)
    extra_rate = np.asarray(eph.af1) - np.asarray(geometry.eph.af1)
    wavelength = np.array([C_LIGHT / signals[x].frequency_hz for x in system]) if present != ["G"] else LAMBDA_L1
    code = pr - C_LIGHT * (geometry.sat_clock_s + extra)
    doppler = -(rr - C_LIGHT * (geometry.sat_clock_rate + extra_rate)) / wavelength
    cn0 = cn0_from_elevation(geometry.elevation, cn0_horizon_dbhz, cn0_zenith_dbhz)
    t_gps = np.asarray(gnss.t_gps, float) + np.asarray(bias, float) / C_LIGHT  # receiver-clock time tags
    obs_path = out_dir / f"{name}.obs"
    write_obs(obs_path, t_gps, system, np.asarray(gnss.prn), vis,
              {x: {signals[x].observation("C"): code, signals[x].observation("D"): doppler,
                   signals[x].observation("S"): cn0} for x in present}, name=name)
    nav_path = write_nav(eph, (t_gps[0], t_gps[-1]), out_dir / f"{name}.nav")
    return obs_path, nav_path


def _obs_types_lines(columns: dict[str, dict[str, NDArray]]) -> list[str]:
    """SYS / # / OBS TYPES records (13 types a line, continuation lines indented)."""
    out = []
    for x, cols in columns.items():
        names = list(cols)
        for a in range(0, len(names), 13):
            head = f"{x}{len(names):5d}" if a == 0 else " " * 6
            out.append(_hl(head + "".join(f" {n}" for n in names[a:a + 13]), "SYS / # / OBS TYPES"))
    return out


def write_obs(path: Path, t_tag: NDArray, system: NDArray, prn: NDArray, visible: NDArray,
              columns: dict[str, dict[str, NDArray]], *, name: str = "testbed") -> Path:
    """A RINEX 3 observation file: epochs at receiver-clock tags ``t_tag`` (T,), satellites (``system``, ``prn``)
    (S,) where ``visible`` (T, S), observations per system letter {code: (T, S) values} in file order.

    One system: RINEX 3.04 of that system; several: RINEX 3.05 ``M`` (mixed).
    """
    mixed = len(columns) > 1
    c0 = gps_seconds_to_calendar(t_tag[0])
    interval = float(np.median(np.diff(t_tag))) if t_tag.size > 1 else 1.0
    head = [
        _hl(f"{'3.05' if mixed else '3.04':>9}{'':11}{'OBSERVATION DATA':<20}{'M' if mixed else next(iter(columns)):<20}",
            "RINEX VERSION / TYPE"),
        _pgm_line(),
        _hl(name.upper()[:60], "MARKER NAME"),
        _hl("AIRBORNE", "MARKER TYPE"),
        _hl(f"{'testbed':<20}{'synthetic':<40}", "OBSERVER / AGENCY"),
        _hl(f"{'0':<20}{'TESTBED SYNTHETIC':<20}{'1':<20}", "REC # / TYPE / VERS"),
        _hl(f"{'0':<20}{'UNKNOWN':<20}", "ANT # / TYPE"),
        _hl(f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}", "APPROX POSITION XYZ"),
        _hl(f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}", "ANTENNA: DELTA H/E/N"),
        *_obs_types_lines(columns),
        _hl("DBHZ", "SIGNAL STRENGTH UNIT"),
        _hl("testbed: C1C is an iono-free-equivalent range (no iono,", "COMMENT") if not mixed else
        _hl("testbed: code ranges are iono-free-equivalent (no iono,", "COMMENT"),
        _hl("tropo delay in it): solve with atmosphere models off", "COMMENT"),
        *([_hl("testbed: GPS time tags; each system's ranges may hold", "COMMENT"),
           _hl("an inter-system clock offset: solve one clock per", "COMMENT"),
           _hl("system; GST = GPST, BDT = GPST - 14 s exactly", "COMMENT")] if mixed else []),
        _hl(f"{interval:10.3f}", "INTERVAL"),
        _hl(f"{c0.year:6d}{c0.month:6d}{c0.day:6d}{c0.hour:6d}{c0.minute:6d}"
            f"{c0.second + c0.microsecond * 1e-6:13.7f}     GPS", "TIME OF FIRST OBS"),
        _hl(f"{leap_seconds(gps_seconds_to_utc(t_tag[0])):6d}", "LEAP SECONDS"),
        _hl("", "END OF HEADER"),
    ]
    body = []
    for k in range(t_tag.size):  # text output: one line per measurement, a loop is the honest form
        idx = np.flatnonzero(visible[k])
        minute = np.floor(t_tag[k] / 60.0) * 60.0  # the seconds from the float itself: 0.1 µs, not datetime's 1 µs
        if round(t_tag[k] - minute, 7) >= 60.0:
            minute += 60.0
        c = gps_seconds_to_calendar(minute)
        body.append(f"> {c.year:4d} {c.month:02d} {c.day:02d} {c.hour:02d} {c.minute:02d}"
                    f"{max(t_tag[k] - minute, 0.0):11.7f}  0{idx.size:3d}\n")
        for s in idx:
            body.append(f"{system[s]}{int(prn[s]):02d}" + "".join(f"{v[k, s]:14.3f}  "
                                                               for v in columns[system[s]].values()) + "\n")
    path.write_text("".join(head + body))
    return path


def rtklib_single_point(obs_path: str | Path, nav_path: str | Path, out_path: str | Path, *,
                        elevation_mask_deg: float = 5.0, raim_fde: bool = False, exe: str = "rnx2rtkp",
                        timeout_s: float = 120.0, systems: str = "G", residuals: bool = False) -> Path:
    """Run RTKLIB ``rnx2rtkp`` single-point positioning, iono/tropo models off.

    Options (written to ``<out>.conf`` and repeated on the command line):
    ``-p 0`` single, ``-m`` mask, ``-sys`` ``systems`` (letters among G, E, C; RTKLIB then estimates
    one clock offset per system besides GPS's), ``-e`` ECEF output, time GPST as
    week/TOW; ``pos1-ionoopt=off``, ``pos1-tropopt=off`` (see module doc),
    ``pos1-sateph=brdc``, ``pos1-posopt5`` = RAIM FDE on/off.
    ``residuals``: also write RTKLIB's per-satellite residuals (``<out>.pos.stat``, read by
    :func:`read_rtklib_residuals`).
    Returns the ``.pos`` path. Raises FileNotFoundError if ``exe`` is not on PATH.
    """
    bad = sorted(set(systems) - set(_RTKLIB_SYSTEM_BITS))
    if bad or not systems:
        raise ValueError(f"systems: expected letters among {sorted(_RTKLIB_SYSTEM_BITS)}, got {systems!r}")
    if shutil.which(exe) is None:
        raise FileNotFoundError(f"{exe}: not on PATH (install RTKLIB: apt-get install rtklib)")
    out_path = Path(out_path)
    conf = out_path.with_suffix(".conf")
    conf.write_text("\n".join([
        "pos1-posmode       =single", "pos1-frequency     =l1", f"pos1-elmask        ={elevation_mask_deg}",
        "pos1-ionoopt       =off", "pos1-tropopt       =off", "pos1-sateph        =brdc",
        f"pos1-posopt5       ={'on' if raim_fde else 'off'}",
        f"pos1-navsys        ={sum(_RTKLIB_SYSTEM_BITS[x] for x in set(systems))}",
        "out-solformat      =xyz", "out-timesys        =gpst", "out-timeform       =tow",
        "out-timendec       =3", *(["out-outstat        =residual"] if residuals else []), ""]))
    cmd = [exe, "-k", str(conf), "-p", "0", "-m", f"{elevation_mask_deg}", "-sys", ",".join(systems), "-e",
           "-o", str(out_path), str(obs_path), str(nav_path)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    if res.returncode != 0 or not out_path.exists():
        raise RuntimeError(f"{' '.join(cmd)} failed ({res.returncode}): {res.stderr.strip()[-500:]}")
    return out_path


#: RTKLIB's navigation-system bits (rtklib.h SYS_GPS, SYS_GAL, SYS_CMP)
_RTKLIB_SYSTEM_BITS = {"G": 1, "E": 8, "C": 32}


def read_rtklib_residuals(path: str | Path) -> dict[str, NDArray]:
    """RTKLIB's per-satellite solution status (``$SAT`` records of a ``.pos.stat`` file, residual level).

    Returns ``t_gps`` (N,), ``sat`` (N,) RINEX 3 ids, ``az_deg``, ``el_deg`` (N,), ``resp_m`` (N,) the
    pseudorange residual after the fix (RTKLIB's validity flag is for RTK modes: 0 in single-point).
    """
    rows = []
    for ln in Path(path).read_text().splitlines():
        if ln.startswith("$SAT,"):
            f = ln.split(",")
            rows.append((float(f[1]) * SECONDS_PER_WEEK + float(f[2]), f[3], float(f[5]), float(f[6]),
                         float(f[7])))
    t, sat, az, el, resp = zip(*rows) if rows else ((),) * 5
    return {"t_gps": np.array(t), "sat": np.array(sat, dtype="<U3"), "az_deg": np.array(az),
            "el_deg": np.array(el), "resp_m": np.array(resp)}


def read_rtklib_pos(path: str | Path) -> dict[str, NDArray]:
    """Parse an RTKLIB ``.pos`` file written with ECEF output and GPST week/TOW time tags.

    Returns ``t_gps`` (N,), ``pos_ecef`` (N, 3), ``q`` (N,) quality flag, ``ns`` (N,) satellites used,
    ``sd`` (N, 3) RTKLIB's own 1σ (m).
    """
    rows = []
    for ln in Path(path).read_text().splitlines():
        if not ln.strip() or ln.startswith("%"):
            continue
        f = ln.split()
        rows.append([float(v) for v in f[:10]])
    a = np.array(rows).reshape(-1, 10)
    return {"t_gps": a[:, 0] * SECONDS_PER_WEEK + a[:, 1], "pos_ecef": a[:, 2:5], "q": a[:, 5].astype(int),
            "ns": a[:, 6].astype(int), "sd": a[:, 7:10]}

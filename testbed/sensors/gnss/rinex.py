"""RINEX 3.04 export of a synthesized flight, and an RTKLIB single-point check.

:func:`write_rinex` writes a GPS observation file (C1C, D1C, S1C) and a
matching GPS navigation file whose broadcast records reproduce the orbits the
synthesis used (the constellation re-referenced to toe = toc on a 2-hour grid
so that every epoch is within RTKLIB's ±2 h validity; the rebasing is exact
for the IS-GPS-200 model, see :meth:`Ephemeris.rebased`).

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
from testbed.sensors.gnss.orbits import Ephemeris
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


def write_nav(eph: Ephemeris, t_gps_span: tuple[float, float], path: str | Path) -> Path:
    """RINEX 3.04 GPS navigation file covering ``t_gps_span`` (records every 2 h per satellite)."""
    _require_gps_only(eph, "write_nav")
    t0, t1 = float(t_gps_span[0]), float(t_gps_span[1])
    toes = np.arange(np.round(t0 / _TOE_GRID_S), np.round(t1 / _TOE_GRID_S) + 1) * _TOE_GRID_S
    out = [_hl(f"{'3.04':>9}{'':11}{'N: GNSS NAV DATA':<20}{'G: GPS':<20}", "RINEX VERSION / TYPE"),
           _pgm_line(),
           _hl(f"{leap_seconds(gps_seconds_to_utc(t0)):6d}", "LEAP SECONDS"),
           _hl("", "END OF HEADER")]
    for k, toe in enumerate(toes):
        e = eph.rebased(toe)
        c = gps_seconds_to_calendar(toe)
        iod = int(k % 256)
        for s in range(len(e)):
            g = lambda name: float(np.asarray(getattr(e, name))[s])  # noqa: E731
            rows = [
                [iod, g("crs"), g("delta_n"), g("m0")],
                [g("cuc"), g("e"), g("cus"), g("sqrt_a")],
                [g("toe_sow"), g("cic"), g("omega0"), g("cis")],
                [g("i0"), g("crc"), g("w"), g("omega_dot")],
                [g("idot"), 1.0, g("week"), 0.0],
                [2.0, g("health"), g("tgd"), iod],  # SV accuracy 2 m (URA index 0)
                [g("toe_sow"), 4.0],
            ]
            out.append(f"G{int(e.prn[s]):02d} {c.year:04d} {c.month:02d} {c.day:02d} {c.hour:02d} {c.minute:02d} "
                       f"{c.second:02d}{_d19(g('af0'))}{_d19(g('af1'))}{_d19(g('af2'))}\n")
            out += ["    " + "".join(_d19(v) for v in r) + "\n" for r in rows]
    path = Path(path)
    path.write_text("".join(out))
    return path


def _require_gps_only(eph: Ephemeris, what: str) -> None:
    """Refuse a constellation with non-GPS slots: these writers label every satellite ``G``."""
    other = sorted(set(eph.sat_id[eph.system != "G"].tolist()))
    if other:
        raise ValueError(f"{what}: writes GPS satellites only, got {len(other)} others ({', '.join(other[:4])}"
                         f"{', ...' if len(other) > 4 else ''})")


#: seed words of the satellite clocks given to a constellation whose almanac has none
_SAT_CLOCK_WORDS = (0x5A7C10C5, 19)


def satellite_clocks(eph: Ephemeris) -> Ephemeris:
    """``eph`` with realistic satellite clocks when its af0/af1 are all zero (see the module doc), else itself."""
    if np.any(np.asarray(eph.af0) != 0) or np.any(np.asarray(eph.af1) != 0):
        return eph
    prn = np.asarray(eph.prn, np.int64)
    af0 = np.array([np.random.default_rng([*_SAT_CLOCK_WORDS, int(p)]).uniform(-5e-4, 5e-4) for p in prn])
    af1 = np.array([np.random.default_rng([*_SAT_CLOCK_WORDS, int(p), 1]).normal(0.0, 5e-12) for p in prn])
    return replace(eph, af0=af0, af1=af1)


def write_rinex(gnss: GnssEpochs, geometry: GnssGeometry, out_dir: str | Path, *, clock_bias_m: NDArray,
                name: str = "testbed", trial: int = 0, cn0_horizon_dbhz: float = 35.0,
                cn0_zenith_dbhz: float = 50.0) -> tuple[Path, Path]:
    """Write ``<name>.obs`` (RINEX 3.04 GPS observations) and ``<name>.nav`` into ``out_dir``.

    Parameters
    ----------
    gnss : synthesized observations (one trial is exported: ``trial`` of a batch).
    geometry : the :class:`GnssGeometry` they were drawn on (constellation, satellite
        clocks, elevations for C/N0) — the truth-side inputs of the export.
    clock_bias_m : (T,) or (B, T) the receiver clock c·δt_rx inside the ranges
        (``GnssTruth.clock_bias``): it goes into the time tags.

    Returns
    -------
    (obs_path, nav_path)
    """
    _require_gps_only(geometry.eph, "write_rinex")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if gnss.pseudorange.ndim not in (2, 3):
        raise ValueError(f"gnss.pseudorange: expected shape (T, S) or (B, T, S), got {gnss.pseudorange.shape}")
    if gnss.pseudorange.ndim == 3 and not 0 <= trial < gnss.pseudorange.shape[0]:
        raise ValueError(f"trial: expected 0..{gnss.pseudorange.shape[0] - 1}, got {trial}")
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
    c1c = pr - C_LIGHT * (geometry.sat_clock_s + extra)
    d1c = -(rr - C_LIGHT * (geometry.sat_clock_rate + extra_rate)) / LAMBDA_L1
    s1c = cn0_from_elevation(geometry.elevation, cn0_horizon_dbhz, cn0_zenith_dbhz)
    t_gps = np.asarray(gnss.t_gps, float) + np.asarray(bias, float) / C_LIGHT  # receiver-clock time tags
    c0 = gps_seconds_to_calendar(t_gps[0])
    interval = float(np.median(np.diff(t_gps))) if t_gps.size > 1 else 1.0
    head = [
        _hl(f"{'3.04':>9}{'':11}{'OBSERVATION DATA':<20}{'G':<20}", "RINEX VERSION / TYPE"),
        _pgm_line(),
        _hl(name.upper()[:60], "MARKER NAME"),
        _hl("AIRBORNE", "MARKER TYPE"),
        _hl(f"{'testbed':<20}{'synthetic':<40}", "OBSERVER / AGENCY"),
        _hl(f"{'0':<20}{'TESTBED SYNTHETIC':<20}{'1':<20}", "REC # / TYPE / VERS"),
        _hl(f"{'0':<20}{'UNKNOWN':<20}", "ANT # / TYPE"),
        _hl(f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}", "APPROX POSITION XYZ"),
        _hl(f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}", "ANTENNA: DELTA H/E/N"),
        _hl(f"G{3:5d} C1C D1C S1C", "SYS / # / OBS TYPES"),
        _hl("DBHZ", "SIGNAL STRENGTH UNIT"),
        _hl("testbed: C1C is an iono-free-equivalent range (no iono,", "COMMENT"),
        _hl("tropo delay in it): solve with atmosphere models off", "COMMENT"),
        _hl(f"{interval:10.3f}", "INTERVAL"),
        _hl(f"{c0.year:6d}{c0.month:6d}{c0.day:6d}{c0.hour:6d}{c0.minute:6d}"
            f"{c0.second + c0.microsecond * 1e-6:13.7f}     GPS", "TIME OF FIRST OBS"),
        _hl(f"{leap_seconds(gps_seconds_to_utc(t_gps[0])):6d}", "LEAP SECONDS"),
        _hl("", "END OF HEADER"),
    ]
    body = []
    prn = np.asarray(gnss.prn)
    for k in range(t_gps.size):  # text output: one line per measurement, a loop is the honest form
        idx = np.flatnonzero(vis[k])
        minute = np.floor(t_gps[k] / 60.0) * 60.0  # the seconds from the float itself: 0.1 µs, not datetime's 1 µs
        if round(t_gps[k] - minute, 7) >= 60.0:
            minute += 60.0
        c = gps_seconds_to_calendar(minute)
        body.append(f"> {c.year:4d} {c.month:02d} {c.day:02d} {c.hour:02d} {c.minute:02d}"
                    f"{max(t_gps[k] - minute, 0.0):11.7f}  0{idx.size:3d}\n")
        body += [f"G{int(prn[s]):02d}{c1c[k, s]:14.3f}  {d1c[k, s]:14.3f}  {s1c[k, s]:14.3f}  \n" for s in idx]
    obs_path = out_dir / f"{name}.obs"
    obs_path.write_text("".join(head + body))
    nav_path = write_nav(eph, (t_gps[0], t_gps[-1]), out_dir / f"{name}.nav")
    return obs_path, nav_path


def rtklib_single_point(obs_path: str | Path, nav_path: str | Path, out_path: str | Path, *,
                        elevation_mask_deg: float = 5.0, raim_fde: bool = False, exe: str = "rnx2rtkp",
                        timeout_s: float = 120.0) -> Path:
    """Run RTKLIB ``rnx2rtkp`` single-point positioning, GPS only, iono/tropo models off.

    Options (written to ``<out>.conf`` and repeated on the command line):
    ``-p 0`` single, ``-m`` mask, ``-sys G``, ``-e`` ECEF output, time GPST as
    week/TOW; ``pos1-ionoopt=off``, ``pos1-tropopt=off`` (see module doc),
    ``pos1-sateph=brdc``, ``pos1-posopt5`` = RAIM FDE on/off.
    Returns the ``.pos`` path. Raises FileNotFoundError if ``exe`` is not on PATH.
    """
    if shutil.which(exe) is None:
        raise FileNotFoundError(f"{exe}: not on PATH (install RTKLIB: apt-get install rtklib)")
    out_path = Path(out_path)
    conf = out_path.with_suffix(".conf")
    conf.write_text("\n".join([
        "pos1-posmode       =single", "pos1-frequency     =l1", f"pos1-elmask        ={elevation_mask_deg}",
        "pos1-ionoopt       =off", "pos1-tropopt       =off", "pos1-sateph        =brdc",
        f"pos1-posopt5       ={'on' if raim_fde else 'off'}", "pos1-navsys        =1",
        "out-solformat      =xyz", "out-timesys        =gpst", "out-timeform       =tow",
        "out-timendec       =3", ""]))
    cmd = [exe, "-k", str(conf), "-p", "0", "-m", f"{elevation_mask_deg}", "-sys", "G", "-e",
           "-o", str(out_path), str(obs_path), str(nav_path)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    if res.returncode != 0 or not out_path.exists():
        raise RuntimeError(f"{' '.join(cmd)} failed ({res.returncode}): {res.stderr.strip()[-500:]}")
    return out_path


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

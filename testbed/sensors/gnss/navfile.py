"""RINEX 2.xx and 3.xx navigation files: GPS, Galileo and BeiDou broadcast ephemerides, Klobuchar coefficients.

Formats (RINEX 2.11 and 3.04 specifications, IGS/RTCM):

* 2.xx GPS (``N``): ``ION ALPHA`` / ``ION BETA`` header records; a record is
  8 lines, the first ``I2,5I3,F5.1,3D19.12`` (PRN, 2-digit year ... second,
  af0, af1, af2), the others ``3X,4D19.12``.
* 3.xx (``N``, GPS or mixed): ``IONOSPHERIC CORR`` records ``GPSA``/``GPSB``;
  a GPS, Galileo or BeiDou record is ``A1,I2.2,1X,I4,5(1X,I2.2),3D19.12`` then 7
  lines ``4X,4D19.12`` (RINEX 3.05 Tables A6, A8, A14). Galileo records are in
  GST with the GPS-aligned week; BeiDou records in BDT with the BDT week; both
  are converted to the internal GPS conventions by
  :mod:`testbed.sensors.gnss.broadcast` (BeiDou GEO records, C01–C05 and
  C59–C63, keep their GEO form). The group delay kept as ``tgd``: GPS TGD,
  Galileo BGD E5b/E1 (I/NAV, RTKLIB's default too), BeiDou TGD1 (B1I). Records of
  other systems (GLONASS, QZSS, NavIC, SBAS) are skipped by their line count
  and counted in :attr:`NavData.skipped`, as are Galileo F/NAV records when
  the file has I/NAV ones (the E1 user's clock is I/NAV's).

Broadcast orbit lines (both versions, 4 values each after the first):
IODE Crs Δn M0 / Cuc e Cus √A / Toe Cic Ω0 Cis / i0 Crc ω Ω̇ / IDOT L2codes week L2P /
accuracy health TGD IODC / transmission-time fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from testbed.schema import ConfigError
from testbed.sensors.gnss.broadcast import from_broadcast, is_bds_geo, system_time_to_gps
from testbed.sensors.gnss.orbits import SYSTEM_NAMES, Ephemeris
from testbed.sensors.gnss.rinex_text import RinexText, read_lines, rinex_float
from testbed.sensors.gnss.timebase import SECONDS_PER_WEEK, gps_seconds_to_calendar, gpst_calendar_to_gps_seconds

#: lines per record of each system in a RINEX 3 navigation file
_RECORD_LINES_V3 = {"G": 8, "E": 8, "J": 8, "C": 8, "I": 8, "R": 4, "S": 4}


@dataclass(frozen=True)
class NavData:
    """What a navigation file gives the pseudorange corrections.

    eph : every GPS, Galileo and BeiDou record (several per satellite; :func:`nearest_records` picks per epoch).
    klobuchar_alpha, klobuchar_beta : (4,) broadcast ionosphere coefficients (s, s/semicircle^n),
        or None when the header has none.
    skipped : records not read, by system name, with counts (GLONASS, SBAS...).
    """

    eph: Ephemeris
    klobuchar_alpha: NDArray | None
    klobuchar_beta: NDArray | None
    version: str
    path: Path
    skipped: dict[str, int] = field(default_factory=dict)

    @property
    def systems(self) -> tuple[str, ...]:
        """The system letters with at least one record, in G, E, C order."""
        return tuple(x for x in SYSTEM_NAMES if (self.eph.system == x).any())


def _values(text: RinexText, k: int, first_col: int, cont_col: int, name: str = "GPS") -> list[float]:
    """The 31 numbers of the ``name`` record starting at line index ``k`` (3 on the first line, 4 on the
    others; blank = 0)."""
    block = text.lines[k:k + 8]
    if len(block) < 8:
        raise text.fail(f"truncated {name} record ({len(block)} of 8 lines before the end of the file)", k + 1)
    try:
        vals = [rinex_float(block[0][first_col + 19 * j:first_col + 19 + 19 * j]) for j in range(3)]
        for b in block[1:]:
            vals += [rinex_float(b[cont_col + 19 * j:cont_col + 19 + 19 * j]) for j in range(4)]
    except ValueError as exc:
        raise text.fail(f"unreadable {name} record ({exc}); expected D19.12 numbers", k + 1) from None
    return vals


def _iono(text: RinexText) -> tuple[NDArray | None, NDArray | None]:
    def coeffs(label: str, key: str | None, start: int):
        for n, ln in text.header(label):
            if key is None or ln[:4] == key:
                try:
                    return np.array([rinex_float(ln[start + 12 * j:start + 12 + 12 * j]) for j in range(4)])
                except ValueError:
                    raise text.fail(f"unreadable {label} {key or ''} coefficients {ln[:60]!r}", n) from None
        return None

    if text.version.startswith("2"):
        return coeffs("ION ALPHA", None, 2), coeffs("ION BETA", None, 2)
    return coeffs("IONOSPHERIC CORR", "GPSA", 5), coeffs("IONOSPHERIC CORR", "GPSB", 5)


#: IS-GPS-200 20.3.4.4: a record's clock (toc) and orbit (toe) epochs lie in its curve-fit interval, 4 h
#: in normal operation; a record whose fit interval field says more (hours) is given that
NOMINAL_FIT_S = 4 * 3600.0


def _check_records(text: RinexText, sat: NDArray, toc: NDArray, P: NDArray, line: NDArray, toe_gps: NDArray,
                   system: NDArray) -> None:
    """Refuse records a receiver cannot have broadcast: a number that is not finite, toe outside its week,
    or a time of clock (the record's epoch) further from its time of ephemeris than the fit interval (a
    record of another week, or damaged: its clock would be extrapolated over days, kilometres of range).
    The message names the line of the first such record and counts the others."""
    bad_number = ~np.isfinite(P).all(axis=1)
    toe_sow = P[:, 11]
    week = np.where(bad_number, 0.0, P[:, 21])
    bad_toe = ~bad_number & ((toe_sow < 0) | (toe_sow >= SECONDS_PER_WEEK) | (week < 0) | (week != np.round(week)))
    # the fit-interval field is GPS's; Galileo's is spare and BeiDou's holds AODC there
    fit_s = np.maximum(NOMINAL_FIT_S, np.where(bad_number | (system != "G"), 0.0, P[:, 28]) * 3600.0)
    gap = toc - np.where(bad_number | bad_toe, toc, toe_gps)
    bad_gap = ~bad_number & ~bad_toe & (np.abs(gap) > fit_s)
    problems = []
    for bad, say in (
            (bad_number, lambda j: "a value that is not a finite number (NaN or infinite); expected D19.12 numbers"),
            (bad_toe, lambda j: f"time of ephemeris {toe_sow[j]:g} s in week {week[j]:g}: expected 0 <= toe < "
                                f"{SECONDS_PER_WEEK:g} s of a whole, non-negative week"),
            (bad_gap, lambda j: f"time of clock {gps_seconds_to_calendar(toc[j]):%Y-%m-%d %H:%M:%S} is "
                                f"{gap[j] / 3600.0:+.1f} h from its time of ephemeris "
                                f"{gps_seconds_to_calendar(toc[j] - gap[j]):%Y-%m-%d %H:%M:%S} (week {week[j]:g}, "
                                f"toe {toe_sow[j]:g} s); expected them within the record's fit interval "
                                f"({fit_s[j] / 3600.0:g} h, IS-GPS-200 20.3.4.4): a record of another week, or "
                                f"a damaged one")):
        if bad.any():
            j = int(np.flatnonzero(bad)[0])
            more = int(bad.sum()) - 1
            problems.append(f"line {line[j]}: {sat[j]} record: {say(j)}"
                            + (f" (and {more} more record{'s' if more > 1 else ''} like it)" if more else ""))
    if problems:
        raise ConfigError(text.path, problems)


#: which number of a Galileo / BeiDou / GPS record is its group delay (see the module doc)
_TGD_FIELD = {"G": 25, "E": 26, "C": 25}


def read_nav(path: str | Path) -> NavData:
    """All GPS, Galileo and BeiDou broadcast records and the Klobuchar coefficients of a RINEX 2.xx/3.xx
    navigation file."""
    text = read_lines(path, "GPS (or mixed) navigation", "N")
    vers = text.version
    recs: list[tuple[str, int, float, list[float], int]] = []
    skipped: dict[str, int] = {}
    k, n = text.header_end + 1, len(text.lines)
    v2 = vers.startswith("2")
    while k < n:
        ln = text.lines[k]
        if not ln.strip():
            k += 1
            continue
        letter = "G"
        try:
            if v2:
                prn = int(ln[0:2])
                y = int(ln[3:5])
                y += 2000 if y < 80 else 1900
                mo, d, h, mi = int(ln[6:8]), int(ln[9:11]), int(ln[12:14]), int(ln[15:17])
                s = float(ln[17:22])
                first, cont, nlines = 22, 3, 8
            else:
                letter = ln[0]
                nlines = _RECORD_LINES_V3.get(letter)
                if nlines is None:
                    raise text.fail(f"unexpected record start {ln[:10]!r}; expected a satellite system letter "
                                    f"({''.join(_RECORD_LINES_V3)}) and a PRN", k + 1)
                if letter not in SYSTEM_NAMES:
                    skipped[f"system {letter} records"] = skipped.get(f"system {letter} records", 0) + 1
                    k += nlines
                    continue
                prn = int(ln[1:3])
                y, mo, d, h, mi, s = (int(ln[4:8]), int(ln[9:11]), int(ln[12:14]), int(ln[15:17]),
                                      int(ln[18:20]), float(ln[21:23]))
                first, cont = 23, 4
        except ValueError:
            raise text.fail(f"unreadable record time {ln[:23]!r}; expected the PRN and the time of clock", k + 1) \
                from None
        if not 1 <= prn <= 63:
            raise text.fail(f"PRN {prn}: expected 1..63", k + 1)
        # the record's epoch is in its system's time scale (GST, BDT): to GPS time
        toc = float(system_time_to_gps(gpst_calendar_to_gps_seconds(y, mo, d, h, mi, s), letter))
        recs.append((letter, prn, toc, _values(text, k, first, cont, SYSTEM_NAMES[letter]), k + 1))
        k += nlines
    if not recs:
        others = f" (skipped: {', '.join(f'{v} {q}' for q, v in sorted(skipped.items()))})" if skipped else ""
        raise text.fail(f"no GPS, Galileo or BeiDou ephemeris records after the header{others}")
    recs = _inav_only(recs, skipped)
    P = np.array([r[3] for r in recs])
    system = np.array([r[0] for r in recs], dtype="<U1")
    prn = np.array([r[1] for r in recs])
    toc = np.array([r[2] for r in recs])
    geo = is_bds_geo(system, prn)
    bad = ~np.isfinite(P).all(axis=1)
    conv = from_broadcast(system, week_s=np.where(bad, 0.0, P[:, 21]), toe_s=np.where(bad, 0.0, P[:, 11]),
                          sqrt_a=np.where(bad, 1.0, P[:, 10]), delta_n=P[:, 5], omega0=P[:, 13],
                          omega_dot=P[:, 18], bds_geo=geo)
    sat = np.array([f"{x}{p:02d}" for x, p in zip(system, prn)])
    _check_records(text, sat, toc, P, np.array([r[4] for r in recs]),
                   conv["week"] * SECONDS_PER_WEEK + conv["toe_sow"], system)
    week = conv["week"]
    # the record's week goes with toe; toc can sit across a week boundary from it
    toc_sow = toc - week * SECONDS_PER_WEEK
    tgd = P[np.arange(len(recs)), [_TGD_FIELD[x] for x in system]]
    eph = Ephemeris(prn=prn, health=P[:, 24].astype(np.int64), week=week, toe_sow=conv["toe_sow"], toc_sow=toc_sow,
                    sqrt_a=P[:, 10], e=P[:, 8], i0=P[:, 15], idot=P[:, 19], omega0=conv["omega0"],
                    omega_dot=conv["omega_dot"], w=P[:, 17], m0=P[:, 6], delta_n=conv["delta_n"], cuc=P[:, 7],
                    cus=P[:, 9], crc=P[:, 16], crs=P[:, 4], cic=P[:, 12], cis=P[:, 14], af0=P[:, 0],
                    af1=P[:, 1], af2=P[:, 2], tgd=tgd, iode=P[:, 3].astype(np.int64),
                    source=f"RINEX nav {text.path.name}", system=system, bds_geo=geo)
    alpha, beta = _iono(text)
    return NavData(eph, alpha, beta, vers, text.path, skipped)


def _inav_only(recs: list, skipped: dict[str, int]) -> list:
    """Without Galileo F/NAV records when the file has I/NAV ones: an F/NAV record's clock is for E5a/E1, an
    I/NAV record's for E5b/E1, whose group delay (BGD E5b/E1) is the one kept (RTKLIB's default choice too).
    Data sources (RINEX 3.05 Table A8): bit 0 I/NAV E1-B, bit 1 F/NAV E5a-I, bit 2 I/NAV E5b-I."""
    sources = [int(r[3][20]) if r[0] == "E" and np.isfinite(r[3][20]) else 0 for r in recs]
    fnav = [r[0] == "E" and bool(q & 2) for r, q in zip(recs, sources)]
    if not any(fnav) or not any(r[0] == "E" and q & 5 for r, q in zip(recs, sources)):
        return recs
    skipped["Galileo F/NAV records (I/NAV used)"] = sum(fnav)
    return [r for r, f in zip(recs, fnav) if not f]


#: RTKLIB's and the ICD's usual validity of a broadcast record about its toe (s)
MAX_AGE_S = 7200.0


def nearest_records(eph: Ephemeris, prn: NDArray, t_gps: NDArray, max_age_s: float = MAX_AGE_S,
                    system: NDArray | None = None) -> NDArray:
    """Index into ``eph`` of the record nearest in toe to each (epoch, satellite), -1 where none is within
    ``max_age_s``.

    prn : (S,), with ``system`` (S,) letters (default: every one GPS).  t_gps : (E,).  Returns (E, S) int.
    """
    out = np.full((t_gps.size, prn.size), -1, np.intp)
    toe = eph.toe_gps
    system = np.full(prn.shape, "G") if system is None else np.asarray(system)
    for j, (x, p) in enumerate(zip(system, prn)):  # one pass per satellite: O(E log R)
        idx = np.flatnonzero((eph.prn == p) & (eph.system == x))
        if idx.size == 0:
            continue
        idx = idx[np.argsort(toe[idx], kind="stable")]
        tt = toe[idx]
        pos = np.clip(np.searchsorted(tt, t_gps), 1, max(tt.size - 1, 1))
        lo = np.where(np.abs(t_gps - tt[pos - 1]) <= np.abs(t_gps - tt[np.minimum(pos, tt.size - 1)]), pos - 1,
                      np.minimum(pos, tt.size - 1)) if tt.size > 1 else np.zeros(t_gps.size, np.intp)
        ok = np.abs(t_gps - tt[lo]) <= max_age_s
        out[:, j] = np.where(ok, idx[lo], -1)
    return out

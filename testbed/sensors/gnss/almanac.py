"""Constellation sources: the shipped DO-229 almanac, YUMA and SEM almanacs, RINEX navigation files.

Every loader returns an :class:`~testbed.sensors.gnss.orbits.Ephemeris` with
full GPS weeks. Almanacs carry a 10-bit week (DO-229: week 703); two ways to
place it in time, chosen by ``week_mode``:

``"periodic"`` (default for DO-229)
    The almanac is a nominal constellation, not a dated one: its toa is put in
    the GPS week that brings it nearest the requested time, so the same sky
    repeats every GPS week at the same time of week (the orbits are exact
    Keplerian ellipses; only the reference epoch moves). With e = 0 and
    Ω̇ = 0, as in DO-229, this is also the true propagation of the nominal orbits.
``"nearest_rollover"`` (default for YUMA and SEM)
    The 10-bit week is unwrapped (week + k·1024) to the value that puts toa
    nearest the requested time: right for a dated almanac such as a NAVCEN
    YUMA file used within a few weeks of its issue.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path
from typing import Literal

import numpy as np

from testbed.sensors.gnss.orbits import SYSTEM_NAMES, Ephemeris, from_keplerian
from testbed.sensors.gnss.navfile import read_nav
from testbed.sensors.gnss.timebase import SECONDS_PER_WEEK

WeekMode = Literal["auto", "periodic", "nearest_rollover"]
_DO229_FILE = "do229_gps_almanac_24sat.tsv"


class OrbitFileProblem(ValueError):
    """An orbit file that reads but cannot serve the constellation asked of it (no records of its system, none
    current): the message says what was expected."""


def resolve_week(week_raw, toa_sow, t_ref_gps: float, mode: str) -> np.ndarray:
    """Full GPS week(s) for almanac week number(s) ``week_raw`` (see module doc for modes)."""
    week_raw = np.asarray(week_raw, np.int64)
    toa_sow = np.asarray(toa_sow, float)
    if mode == "periodic":
        return np.round((t_ref_gps - toa_sow) / SECONDS_PER_WEEK).astype(np.int64) + 0 * week_raw
    if mode == "nearest_rollover":
        base = np.mod(week_raw, 1024)
        k = np.round((t_ref_gps - toa_sow - base * SECONDS_PER_WEEK) / (1024 * SECONDS_PER_WEEK))
        return (base + 1024 * k).astype(np.int64)
    raise ValueError(f"week_mode: expected 'periodic' or 'nearest_rollover', got {mode!r}")


def load_do229(t_ref_gps: float, week_mode: WeekMode = "auto") -> Ephemeris:
    """The RTCA DO-229 24-satellite almanac shipped as package data, placed near ``t_ref_gps``."""
    text = importlib.resources.files("testbed.data").joinpath(_DO229_FILE).read_text()
    return _from_table(text, t_ref_gps, "periodic" if week_mode == "auto" else week_mode, "DO-229")


def _from_table(text: str, t_ref_gps: float, mode: str, source: str) -> Ephemeris:
    rows = [ln.split("\t") for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    header, body = rows[0], np.array([[float(v) for v in r] for r in rows[1:]])
    col = {name: body[:, k] for k, name in enumerate(header)}
    week = resolve_week(col["week"], col["toa_s"], t_ref_gps, mode)
    return from_keplerian(col["prn"].astype(int), week=week, toe_sow=col["toa_s"], sqrt_a=col["sqrt_a_m05"],
                          e=col["eccentricity"], i0=col["inclination_rad"], omega0=col["raan_at_toa_rad"],
                          omega_dot=col["raan_rate_rad_s"], w=col["arg_perigee_rad"],
                          m0=col["mean_anomaly_rad"], af0=col["af0_s"], af1=col["af1_s_s"],
                          health=col["health"].astype(int), source=source)


_YUMA_KEYS = {
    "id": "prn", "health": "health", "eccentricity": "e", "time of applicability": "toa",
    "orbital inclination": "i0", "rate of right ascen": "omega_dot", "sqrt(a)": "sqrt_a",
    "right ascen at week": "omega0", "argument of perigee": "w", "mean anom": "m0", "af0": "af0",
    "af1": "af1", "week": "week",
}


def load_yuma(path: str | Path, t_ref_gps: float, week_mode: WeekMode = "auto") -> Ephemeris:
    """A YUMA almanac file (NAVCEN / CelesTrak format), weeks resolved near ``t_ref_gps``.

    The Ω0 field ("Right Ascen at Week") is the IS-GPS-200 longitude of the
    node at the weekly epoch; "Orbital Inclination" is the full inclination.
    """
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise ValueError(f"YUMA almanac {path}: cannot read ({exc})") from exc
    recs, cur = [], None
    for n, ln in enumerate(lines, 1):
        if ln.startswith("*"):
            cur = {}
            recs.append(cur)
            continue
        if ":" not in ln or cur is None:
            continue
        key, val = ln.split(":", 1)
        key = key.strip().lower()
        for prefix, name in _YUMA_KEYS.items():
            if key.startswith(prefix):
                try:
                    cur[name] = float(val)
                except ValueError as exc:
                    raise ValueError(f"YUMA almanac {path}, line {n}: expected a number for "
                                     f"{key!r}, got {val.strip()!r}") from exc
                break
    need = set(_YUMA_KEYS.values())
    recs = [r for r in recs if r]
    if not recs:
        raise ValueError(f"YUMA almanac {path}: no '******** Week ... almanac for PRN-xx' blocks found")
    for r in recs:
        if need - set(r):
            raise ValueError(f"YUMA almanac {path}: PRN {r.get('prn', '?')} lacks {sorted(need - set(r))}")
    col = {k: np.array([r[k] for r in recs]) for k in need}
    mode = "nearest_rollover" if week_mode == "auto" else week_mode
    week = resolve_week(col["week"].astype(int), col["toa"], t_ref_gps, mode)
    order = np.argsort(col["prn"])
    return from_keplerian(col["prn"].astype(int), week=week, toe_sow=col["toa"], sqrt_a=col["sqrt_a"],
                          e=col["e"], i0=col["i0"], omega0=col["omega0"], omega_dot=col["omega_dot"],
                          w=col["w"], m0=col["m0"], af0=col["af0"], af1=col["af1"],
                          health=col["health"].astype(int), source=f"YUMA {path.name}").take(order)


#: SEM almanac: the reference inclination its "inclination offset" is from (IS-GPS-200 Table 20-VI), semicircles
SEM_I0_SEMICIRCLES = 0.30
#: values per line of one SEM record: PRN, SVN, URA; e, δi, Ω̇; √A, Ω0, ω; M0, af0, af1; health; configuration
_SEM_LINE_VALUES = (1, 1, 1, 3, 3, 3, 1, 1)


def load_sem(path: str | Path, t_ref_gps: float, week_mode: WeekMode = "auto") -> Ephemeris:
    """A SEM almanac file (NAVCEN ``.al3`` format, ICD-GPS-240 / IS-GPS-200 units), weeks resolved near ``t_ref_gps``.

    Header: the record count and a name, then the 10-bit week and the time of applicability (s). Each record,
    one value or three per line: PRN; SVN; URA index; e, inclination offset δi and rate of right ascension;
    √A, longitude of the node at the weekly epoch Ω0 and argument of perigee ω; mean anomaly M0, af0, af1;
    health; configuration. Angles are in semicircles, i = 0.30 semicircles + δi (IS-GPS-200 Table 20-VI).
    """
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"SEM almanac {path}: cannot read ({exc})") from exc
    body = [(n, ln.split()) for n, ln in enumerate(lines, 1) if ln.strip()]

    def numbers(k: int, count: int, what: str) -> list[float]:
        if k >= len(body):
            raise ValueError(f"SEM almanac {path}: ends before {what} (line {len(lines) + 1})")
        n, tokens = body[k]
        try:
            vals = [float(v) for v in tokens[:count]]
        except ValueError:
            vals = []
        if len(vals) != count:
            raise ValueError(f"SEM almanac {path}, line {n}: expected {count} number(s) for {what}, got "
                             f"{lines[n - 1].strip()[:60]!r}")
        return vals

    count = int(numbers(0, 1, "the record count")[0])
    week_raw, toa = numbers(1, 2, "the week and time of applicability")
    if count < 1 or len(body) - 2 < count * len(_SEM_LINE_VALUES):
        raise ValueError(f"SEM almanac {path}: the header announces {count} record(s), expected at least one and "
                         f"{len(_SEM_LINE_VALUES)} lines for each")
    rows = []
    for r in range(count):
        k0 = 2 + r * len(_SEM_LINE_VALUES)
        rows.append(sum((numbers(k0 + j, c, f"record {r + 1} line {j + 1}")
                         for j, c in enumerate(_SEM_LINE_VALUES)), []))
    a = np.array(rows)
    semi = np.pi
    mode = "nearest_rollover" if week_mode == "auto" else week_mode
    week = resolve_week(np.full(count, int(week_raw)), np.full(count, toa), t_ref_gps, mode)
    order = np.argsort(a[:, 0])
    return from_keplerian(a[:, 0].astype(int), week=week, toe_sow=toa, sqrt_a=a[:, 6], e=a[:, 3],
                          i0=(SEM_I0_SEMICIRCLES + a[:, 4]) * semi, omega0=a[:, 7] * semi,
                          omega_dot=a[:, 5] * semi, w=a[:, 8] * semi, m0=a[:, 9] * semi, af0=a[:, 10],
                          af1=a[:, 11], health=a[:, 12].astype(int), source=f"SEM {path.name}").take(order)


def load_rinex_nav(path: str | Path, systems: str = "G") -> Ephemeris:
    """The broadcast records of ``systems`` (letters among G, E, C; default GPS only) in a RINEX 2.xx/3.xx
    navigation file (other systems skipped).

    Returns every record (several per satellite); call :meth:`Ephemeris.select` to
    keep the one nearest a flight. Full IS-GPS-200 model: Δn, IDOT, the six
    harmonic terms, af0..af2, TGD are all used (:func:`testbed.sensors.gnss.navfile.read_nav`).
    """
    eph = read_nav(path).eph
    keep = np.flatnonzero(np.isin(eph.system, list(systems)))
    if keep.size == 0:
        want = " or ".join(SYSTEM_NAMES[x] for x in systems)
        have = ", ".join(SYSTEM_NAMES[x] for x in SYSTEM_NAMES if (eph.system == x).any())
        raise OrbitFileProblem(f"RINEX nav {Path(path).name}: no {want} records (it has {have} ones): expected a "
                               f"navigation file with {want} broadcast records")
    return eph if keep.size == len(eph) else eph.take(keep)


def load_constellation(source: str, path: str | Path | None, t_ref_gps: float,
                       week_mode: WeekMode = "auto") -> Ephemeris:
    """The constellation named by settings (``"do229"``, ``"yuma"``, ``"sem"``, ``"rinex_nav"``) near ``t_ref_gps``."""
    if source == "do229":
        return load_do229(t_ref_gps, week_mode)
    if path is None:
        raise ValueError(f"almanac_path: required when almanac_source is {source!r}")
    if source == "yuma":
        return load_yuma(path, t_ref_gps, week_mode)
    if source == "sem":
        return load_sem(path, t_ref_gps, week_mode)
    if source == "rinex_nav":
        return load_rinex_nav(path).select(t_ref_gps)
    raise ValueError(f"almanac_source: expected 'do229', 'yuma', 'sem' or 'rinex_nav', got {source!r}")

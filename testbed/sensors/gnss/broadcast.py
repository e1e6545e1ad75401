"""Galileo and BeiDou broadcast conventions, converted exactly to and from the internal :class:`Ephemeris`.

An :class:`~testbed.sensors.gnss.orbits.Ephemeris` follows the GPS conventions
for every system (μ and Ω̇e of IS-GPS-200, GPS time, GPS weeks), so one
propagator serves all. A broadcast record of another system differs in four
ways, each converted exactly here (the positions do not change):

* **μ** (Galileo OS SIS ICD §5.1.1, BDS-SIS-ICD-B1I-3.0 §5.2.4.10: 3.986004418e14
  m³/s²): the record's mean motion √(μ_s/A³) + Δn is carried as
  Δn' = Δn + √(μ_s/A³) − √(μ_GPS/A³).
* **Ω̇e** (BeiDou: 7.292115e-5 rad/s, CGCS2000; Galileo: the GPS value): the node
  Ω = Ω0 + (Ω̇ − Ω̇e,s)·tk − Ω̇e,s·toe_s is carried as Ω̇' = Ω̇ + Ω̇e − Ω̇e,s and
  Ω0' = Ω0 − Ω̇e,s·toe_s + Ω̇e·toe (toe_s in the record's own week).
* **time scale**: Galileo System Time is steered to GPS time (GST = GPST, the
  broadcast GGTO of a few ns taken as 0) and RINEX 3 writes the Galileo week
  aligned with the GPS week; BeiDou Time is BDT = GPST − 14 s (BDT started at
  2006-01-01 00:00:00 UTC, when GPS − UTC was 14 s; the broadcast fraction
  A0,BGTO taken as 0), with its own weeks: BDT week = GPS week − 1356. Record
  epochs (toc) are written in each system's scale.
* **BeiDou GEO** (PRN C01–C05, C59–C63; BDS-SIS-ICD-B1I-3.0 §5.2.4.12): the
  elements are in a frame inclined 5° that does not follow the Earth over tk;
  such records keep that form (``bds_geo``) and
  :func:`~testbed.sensors.gnss.orbits.sat_states` applies the GEO rotation.
  :func:`geo_record` builds one from any orbit (the export writes the nominal
  GEO satellites so, as a real one broadcasts them, and RTKLIB reads them so).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.frames import OMEGA_EARTH
from testbed.sensors.gnss.orbits import MU_GPS, OMEGA_EARTH_BDS, Ephemeris, sat_states
from testbed.sensors.gnss.timebase import SECONDS_PER_WEEK

#: gravitational parameter of each system's ICD, m³/s²
MU = {"G": MU_GPS, "E": 3.986004418e14, "C": 3.986004418e14}
#: Earth rotation rate of each system's ICD, rad/s
OMEGA_E = {"G": OMEGA_EARTH, "E": OMEGA_EARTH, "C": OMEGA_EARTH_BDS}
#: system time − GPS time, s (whole seconds; the broadcast fractional offsets are taken as 0)
TIME_OFFSET_S = {"G": 0.0, "E": 0.0, "C": -14.0}
#: GPS week − the week number a RINEX 3 navigation record carries (Galileo: aligned with GPS in RINEX)
WEEK_OFFSET = {"G": 0, "E": 0, "C": 1356}
#: the system-time name of each system in RINEX headers
TIME_SYSTEM = {"G": "GPS", "E": "GAL", "C": "BDT"}
#: BeiDou GEO PRNs (BDS-SIS-ICD-B1I-3.0 §3; BDS-3 adds C59–C63 to BDS-2's C01–C05)
BDS_GEO_PRNS = frozenset((1, 2, 3, 4, 5, 59, 60, 61, 62, 63))


def _per_slot(table: dict, system: NDArray) -> NDArray:
    return np.array([table[s] for s in np.asarray(system).ravel()], dtype=float).reshape(np.shape(system))


def is_bds_geo(system: ArrayLike, prn: ArrayLike) -> NDArray:
    """(S,) bool: the slots whose broadcast records use the BeiDou GEO form."""
    system, prn = np.asarray(system), np.asarray(prn)
    return (system == "C") & np.isin(prn, sorted(BDS_GEO_PRNS))


def system_time_to_gps(t_sys: ArrayLike, system: ArrayLike) -> NDArray:
    """GPS seconds of times given as seconds since the GPS epoch in each system's scale (calendar read as such)."""
    return np.asarray(t_sys, float) - _per_slot(TIME_OFFSET_S, system)


def gps_to_system_time(t_gps: ArrayLike, system: ArrayLike) -> NDArray:
    """Inverse of :func:`system_time_to_gps`: the time each system's clock reads at ``t_gps``."""
    return np.asarray(t_gps, float) + _per_slot(TIME_OFFSET_S, system)


def from_broadcast(system: NDArray, *, week_s: NDArray, toe_s: NDArray, sqrt_a: NDArray, delta_n: NDArray,
                   omega0: NDArray, omega_dot: NDArray, bds_geo: NDArray) -> dict[str, NDArray]:
    """Internal ``week, toe_sow, delta_n, omega0, omega_dot`` of broadcast records (arrays (S,)).

    ``week_s`` / ``toe_s``: the record's week number and toe as written (its own system's week and time).
    """
    system = np.asarray(system)
    toe_gps = (np.asarray(week_s) + _per_slot(WEEK_OFFSET, system)) * SECONDS_PER_WEEK + toe_s \
        - _per_slot(TIME_OFFSET_S, system)
    week = np.floor(toe_gps / SECONDS_PER_WEEK)
    toe_sow = toe_gps - week * SECONDS_PER_WEEK
    mu, om = _per_slot(MU, system), _per_slot(OMEGA_E, system)
    A3 = np.asarray(sqrt_a, float) ** 6
    gps = system == "G"  # GPS records are taken as they are (bit for bit)
    return {"week": np.where(gps, week_s, week).astype(np.int64), "toe_sow": np.where(gps, toe_s, toe_sow),
            "delta_n": np.where(gps, delta_n, delta_n + np.sqrt(mu / A3) - np.sqrt(MU_GPS / A3)),
            "omega0": np.where(gps, omega0, _wrap(omega0 - om * toe_s + OMEGA_EARTH * toe_sow)),
            "omega_dot": np.where(gps | bds_geo, omega_dot, omega_dot + OMEGA_EARTH - om)}


def to_broadcast(eph: Ephemeris) -> dict[str, NDArray]:
    """The broadcast fields of each slot (the inverse of :func:`from_broadcast`), arrays (S,):
    ``week_s``, ``toe_s`` (own week and seconds), ``toc_sys`` (toc as seconds since the GPS epoch in the
    system's own scale, for the record's calendar epoch), ``delta_n``, ``omega0``, ``omega_dot``."""
    system = eph.system
    t_sys = eph.toe_gps + _per_slot(TIME_OFFSET_S, system)
    week_s = np.floor(t_sys / SECONDS_PER_WEEK) - _per_slot(WEEK_OFFSET, system)
    toe_s = t_sys - np.floor(t_sys / SECONDS_PER_WEEK) * SECONDS_PER_WEEK
    mu, om = _per_slot(MU, system), _per_slot(OMEGA_E, system)
    A3 = eph.sqrt_a**6
    gps = system == "G"  # GPS records are written as they are (bit for bit)
    return {"week_s": np.where(gps, eph.week, week_s), "toe_s": np.where(gps, eph.toe_sow, toe_s),
            "toc_sys": eph.toc_gps + _per_slot(TIME_OFFSET_S, system),
            "delta_n": np.where(gps, eph.delta_n, eph.delta_n - np.sqrt(mu / A3) + np.sqrt(MU_GPS / A3)),
            "omega0": np.where(gps, eph.omega0, _wrap(eph.omega0 - OMEGA_EARTH * eph.toe_sow + om * toe_s)),
            "omega_dot": np.where(gps | eph.bds_geo, eph.omega_dot, eph.omega_dot - OMEGA_EARTH + om)}


def _rx(angle: float) -> NDArray:
    """The ICD's R_X(φ) = [[1, 0, 0], [0, cos φ, sin φ], [0, −sin φ, cos φ]]."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


#: half-span (s) over which :func:`geo_record` measures the orbit's angular rate in the GEO frame
_GEO_RATE_SPAN_S = 1800.0


def geo_record(eph: Ephemeris, toe_gps: float) -> Ephemeris:
    """BeiDou GEO-form records (``bds_geo``) with toe = toc = ``toe_gps`` for the slots of ``eph``.

    The satellite's state at toe (from ``eph``, any form) is expressed in the GEO frame
    x_G = R_X(+5°)·r (the ICD turns x_G into ECEF by R_Z(Ω̇e·tk)·R_X(−5°)) and turned into
    two-body elements; the mean motion is the one the orbit shows in that frame over toe ± 30 min
    (so a satellite fixed over the Earth stays fixed, although the GEO frame turns at
    BeiDou's Ω̇e and the Earth at the GPS value), carried as Δn. The harmonic terms, IDOT
    and Ω̇ are zero. A two-body orbit is reproduced exactly: the nominal (circular, fixed)
    GEO orbits to < 1 mm over ±2 h, an eccentric GEO-form record re-referenced an hour
    later likewise (tested); a broadcast record's harmonic terms are not carried over.
    """
    S = len(eph)
    t0 = float(toe_gps)
    pos, vel = (np.asarray(a) for a in sat_states(eph, t0)[:2])
    dtc = t0 - eph.toc_gps
    P = _rx(np.radians(5.0))
    xg = pos @ P.T
    # ECEF velocity = R_X(−5°)·v_G + Ω̇e·(y, −x, 0) at tk = 0
    vg = (vel - OMEGA_EARTH_BDS * np.stack([pos[:, 1], -pos[:, 0], np.zeros(S)], -1)) @ P.T
    r = np.linalg.norm(xg, axis=-1)
    v2 = np.sum(vg**2, axis=-1)
    h = np.cross(xg, vg)
    hn = np.linalg.norm(h, axis=-1)
    inc = np.arccos(np.clip(h[:, 2] / hn, -1.0, 1.0))
    node = np.arctan2(h[:, 0], -h[:, 1])
    # in-plane axes: p along the node line, q = h × p / |h|
    p_ax = np.stack([np.cos(node), np.sin(node), np.zeros(S)], -1)
    q_ax = np.cross(h / hn[:, None], p_ax)

    def u_of(x):  # argument of latitude of x_G in the toe plane
        return np.arctan2(np.sum(x * q_ax, -1), np.sum(x * p_ax, -1))

    # u in the GEO frame at toe and toe ± span (positions taken back through R_Z(Ω̇e·tk))
    u_at = [u_of(xg)]
    for tk in (-_GEO_RATE_SPAN_S, _GEO_RATE_SPAN_S):
        p_t = np.asarray(sat_states(eph, t0 + tk)[0])
        c, s = np.cos(OMEGA_EARTH_BDS * tk), np.sin(OMEGA_EARTH_BDS * tk)
        unrot = np.stack([c * p_t[:, 0] - s * p_t[:, 1], s * p_t[:, 0] + c * p_t[:, 1], p_t[:, 2]], -1)
        u_at.append(u_of(unrot @ P.T))
    # The mean motion is the one the orbit shows in the GEO frame, and the elements take the μ that makes the
    # two-body motion match it: the GEO frame turns at BeiDou's Ω̇e, the orbit was made with another, and with
    # BeiDou's μ a fixed satellite would get a spurious eccentricity (4e-8: 1.7 m). Start from the mean rate of
    # u (exact for a circular orbit), then take the mean anomaly's (exact for an eccentric one) with the
    # elements it gives. Vis-viva 1/a = 2/r − v²/μ with μ = n²·a³ is the cubic 2a³/r − a² − v²/n² = 0
    # (Newton from a = r).
    def elements(n):  # a, e, ω, M at toe for mean motion n, and the mean motion their M shows over toe ± span
        k = v2 / n**2
        a = r.copy()
        for _ in range(8):
            a = a - (2 * a**3 / r - a**2 - k) / (6 * a**2 / r - 2 * a)
        mu = n**2 * a**3
        e_vec = ((v2 - mu / r)[:, None] * xg - np.sum(xg * vg, -1)[:, None] * vg) / mu
        e = np.linalg.norm(e_vec, axis=-1)
        w = np.where(e > 1e-12, np.arctan2(np.sum(e_vec * q_ax, -1), np.sum(e_vec * p_ax, -1)), 0.0)
        M0, M_minus, M_plus = (_mean_anomaly(u - w, e) for u in u_at)
        return a, e, w, M0, _wrap(M_plus - M_minus) / (2 * _GEO_RATE_SPAN_S)

    # the root of shown(n) − n by the secant method from the mean rate of u (the root for a circular orbit)
    n0 = _wrap(u_at[2] - u_at[1]) / (2 * _GEO_RATE_SPAN_S)
    n1 = n0 * (1.0 + 1e-7)
    f0 = elements(n0)[4] - n0
    for _ in range(12):
        a, e, w, M, shown = elements(n1)
        f1 = shown - n1
        step = np.where(f1 != f0, f1 * (n1 - n0) / np.where(f1 != f0, f1 - f0, 1.0), 0.0)
        n0, f0, n1 = n1, f1, n1 - step
        if np.all(np.abs(step) < 1e-20):
            break
    a, e, w, M, _ = elements(n1)
    rate = n1
    week = np.floor(t0 / SECONDS_PER_WEEK)
    toe_sow = t0 - week * SECONDS_PER_WEEK
    zeros = np.zeros(S)
    return replace(
        eph, week=np.full(S, int(week), np.int64), toe_sow=np.full(S, toe_sow), toc_sow=np.full(S, toe_sow),
        sqrt_a=np.sqrt(a), e=e, i0=inc, idot=zeros, omega0=_wrap(node + OMEGA_EARTH * toe_sow),
        omega_dot=zeros.copy(), w=w, m0=_wrap(M), delta_n=rate - np.sqrt(MU_GPS / a**3),
        cuc=zeros.copy(), cus=zeros.copy(), crc=zeros.copy(), crs=zeros.copy(), cic=zeros.copy(),
        cis=zeros.copy(), af0=eph.af0 + eph.af1 * dtc + eph.af2 * dtc**2, af1=eph.af1 + 2 * eph.af2 * dtc,
        af2=eph.af2,
        bds_geo=np.ones(S, bool))


def _mean_anomaly(nu: NDArray, e: NDArray) -> NDArray:
    """Mean anomaly of true anomaly ``nu`` (rad) at eccentricity ``e``."""
    E = 2.0 * np.arctan2(np.sqrt(1.0 - e) * np.sin(nu / 2), np.sqrt(1.0 + e) * np.cos(nu / 2))
    return E - e * np.sin(E)


def _wrap(angle: ArrayLike) -> NDArray:
    return np.mod(np.asarray(angle, float) + np.pi, 2 * np.pi) - np.pi


__all__ = ["BDS_GEO_PRNS", "MU", "OMEGA_E", "TIME_OFFSET_S", "TIME_SYSTEM", "WEEK_OFFSET", "from_broadcast",
           "geo_record", "gps_to_system_time", "is_bds_geo", "system_time_to_gps", "to_broadcast"]

"""Nominal Galileo and BeiDou-3 constellations as orbit sources, beside the DO-229 GPS almanac.

Each satellite is a circular Keplerian orbit at an epoch, stored as an
:class:`~testbed.sensors.gnss.orbits.Ephemeris` (the record the GPS almanac
loaders return), so :func:`~testbed.sensors.gnss.orbits.sat_states` and
:func:`~testbed.sensors.gnss.synth.gnss_geometry` take it unchanged. Slots carry
their RINEX 3 system letter (``E``, ``C``) and a PRN; :func:`nominal_constellations`
joins several systems into one record.

Galileo (``"galileo"``): the 24 nominal slots of the Walker 56°: 24/3/1
reference constellation published by the European GNSS Service Centre
("Galileo constellation: orbital and technical parameters", reference epoch
2016-11-21 00:00:00 UTC): a = 29 599.8 km, e = 0, i = 56°, ω = 0, plane RAANs
317.632° (A), 77.632° (B), 197.632° (C), slot A05 at mean anomaly 0.153°, 45°
between slots of a plane and 15° between adjacent planes (F = 1), and the
published nominal rates dΩ/dt = −0.02764398°/day and dM/dt = 613.72253566°/day
(J2 and luni-solar secular drift included), carried exactly. The nominal
semi-major axis of the Galileo OS SIS ICD almanac (29 600.000 km, √A =
5440.588203494 m^½, i = 56°) is 0.2 km away. The six spare slots are left out:
their occupation changes with the operational constellation; a real almanac
or navigation file covers it. PRNs are the slot order: E01–E08 plane A slots
1–8, E09–E16 plane B, E17–E24 plane C (not the PRNs of the satellites flying there).

BeiDou-3 (``"beidou"``), per the BDS open-service ICDs (China Satellite
Navigation Office, BDS-SIS-ICD-B1C-1.0 and BDS-SIS-ICD-B2a-1.0, 2017, §3):
24 MEO at 21 528 km altitude (a = 27 906.137 km) and i = 55°, in a Walker
55°: 24/3/1 pattern; 3 IGSO at the geostationary altitude class (35 786 km) and
i = 55°, sharing one figure-eight ground track whose node is at 118°E; 3 GEO at
80°E, 110.5°E and 140°E. Two-body propagation (no published nominal rates).
No slot epoch for the MEO pattern or phase for the IGSOs is published: the
pattern is placed by ``meo_raan_deg`` / ``meo_arg_latitude_deg`` /
``igso_arg_latitude_deg`` at ``beidou_epoch_utc`` (defaults: 0° at the BDT origin,
2006-01-01 00:00:00 UTC) — an arbitrary but fixed phase. The IGSO and GEO mean
motion is Earth's rotation rate exactly (a = 42 164.17 km), so a GEO stays on
its longitude and the IGSO figure-eight closes each sidereal day. PRNs: GEO
C59 (140°E), C60 (80°E), C61 (110.5°E), IGSO C38–C40 and the 24 MEO PRNs of
BDS-3 (C19–C30, C32–C37, C41–C46) in slot order A1…C8; the real PRN-to-slot
assignment is not modelled.

GPS (``"gps"``) is the shipped DO-229 almanac (:func:`~testbed.sensors.gnss.almanac.load_do229`,
placed weekly), unchanged.

Times are GPS system time throughout; the nominal orbits carry no system-time
offset (GST, BDT) and zero satellite clocks. Right ascensions are turned into
Earth-fixed node longitudes with Greenwich mean sidereal time (IAU 1982,
UT1 = UTC); precession/nutation between the published frame and the
equator of date (≤ 0.3° in node longitude) is not modelled: irrelevant to a
nominal geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.frames import OMEGA_EARTH
from testbed.sensors.gnss.almanac import OrbitFileProblem, load_constellation, load_do229, load_rinex_nav
from testbed.sensors.gnss.navfile import MAX_AGE_S
from testbed.sensors.gnss.orbits import (MU_GPS, SYSTEM_NAMES, Ephemeris, concat_ephemerides, from_keplerian,
                                        sat_states)
from testbed.sensors.gnss.settings import CONSTELLATION_SYSTEMS, GnssSettings
from testbed.sensors.gnss.timebase import _as_utc, gps_seconds_to_utc, gps_seconds_to_week_sow, utc_to_gps_seconds

#: Gravitational parameter of the Galileo (GTRF) and BeiDou (CGCS2000) ICDs, m³/s².
MU_GALILEO_BEIDOU = 3.986004418e14
#: CGCS2000 (and WGS84) equatorial radius, m: the BDS ICD altitudes are above it.
EARTH_RADIUS_EQ = 6_378_137.0
SECONDS_PER_DAY = 86_400.0
#: Constellation names accepted by :func:`nominal_constellation`.
NOMINAL_NAMES = ("gps", "galileo", "beidou")

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class Walker:
    """A Walker delta pattern i: T/P/F at an epoch (circular orbits).

    Slot s (1…T/P) of plane p (0…P−1): RAAN = ``raan_deg`` + 360°·p/P,
    argument of latitude u = ``arg_latitude_deg`` + 360°·(s−1)/(T/P) + 360°·F·p/T.
    """

    total: int
    planes: int
    phasing: int
    semi_major_axis_m: float
    inclination_deg: float
    raan_deg: float
    arg_latitude_deg: float

    def slots(self) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """Plane index, slot number, RAAN (deg) and argument of latitude (deg), each ``(T,)``, plane-major."""
        per_plane = self.total // self.planes
        if per_plane * self.planes != self.total:
            raise ValueError(f"Walker: total {self.total} is not a multiple of planes {self.planes}")
        plane, slot = np.divmod(np.arange(self.total), per_plane)
        raan = np.mod(self.raan_deg + 360.0 * plane / self.planes, 360.0)
        u = np.mod(self.arg_latitude_deg + 360.0 * slot / per_plane + 360.0 * self.phasing * plane / self.total, 360.0)
        return plane, slot + 1, raan, u


#: Galileo reference constellation (European GNSS Service Centre, epoch 2016-11-21 00:00:00 UTC).
GALILEO_EPOCH_UTC = "2016-11-21T00:00:00Z"
GALILEO_WALKER = Walker(total=24, planes=3, phasing=1, semi_major_axis_m=29_599_800.0, inclination_deg=56.0,
                        raan_deg=317.632, arg_latitude_deg=0.153 - 4 * 45.0)  # slot A05 at M = 0.153°
GALILEO_RAAN_RATE_DEG_DAY = -0.02764398
GALILEO_MEAN_MOTION_DEG_DAY = 613.72253566

#: BDS-3 nominal orbits (BDS-SIS-ICD-B1C-1.0 §3): altitudes above the CGCS2000 equatorial radius.
BEIDOU_MEO_ALTITUDE_M = 21_528_000.0
BEIDOU_INCLINATION_DEG = 55.0
BEIDOU_GEO_LONGITUDES_DEG = {59: 140.0, 60: 80.0, 61: 110.5}
BEIDOU_IGSO_PRNS = (38, 39, 40)
BEIDOU_IGSO_NODE_LONGITUDE_DEG = 118.0
BEIDOU_MEO_PRNS = tuple(range(19, 31)) + tuple(range(32, 38)) + tuple(range(41, 47))
#: BeiDou time origin (BDT week 0), used as the default epoch of the unpublished phases.
BEIDOU_EPOCH_UTC = "2006-01-01T00:00:00Z"


def geosynchronous_radius(mu: float = MU_GALILEO_BEIDOU) -> float:
    """Radius (m) of the circular orbit whose mean motion is Earth's rotation rate: (μ/Ω̇e²)^(1/3)."""
    return (mu / OMEGA_EARTH**2) ** (1.0 / 3.0)


def greenwich_mean_sidereal_angle(utc: datetime | str) -> float:
    """Greenwich mean sidereal angle (rad, in [0, 2π)) at a UTC instant, IAU 1982 (UT1 = UTC).

    GMST = 67310.54841 s + (876600 h + 8640184.812866 s)·T + 0.093104 s·T² − 6.2e-6 s·T³,
    T in Julian centuries of UT1 from J2000.0 (Aoki et al., "The new definition of
    universal time", Astron. Astrophys. 105, 359–361, 1982). UT1 − UTC < 0.9 s
    moves it by < 4e-3°.
    """
    u = _as_utc(utc)
    j2000 = datetime(2000, 1, 1, 12, tzinfo=timezone.utc)
    T = (u - j2000).total_seconds() / (SECONDS_PER_DAY * 36525.0)
    gmst_s = 67310.54841 + (876600.0 * 3600.0 + 8640184.812866) * T + 0.093104 * T**2 - 6.2e-6 * T**3
    return (gmst_s % SECONDS_PER_DAY) / SECONDS_PER_DAY * 2.0 * math.pi


def circular_orbits(prn: ArrayLike, system: str, *, epoch_utc: datetime | str, semi_major_axis_m: ArrayLike,
                    inclination_deg: ArrayLike, node_longitude_deg: ArrayLike, arg_latitude_deg: ArrayLike,
                    mean_motion_rad_s: ArrayLike | None = None, raan_rate_rad_s: ArrayLike = 0.0,
                    source: str) -> Ephemeris:
    """Circular orbits given at an epoch, as an :class:`Ephemeris` (arrays ``(S,)``, or scalars).

    Parameters
    ----------
    node_longitude_deg : Earth-fixed longitude of the ascending node at the epoch
        (right ascension minus the Greenwich sidereal angle).
    arg_latitude_deg : argument of latitude u at the epoch (ω = 0, so M = u).
    mean_motion_rad_s : rate of u; default Keplerian √(μ/a³) with the Galileo/BeiDou μ.
    raan_rate_rad_s : inertial rate of the node (secular drift), default 0.
    """
    t0 = utc_to_gps_seconds(epoch_utc)
    week, toe_sow = gps_seconds_to_week_sow(t0)
    a = np.asarray(semi_major_axis_m, float)
    n = np.sqrt(MU_GALILEO_BEIDOU / a**3) if mean_motion_rad_s is None else np.asarray(mean_motion_rad_s, float)
    # sat_states: Ω(t) = Ω0 + (Ω̇ − Ω̇e)·tk − Ω̇e·toe_sow, so the node longitude at toe is Ω0 − Ω̇e·toe_sow.
    omega0 = np.asarray(node_longitude_deg, float) * _DEG + OMEGA_EARTH * float(toe_sow)
    return from_keplerian(prn, week=int(week), toe_sow=float(toe_sow), sqrt_a=np.sqrt(a), e=0.0,
                          i0=np.asarray(inclination_deg, float) * _DEG, omega0=_wrap(omega0),
                          omega_dot=raan_rate_rad_s, w=0.0, m0=_wrap(np.asarray(arg_latitude_deg, float) * _DEG),
                          delta_n=n - np.sqrt(MU_GPS / a**3), system=system, source=source)


def walker_orbits(pattern: Walker, prn: ArrayLike, system: str, *, epoch_utc: datetime | str,
                  mean_motion_rad_s: float | None = None, raan_rate_rad_s: float = 0.0,
                  source: str) -> Ephemeris:
    """The slots of a Walker pattern whose RAANs are right ascensions at ``epoch_utc``."""
    _, _, raan, u = pattern.slots()
    node_lon = raan - greenwich_mean_sidereal_angle(epoch_utc) / _DEG
    return circular_orbits(prn, system, epoch_utc=epoch_utc, semi_major_axis_m=pattern.semi_major_axis_m,
                           inclination_deg=pattern.inclination_deg, node_longitude_deg=node_lon,
                           arg_latitude_deg=u, mean_motion_rad_s=mean_motion_rad_s,
                           raan_rate_rad_s=raan_rate_rad_s, source=source)


def galileo_nominal(t_ref_gps: float | None = None) -> Ephemeris:
    """Galileo's 24 nominal slots (E01–E24), referred to the hour nearest ``t_ref_gps`` if given."""
    eph = walker_orbits(GALILEO_WALKER, np.arange(1, 25), "E", epoch_utc=GALILEO_EPOCH_UTC,
                        mean_motion_rad_s=GALILEO_MEAN_MOTION_DEG_DAY * _DEG / SECONDS_PER_DAY,
                        raan_rate_rad_s=GALILEO_RAAN_RATE_DEG_DAY * _DEG / SECONDS_PER_DAY,
                        source="Galileo nominal 24/3/1 (reference slots, epoch 2016-11-21)")
    return _near(eph, t_ref_gps)


def beidou3_nominal(t_ref_gps: float | None = None, *, meo_raan_deg: float = 0.0,
                    meo_arg_latitude_deg: float = 0.0, igso_arg_latitude_deg: float = 0.0,
                    beidou_epoch_utc: datetime | str = BEIDOU_EPOCH_UTC) -> Ephemeris:
    """BeiDou-3's 24 MEO, 3 IGSO and 3 GEO nominal orbits (see the module doc), MEO first.

    ``meo_raan_deg`` / ``meo_arg_latitude_deg``: right ascension of plane A's node and
    argument of latitude of slot A1 at ``beidou_epoch_utc``; ``igso_arg_latitude_deg``:
    argument of latitude of C38 then (C39, C40 follow 120° and 240° behind on the same track).
    """
    meo = walker_orbits(Walker(total=24, planes=3, phasing=1,
                               semi_major_axis_m=EARTH_RADIUS_EQ + BEIDOU_MEO_ALTITUDE_M,
                               inclination_deg=BEIDOU_INCLINATION_DEG, raan_deg=meo_raan_deg,
                               arg_latitude_deg=meo_arg_latitude_deg),
                        BEIDOU_MEO_PRNS, "C", epoch_utc=beidou_epoch_utc, source="BeiDou-3 MEO nominal 24/3/1")
    a_gso = geosynchronous_radius()
    # One ground track for the three IGSOs: with n = Ω̇e, Δt after the epoch u = u_k + Ω̇e·Δt and the
    # Earth-fixed node is at λ_k − Ω̇e·Δt, so when u passes 0 the node is at λ_k + u_k: λ_k = λ_node − u_k.
    u_igso = igso_arg_latitude_deg - 120.0 * np.arange(3)
    igso = circular_orbits(BEIDOU_IGSO_PRNS, "C", epoch_utc=beidou_epoch_utc, semi_major_axis_m=a_gso,
                           inclination_deg=BEIDOU_INCLINATION_DEG,
                           node_longitude_deg=BEIDOU_IGSO_NODE_LONGITUDE_DEG - u_igso, arg_latitude_deg=u_igso,
                           mean_motion_rad_s=OMEGA_EARTH, source="BeiDou-3 IGSO nominal")
    geo_prn = np.array(sorted(BEIDOU_GEO_LONGITUDES_DEG))
    geo = circular_orbits(geo_prn, "C", epoch_utc=beidou_epoch_utc, semi_major_axis_m=a_gso, inclination_deg=0.0,
                          node_longitude_deg=[BEIDOU_GEO_LONGITUDES_DEG[p] for p in geo_prn], arg_latitude_deg=0.0,
                          mean_motion_rad_s=OMEGA_EARTH, source="BeiDou-3 GEO nominal")
    eph = concat_ephemerides([meo, igso, geo], source="BeiDou-3 nominal (24 MEO + 3 IGSO + 3 GEO)")
    return _near(eph, t_ref_gps)


def nominal_constellation(name: str, t_ref_gps: float) -> Ephemeris:
    """One nominal constellation by name (``"gps"``: the DO-229 almanac; ``"galileo"``; ``"beidou"``)."""
    if name == "gps":
        return load_do229(t_ref_gps)
    if name == "galileo":
        return galileo_nominal(t_ref_gps)
    if name == "beidou":
        return beidou3_nominal(t_ref_gps)
    raise ValueError(f"constellation: expected one of {list(NOMINAL_NAMES)}, got {name!r}")


def nominal_constellations(names: Sequence[str], t_ref_gps: float) -> Ephemeris:
    """Several nominal constellations as one mixed :class:`Ephemeris`, in the order named."""
    names = list(names)
    bad = [n for n in names if n not in NOMINAL_NAMES]
    if bad or not names or len(set(names)) != len(names):
        raise ValueError(f"constellations: expected distinct names from {list(NOMINAL_NAMES)}, got {names!r}")
    return concat_ephemerides([nominal_constellation(n, t_ref_gps) for n in names])


def tracked_constellations(settings: GnssSettings, t_ref_gps: float) -> Ephemeris:
    """The satellites ``settings`` track near ``t_ref_gps``: its ``constellations`` in order, each from its orbit
    source (:meth:`GnssSettings.orbit_source_of`: nominal slots, the GPS almanac, or a file's records of that
    system alone), each constellation's ``excluded_prns`` marked unhealthy. GPS alone is the almanac loader's
    record itself."""
    parts = []
    for name in settings.constellations:
        source, path, _ = settings.orbit_source_of(name)
        eph = constellation_orbits(name, source, path, t_ref_gps, settings.almanac_week)
        parts.append(with_excluded(eph, getattr(settings, name).excluded_prns, name))
    return parts[0] if len(parts) == 1 else concat_ephemerides(parts)


class StaleOrbits(OrbitFileProblem):
    """A navigation file whose records of a system are all too far from the flight to be used."""


def constellation_orbits(name: str, source: str, path, t_ref_gps: float, week_mode: str = "auto") -> Ephemeris:
    """Constellation ``name``'s satellites near ``t_ref_gps`` from ``source``: ``"nominal"`` (GPS: the DO-229
    almanac), ``"yuma"`` / ``"sem"`` (GPS almanac files), ``"rinex_nav"`` (the file's records of this system:
    per satellite the one whose toe is nearest ``t_ref_gps``; a satellite whose nearest record is more than
    :data:`~testbed.sensors.gnss.navfile.MAX_AGE_S` away has no orbit a receiver would use and is left out).
    Raises :class:`~testbed.sensors.gnss.almanac.OrbitFileProblem` when the file has no record of the system,
    :class:`StaleOrbits` when none is current, ValueError when it cannot be read."""
    letter = CONSTELLATION_SYSTEMS[name]
    if source == "nominal":
        return load_do229(t_ref_gps, week_mode) if name == "gps" else nominal_constellation(name, t_ref_gps)
    if source == "rinex_nav":
        eph = load_rinex_nav(path, systems=letter).select(t_ref_gps)
        current = np.abs(eph.toe_gps - t_ref_gps) <= MAX_AGE_S
        if not current.any():
            age = float(np.min(np.abs(eph.toe_gps - t_ref_gps)))
            raise StaleOrbits(f"its nearest {SYSTEM_NAMES[letter]} broadcast record is {age / 3600:.1f} h from "
                              f"{gps_seconds_to_utc(t_ref_gps):%Y-%m-%dT%H:%M:%SZ}: expected a "
                              f"navigation file with records within {MAX_AGE_S / 3600:.0f} h of the flight")
        return eph if current.all() else eph.take(np.flatnonzero(current))
    eph = load_constellation(source, path, t_ref_gps, week_mode)  # a GPS almanac file
    return eph if np.all(eph.system == letter) else eph.take(np.flatnonzero(eph.system == letter))


def with_excluded(eph: Ephemeris, excluded_prns: Sequence[int], name: str) -> Ephemeris:
    """``eph`` with the slots of ``excluded_prns`` unhealthy (health 1); unchanged when there are none."""
    if not excluded_prns:
        return eph
    missing = sorted(set(excluded_prns) - set(np.asarray(eph.prn).tolist()))
    if missing:
        letter = CONSTELLATION_SYSTEMS[name]
        raise ValueError(f"gnss.{name}.excluded_prns: {[f'{letter}{p:02d}' for p in missing]} not in the "
                         f"constellation (it has {sorted(set(np.asarray(eph.prn).tolist()))})")
    health = np.where(np.isin(eph.prn, list(excluded_prns)), 1, np.asarray(eph.health))
    return replace(eph, health=health)


def repeat_period(eph: Ephemeris, t_gps: float, near_s: float, *, search_s: float = 3600.0,
                  step_s: float = 10.0) -> tuple[NDArray, NDArray]:
    """Per slot, the delay τ near ``near_s`` after which the Earth-fixed position comes back closest.

    A coarse scan of |r(t+τ) − r(t)| (ECEF) over ``near_s ± search_s`` at ``step_s``, then
    a parabola through the three samples around the minimum of the squared distance.

    Returns
    -------
    tau_s : (S,) s.   miss_m : (S,) m, the distance left at τ.
    """
    r0 = sat_states(eph, t_gps)[0]  # (S, 3)
    tau = near_s + np.arange(-search_s, search_s + step_s / 2, step_s)
    d2 = np.sum((sat_states(eph, t_gps + tau)[0] - r0) ** 2, axis=-1)  # (K, S)
    k = np.clip(np.argmin(d2, axis=0), 1, tau.size - 2)
    cols = np.arange(d2.shape[1])
    ym, y0, yp = d2[k - 1, cols], d2[k, cols], d2[k + 1, cols]
    curv = ym - 2 * y0 + yp
    shift = np.where(curv > 0, 0.5 * (ym - yp) / np.where(curv > 0, curv, 1.0), 0.0)
    best = tau[k] + shift * step_s
    miss = np.linalg.norm(sat_states(eph, t_gps + best, per_slot=True)[0] - r0, axis=-1)
    return best, miss


def _near(eph: Ephemeris, t_ref_gps: float | None) -> Ephemeris:
    """The same orbits referred to the whole hour nearest ``t_ref_gps`` (short propagation spans)."""
    if t_ref_gps is None:
        return eph
    return eph.rebased(np.round(float(t_ref_gps) / 3600.0) * 3600.0)


def _wrap(angle_rad: NDArray) -> NDArray:
    return np.mod(np.asarray(angle_rad) + np.pi, 2 * np.pi) - np.pi


__all__ = ["GALILEO_WALKER", "NOMINAL_NAMES", "StaleOrbits", "Walker", "beidou3_nominal", "circular_orbits",
           "constellation_orbits", "galileo_nominal", "geosynchronous_radius", "greenwich_mean_sidereal_angle",
           "nominal_constellation", "nominal_constellations", "repeat_period", "tracked_constellations",
           "walker_orbits", "with_excluded"]

"""GNSS satellite orbits and clocks from almanac or broadcast ephemeris (IS-GPS-200).

One record type, :class:`Ephemeris`, holds a constellation as arrays over
satellite slots ``(S,)``; each slot carries its RINEX 3 system letter
(``G`` GPS, ``E`` Galileo, ``C`` BeiDou) next to its PRN, so a mixed
constellation (:func:`concat_ephemerides`) keeps G01 and E01 apart. An almanac is an ephemeris whose perturbation terms
(Δn, IDOT, the six harmonic corrections, af2) are zero, so the same
IS-GPS-200 equations (Table 20-IV) serve both: semi-major axis from √A,
corrected mean motion, Kepler's equation, argument of latitude with harmonic
corrections, and the longitude of the ascending node corrected for Earth
rotation, Ω = Ω0 + (Ω̇ − Ω̇e)·tk − Ω̇e·toe.

:func:`sat_states` is vectorised over any leading shape of times and returns
ECEF (WGS84, Earth-fixed at the same instant) position, velocity and the
satellite clock offset and rate. Velocity is the analytic time derivative of
the position equations (checked against finite differences in the tests).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.frames import OMEGA_EARTH
from testbed.records import satellite_ids
from testbed.sensors.gnss.timebase import SECONDS_PER_WEEK

#: WGS84 gravitational parameter used by GPS (IS-GPS-200), m³/s².
MU_GPS = 3.986005e14
#: RINEX 3 system letters the records carry, and what they name.
SYSTEM_NAMES = {"G": "GPS", "E": "Galileo", "C": "BeiDou"}
#: Relativistic clock-correction constant F = −2√μ/c² (IS-GPS-200 20.3.3.3.3.1), s/√m.
F_REL = -4.442807633e-10
_KEPLER_ITERATIONS = 8  # Newton from E0 = M: quadratic convergence, e < 0.03 -> machine precision in 3-4


@dataclass(frozen=True)
class Ephemeris:
    """Keplerian orbit + clock parameters per satellite slot, all arrays ``(S,)``.

    Angles in rad, rates in rad/s, times in s. ``week`` is the full GPS week of
    ``toe_sow``/``toc_sow`` (no 10-bit ambiguity left once a record is built);
    every time is GPS system time, whatever the satellite's system.
    ``system`` (S,) holds the RINEX 3 system letter of each slot; omitted, every
    slot is GPS (``"G"``), as for every loader that reads GPS records only.
    ``bds_geo`` (S,) marks BeiDou GEO broadcast records, whose orbit elements are
    given in the ICD's GEO frame (inclined 5° and not rotating with the Earth over
    tk; BDS-SIS-ICD-B1I-3.0 §5.2.4.12): :func:`sat_states` applies the GEO rotation
    to them. Omitted, no slot is (every nominal orbit is in the ordinary form).
    Records of every system follow the GPS conventions here (μ and Ω̇e of
    IS-GPS-200, GPS time); :mod:`testbed.sensors.gnss.broadcast` converts
    Galileo and BeiDou broadcast elements exactly on the way in and out.
    """

    prn: NDArray
    health: NDArray
    week: NDArray
    toe_sow: NDArray
    toc_sow: NDArray
    sqrt_a: NDArray
    e: NDArray
    i0: NDArray
    idot: NDArray
    omega0: NDArray
    omega_dot: NDArray
    w: NDArray
    m0: NDArray
    delta_n: NDArray
    cuc: NDArray
    cus: NDArray
    crc: NDArray
    crs: NDArray
    cic: NDArray
    cis: NDArray
    af0: NDArray
    af1: NDArray
    af2: NDArray
    tgd: NDArray
    iode: NDArray
    source: str = "ephemeris"
    system: NDArray | None = None
    bds_geo: NDArray | None = None

    def __post_init__(self) -> None:
        prn_shape = np.shape(self.prn)
        system = np.full(prn_shape, "G") if self.system is None else np.asarray(self.system, dtype="<U1")
        if system.shape != prn_shape:
            raise ValueError(f"Ephemeris.system: expected shape {prn_shape} (one letter per slot), got {system.shape}")
        unknown = sorted(set(system.tolist()) - set(SYSTEM_NAMES))
        if unknown:
            raise ValueError(f"Ephemeris.system: expected letters from {sorted(SYSTEM_NAMES)}, got {unknown}")
        object.__setattr__(self, "system", system)
        geo = np.zeros(prn_shape, bool) if self.bds_geo is None else np.asarray(self.bds_geo, dtype=bool)
        if geo.shape != prn_shape:
            raise ValueError(f"Ephemeris.bds_geo: expected shape {prn_shape} (one flag per slot), got {geo.shape}")
        if (geo & (system != "C")).any():
            raise ValueError(f"Ephemeris.bds_geo: only BeiDou slots can be GEO records, got "
                             f"{self.sat_id[geo & (system != 'C')].tolist() if prn_shape else 'a non-C slot'}")
        object.__setattr__(self, "bds_geo", geo)

    @property
    def sat_id(self) -> NDArray:
        """RINEX 3 satellite identifiers ``(S,)``, e.g. ``"G05"``, ``"E12"``, ``"C59"``."""
        return satellite_ids(self.system, self.prn)

    @property
    def toe_gps(self) -> NDArray:
        """Time of ephemeris as seconds since the GPS epoch ``(S,)``."""
        return self.week * SECONDS_PER_WEEK + self.toe_sow

    @property
    def toc_gps(self) -> NDArray:
        return self.week * SECONDS_PER_WEEK + self.toc_sow

    def __len__(self) -> int:
        return len(self.prn)

    def take(self, idx: ArrayLike) -> "Ephemeris":
        """A sub-constellation (slots ``idx``)."""
        idx = np.asarray(idx)
        return replace(self, **{f.name: np.asarray(getattr(self, f.name))[idx]
                                for f in fields(self) if f.name != "source"})

    def select(self, t_ref_gps: float) -> "Ephemeris":
        """One record per PRN: the one whose toe is nearest ``t_ref_gps``; slots sorted by PRN.

        A broadcast navigation file holds one record every ~2 h per satellite;
        a flight lasts minutes, so one record per satellite (the nearest) is used
        for the whole flight (its fit interval is ±2 h).
        """
        ids = self.sat_id
        dist = np.abs(self.toe_gps - float(t_ref_gps))
        keep = [np.flatnonzero(ids == i)[np.argmin(dist[ids == i])] for i in np.unique(ids)]
        return self.take(np.asarray(keep, int))

    def rebased(self, toe_gps: ArrayLike) -> "Ephemeris":
        """The same orbits and clocks expressed with a new toe = toc (seconds since GPS epoch).

        Exact for the IS-GPS-200 model: time enters only through the mean
        anomaly, the node, the inclination rate and the clock polynomial, all
        propagated here; the harmonic terms depend on the argument of latitude only.
        Used to write broadcast records valid (|t − toe| < 2 h) at a flight's time.
        A BeiDou GEO record (``bds_geo``) cannot be moved so (its frame turns with
        tk): refused; :func:`testbed.sensors.gnss.broadcast.geo_record` re-fits one.
        """
        if np.any(self.bds_geo):
            raise ValueError(f"Ephemeris.rebased: BeiDou GEO records {self.sat_id[self.bds_geo].tolist()} cannot be "
                             f"re-referenced exactly; expected ordinary-form records only")
        new = np.broadcast_to(np.asarray(toe_gps, float), self.prn.shape)
        dt = new - self.toe_gps
        new_week = np.floor(new / SECONDS_PER_WEEK)
        n = np.sqrt(MU_GPS / self.sqrt_a**6) + self.delta_n
        # Ω0' = Ω0 + Ω̇·Δ − Ω̇e·604800·Δweek keeps Ω(t) = Ω0 + (Ω̇−Ω̇e)(t−toe) − Ω̇e·toe_sow unchanged.
        omega0 = self.omega0 + self.omega_dot * dt - OMEGA_EARTH * SECONDS_PER_WEEK * (new_week - self.week)
        dtc = new - self.toc_gps
        return replace(
            self,
            week=new_week.astype(np.int64), toe_sow=new - new_week * SECONDS_PER_WEEK,
            toc_sow=new - new_week * SECONDS_PER_WEEK,
            m0=np.mod(self.m0 + n * dt + np.pi, 2 * np.pi) - np.pi,
            omega0=np.mod(omega0 + np.pi, 2 * np.pi) - np.pi,
            i0=self.i0 + self.idot * dt,
            af0=self.af0 + self.af1 * dtc + self.af2 * dtc**2,
            af1=self.af1 + 2 * self.af2 * dtc,
        )


def concat_ephemerides(parts: Sequence[Ephemeris], source: str | None = None) -> Ephemeris:
    """One constellation from several (e.g. GPS + Galileo + BeiDou), slots in the order given.

    A satellite (system letter + PRN) present in two parts is refused: a mixed
    constellation is a set of distinct satellites.
    """
    if not parts:
        raise ValueError("concat_ephemerides: expected at least one constellation, got none")
    ids = np.concatenate([p.sat_id for p in parts])
    uniq, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"concat_ephemerides: satellites {uniq[counts > 1].tolist()} appear more than once")
    arrays = {f.name: np.concatenate([np.asarray(getattr(p, f.name)) for p in parts])
              for f in fields(Ephemeris) if f.name != "source"}
    return Ephemeris(**arrays, source=source if source is not None else " + ".join(p.source for p in parts))


def from_keplerian(prn, *, week, toe_sow, sqrt_a, e, i0, omega0, omega_dot, w, m0, af0=0.0, af1=0.0,
                   health=0, source: str = "almanac", delta_n=0.0, system="G") -> Ephemeris:
    """An :class:`Ephemeris` from almanac-type parameters. Arrays ``(S,)``.

    The harmonic terms, IDOT and af2 are zero. ``delta_n`` (rad/s) adds to the
    Keplerian mean motion √(μ/A³) (μ of IS-GPS-200): a nominal orbit whose
    published mean motion differs from it (another system's μ, secular
    perturbations) is carried exactly. ``system``: RINEX 3 letter(s).
    """
    prn = np.asarray(prn, np.int64)
    S = prn.shape

    def arr(v, dtype=float):
        return np.broadcast_to(np.asarray(v, dtype), S).copy()

    z = np.zeros(S)
    return Ephemeris(prn=prn, health=arr(health, np.int64), week=arr(week, np.int64), toe_sow=arr(toe_sow),
                     toc_sow=arr(toe_sow), sqrt_a=arr(sqrt_a), e=arr(e), i0=arr(i0), idot=z.copy(),
                     omega0=arr(omega0), omega_dot=arr(omega_dot), w=arr(w), m0=arr(m0), delta_n=arr(delta_n),
                     cuc=z.copy(), cus=z.copy(), crc=z.copy(), crs=z.copy(), cic=z.copy(), cis=z.copy(),
                     af0=arr(af0), af1=arr(af1), af2=z.copy(), tgd=z.copy(), iode=np.zeros(S, np.int64),
                     source=source, system=arr(system, "<U1"))


def _kepler_E(M: NDArray, e: NDArray) -> NDArray:
    """Solve Kepler's equation M = E − e·sin E (Newton, fixed iteration count, vectorised).

    Circular slots (e = 0: the nominal Galileo and BeiDou orbits) are E = M, which Newton from
    E0 = M returns unchanged: they are left out of the iterations (the same numbers, a third of the work
    with three constellations)."""
    E = M.copy()
    ecc = np.asarray(e)
    if ecc.ndim == 1 and E.shape[-1:] == ecc.shape and not ecc.all():
        cols = np.flatnonzero(ecc)
        E[..., cols] = _kepler_E(M[..., cols], ecc[cols])
        return E
    for _ in range(_KEPLER_ITERATIONS):
        E = E - (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
    return E


def sat_states(eph: Ephemeris, t_gps: ArrayLike, *, per_slot: bool = False, position_only: bool = False
               ) -> tuple[NDArray, NDArray | None, NDArray | None, NDArray | None]:
    """Satellite ECEF position, velocity and clock at GPS times (IS-GPS-200 Table 20-IV).

    Parameters
    ----------
    eph : constellation of S slots.
    t_gps : (...,) seconds since the GPS epoch (system time at which the state is
        wanted: the transmit time for ranging); with ``per_slot=True`` the last
        axis is the satellite slot, (..., S), one time per satellite.
    position_only : the position alone (the others None), the same numbers: what an
        iteration on the light time needs.

    Returns
    -------
    pos_ecef : (..., S, 3) m, in the Earth-fixed frame of the same instant.
    vel_ecef : (..., S, 3) m/s, Earth-relative velocity in that frame.
    clock_s : (..., S) s, satellite clock offset dtsv incl. the relativistic term (not TGD).
    clock_rate : (..., S) s/s.
    """
    t = np.asarray(t_gps, float)
    if not per_slot:
        t = t[..., None]
    elif t.shape[-1:] != (len(eph),):
        raise ValueError(f"t_gps: expected shape (..., {len(eph)}) with per_slot=True, got {t.shape}")
    tk = t - eph.toe_gps  # no week crossover: full GPS times on both sides
    A = eph.sqrt_a**2
    n = np.sqrt(MU_GPS / A**3) + eph.delta_n
    M = eph.m0 + n * tk
    e = eph.e
    E = _kepler_E(np.broadcast_to(M, np.broadcast_shapes(M.shape, e.shape)).copy(), e)
    sE, cE = np.sin(E), np.cos(E)
    one_m_ecosE = 1.0 - e * cE
    sq = np.sqrt(1.0 - e**2)
    nu = np.arctan2(sq * sE, cE - e)
    phi = nu + eph.w
    s2, c2 = np.sin(2 * phi), np.cos(2 * phi)
    u = phi + eph.cus * s2 + eph.cuc * c2
    r = A * one_m_ecosE + eph.crs * s2 + eph.crc * c2
    inc = eph.i0 + eph.cis * s2 + eph.cic * c2 + eph.idot * tk
    Omega_dot_k = eph.omega_dot - OMEGA_EARTH
    Omega = eph.omega0 + Omega_dot_k * tk - OMEGA_EARTH * eph.toe_sow
    su, cu, si, ci, sO, cO = np.sin(u), np.cos(u), np.sin(inc), np.cos(inc), np.sin(Omega), np.cos(Omega)
    xp, yp = r * cu, r * su
    x = xp * cO - yp * ci * sO
    y = xp * sO + yp * ci * cO
    z = yp * si
    if position_only and not np.any(eph.bds_geo):  # the BeiDou GEO form below turns the positions too
        return np.stack([x, y, z], -1), None, None, None
    # Time derivatives (chain rule through E, ν, the harmonic terms, i and Ω).
    E_dot = n / one_m_ecosE
    phi_dot = E_dot * sq / one_m_ecosE
    u_dot = phi_dot * (1.0 + 2.0 * (eph.cus * c2 - eph.cuc * s2))
    r_dot = A * e * sE * E_dot + 2.0 * phi_dot * (eph.crs * c2 - eph.crc * s2)
    i_dot = eph.idot + 2.0 * phi_dot * (eph.cis * c2 - eph.cic * s2)
    xp_dot = r_dot * cu - r * u_dot * su
    yp_dot = r_dot * su + r * u_dot * cu
    vx = xp_dot * cO - yp_dot * ci * sO + yp * si * sO * i_dot - Omega_dot_k * y
    vy = xp_dot * sO + yp_dot * ci * cO - yp * si * cO * i_dot + Omega_dot_k * x
    vz = yp_dot * si + yp * ci * i_dot
    pos, vel = np.stack([x, y, z], -1), np.stack([vx, vy, vz], -1)
    if np.any(eph.bds_geo):
        gpos, gvel = _bds_geo_states(eph, tk, xp, yp, xp_dot, yp_dot, si, ci, i_dot)
        pos = np.where(eph.bds_geo[:, None], gpos, pos)
        vel = np.where(eph.bds_geo[:, None], gvel, vel)
    if position_only:
        return pos, None, None, None
    tc = t - eph.toc_gps
    rel = F_REL * e * eph.sqrt_a * sE
    clock = eph.af0 + eph.af1 * tc + eph.af2 * tc**2 + rel
    clock_rate = eph.af1 + 2 * eph.af2 * tc + F_REL * e * eph.sqrt_a * cE * E_dot
    return pos, vel, clock, clock_rate


#: BeiDou's Earth rotation rate (CGCS2000, BDS-SIS-ICD-B1I-3.0 §5.2.4.12), rad/s: the GEO frame turns at it
OMEGA_EARTH_BDS = 7.292115e-5
_GEO_TILT = np.radians(-5.0)  # the ICD's R_X(−5°)


def _bds_geo_states(eph: Ephemeris, tk, xp, yp, xp_dot, yp_dot, si, ci, i_dot) -> tuple[NDArray, NDArray]:
    """ECEF position and velocity (..., S, 3) of BeiDou GEO records (BDS-SIS-ICD-B1I-3.0 §5.2.4.12).

    The orbit is placed in a frame whose node does not follow the Earth over tk,
    Ω = Ω0 + Ω̇·tk − Ω̇e·toe, then turned by R_Z(Ω̇e·tk)·R_X(−5°) into ECEF. Ω̇e is
    BeiDou's (:data:`OMEGA_EARTH_BDS`) for the turn; ``omega0`` holds the record's Ω0
    re-referred by :mod:`~testbed.sensors.gnss.broadcast` so that the GPS Ω̇e·toe here
    gives the ICD's Ω at toe.
    """
    Omega = eph.omega0 + eph.omega_dot * tk - OMEGA_EARTH * eph.toe_sow
    sO, cO = np.sin(Omega), np.cos(Omega)
    xg = xp * cO - yp * ci * sO
    yg = xp * sO + yp * ci * cO
    zg = yp * si
    vxg = xp_dot * cO - yp_dot * ci * sO + yp * si * sO * i_dot - eph.omega_dot * yg
    vyg = xp_dot * sO + yp_dot * ci * cO - yp * si * cO * i_dot + eph.omega_dot * xg
    vzg = yp_dot * si + yp * ci * i_dot
    c5, s5 = np.cos(_GEO_TILT), np.sin(_GEO_TILT)
    # R_X(−5°): (x, y c5 + z s5, −y s5 + z c5); then R_Z(φ), φ = Ω̇e·tk: (x cφ + y sφ, −x sφ + y cφ, z)
    y1, z1 = yg * c5 + zg * s5, -yg * s5 + zg * c5
    vy1, vz1 = vyg * c5 + vzg * s5, -vyg * s5 + vzg * c5
    phi = OMEGA_EARTH_BDS * tk
    sp, cp = np.sin(phi), np.cos(phi)
    pos = np.stack([xg * cp + y1 * sp, -xg * sp + y1 * cp, z1], -1)
    vel = np.stack([vxg * cp + vy1 * sp + OMEGA_EARTH_BDS * (-xg * sp + y1 * cp),
                    -vxg * sp + vy1 * cp - OMEGA_EARTH_BDS * (xg * cp + y1 * sp), vz1], -1)
    return pos, vel

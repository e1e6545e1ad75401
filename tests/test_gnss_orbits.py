"""GNSS constellation: time base, loaders, IS-GPS-200 orbits against independent forms."""

import math
from datetime import datetime, timezone

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from testbed.frames import OMEGA_EARTH
from testbed.sensors.gnss.almanac import load_do229, load_rinex_nav, load_sem, load_yuma, resolve_week
from testbed.sensors.gnss.orbits import MU_GPS, sat_states
from testbed.sensors.gnss.rinex import write_nav
from testbed.sensors.gnss.timebase import (gps_seconds_to_calendar, gps_seconds_to_week_sow,
                                           utc_to_gps_seconds)

ONE_MM = 1e-3
ONE_CM = 1e-2
T_REF = utc_to_gps_seconds("2024-03-15T06:00:00Z")


def test_gps_time_known_instants():
    # Second GPS week rollover (published): 2019-04-07 00:00:00 GPST = week 2048, TOW 0.
    # In UTC that is 18 s earlier (GPS − UTC = 18 s since 2017-01-01).
    w, sow = gps_seconds_to_week_sow(utc_to_gps_seconds("2019-04-06T23:59:42Z"))
    assert (w, sow) == (2048, 0.0)
    # The leap second of 2017-01-01: 17 s before, 18 s after.
    base = (datetime(2017, 1, 1, tzinfo=timezone.utc) - datetime(1980, 1, 6, tzinfo=timezone.utc)).total_seconds()
    assert utc_to_gps_seconds("2017-01-01T00:00:00Z") - base == 18
    assert utc_to_gps_seconds("2016-12-31T23:59:59Z") - (base - 1) == 17
    assert gps_seconds_to_calendar(utc_to_gps_seconds("2024-03-15T06:00:00Z")) == datetime(2024, 3, 15, 6, 0, 18)
    with pytest.raises(ValueError, match="start_utc"):
        utc_to_gps_seconds("15/03/2024")


def test_week_modes():
    # periodic: toa placed in the week that brings it nearest the reference time
    assert resolve_week(703, 344063.0, T_REF, "periodic") == round((T_REF - 344063) / 604800)
    # nearest rollover: 703 + k·1024 nearest (2024 lies between 1727 and 2751)
    w = resolve_week(703, 344063.0, T_REF, "nearest_rollover")
    assert w in (1727, 2751) and abs(w * 604800 - T_REF) <= 512 * 604800
    with pytest.raises(ValueError, match="week_mode"):
        resolve_week(703, 0.0, T_REF, "bogus")


def test_radius_period_inclination():
    eph = load_do229(T_REF)
    assert len(eph) == 24 and list(eph.prn) == list(range(1, 25))
    A = eph.sqrt_a**2
    t = T_REF + np.arange(0.0, 86400.0, 600.0)
    pos, vel, clk, _ = sat_states(eph, t)
    # radius: e = 0 circular orbits of radius A
    np.testing.assert_allclose(np.linalg.norm(pos, axis=-1), A[None, :] * np.ones((t.size, 1)), atol=ONE_MM)
    # inclination from the inertial angular momentum h = r × (v_ecef + ω × r)
    w = np.array([0.0, 0.0, OMEGA_EARTH])
    h = np.cross(pos, vel + np.cross(w, pos))
    inc = np.degrees(np.arccos(h[..., 2] / np.linalg.norm(h, axis=-1)))
    np.testing.assert_allclose(inc, 55.0, atol=1e-7)
    # period: the inertial position repeats after 2π/n (Kepler's third law), ≈ half a sidereal day
    P = 2 * np.pi / math.sqrt(MU_GPS / A[0] ** 3)
    assert abs(P - 86164.0905 / 2) < 10.0
    p0, *_ = sat_states(eph, T_REF)
    p1, *_ = sat_states(eph, T_REF + P)
    p1_inertial_back = Rotation.from_rotvec([0, 0, OMEGA_EARTH * P]).apply(p1.reshape(-1, 3))  # ECEF(t+P) -> ECEF(t)
    np.testing.assert_allclose(p1_inertial_back, p0.reshape(-1, 3), atol=ONE_CM)
    # DO-229 clocks are zero
    assert np.all(clk == 0.0)


def test_positions_vs_rotation_composition():
    """Independent form: r = Rz(Ω)·Rx(i)·Rz(u)·[A, 0, 0] with scipy rotations (e = 0, ω = 0)."""
    eph = load_do229(T_REF)
    tk = np.array([-5000.0, 0.0, 1234.5, 7200.0])
    pos, *_ = sat_states(eph, eph.toe_gps[0] + tk)
    A = eph.sqrt_a**2
    n = np.sqrt(MU_GPS / A**3)
    for k, dt in enumerate(tk):
        u = eph.m0 + n * dt + eph.w
        Om = eph.omega0 - OMEGA_EARTH * (eph.toe_sow + dt)
        R = Rotation.from_euler("ZXZ", np.stack([Om, eph.i0, u], -1))
        ref = R.apply(np.stack([A, 0 * A, 0 * A], -1))
        np.testing.assert_allclose(pos[k], ref, atol=ONE_MM)


def test_hand_reference_prn1():
    """tests/references/gnss_do229_prn1_reference.md: PRN 1, toa + 3600 s."""
    eph = load_do229(T_REF)
    pos, *_ = sat_states(eph, eph.toe_gps[0] + 3600.0)
    np.testing.assert_allclose(pos[0], [-15350569.27754523, -10110201.937991962, -19172032.12307781], atol=ONE_MM)


def _perturbed():
    eph = load_do229(T_REF)
    from dataclasses import replace
    S = len(eph)
    rng = np.random.default_rng(7)
    return replace(eph, e=rng.uniform(0.001, 0.02, S), w=rng.uniform(-np.pi, np.pi, S),
                   delta_n=np.full(S, 4.5e-9), idot=np.full(S, -3e-10), cuc=np.full(S, 2e-6),
                   cus=np.full(S, 8e-6), crc=np.full(S, 250.0), crs=np.full(S, -40.0),
                   cic=np.full(S, 1e-7), cis=np.full(S, -8e-8), omega_dot=np.full(S, -8e-9),
                   af0=rng.uniform(-3e-4, 3e-4, S), af1=np.full(S, 2e-12), af2=np.zeros(S))


def test_velocity_is_derivative_of_position():
    """Analytic velocity and clock rate vs central differences (full ephemeris model)."""
    eph = _perturbed()
    t = eph.toe_gps[0] + np.array([-3000.0, 100.0, 5000.0])
    h = 0.5
    p, v, c, cr = sat_states(eph, t)
    pp, _, cp, _ = sat_states(eph, t + h)
    pm, _, cm, _ = sat_states(eph, t - h)
    np.testing.assert_allclose(v, (pp - pm) / (2 * h), atol=1e-3)  # m/s; FD truncation ~ a·h²/6 ≈ 1e-4
    np.testing.assert_allclose(cr, (cp - cm) / (2 * h), atol=1e-14)


def test_rebase_and_rinex_nav_round_trip(tmp_path):
    """Re-referenced records written to RINEX nav and read back give the same orbits and clocks."""
    eph = _perturbed()
    t = T_REF + np.arange(0.0, 3 * 3600.0, 900.0)
    nav = write_nav(eph, (t[0], t[-1]), tmp_path / "x.nav")
    back = load_rinex_nav(nav)
    assert len(back) % 24 == 0 and len(back) >= 48  # one record per 2-h grid point per satellite
    p0, v0, c0, _ = sat_states(eph, t)
    for k, tt in enumerate(t):
        b = back.select(tt)
        assert np.all(np.abs(b.toe_gps - tt) <= 3600.0)
        p1, v1, c1, _ = sat_states(b, tt)
        np.testing.assert_allclose(p1, p0[k], atol=ONE_CM)  # RINEX keeps 13 significant digits
        np.testing.assert_allclose(v1, v0[k], atol=1e-5)
        np.testing.assert_allclose(c1, c0[k], atol=1e-12)


def test_yuma_loader_matches_do229(tmp_path):
    eph = load_do229(T_REF)
    blocks = []
    for s in range(len(eph)):
        blocks.append(
            f"******** Week 703 almanac for PRN-{eph.prn[s]:02d} ********\n"
            f"ID:                         {eph.prn[s]:02d}\nHealth:                     000\n"
            f"Eccentricity:               {eph.e[s]:.10E}\nTime of Applicability(s):  {eph.toe_sow[s]:.4f}\n"
            f"Orbital Inclination(rad):   {eph.i0[s]:.10f}\nRate of Right Ascen(r/s):   {eph.omega_dot[s]:.10E}\n"
            f"SQRT(A)  (m 1/2):           {eph.sqrt_a[s]:.6f}\nRight Ascen at Week(rad):   {eph.omega0[s]:.10E}\n"
            f"Argument of Perigee(rad):   {eph.w[s]:.9f}\nMean Anom(rad):             {eph.m0[s]:.10E}\n"
            f"Af0(s):                     {eph.af0[s]:.10E}\nAf1(s/s):                   {eph.af1[s]:.10E}\n"
            f"week:                        703\n\n")
    path = tmp_path / "almanac.alm"
    path.write_text("".join(blocks[::-1]))  # reversed order: the loader sorts by PRN
    y = load_yuma(path, T_REF, week_mode="periodic")
    np.testing.assert_array_equal(y.prn, eph.prn)
    t = T_REF + np.array([0.0, 4000.0])
    np.testing.assert_allclose(sat_states(y, t)[0], sat_states(eph, t)[0], atol=ONE_CM)
    bad = tmp_path / "bad.alm"
    bad.write_text("******** Week 703 almanac for PRN-01 ********\nID: 01\nHealth: abc\n")
    with pytest.raises(ValueError, match="line 3"):
        load_yuma(bad, T_REF)


def test_sem_loader_matches_do229(tmp_path):
    """A SEM almanac (NAVCEN .al3 layout: angles in semicircles, the inclination as an offset from 0.30
    semicircles, the node in [-1, 1) semicircles) of the DO-229 almanac flies its satellites to < 1 cm."""
    eph = load_do229(T_REF)
    semi = lambda x: (np.asarray(x) / math.pi + 1.0) % 2.0 - 1.0  # noqa: E731  rad -> semicircles in [-1, 1)
    records = []
    for s in range(len(eph))[::-1]:  # reversed order: the loader sorts by PRN
        records.append(f"{eph.prn[s]}\n{eph.prn[s] + 30}\n0\n"
                       f"{eph.e[s]: .14E} {eph.i0[s] / math.pi - 0.30: .14E} {eph.omega_dot[s] / math.pi: .14E}\n"
                       f"{eph.sqrt_a[s]: .14E} {semi(eph.omega0[s]): .14E} {semi(eph.w[s]): .14E}\n"
                       f"{semi(eph.m0[s]): .14E} {eph.af0[s]: .14E} {eph.af1[s]: .14E}\n0\n11\n")
    path = tmp_path / "almanac.al3"
    path.write_text(f"{len(eph)} CURRENT.ALM\n 703 {eph.toe_sow[0]:.0f}\n" + "\n".join(records))
    sem = load_sem(path, T_REF, week_mode="periodic")
    np.testing.assert_array_equal(sem.prn, eph.prn)
    t = T_REF + np.array([0.0, 4000.0])
    np.testing.assert_allclose(sat_states(sem, t)[0], sat_states(eph, t)[0], atol=ONE_CM)
    bad = tmp_path / "bad.al3"
    bad.write_text("1 BAD.ALM\n 703 344064\n1\n31\n0\n 1.0E-02 abc 0.0\n5153.6 0.1 0.0\n0.2 0.0 0.0\n0\n11\n")
    with pytest.raises(ValueError, match="line 6"):
        load_sem(bad, T_REF)
    short = tmp_path / "short.al3"
    short.write_text("2 SHORT.ALM\n 703 344064\n1\n")
    with pytest.raises(ValueError, match="announces 2 record"):
        load_sem(short, T_REF)

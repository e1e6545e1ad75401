"""Nominal Galileo and BeiDou-3 constellations: published slot tables, GEO/IGSO tracks, repeat periods, sky counts."""

import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from testbed.flight.kinematic import straight_truth
from testbed.frames import OMEGA_EARTH, R_ecef_to_enu, geodetic_to_ecef
from testbed.records import Mount
from testbed.sensors.gnss.constellations import (BEIDOU_MEO_PRNS, GALILEO_EPOCH_UTC, beidou3_nominal,
                                                 galileo_nominal, greenwich_mean_sidereal_angle,
                                                 nominal_constellation, nominal_constellations, repeat_period)
from testbed.sensors.gnss.orbits import Ephemeris, concat_ephemerides, sat_states
from testbed.sensors.gnss.rinex import write_nav
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.synth import gnss_geometry
from testbed.sensors.gnss.timebase import utc_to_gps_seconds
from testbed.world.airport import runway_frame

REFS = Path(__file__).parent / "references"
ONE_METRE = 1.0
ONE_MAS_DEG = 1.0 / 3.6e6
#: ITU Radio Regulations No. 22.7: a geostationary station keeps within ±0.1° of its nominal longitude.
GEO_BOX_DEG = 0.1
SIDEREAL_DAY_S = 2 * math.pi / OMEGA_EARTH
T_REF = utc_to_gps_seconds("2024-03-15T00:00:00Z")
ZUNZ = (29.3, 94.3, 2949.0)  # Nyingchi airport: lat, lon (deg), height (m)
R_EARTH = 6_378_137.0


def _table(name):
    lines = [ln for ln in (REFS / name).read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    header = lines[0].split("\t")
    return [dict(zip(header, ln.split("\t"))) for ln in lines[1:]]


def _inertial_circular(a, i_deg, raan_deg, u_deg):
    """r = R3(−Ω)·R1(−i)·[a cos u, a sin u, 0] (plain trigonometry, no testbed code)."""
    i, O, u = np.radians(i_deg), np.radians(raan_deg), np.radians(u_deg)
    x, y = a * np.cos(u), a * np.sin(u)
    return np.stack([x * np.cos(O) - y * np.cos(i) * np.sin(O), x * np.sin(O) + y * np.cos(i) * np.cos(O),
                     y * np.sin(i)], -1)


def _to_ecef(r_inertial, gmst_rad):
    c, s = math.cos(gmst_rad), math.sin(gmst_rad)
    return np.stack([c * r_inertial[..., 0] + s * r_inertial[..., 1], -s * r_inertial[..., 0] + c * r_inertial[..., 1],
                     r_inertial[..., 2]], -1)


def _inertial_state(pos_ecef, vel_ecef):
    """Orbit normal (unit angular momentum) and RAAN (deg) from Earth-fixed states (frame of date)."""
    w = np.array([0.0, 0.0, OMEGA_EARTH])
    h = np.cross(pos_ecef, vel_ecef + np.cross(w, pos_ecef))
    return h / np.linalg.norm(h, axis=-1, keepdims=True)


def _counts_in_view(eph, t_gps, mask_deg=5.0):
    site = geodetic_to_ecef(*ZUNZ)
    d = sat_states(eph, t_gps)[0] - site
    up = R_ecef_to_enu(ZUNZ[0], ZUNZ[1])[2]
    el = np.degrees(np.arcsin(d @ up / np.linalg.norm(d, axis=-1)))
    return el >= mask_deg, el


def test_gmst_against_published_values():
    # GMST at J2000.0 (2000-01-01 12:00 UT1) = 18h 41m 50.54841s = 280.46061837504° (the constant term of IAU 1982)
    assert math.degrees(greenwich_mean_sidereal_angle("2000-01-01T12:00:00Z")) == pytest.approx(280.46061837504,
                                                                                               abs=ONE_MAS_DEG)
    # D. A. Vallado, Fundamentals of Astrodynamics and Applications, Example 3-5: 1992-08-20 12:14 UT1 -> 152.578787810°
    gmst = math.degrees(greenwich_mean_sidereal_angle(datetime(1992, 8, 20, 12, 14, tzinfo=timezone.utc)))
    assert gmst == pytest.approx(152.578787810, abs=1e-6)  # 1e-6° = 0.5 m at Galileo's radius


def test_galileo_against_the_published_slot_table():
    rows = _table("galileo_reference_slots.tsv")
    assert len(rows) == 24 and {r["provenance"] for r in rows} == {"published", "pattern"}
    eph = galileo_nominal()  # referred to the reference epoch itself
    t0 = utc_to_gps_seconds(GALILEO_EPOCH_UTC)
    assert np.all(eph.toe_gps == t0)
    assert list(eph.sat_id) == [f"E{k:02d}" for k in range(1, 25)]
    assert [r["slot"] for r in rows] == [f"{p}{s:02d}" for p in "ABC" for s in range(1, 9)]  # E01..E24 in slot order
    a = np.array([float(r["a_km"]) for r in rows]) * 1e3
    r_ref = _inertial_circular(a, np.array([float(r["i_deg"]) for r in rows]),
                               np.array([float(r["raan_deg"]) for r in rows]),
                               np.array([float(r["argp_deg"]) + float(r["mean_anomaly_deg"]) for r in rows]))
    pos, vel, clk, _ = sat_states(eph, t0)
    np.testing.assert_allclose(pos, _to_ecef(r_ref, greenwich_mean_sidereal_angle(GALILEO_EPOCH_UTC)), rtol=0,
                               atol=ONE_METRE)
    np.testing.assert_allclose(eph.sqrt_a**2, 29_599_800.0, rtol=0, atol=1e-3)
    np.testing.assert_allclose(np.degrees(eph.i0), 56.0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(eph.e, 0.0)
    np.testing.assert_array_equal(clk, 0.0)


def test_galileo_nominal_rates_are_carried():
    """10 days on: the published rates (node −0.02764398°/day, M 613.72253566°/day), Earth turning at Ω̇e."""
    rows = _table("galileo_reference_slots.tsv")
    days = 10.0
    raan = np.array([float(r["raan_deg"]) for r in rows]) - 0.02764398 * days
    u = np.array([float(r["mean_anomaly_deg"]) for r in rows]) + 613.72253566 * days
    r_ref = _inertial_circular(29_599_800.0, 56.0, raan, u)
    # the IS-GPS-200 model turns the Earth at Ω̇e from the epoch's sidereal angle (no precession of the equinox)
    theta = greenwich_mean_sidereal_angle(GALILEO_EPOCH_UTC) + OMEGA_EARTH * days * 86400.0
    t = utc_to_gps_seconds(GALILEO_EPOCH_UTC) + days * 86400.0
    np.testing.assert_allclose(sat_states(galileo_nominal(), t)[0], _to_ecef(r_ref, theta), rtol=0, atol=ONE_METRE)
    # referring the elements to a 2024 epoch changes no position
    np.testing.assert_allclose(sat_states(galileo_nominal(T_REF), T_REF)[0], sat_states(galileo_nominal(), T_REF)[0],
                               rtol=0, atol=0.01)


def _beidou_rows():
    rows = _table("beidou3_nominal_orbits.tsv")
    return {r["kind"]: r for r in rows if r["kind"] != "GEO"}, [r for r in rows if r["kind"] == "GEO"]


def test_beidou3_against_the_published_orbits():
    kinds, geos = _beidou_rows()
    eph = beidou3_nominal(T_REF)
    assert len(eph) == 30 and set(eph.system) == {"C"} and len(set(eph.sat_id)) == 30
    t = T_REF + np.arange(0.0, 86400.0, 900.0)
    pos, vel, _, _ = sat_states(eph, t)
    radius = np.linalg.norm(pos, axis=-1)
    h = _inertial_state(pos, vel)
    incl = np.degrees(np.arccos(np.clip(h[..., 2], -1, 1)))
    meo = np.isin(eph.prn, BEIDOU_MEO_PRNS)
    igso = np.isin(eph.prn, [38, 39, 40])
    geo = np.isin(eph.prn, [int(g["prn"]) for g in geos])
    assert meo.sum() == 24 and igso.sum() == 3 and geo.sum() == 3
    # altitudes above the CGCS2000 equatorial radius: MEO exact; GSO 35 786 km is the geosynchronous radius rounded
    np.testing.assert_allclose(radius[:, meo] - R_EARTH, float(kinds["MEO"]["altitude_km"]) * 1e3, atol=ONE_METRE)
    np.testing.assert_allclose(radius[:, igso | geo] - R_EARTH, float(kinds["IGSO"]["altitude_km"]) * 1e3, atol=100.0)
    np.testing.assert_allclose(incl[:, meo | igso], float(kinds["MEO"]["inclination_deg"]), atol=1e-9)
    np.testing.assert_allclose(incl[:, geo], 0.0, atol=1e-6)
    # Walker 24/3/1: 3 planes 120° apart (inertial normals), 8 per plane 45° apart, +15° between adjacent planes
    n0 = h[0, meo]
    plane_of = np.argmax(np.abs(n0 @ n0[[0, 8, 16]].T) > 1 - 1e-12, axis=1)
    assert np.array_equal(plane_of, np.repeat([0, 1, 2], 8))
    cosang = n0[[0, 8, 16]] @ n0[[0, 8, 16]].T
    angle_between_normals = np.degrees(np.arccos(np.clip(cosang[[0, 1, 2], [1, 2, 0]], -1, 1)))
    sin_i = math.sin(math.radians(55.0))
    # two normals tilted by i with nodes 120° apart: cos θ = cos²i + sin²i cos 120°
    expect = math.degrees(math.acos(math.cos(math.radians(55.0)) ** 2 + sin_i**2 * -0.5))
    np.testing.assert_allclose(angle_between_normals, expect, atol=1e-9)
    u = _arg_latitude(pos[0, meo], n0)
    per_plane = np.mod(np.diff(u.reshape(3, 8), axis=1), 360.0)
    np.testing.assert_allclose(per_plane, 45.0, atol=1e-9)
    np.testing.assert_allclose(np.mod(u[[8, 16]] - u[[0, 8]], 360.0), 15.0, atol=1e-9)  # F = 1
    # GEO stations
    lon = np.degrees(np.arctan2(pos[0, geo, 1], pos[0, geo, 0]))
    np.testing.assert_allclose(lon, [float(g["longitude_deg"]) for g in geos], atol=1e-9)


def _arg_latitude(pos, normal):
    """Argument of latitude (deg) of inertial positions ``pos`` (N, 3) in planes ``normal`` (N, 3)."""
    node = np.cross([0.0, 0.0, 1.0], normal)
    node /= np.linalg.norm(node, axis=-1, keepdims=True)
    y = np.cross(normal, node)
    return np.degrees(np.arctan2(np.sum(pos * y, -1), np.sum(pos * node, -1))) % 360.0


def test_geo_longitudes_stay_put():
    _, geos = _beidou_rows()
    eph = beidou3_nominal(T_REF)
    geo = np.isin(eph.prn, [59, 60, 61])
    day = T_REF + np.arange(0.0, 86400.0 + 1, 60.0)
    pos = sat_states(eph, day)[0][:, geo]
    lon = np.degrees(np.arctan2(pos[..., 1], pos[..., 0]))
    lat = np.degrees(np.arcsin(pos[..., 2] / np.linalg.norm(pos, axis=-1)))
    published = np.array([float(g["longitude_deg"]) for g in geos])
    assert np.abs(lon - published).max() < GEO_BOX_DEG and np.abs(lat).max() < GEO_BOX_DEG
    # the nominal slot is a fixed point, not a slow drift inside the box: a month later, same place
    # (a = 42 162.2 km, the ICD's broadcast reference, would drift 0.025°/day and fail this)
    month = sat_states(eph, T_REF + np.array([0.0, 30 * 86400.0]))[0][:, geo]
    drift = np.degrees(np.arctan2(month[1, :, 1], month[1, :, 0]) - np.arctan2(month[0, :, 1], month[0, :, 0]))
    assert np.abs(drift).max() < 1e-6


def test_igso_figure_eight_crosses_at_the_published_longitude():
    kinds, _ = _beidou_rows()
    node = float(kinds["IGSO"]["longitude_deg"])
    i = math.radians(float(kinds["IGSO"]["inclination_deg"]))
    eph = beidou3_nominal(T_REF)
    igso = np.flatnonzero(np.isin(eph.prn, [38, 39, 40]))
    t = T_REF + np.arange(0.0, SIDEREAL_DAY_S, 30.0)
    pos = sat_states(eph, t)[0][:, igso]  # (T, 3, 3)
    lat = np.degrees(np.arcsin(pos[..., 2] / np.linalg.norm(pos, axis=-1)))  # geocentric
    lon = np.degrees(np.arctan2(pos[..., 1], pos[..., 0]))
    for k in range(3):
        cross = np.flatnonzero(np.sign(lat[1:, k]) != np.sign(lat[:-1, k]))
        assert cross.size == 2  # once ascending, once descending: the waist of the eight
        w = lat[cross, k] / (lat[cross, k] - lat[cross + 1, k])
        lon_cross = lon[cross, k] + w * (lon[cross + 1, k] - lon[cross, k])
        np.testing.assert_allclose(lon_cross, node, atol=0.01)
    np.testing.assert_allclose(np.abs(lat).max(axis=0), np.degrees(i), atol=0.01)
    # half-width of the eight: max over u of |atan2(cos i sin u, cos u) − u| (closed form for n = Ω̇e, e = 0)
    u = np.linspace(0.0, 2 * np.pi, 200_001)
    half_width = np.degrees(np.max(np.abs(np.angle(np.exp(1j * (np.arctan2(np.cos(i) * np.sin(u), np.cos(u)) - u))))))
    np.testing.assert_allclose(np.abs(lon - node).max(axis=0), half_width, atol=0.01)
    # the eight closes each sidereal day, and the three satellites run on the same one 8 sidereal hours apart
    again = sat_states(eph, t[:1] + SIDEREAL_DAY_S)[0][0, igso]
    np.testing.assert_allclose(again, pos[0], atol=ONE_METRE)
    third = sat_states(eph, T_REF + SIDEREAL_DAY_S / 3)[0][igso]
    np.testing.assert_allclose(third[1], pos[0, 0], atol=ONE_METRE)
    np.testing.assert_allclose(third[2], pos[0, 1], atol=ONE_METRE)


def test_meo_repeat_periods_from_the_propagation():
    # Galileo: 17 orbits in 10 node-days; both expressions of the published rates give the same 9.9719 days
    gal = galileo_nominal(T_REF)
    tau, miss = repeat_period(gal, T_REF, 10 * SIDEREAL_DAY_S, search_s=7200.0)
    by_orbits = 17 * 360.0 / 613.72253566 * 86400.0
    by_node_days = 10 * 360.0 / (math.degrees(OMEGA_EARTH) * 86400.0 + 0.02764398) * 86400.0
    assert by_orbits == pytest.approx(by_node_days, abs=0.01)
    np.testing.assert_allclose(tau, by_orbits, atol=1.0)
    assert miss.max() < 10.0  # metres: the rates are commensurate by design
    # BeiDou MEO: 13 orbits in about 7 sidereal days (two-body at 21 528 km: 27 s short of 7 sidereal days)
    bds = beidou3_nominal(T_REF)
    meo = bds.take(np.flatnonzero(np.isin(bds.prn, BEIDOU_MEO_PRNS)))
    tau_c, miss_c = repeat_period(meo, T_REF, 7 * SIDEREAL_DAY_S, search_s=7200.0)
    n = np.sqrt(3.986005e14 / meo.sqrt_a**6) + meo.delta_n
    np.testing.assert_allclose(tau_c * n / (2 * np.pi), 13.0, atol=1e-3)
    np.testing.assert_allclose(tau_c / SIDEREAL_DAY_S, 7.0, atol=1e-3)
    assert miss_c.max() < 100e3  # the ground track slips by ~0.1° of longitude per repeat: ~60 km at MEO
    # a geostationary slot "repeats" every sidereal day with no miss
    geo = bds.take(np.flatnonzero(np.isin(bds.prn, [59, 60, 61])))
    tau_g, miss_g = repeat_period(geo, T_REF, SIDEREAL_DAY_S, search_s=600.0)
    assert miss_g.max() < ONE_METRE


def _cap_fraction(radius_m, mask_deg):
    """Fraction of a sphere of radius ``radius_m`` above the mask from a site on the Earth's surface."""
    e = math.radians(mask_deg)
    central = math.pi / 2 - e - math.asin(R_EARTH * math.cos(e) / radius_m)
    return (1 - math.cos(central)) / 2


def test_satellites_in_view_over_zunz_open_sky():
    """24 h at 60 s, 5° mask, no terrain (the figures of docs/design/physics-notes.md)."""
    eph = nominal_constellations(["gps", "galileo", "beidou"], T_REF)
    vis, el = _counts_in_view(eph, T_REF + np.arange(0.0, 86400.0, 60.0))
    sys_ = eph.system
    for letter, members, radius in (("G", sys_ == "G", 26_559_800.0),
                                    ("E", sys_ == "E", 29_599_800.0),
                                    ("C", np.isin(eph.sat_id, [f"C{p}" for p in BEIDOU_MEO_PRNS]), R_EARTH + 21_528e3)):
        mean = vis[:, members].sum(1).mean()
        # a uniformly spread constellation shows N × (cap fraction) on average; an inclined one over 29°N and
        # a single day stay within 20 % of it
        assert mean == pytest.approx(members.sum() * _cap_fraction(radius, 5.0), rel=0.20), letter
    geo = np.isin(eph.sat_id, ["C59", "C60", "C61"])
    igso = np.isin(eph.sat_id, ["C38", "C39", "C40"])
    assert vis[:, geo].all()  # 30°, 51.5° and 52.4° elevation over Nyingchi
    assert vis[:, igso].sum(1).min() >= 2
    total = vis.sum(1)
    # terrain only removes satellites: the open sky cannot show fewer than the valley's minimum of 17
    assert total.min() >= 17


def test_gnss_geometry_takes_a_mixed_constellation():
    eph = nominal_constellations(["gps", "galileo", "beidou"], T_REF)
    truth = straight_truth(runway_frame(), [-9000.0, -6400.0, 650.0], [-3000.0, -2100.0, 200.0], 20.0, rate_hz=1.0)
    g = gnss_geometry(truth, Mount(np.zeros(3)), GnssSettings(terrain_masking=False), start_utc="2024-03-15T06:00:00Z",
                      constellation=eph)
    assert g.visible.shape == (truth.t.size, 78)
    seen = set(eph.system[g.visible.any(0)])
    assert seen == {"G", "E", "C"}
    np.testing.assert_allclose(g.geometric_range[g.visible].min(), 19_000e3, rtol=0.2)


def test_mixed_records_keep_systems_apart_and_bad_names_are_refused():
    gal = nominal_constellation("galileo", T_REF)
    gps = nominal_constellation("gps", T_REF)
    both = concat_ephemerides([gps, gal])
    assert both.prn[0] == both.prn[24] == 1 and both.sat_id[0] == "G01" and both.sat_id[24] == "E01"
    # select() keeps one record per satellite, not per PRN number
    assert len(both.select(T_REF)) == 48
    # a legacy GPS record (no system given) is GPS
    plain = Ephemeris(**{k: getattr(gps, k) for k in gps.__dataclass_fields__ if k not in ("system",)})
    assert set(plain.system) == {"G"}
    with pytest.raises(ValueError, match="appear more than once"):
        concat_ephemerides([gal, gal])
    with pytest.raises(ValueError, match=r"expected one of \['gps', 'galileo', 'beidou'\], got 'glonass'"):
        nominal_constellation("glonass", T_REF)
    with pytest.raises(ValueError, match="distinct names"):
        nominal_constellations(["gps", "gps"], T_REF)
    with pytest.raises(ValueError, match="expected letters"):
        Ephemeris(**{**{k: getattr(gps, k) for k in gps.__dataclass_fields__}, "system": np.full(24, "R")})


def test_the_rinex_writers_label_each_system(tmp_path):
    """Galileo slots are written as Galileo (E) records, not labelled G (tests/test_rinex_mixed.py has the rest)."""
    mixed = nominal_constellations(["gps", "galileo"], T_REF)
    text = write_nav(mixed, (T_REF, T_REF + 3600.0), tmp_path / "x.nav").read_text().splitlines()
    starts = [ln[:3] for ln in text if ln[:1] in "GE" and ln[1:3].isdigit()]
    assert sorted(set(starts)) == sorted(mixed.sat_id.tolist())

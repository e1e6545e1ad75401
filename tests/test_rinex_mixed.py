"""Mixed GPS + Galileo + BeiDou RINEX 3.05: export, navigation records both ways, and RTKLIB on them.

The RTKLIB checks run (do not skip) whenever ``rnx2rtkp`` is on PATH (Debian package ``rtklib``,
2.4.3 b34: it reads Galileo and BeiDou records, BeiDou GEO ones (C01–C05, C59–C63) with the ICD's GEO
rotation, B1C as ``C1P``, and estimates one clock offset per system).
"""

import math
import shutil
from dataclasses import replace
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main
from testbed.flight.kinematic import straight_truth
from testbed.frames import C_LIGHT, R_ecef_to_enu, ecef_to_geodetic
from testbed.records import Mount
from testbed.replay.run import epoch_table, monitor_rinex, summary_record
from testbed.rinex.obs import read_obs
from testbed.rinex.settings import MonitorFileConfig, MonitorIntegritySettings, RinexSettings
from testbed.sensors.gnss.almanac import load_do229
from testbed.sensors.gnss.broadcast import from_broadcast, geo_record, is_bds_geo, to_broadcast
from testbed.sensors.gnss.constellations import beidou3_nominal, nominal_constellations
from testbed.sensors.gnss.navfile import read_nav
from testbed.sensors.gnss.orbits import OMEGA_EARTH_BDS, concat_ephemerides, sat_states
from testbed.sensors.gnss.errors import F_L1
from testbed.sensors.gnss.rinex import (read_rtklib_pos, read_rtklib_residuals, rtklib_single_point, write_nav,
                                        write_obs, write_rinex)
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.signals import FREQUENCY_HZ, code_problem
from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss
from testbed.sensors.gnss.timebase import utc_to_gps_seconds
from testbed.world.airport import runway_frame

START = "2024-03-15T06:00:00Z"
T_REF = utc_to_gps_seconds(START)
ONE_MM = 1e-3
#: a satellite position at a float64 GPS time: near 1.4e9 s the time resolves 2**-22 s = 0.24 us, in which a
#: satellite moves 0.7 mm; two computations of one epoch's time by different arithmetic differ by a step or two
TIME_ULP_MOTION = 2 * 2.0**-22 * 4000.0
FIVE_CM = 0.05  # the GPS check's tolerance (tests/test_gnss_rtklib.py): RINEX mm resolution, tag − P/c
rtklib = pytest.mark.skipif(shutil.which("rnx2rtkp") is None,
                            reason="RTKLIB rnx2rtkp not on PATH (apt-get install rtklib)")


@pytest.fixture(scope="module")
def mixed():
    frame = runway_frame()
    truth = straight_truth(frame, [-6300.0, -4450.0, 410.0], [-1600.0, -1130.0, 80.0], 90.0, rate_hz=1.0)
    s = GnssSettings(terrain_masking=False)
    eph = nominal_constellations(["gps", "galileo", "beidou"], T_REF)
    g = gnss_geometry(truth, Mount(np.array([0.0, 0.0, -2.0])), s, start_utc=START, constellation=eph)
    return frame, truth, s, g


def _perturbed(eph, seed=3):
    """Every non-GEO record with e, Δn, IDOT, Ω̇, the six harmonic terms and a clock; GEO records as GEO-form
    records (at the export's toe) with the same kind of terms."""
    geo = is_bds_geo(eph.system, eph.prn)
    plain = eph.take(np.flatnonzero(~geo))
    S = len(plain)
    r = np.random.default_rng(seed)
    terms = dict(e=r.uniform(0.002, 0.02, S), w=r.uniform(-3, 3, S), delta_n=np.full(S, 4.5e-9),
                 idot=np.full(S, -3e-10), cuc=np.full(S, 2e-6), cus=np.full(S, 8e-6), crc=np.full(S, 250.0),
                 crs=np.full(S, -40.0), cic=np.full(S, 1e-7), cis=np.full(S, -8e-8), omega_dot=np.full(S, -8e-9),
                 af0=r.uniform(-3e-4, 3e-4, S), af1=np.full(S, 2e-12))
    plain = replace(plain, **terms)
    # GEO-form records at the BDT hour of the flight (toe = 06:00:00 BDT = 06:00:14 GPST)
    toe_geo = round(T_REF / 7200.0) * 7200.0 + 14.0
    g = geo_record(eph.take(np.flatnonzero(geo)), toe_geo)
    n = len(g)
    g = replace(g, e=np.full(n, 4e-4), cuc=np.full(n, -3e-6), cus=np.full(n, 6e-6), crc=np.full(n, -120.0),
                crs=np.full(n, 300.0), cic=np.full(n, -5e-8), cis=np.full(n, 9e-8), idot=np.full(n, 2e-10),
                omega_dot=np.full(n, 3e-9), af0=r.uniform(-3e-4, 3e-4, n), af1=np.full(n, -1e-12))
    return concat_ephemerides([plain, g])


def test_broadcast_conversion_round_trip():
    eph = _perturbed(nominal_constellations(["gps", "galileo", "beidou"], T_REF))
    b = to_broadcast(eph)
    back = from_broadcast(eph.system, week_s=b["week_s"], toe_s=b["toe_s"], sqrt_a=eph.sqrt_a, delta_n=b["delta_n"],
                          omega0=b["omega0"], omega_dot=b["omega_dot"], bds_geo=eph.bds_geo)
    np.testing.assert_array_equal(back["week"], eph.week)
    np.testing.assert_allclose(back["toe_sow"], eph.toe_sow, atol=1e-9)
    for k in ("delta_n", "omega_dot"):
        np.testing.assert_allclose(back[k], getattr(eph, k), rtol=0, atol=1e-18)  # rad/s: < 1 µm in 2 h
    np.testing.assert_allclose(np.angle(np.exp(1j * (back["omega0"] - eph.omega0))), 0.0, atol=1e-13)
    # BDT: 14 s behind GPST, weeks counted from 2006-01-01 (a Sunday); Galileo's RINEX week = GPS week
    c = eph.system == "C"
    bdt_week = (datetime(2024, 3, 15) - datetime(2006, 1, 1)).days // 7
    assert set(b["week_s"][c].tolist()) == {bdt_week} and set(b["week_s"][eph.system == "E"].tolist()) == {2305}
    np.testing.assert_allclose(b["toc_sys"][c], eph.toc_gps[c] - 14.0)


def test_bds_geo_form_against_the_icd_formula():
    """sat_states on GEO-form records = the ICD's §5.2.4.12 steps written out here, one satellite at a time;
    the analytic velocity = finite differences; the same elements read as an ordinary record are km off."""
    eph = _perturbed(nominal_constellations(["beidou"], T_REF))
    geo = eph.take(np.flatnonzero(eph.bds_geo))
    t = geo.toe_gps[0] + np.array([-3600.0, -60.0, 0.0, 900.0, 5400.0])
    pos, vel, _, _ = sat_states(geo, t)
    mu, om = 3.986004418e14, OMEGA_EARTH_BDS
    for s in range(len(geo)):
        a = geo.sqrt_a[s] ** 2
        b = to_broadcast(geo.take([s]))
        for k, tt in enumerate(t):
            tk = tt - geo.toe_gps[s]
            M = geo.m0[s] + (math.sqrt(mu / a**3) + b["delta_n"][0]) * tk
            E = M
            for _ in range(30):
                E = M + geo.e[s] * math.sin(E)
            nu = math.atan2(math.sqrt(1 - geo.e[s] ** 2) * math.sin(E), math.cos(E) - geo.e[s])
            phi = nu + geo.w[s]
            u = phi + geo.cus[s] * math.sin(2 * phi) + geo.cuc[s] * math.cos(2 * phi)
            r = a * (1 - geo.e[s] * math.cos(E)) + geo.crs[s] * math.sin(2 * phi) + geo.crc[s] * math.cos(2 * phi)
            i = geo.i0[s] + geo.idot[s] * tk + geo.cis[s] * math.sin(2 * phi) + geo.cic[s] * math.cos(2 * phi)
            Om = b["omega0"][0] + b["omega_dot"][0] * tk - om * b["toe_s"][0]  # no Earth rotation over tk
            x, y = r * math.cos(u), r * math.sin(u)
            xg = np.array([x * math.cos(Om) - y * math.cos(i) * math.sin(Om),
                           x * math.sin(Om) + y * math.cos(i) * math.cos(Om), y * math.sin(i)])
            f = math.radians(-5.0)
            Rx = np.array([[1, 0, 0], [0, math.cos(f), math.sin(f)], [0, -math.sin(f), math.cos(f)]])
            z = om * tk
            Rz = np.array([[math.cos(z), math.sin(z), 0], [-math.sin(z), math.cos(z), 0], [0, 0, 1]])
            np.testing.assert_allclose(pos[k, s], Rz @ Rx @ xg, atol=ONE_MM)
    h = 0.5
    fd = (sat_states(geo, t + h)[0] - sat_states(geo, t - h)[0]) / (2 * h)
    np.testing.assert_allclose(vel, fd, atol=1e-5)
    ordinary = replace(geo, bds_geo=np.zeros(len(geo), bool))
    assert np.linalg.norm(sat_states(ordinary, t)[0] - pos, axis=-1).min() > 1e3


def test_geo_record_reproduces_the_nominal_geo_orbits():
    eph = beidou3_nominal(T_REF)
    geo = eph.take(np.flatnonzero(is_bds_geo(eph.system, eph.prn)))
    assert sorted(geo.prn.tolist()) == [59, 60, 61]
    toe = round(T_REF / 7200.0) * 7200.0 + 14.0
    rec = geo_record(geo, toe)
    t = toe + np.linspace(-7200.0, 7200.0, 97)
    p0, v0, c0, _ = sat_states(geo, t)
    p1, v1, c1, _ = sat_states(rec, t)
    assert np.abs(p1 - p0).max() < ONE_MM and np.abs(v1 - v0).max() < 1e-6 and np.abs(c1 - c0).max() < 1e-15
    np.testing.assert_allclose(np.degrees(rec.i0), 5.0, atol=1e-9)  # an equatorial orbit seen from the 5° frame
    # an eccentric GEO-form record (two-body) re-referenced an hour later: the same orbit
    ecc = replace(rec, e=np.full(3, 4e-4), w=np.array([1.0, -2.0, 0.3]))
    moved = geo_record(ecc, toe + 3600.0)
    t2 = toe + 3600.0 + np.linspace(-3600.0, 3600.0, 49)
    assert np.abs(sat_states(moved, t2)[0] - sat_states(ecc, t2)[0]).max() < ONE_MM


def test_mixed_nav_file_round_trip(tmp_path):
    """write_nav -> read_nav gives back the orbits and clocks of every system (GEO records re-fitted)."""
    eph = nominal_constellations(["gps", "galileo", "beidou"], T_REF)
    eph = replace(eph, af0=np.linspace(-4e-4, 4e-4, len(eph)), af1=np.full(len(eph), 3e-12))
    path = write_nav(eph, (T_REF, T_REF + 1800.0), tmp_path / "mix.nav")
    text = path.read_text().splitlines()
    assert text[0][:9].strip() == "3.05" and text[0][40] == "M"
    c59 = next(ln for ln in text if ln.startswith("C59"))
    assert c59[4:23] == "2024 03 15 06 00 00"  # a whole BDT hour: 06:00:14 GPST
    assert next(ln for ln in text if ln.startswith("E01"))[4:23] == "2024 03 15 06 00 00"
    nav = read_nav(path)
    assert nav.systems == ("G", "E", "C") and len(nav.eph) == len(eph)
    assert sorted(nav.eph.sat_id[nav.eph.bds_geo].tolist()) == ["C59", "C60", "C61"]
    rec = nav.eph.select(T_REF + 900.0)
    order = np.argsort(rec.sat_id)
    ref = eph.take(np.argsort(eph.sat_id))
    t = T_REF + np.linspace(0.0, 1800.0, 7)
    p0, _, c0, _ = sat_states(ref, t)
    p1, _, c1, _ = sat_states(rec.take(order), t)
    assert np.abs(p1 - p0).max() < ONE_MM  # D19.12: 13 digits, sub-mm
    assert np.abs(c1 - c0).max() * C_LIGHT < ONE_MM


def test_gps_only_nav_file_unchanged(tmp_path):
    """A GPS constellation still writes a RINEX 3.04 GPS file, byte for byte as before."""
    path = write_nav(load_do229(T_REF), (T_REF, T_REF + 60.0), tmp_path / "g.nav")
    ref = (Path(__file__).parent / "references" / "rinex" / "do229_gps_3.04.nav").read_text()
    got = path.read_text().splitlines()
    want = ref.splitlines()
    assert got[0] == want[0] and got[2:] == want[2:]  # line 2 is PGM / RUN BY / DATE


def test_observation_codes_per_system(mixed, tmp_path):
    frame, truth, s, g = mixed
    ep, tr = sample_gnss(g, s, rng=np.random.default_rng(1))
    obs, _ = write_rinex(ep, g, tmp_path, name="b1c", clock_bias_m=tr.clock_bias)
    head = obs.read_text().split("END OF HEADER")[0]
    assert "G    3 C1C D1C S1C" in head and "E    3 C1C D1C S1C" in head and "C    3 C1P D1P S1P" in head
    assert head.splitlines()[0][40] == "M" and head.splitlines()[0][:9].strip() == "3.05"
    obs2, _ = write_rinex(ep, g, tmp_path, name="b1i", clock_bias_m=tr.clock_bias, beidou_signal="B1I")
    assert "C    3 C2I D2I S2I" in obs2.read_text()

    def doppler(path, sat):
        for ln in path.read_text().split("END OF HEADER")[1].splitlines():
            if ln.startswith(sat):
                return float(ln[19:33])

    sat = f"C{int(g.prn[(g.eph.system == 'C') & g.visible[0]][0]):02d}"
    # same range rate, Doppler scaled by the carrier: B1C 1575.42 MHz, B1I 1561.098 MHz
    assert doppler(obs2, sat) / doppler(obs, sat) == pytest.approx(1561.098 / 1575.42, rel=1e-6)
    for x, codes in (("G", ("C1C", "C5Q")), ("E", ("C1C", "C5Q")), ("C", ("C1P", "C2I", "C5P"))):
        assert all(code_problem(x, c) is None for c in codes)
    assert code_problem("C", "C1C") is not None and code_problem("E", "C2W") is not None
    with pytest.raises(ValueError, match="beidou_signal"):
        write_rinex(ep, g, tmp_path, name="x", clock_bias_m=tr.clock_bias, beidou_signal="B3I")


# RTKLIB 2.4.3 b34 single-point variance per satellite with our options (pntpos.c varerr + rescode):
# code error 100² × (0.003² + 0.003²/sin el) + σ_eph² + code bias 0.3² + iono-off 5² + tropo-off 3².
# σ_eph: GPS URA 2 m and BeiDou URA 2 m -> URA index 0 -> 2.4 m; Galileo SISA 3.12 m -> its sisa_index()
# -> index 106 -> 2.0 + 6 × 0.16 = 2.96 m (ephemeris.c var_uraeph).
RTK_EPH_SIGMA = {"G": 2.4, "E": 2.96, "C": 2.4}


def _rtklib_weights(el, system):
    eph_var = np.array([RTK_EPH_SIGMA[x] ** 2 for x in system])
    return 1.0 / (eph_var + 0.3**2 + 5.0**2 + 3.0**2 + 100.0**2 * (0.003**2 + 0.003**2 / np.sin(el)))


def _enu_error(g, k, sol):
    lat, lon, _ = ecef_to_geodetic(g.ant_pos_ecef[k])
    return np.einsum("tij,tj->ti", R_ecef_to_enu(lat, lon), sol["pos_ecef"] - g.ant_pos_ecef[k])


@rtklib
def test_rtklib_solves_the_mixed_export(mixed, tmp_path):
    """RTKLIB's fix from the G+E+C export = the truth moved by RTKLIB's own weighted LS (a clock per system) of
    the range errors we drew, to the GPS check's 5 mm."""
    frame, truth, s, g = mixed
    ep, tr = sample_gnss(g, s, rng=np.random.default_rng(2024))
    obs, nav = write_rinex(ep, g, tmp_path, name="mixed", clock_bias_m=tr.clock_bias)
    sol = read_rtklib_pos(rtklib_single_point(obs, nav, tmp_path / "mixed.pos", systems="GEC"))
    k = np.round(sol["t_gps"] - g.t_gps[0]).astype(int)
    assert k.size == g.t.size and np.all(sol["q"] == 5)
    assert np.all(sol["ns"] == g.visible.sum(1)[k])
    system = g.eph.system
    assert all(((system == x) & g.visible[0]).any() for x in "GEC")
    err = _enu_error(g, k, sol)
    lat, lon, _ = ecef_to_geodetic(g.ant_pos_ecef[k])
    u = (g.sat_pos_ecef[k] - g.ant_pos_ecef[k][:, None]) / g.geometric_range[k][..., None]
    u_enu = np.einsum("tij,tsj->tsi", R_ecef_to_enu(lat, lon), u)
    ones = np.ones(u_enu.shape[:-1] + (1,))
    isb = np.stack([np.broadcast_to(system == x, u_enu.shape[:-1]) for x in "EC"], -1).astype(float)
    G = np.concatenate([-u_enu, ones, isb], -1) * g.visible[k][..., None]
    W = _rtklib_weights(g.elevation[k], system) * g.visible[k]
    A = np.einsum("tij,tsj,ts->tis", np.linalg.inv(np.einsum("tsi,ts,tsj->tij", G, W, G)), G, W)
    eps = np.where(g.visible[k], ep.pseudorange[k] - g.geometric_range[k] - tr.clock_bias[k, None], 0.0)
    gap = np.linalg.norm(err - np.einsum("tis,ts->ti", A, eps)[:, :3], axis=-1)
    print(f"\nG+E+C export ({g.visible.sum(1).min()}-{g.visible.sum(1).max()} satellites): RTKLIB fix vs truth "
          f"+ A·ε: max {gap.max() * 1e3:.2f} mm, 3D error RMS {np.sqrt(np.mean(np.sum(err**2, 1))):.2f} m")
    assert gap.max() < 5e-3


@rtklib
def test_galileo_beidou_records_propagate_as_rtklib(mixed, tmp_path):
    """Galileo and BeiDou (MEO, IGSO, GEO-form) records with every perturbation term: our reader +
    propagator make noise-free ranges from the nav file, RTKLIB solves them with the same file: its fix is
    the truth to the GPS check's 5 cm, each satellite's residual < 1 cm (the GEO form matters: read as
    ordinary records the GEO satellites are kilometres off, test_bds_geo_form_against_the_icd_formula)."""
    frame, truth, s, g0 = mixed
    nav_path = write_nav(_perturbed(g0.eph), (g0.t_gps[0], g0.t_gps[-1]), tmp_path / "records.nav")
    eph = read_nav(nav_path).eph.select(float(g0.t_gps[0]))
    assert eph.bds_geo.sum() == 3
    g = gnss_geometry(truth, g0.antenna, s, start_utc=START, constellation=eph)
    ep, tr = sample_gnss(g, s, rng=np.random.default_rng(1))
    ep = replace(ep, pseudorange=np.where(g.visible, g.geometric_range + tr.clock_bias[:, None], np.nan))
    obs, nav = write_rinex(ep, g, tmp_path, name="pert", clock_bias_m=tr.clock_bias)
    shutil.copyfile(nav_path, nav)  # RTKLIB reads the very records we propagated
    sol = read_rtklib_pos(rtklib_single_point(obs, nav, tmp_path / "pert.pos", systems="GEC", residuals=True))
    k = np.round(sol["t_gps"] - g.t_gps[0]).astype(int)
    assert k.size == g.t.size
    err = np.linalg.norm(_enu_error(g, k, sol), axis=-1)
    res = read_rtklib_residuals(tmp_path / "pert.pos.stat")
    assert res["sat"].size == g.visible.sum()  # every satellite of every epoch has its residual
    worst = {x: float(np.abs(res["resp_m"][np.char.startswith(res["sat"], x)]).max()) for x in "GEC"}
    geo_res = float(np.abs(res["resp_m"][np.isin(res["sat"], eph.sat_id[eph.bds_geo])]).max())
    print(f"\nperturbed G/E/C records, noise-free: RTKLIB 3D error max {err.max() * 100:.2f} cm; residual max "
          f"G {worst['G'] * 100:.2f} / E {worst['E'] * 100:.2f} / C {worst['C'] * 100:.2f} cm (GEO "
          f"{geo_res * 100:.2f} cm)")
    assert err.max() < FIVE_CM
    assert max(worst.values()) < 0.01 and geo_res < 0.01


# ------------------------------------------------------------------------------------- testbed monitor on them

def _export(mixed, tmp_path, name="mixed", **kw):
    frame, truth, s, g = mixed
    ep, tr = sample_gnss(g, s, rng=np.random.default_rng(7))
    obs, nav = write_rinex(ep, g, tmp_path, name=name, clock_bias_m=tr.clock_bias, **kw)
    return frame, g, ep, tr, obs, nav


def test_monitor_uses_every_system_of_a_mixed_export(mixed, tmp_path):
    """The G+E+C export read back: every satellite of every system is used (one clock: the export has no
    inter-system bias), the satellite positions are the synthesis's to the millimetre, and the fix is the
    truth within the noise (as with GPS alone, tests/test_rinex.py's round trip)."""
    frame, g, ep, tr, obs, nav = _export(mixed, tmp_path)
    cfg = MonitorFileConfig(rinex=RinexSettings(origin=(frame.lat_deg, frame.lon_deg, frame.h)))
    run = monitor_rinex(obs, nav, config=cfg)
    f = run.formation
    assert f.systems == ("G", "E", "C") and f.skipped_systems == {}
    assert f.codes == {"G": "C1C", "E": "C1C", "C": "C1P"}
    ids = list(g.eph.sat_id)
    seen = np.array([ids.index(x) for x in run.obs.sat_id])  # the file's order: by system, then PRN
    assert sorted(run.obs.sat_id) == sorted(g.eph.sat_id[ep.visible.any(0)])
    np.testing.assert_array_equal(run.gnss.visible, ep.visible[:, seen])
    vis = run.gnss.visible
    assert np.abs(run.gnss.sat_pos_ecef[vis] - g.sat_pos_ecef[:, seen][vis]).max() < TIME_ULP_MOTION
    # ranges: the synthesised ones (satellite clock put back and taken out; 1 mm rounding)
    assert np.abs(run.gnss.pseudorange[vis] - ep.pseudorange[:, seen][vis]).max() < ONE_MM
    rec = summary_record(run)
    assert rec["systems_used"] == ["G", "E", "C"] and rec["satellites"] == {
        x: int(((g.eph.system == x) & ep.visible.any(0)).sum()) for x in "GEC"}
    out = run.outputs["gps_raim"]
    err = np.linalg.norm(out.pos_enu - frame.ecef_to_enu(g.ant_pos_ecef), axis=-1)
    assert np.median(err) < 3.0 and np.isfinite(out.vpl).all()


def test_monitor_reads_b1i_and_bdt_tags(mixed, tmp_path):
    frame, g, ep, tr, obs, nav = _export(mixed, tmp_path, beidou_signal="B1I")
    run = monitor_rinex(obs, nav)
    assert run.formation.codes["C"] == "C2I"
    # the same file with its tags written in BeiDou time (BDT = GPST − 14 s) gives the same epochs
    text = obs.read_text().splitlines()
    out = []
    for ln in text:
        if ln.startswith(">"):
            t = float(ln[16:18]) * 60 + float(ln[18:29]) - 14.0  # minutes and seconds of the tag, minus 14 s
            ln = ln[:16] + f"{int(t // 60):02d}{t % 60:11.7f}" + ln[29:]
        elif ln[60:].strip() == "TIME OF FIRST OBS":
            ln = ln[:48] + "BDT" + ln[51:]
        out.append(ln)
    bdt = tmp_path / "bdt.obs"
    bdt.write_text("\n".join(out) + "\n")
    assert all(ln[16:18] in ("00", "01") for ln in out if ln.startswith(">"))  # the flight stays in its hour
    np.testing.assert_allclose(read_obs(bdt).t_tag, run.obs.t_tag, atol=1e-6)


def test_monitor_estimates_each_systems_clock_in_another_receivers_mixed_file(mixed, tmp_path, capsys):
    """A mixed file with inter-system biases nobody told us (+25 m on every Galileo range, -40 m on every BeiDou
    one): 'auto' uses all three systems, and the fix is the unbiased file's (the monitors solve one clock per
    system); an explicit [rinex] systems list works through the command line."""
    frame, g, ep, tr, obs, nav = _export(mixed, tmp_path)
    # the export has no delays; no exclusion, so that an epoch at the threshold cannot flip between the files (the
    # shifted ranges move the transmit times by 0.1 us, the satellites by 0.5 mm)
    off = MonitorFileConfig(rinex=RinexSettings(ionosphere="off", troposphere="off"),
                            integrity=MonitorIntegritySettings(fde=False))
    plain = monitor_rinex(obs, nav, config=off)
    base = read_obs(obs)
    shift = np.where(base.system == "E", 25.0, np.where(base.system == "C", -40.0, 0.0))
    cols = {x: {c: base.values[c] + (shift if c.startswith("C") else 0.0) for c in base.types[x]} for x in "GEC"}
    seen = np.isfinite(base.values["C1C"]) | np.isfinite(base.values.get("C1P", np.full_like(base.values["C1C"], np.nan)))
    other = write_obs(tmp_path / "receiver.obs", base.t_tag, base.system, base.prn, seen, cols, name="receiver")
    run = monitor_rinex(other, nav, config=off)  # (the same receiver type: the same σ model, hence weights)
    assert run.formation.systems == ("G", "E", "C") and run.formation.skipped_systems == {}
    assert set(run.gnss.system.tolist()) == {"G", "E", "C"}
    a, b = run.outputs["gps_raim"], plain.outputs["gps_raim"]
    ok = (a.reason == 0) & (b.reason == 0)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(run.frame.enu_to_ecef(a.pos_enu[ok]), plain.frame.enu_to_ecef(b.pos_enu[ok]), atol=1e-3)
    # the preliminary fix (the frame's origin, the light time, the elevations) is not pulled by the biases either
    np.testing.assert_allclose(run.formation.fix_ecef, plain.formation.fix_ecef, atol=1e-3)
    cfg = tmp_path / "all.toml"
    cfg.write_text('[rinex]\nsystems = ["G", "E"]\nionosphere = "off"\ntroposphere = "off"\n')
    out = tmp_path / "out"
    assert main(["monitor", str(other), str(nav), "--config", str(cfg), "--out", str(out), "--format", "csv"]) == 0
    printed = capsys.readouterr().out
    assert "systems used" in printed and "Galileo" in printed and "one receiver clock per system" in printed
    table = (out / "epochs-gps_raim.csv").read_text().splitlines()
    assert "excluded_system" in table[0].split(",")


def test_gps_only_export_reads_as_before(tmp_path):
    """A GPS-only export: no system keys in the summary, the table's columns as before."""
    frame = runway_frame()
    truth = straight_truth(frame, [-6300.0, -4450.0, 410.0], [-1600.0, -1130.0, 80.0], 20.0, rate_hz=1.0)
    s = GnssSettings(terrain_masking=False)
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc=START)
    ep, tr = sample_gnss(g, s, rng=np.random.default_rng(7))
    obs, nav = write_rinex(ep, g, tmp_path, name="gps", clock_bias_m=tr.clock_bias)
    run = monitor_rinex(obs, nav)
    rec = summary_record(run)
    assert "systems_used" not in rec and "excluded_system" not in epoch_table(run, "gps_raim")
    assert run.formation.systems == ("G",)


def _edited(src, dst, edit):
    dst.write_text(edit(src.read_text()))
    return dst


BAD_MIXED = [  # (name, make (obs, nav, config text) from the export, fragments of the message)
    ("nav-without-requested-system",
     lambda d, obs, nav: (obs, _edited(nav, d / "gps-only.nav", _drop_records("EC")),
                          '[rinex]\nsystems = ["G", "E"]\n'),
     ["gps-only.nav", "Galileo (E)", "no E records"]),
    ("unknown-observation-code",
     lambda d, obs, nav: (_edited(obs, d / "code.obs", lambda t: t.replace("C    3 C1P D1P S1P", "C    3 C1C D1P S1P")),
                          nav, None),
     ["code.obs", "line 12", "'C1C'", "attribute C", "BeiDou"]),
    ("unknown-system-in-header",
     lambda d, obs, nav: (_edited(obs, d / "sys.obs", lambda t: t.replace("E    3 C1C D1C S1C", "X    3 C1C D1C S1C")),
                          nav, None),
     ["sys.obs", "line 11", "system letter 'X'"]),
    ("unknown-system-in-record",
     lambda d, obs, nav: (_edited(obs, d / "rec.obs", lambda t: t.replace("\nE", "\nY", 1)), nav, None),
     ["rec.obs", "system letter 'Y'", "line "]),
    ("system-not-observed",
     lambda d, obs, nav: (obs, nav, '[rinex]\nsystems = ["G", "E", "C"]\n'),
     None),  # fine: all three are there
    ("bad-systems-setting", lambda d, obs, nav: (obs, nav, '[rinex]\nsystems = ["G", "R"]\n'),
     ["rinex.systems", "R"]),
    ("bad-beidou-code-setting", lambda d, obs, nav: (obs, nav, '[rinex]\nbeidou_codes = ["C1C"]\n'),
     ["beidou_codes", "C1C"]),
]


def _drop_records(letters):
    def edit(text):
        all_lines = text.splitlines()
        end = next(k for k, ln in enumerate(all_lines) if ln[60:].strip() == "END OF HEADER") + 1
        lines, out, skip = all_lines[end:], [], 0
        for ln in lines:
            if skip:
                skip -= 1
                continue
            if ln[:1] in letters:
                skip = 7
                continue
            out.append(ln)
        return "\n".join(all_lines[:end] + out) + "\n"
    return edit


@pytest.mark.parametrize("name, make, fragments", BAD_MIXED, ids=[c[0] for c in BAD_MIXED])
def test_bad_mixed_input_exits_2_naming_file_line_value(mixed, tmp_path, capsys, name, make, fragments):
    frame, g, ep, tr, obs, nav = _export(mixed, tmp_path)
    o, n, cfg_text = make(tmp_path, obs, nav)
    args = ["monitor", str(o), str(n), "--out", str(tmp_path / "out")]
    if cfg_text is not None:
        (tmp_path / "m.toml").write_text(cfg_text)
        args += ["--config", str(tmp_path / "m.toml")]
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "summary.json").write_text("earlier run")
    code = main(args)
    err = capsys.readouterr().err
    if fragments is None:
        assert code == 0, err
        return
    assert code == 2 and "Traceback" not in err
    for f in fragments:
        assert f in err, (f, err)
    assert (tmp_path / "out" / "summary.json").read_text() == "earlier run"


def test_monitor_forms_iono_free_ranges_per_system(mixed, tmp_path):
    """Two frequencies per system, written with the dual-frequency codes (L5 C5Q, E5a C5Q, B2a C5P) and an
    ionosphere of 3-12 m on L1 scaled by (f_L1/f)² to each carrier: the iono-free ranges are the
    single-frequency export's without it (to the 1 mm rounding × the combination's gain)."""
    frame, g, ep, tr, obs, nav = _export(mixed, tmp_path)
    base = read_obs(obs)
    iono = np.random.default_rng(5).uniform(3.0, 12.0, base.values["C1C"].shape)
    first, second = {"G": "C1C", "E": "C1C", "C": "C1P"}, {"G": "C5Q", "E": "C5Q", "C": "C5P"}
    columns = {}
    for x in "GEC":
        f1, f5 = FREQUENCY_HZ[x][first[x][1]], FREQUENCY_HZ[x]["5"]
        p = base.values[first[x]]
        columns[x] = {first[x]: p + iono * (F_L1 / f1) ** 2, second[x]: p + iono * (F_L1 / f5) ** 2}
    present = np.zeros_like(iono, bool)
    for x in "GEC":
        present |= np.isfinite(base.values[first[x]]) & (base.system == x)
    dual = write_obs(tmp_path / "dual.obs", base.t_tag, base.system, base.prn, present, columns, name="dual")
    assert "C    2 C1P C5P" in dual.read_text()
    plain = monitor_rinex(obs, nav, config=MonitorFileConfig(rinex=RinexSettings(ionosphere="off")))
    run = monitor_rinex(dual, nav, config=MonitorFileConfig(rinex=RinexSettings(ionosphere="iono_free")))
    assert run.formation.second_codes == second and run.formation.systems == ("G", "E", "C")
    vis = plain.gnss.visible
    np.testing.assert_array_equal(run.gnss.visible, vis)
    assert np.abs(run.gnss.pseudorange[vis] - plain.gnss.pseudorange[vis]).max() < 5e-3


def test_galileo_fnav_records_give_way_to_inav(tmp_path):
    """A file with both Galileo message types: the I/NAV records (clock for E5b/E1, the E1 user's) are used,
    the F/NAV ones skipped and counted."""
    eph = nominal_constellations(["galileo"], T_REF)
    path = write_nav(eph, (T_REF, T_REF + 60.0), tmp_path / "i.nav")
    lines = path.read_text().splitlines()
    end = next(k for k, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    fnav = []
    for k in range(end, len(lines), 8):  # a copy of each record as F/NAV (data sources 258), clock 1 ms off
        rec = lines[k:k + 8]
        rec[0] = rec[0][:23] + f"{1e-3:19.12E}" + rec[0][42:]
        rec[5] = rec[5][:23] + f"{258.0:19.12E}" + rec[5][42:]
        fnav += rec
    both = tmp_path / "both.nav"
    both.write_text("\n".join(lines + fnav) + "\n")
    nav = read_nav(both)
    assert nav.skipped == {"Galileo F/NAV records (I/NAV used)": len(eph)} and len(nav.eph) == len(eph)
    assert np.all(np.abs(nav.eph.af0) < 1e-9)  # the I/NAV clocks (zero for the nominal orbits)


# ------------------------------------------------------------------ stored RTKLIB output (runs without RTKLIB)

STORED = Path(__file__).parent / "references" / "rinex"


def make_reference(folder: Path) -> None:
    """Write ``gec_perturbed.obs/.nav`` (10 s, noise-free, perturbed G/E/C records) and RTKLIB's solution of them
    (``gec_perturbed.rtklib.pos``) into ``folder``: how the stored files of tests/references/rinex were made."""
    frame = runway_frame()
    truth = straight_truth(frame, [-6300.0, -4450.0, 410.0], [-5600.0, -3950.0, 360.0], 10.0, rate_hz=1.0)
    s = GnssSettings(terrain_masking=False)
    eph0 = nominal_constellations(["gps", "galileo", "beidou"], T_REF)
    g0 = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc=START, constellation=eph0)
    nav_path = write_nav(_perturbed(g0.eph), (g0.t_gps[0], g0.t_gps[-1]), folder / "gec_records.nav")
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc=START,
                      constellation=read_nav(nav_path).eph.select(float(g0.t_gps[0])))
    ep, tr = sample_gnss(g, s, rng=np.random.default_rng(1))
    ep = replace(ep, pseudorange=np.where(g.visible, g.geometric_range + tr.clock_bias[:, None], np.nan))
    obs, nav = write_rinex(ep, g, folder, name="gec_perturbed", clock_bias_m=tr.clock_bias)
    shutil.move(nav_path, nav)
    pos = rtklib_single_point(obs, nav, folder / "gec_perturbed.rtklib.pos", systems="GEC")
    pos.with_suffix(".conf").unlink()


def test_monitor_agrees_with_stored_rtklib_solution_of_perturbed_gec_records():
    """RTKLIB 2.4.3 b34's fixes of a stored noise-free G+E+C file (Galileo and BeiDou MEO/IGSO/GEO records with
    every perturbation term): testbed monitor, reading the same two files, lands on them to 5 mm."""
    obs, nav = STORED / "gec_perturbed.obs", STORED / "gec_perturbed.nav"
    sol = read_rtklib_pos(STORED / "gec_perturbed.rtklib.pos")
    cfg = MonitorFileConfig(rinex=RinexSettings(ionosphere="off", troposphere="off", error_model="rtklib"))
    run = monitor_rinex(obs, nav, config=cfg)
    assert run.formation.systems == ("G", "E", "C") and run.obs.systems == ("G", "E", "C")
    assert read_nav(nav).eph.bds_geo.sum() == 3
    ecef = run.frame.enu_to_ecef(run.outputs["gps_raim"].pos_enu)
    k = np.clip(np.searchsorted(run.gnss.t_gps, sol["t_gps"] - 0.5), 0, run.gnss.t.size - 1)
    assert np.all(np.abs(run.gnss.t_gps[k] - sol["t_gps"]) < 0.01) and k.size == run.gnss.t.size
    gap = np.linalg.norm(ecef[k] - sol["pos_ecef"], axis=1)
    print(f"\nstored RTKLIB fixes of perturbed G/E/C records vs testbed monitor: max {gap.max() * 1e3:.2f} mm")
    assert gap.max() < 5e-3


def test_broadcast_ionosphere_scales_to_the_b1i_carrier(mixed, tmp_path):
    """The Klobuchar delay (an L1 delay) removed from a B1I range is (f_L1 / f_B1I)² = 1.0184 times the one removed
    from the same satellite's B1C range; GPS and Galileo (on L1 / E1) are corrected alike in both files.
    (The header's coefficients: a plausible broadcast set, metres of delay here.)"""
    frame, g, ep, tr, obs_c, nav = _export(mixed, tmp_path / "b1c")
    _, _, _, _, obs_i, _ = _export(mixed, tmp_path / "b1i", beidou_signal="B1I")
    klob = ("GPSA   1.1176E-08  7.4506E-09 -5.9605E-08 -5.9605E-08       IONOSPHERIC CORR    \n"
            "GPSB   9.0112E+04  1.6384E+04 -1.9661E+05 -6.5536E+04       IONOSPHERIC CORR    \n")
    lines = nav.read_text().splitlines(keepends=True)
    k = next(i for i, ln in enumerate(lines) if ln[60:].strip() == "LEAP SECONDS")
    nav_k = tmp_path / "klob.nav"
    nav_k.write_text("".join(lines[:k]) + klob + "".join(lines[k:]))

    def correction(obs):
        runs = [monitor_rinex(obs, nav_k, config=MonitorFileConfig(rinex=RinexSettings(ionosphere=i, troposphere="off")))
                for i in ("off", "klobuchar")]
        return runs[0].obs.system, runs[0].gnss.pseudorange - runs[1].gnss.pseudorange

    sys_c, d_c = correction(obs_c)
    sys_i, d_i = correction(obs_i)
    c = sys_c == "C"
    assert np.nanmin(d_c[:, c]) > 1.0  # metres of ionosphere removed
    np.testing.assert_allclose(d_i[:, c] / d_c[:, c], (1575.42 / 1561.098) ** 2, rtol=1e-6)
    # the fixes the delays are evaluated at differ by the B1I ranges' share: 0.1 µm here
    np.testing.assert_allclose(d_i[:, ~c], d_c[:, ~c], rtol=0, atol=1e-5)


@rtklib
def test_rtklib_solves_a_four_hour_mixed_export(tmp_path):
    """Four hours at 60 s: the navigation file holds three records per satellite (each system re-referenced to its
    own 2-hour grid, the GEOs re-fitted each time); noise-free ranges are solved by RTKLIB to the GPS check's
    5 cm at every epoch, satellites rising and setting."""
    frame = runway_frame()
    truth = straight_truth(frame, [-3000.0, -2000.0, 300.0], [3000.0, 2000.0, 300.0], 4 * 3600.0, rate_hz=1 / 60)
    s = GnssSettings(terrain_masking=False)
    eph = nominal_constellations(["gps", "galileo", "beidou"], T_REF + 7200.0)
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc=START, constellation=eph)
    ep, tr = sample_gnss(g, s, rng=np.random.default_rng(4))
    ep = replace(ep, pseudorange=np.where(g.visible, g.geometric_range + tr.clock_bias[:, None], np.nan))
    obs, nav = write_rinex(ep, g, tmp_path, name="long", clock_bias_m=tr.clock_bias)
    text = nav.read_text()
    assert sum(ln.startswith("C59 ") for ln in text.splitlines()) == 3
    sol = read_rtklib_pos(rtklib_single_point(obs, nav, tmp_path / "long.pos", systems="GEC"))
    k = np.round((sol["t_gps"] - g.t_gps[0]) / 60.0).astype(int)
    assert k.size == g.t.size and np.all(sol["ns"] == g.visible.sum(1)[k])
    err = np.linalg.norm(sol["pos_ecef"] - g.ant_pos_ecef[k], axis=-1)
    changes = int(np.sum(np.any(g.visible[1:] != g.visible[:-1], axis=1)))
    print(f"\n4 h G+E+C export, {g.t.size} epochs ({changes} with a satellite rising or setting): RTKLIB 3D error "
          f"max {err.max() * 1e3:.2f} mm")
    assert err.max() < FIVE_CM

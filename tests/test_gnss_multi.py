"""Several constellations in the GNSS sensor: settings, geometry, the DFMC error model, the inter-system clock
offsets, faults that name satellites or a constellation, and snapshot RAIM with one clock per constellation.

Oracles are written here from the formulas (docs/design/gnss.md), never read back from the code: the
iono-free factor from the carrier frequencies, σ from the curves, least squares by ``np.linalg.lstsq`` on the
selected rows, and χ² distributions by Kolmogorov-Smirnov.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError
from scipy import stats

from testbed.api import run_approach
from testbed.campaign.sorties import sky_repeat_s
from testbed.campaign.spec import expand_cells, load_spec
from testbed.cli import main
from testbed.flight.kinematic import straight_truth
from testbed.integrity import multi_clock
from testbed.integrity.gps_only import gps_satellites
from testbed.integrity.monitor import Observations
from testbed.integrity.raim import gps_raim
from testbed.integrity.settings import IntegritySettings
from testbed.records import Mount, NotVisible
from testbed.resources import approaches_dir
from testbed.sensors.faults import ConstellationBias, GpsStep, gnss_fault_bias
from testbed.sensors.gnss.constellations import (StaleOrbits, constellation_orbits, nominal_constellations,
                                                 tracked_constellations)
from testbed.sensors.gnss.errors import IONO_FREE_CARRIERS, iono_free_variance_factor, range_sigmas
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.rinex import write_nav
from testbed.sensors.gnss.synth import apply_gnss_errors, draw_gnss_errors, gnss_geometry
from testbed.sensors.gnss.timebase import utc_to_gps_seconds
from testbed.viz import readback
from testbed.viz.rerun_sink import COLOURS
from testbed.world.airport import runway_frame

START = "2024-03-15T06:00:00Z"
ALL = ["gps", "galileo", "beidou"]
F1, F5 = 1575.42e6, 1176.45e6
REFS = Path(__file__).parent / "references" / "rinex"


@pytest.fixture(scope="module")
def frame():
    return runway_frame()


@pytest.fixture(scope="module")
def truth(frame):
    return straight_truth(frame, [-9000.0, -6400.0, 650.0], [-3000.0, -2100.0, 200.0], 60.0, rate_hz=1.0)


def geometry(truth, **kw):
    return gnss_geometry(truth, Mount(np.zeros(3)), GnssSettings(**kw), start_utc=START)


@pytest.fixture(scope="module")
def sky3(truth):
    """GPS + Galileo + BeiDou over the final, no terrain."""
    return geometry(truth, terrain_masking=False, constellations=ALL)


# ---------------------------------------------------------------------------------------------- settings


@pytest.mark.parametrize("kw, where, what", [
    ({"constellations": ["gps", "glonass"]}, "constellations", "unknown constellation 'glonass'"),
    ({"constellations": []}, "constellations", "at least one constellation"),
    ({"constellations": ["gps", "gps"]}, "constellations", "each once"),
    ({"constellations": ALL, "galileo": {"elevation_mask_deg": 95.0}}, "galileo.elevation_mask_deg", "90"),
    ({"constellations": ALL, "beidou": {"max_satellites": -1}}, "beidou.max_satellites", "0"),
    ({"constellations": ALL, "galileo": {"excluded_prns": [37]}}, "", "expected 1-36"),
    ({"constellations": ["gps"], "galileo": {"max_satellites": 4}}, "", "not in constellations"),
    ({"constellations": ALL, "error_model": "dfmc", "galileo": {"sigma_ura_m": 0.4, "sigma_ure_m": 0.5}}, "galileo",
     "sigma_ure_m"),
    ({"constellations": ALL, "galileo": {"sigma_ura_m": 6.0}}, "", "galileo.sigma_ura_m: read by error_model = 'dfmc'"),
    ({"user_error": "add_v31"}, "", "user_error: read by error_model = 'dfmc'"),
])
def test_bad_constellation_settings_are_refused(kw, where, what):
    with pytest.raises(ValidationError) as err:
        GnssSettings(**kw)
    text = str(err.value)
    assert what in text and where.split(".")[0] in text


SEED_APPROACH = (approaches_dir() / "va-raim-2015.toml").read_text()
TWO = '\n[gnss]\nconstellations = ["gps", "beidou"]\n'


@pytest.mark.parametrize("tail, key, value", [
    ('\n[gnss]\nconstellations = ["gps", "glonass"]\n', "gnss.constellations", "glonass"),
    (TWO + "[gnss.beidou]\nexcluded_prns = [31]\n", "gnss.beidou.excluded_prns", "C31"),  # not a BDS-3 slot
    (TWO + "[gnss.beidou]\nelevation_mask_deg = 90.0\n", "gnss.beidou.elevation_mask_deg", "90"),
    (TWO + "[gnss.beidou]\nmax_satellites = 65\n", "gnss.beidou.max_satellites", "65"),
    (TWO + '[[faults]]\nkind = "constellation_bias"\nsystem = "galileo"\nbias_m = 5.0\n', "faults.0.system",
     "'galileo': not tracked"),
    (TWO + '[[faults]]\nkind = "gps_step"\nsat = "E07"\nbias_m = 5.0\n', "faults.0.sat", "E07"),
    (TWO + '[[faults]]\nkind = "gps_step"\nsat = "R07"\nbias_m = 5.0\n', "faults.0.sat", "R07"),
])
def test_bad_constellation_input_exits_2_naming_key_and_value(tmp_path, monkeypatch, capsys, tail, key, value):
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "bad.toml"
    p.write_text(SEED_APPROACH + tail)
    code = main(["fly", str(p), "--no-record"])
    out = capsys.readouterr()
    text = out.err + out.out
    assert code == 2 and key in text and value in text, text
    assert "Traceback" not in text
    assert sorted(x.name for x in tmp_path.iterdir()) == ["bad.toml"]  # nothing written


@pytest.mark.parametrize("axis, value", [("[[]]", "[]"), ('[["gps", "gps"]]', "['gps', 'gps']")])
def test_a_bad_constellation_axis_is_refused_at_the_spec(tmp_path, capsys, axis, value):
    """An empty or repeated constellation set on the campaign axis is refused by the spec's own check, naming the
    axis and the value, before any cell is built (the approach's own rule, applied once)."""
    spec = tmp_path / "s.toml"
    spec.write_text('name = "s"\napproaches = ["zunz-rwy05-dfmc"]\nmonitors = ["gps_raim"]\ntrials = 10\n'
                    f'[sweep]\nconstellations = {axis}\n')
    assert main(["check", str(spec)]) == 1
    code = main(["campaign", str(spec), "--out", str(tmp_path / "o"), "--quiet"])
    text = capsys.readouterr()
    text = text.out + text.err
    assert code == 2 and "sweep.constellations" in text and value in text and "cell" not in text, text
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------------------------- geometry


def test_slots_carry_their_system_in_the_order_listed(sky3):
    letters = "".join(dict.fromkeys(sky3.system.tolist()))
    assert letters == "GEC"
    assert (sky3.system == sky3.eph.system).all()
    assert np.bincount(["GEC".index(c) for c in sky3.system]).tolist() == [24, 24, 30]
    n = sky3.visible.sum(-1)
    assert n.min() >= 20  # 17-29 in view along the final with the valley; more in open sky


def test_per_constellation_mask_health_and_cap(truth, sky3):
    g = geometry(truth, terrain_masking=False, constellations=ALL, galileo={"elevation_mask_deg": 30.0},
                 beidou={"excluded_prns": [59], "max_satellites": 4})
    el = np.degrees(g.elevation)
    E, C, G = g.system == "E", g.system == "C", g.system == "G"
    assert (el[g.visible & E] >= 30.0).all() and ((el >= 5.0) & (el < 30.0) & E & ~g.visible).any()
    assert ((el < 30.0) & g.visible & G).any()  # the GPS mask is still 5 deg
    c59 = (g.system == "C") & (g.prn == 59)
    assert not g.visible[:, c59].any() and (g.reason[:, c59] == NotVisible.UNHEALTHY).all()
    assert (g.visible[:, C].sum(-1) <= 4).all() and (g.visible[:, C].sum(-1) == 4).all()
    # the cap keeps the highest of those otherwise in view
    for k in range(0, g.t.size, 20):
        cands = np.flatnonzero(C & sky3.visible[k] & ~c59)
        top = cands[np.argsort(-el[k, cands])][:4]
        assert set(np.flatnonzero(g.visible[k] & C)) == set(top)
        assert (g.reason[k, np.setdiff1d(cands, top)] == NotVisible.EXCLUDED).all()


class SouthWall:
    """A terrain that hides every line of sight with a southward component (a ridge south of the runway)."""

    def __init__(self, frame):
        self.south = -frame.R[1]  # ENU north row of the ECEF->ENU rotation, negated

    def sky_visible(self, origin, direction):
        return np.asarray(direction) @ self.south <= 0.0


def test_terrain_masks_every_constellation(truth, frame):
    g = gnss_geometry(truth, Mount(np.zeros(3)), GnssSettings(constellations=ALL), start_utc=START,
                      terrain=SouthWall(frame))
    az = np.degrees(g.azimuth)
    south = (az > 90.0) & (az < 270.0)
    for c in "GEC":
        hit = (g.system == c) & (g.reason == NotVisible.TERRAIN)
        assert hit.any(), c
        assert not (g.visible & south & (g.system == c)).any(), c
    geo = (g.system == "C") & np.isin(g.prn, [59, 60, 61])  # the GEOs stand south of LinZhi: all hidden
    assert (g.reason[:, geo] == NotVisible.TERRAIN).all()


# ---------------------------------------------------------------------------------------------- error model


def closed_form_sigmas(theta_deg, ura, ure, curve="wgc_m3"):
    """σ told and drawn from the DFMC model, written from the formulas (θ in degrees)."""
    th = np.radians(theta_deg)
    gamma = (F1**4 + F5**4) / (F1**2 - F5**2) ** 2
    tropo = 0.12 * 1.001 / np.sqrt(0.002001 + np.sin(th) ** 2)
    if curve == "wgc_m3":
        user2 = gamma * ((0.13 + 0.53 * np.exp(-theta_deg / 10.0)) ** 2 + (0.15 + 0.43 * np.exp(-theta_deg / 6.9)) ** 2)
    else:  # maast2_dfmc, at iono-free level already
        user2 = 0.4**2 + (0.34 + 0.40 * np.exp(-theta_deg / 14.0)) ** 2 + (40.0 / (261.0 + theta_deg**2) + 0.018) ** 2
    return np.sqrt(ura**2 + tropo**2 + user2), np.sqrt(ure**2 + tropo**2 + user2)


def test_iono_free_factor_of_each_system():
    for c, (f1, f2) in IONO_FREE_CARRIERS.items():
        assert iono_free_variance_factor(f1, f2) == pytest.approx(6.699455, abs=5e-6), c


@pytest.mark.parametrize("curve", ["wgc_m3", "maast2_dfmc"])
def test_dfmc_sigma_against_the_closed_form(curve):
    s = GnssSettings(constellations=ALL, error_model="dfmc", user_error=curve,
                     galileo={"sigma_ura_m": 6.0, "sigma_ure_m": 4.0, "b_nom_m": 0.0})  # the others: defaults
    theta = np.array([5.0, 10.0, 15.0, 30.0, 45.0, 60.0, 90.0])
    system = np.array(["G", "E", "C"])
    told, drawn, b_nom = range_sigmas(np.radians(theta)[:, None] * np.ones(3), system, s)
    for j, (ura, ure, b) in enumerate([(0.75, 0.50, 0.50), (6.0, 4.0, 0.0), (0.75, 0.50, 0.50)]):
        t_ref, d_ref = closed_form_sigmas(theta, ura, ure, curve)
        np.testing.assert_allclose(told[:, j], t_ref, rtol=1e-12)
        np.testing.assert_allclose(drawn[:, j], d_ref, rtol=1e-12)
        assert (b_nom[:, j] == b).all()
    if curve == "wgc_m3":  # σ_user at 5/15/45/90 deg, rounded as published in the design notes' table
        user = np.sqrt(told[:, 0] ** 2 - 0.75**2 - (0.12 * 1.001 / np.sqrt(0.002001 + np.sin(np.radians(theta)) ** 2)) ** 2)
        np.testing.assert_allclose(user[[0, 2, 4, 6]], [1.492, 0.823, 0.525, 0.514], atol=6e-4)


def test_seed_model_is_eq27_for_every_system():
    s = GnssSettings(constellations=ALL)
    theta = np.array([5.0, 20.0, 70.0])
    told, drawn, b = range_sigmas(np.radians(theta)[:, None] * np.ones(3), np.array(["G", "E", "C"]), s)
    ref, _ = closed_form_sigmas(theta, 0.75, 0.75)
    np.testing.assert_allclose(told, np.repeat(ref[:, None], 3, 1), rtol=1e-12)
    assert told is drawn and not b.any()


def residual_chi2(geom, pr, clock_free_sigma, system_code, K):
    """rᵀWr of the WLS of pr − |s − a| on [position, one clock per system] at the true antenna (exact
    linear model: truth is the linearisation point), per (trial, epoch), and the degrees of freedom."""
    out, dof = [], []
    T = geom.t.size
    for k in range(T):
        vis = geom.visible[k]
        u = geom.sat_pos_ecef[k, vis] - geom.ant_pos_ecef[k]
        u /= np.linalg.norm(u, axis=1)[:, None]
        onehot = (system_code[vis][:, None] == np.arange(K)).astype(float)
        present = onehot.any(0)
        H = np.hstack([-u, onehot[:, present]])
        sw = 1.0 / clock_free_sigma[k, vis]
        y = (pr[:, k, vis] - geom.geometric_range[k, vis]) * sw  # (n_trials, n)
        Hw = H * sw[:, None]
        x, *_ = np.linalg.lstsq(Hw, y.T, rcond=None)
        r = y.T - Hw @ x
        out.append((r**2).sum(0))
        dof.append(vis.sum() - H.shape[1])
    return np.array(out), np.array(dof)


@pytest.mark.parametrize("model", ["seed", "dfmc"])
def test_fault_free_normalised_residuals_are_chi2(truth, model):
    """10⁴ epochs (1000 trials × 10 epochs) of three constellations: rᵀC_acc⁻¹r with one clock per system
    follows χ²(n − 3 − K) (KS); the monitors' SSE (weights C_int⁻¹) too in the seed model (C_int = C_acc)."""
    s = GnssSettings(terrain_masking=False, constellations=ALL, error_model=model)
    g = gnss_geometry(truth.decimate(0.1), Mount(np.zeros(3)), s, start_utc=START)
    assert g.t.size >= 6
    n = 10_000 // g.t.size + 1
    epochs, _ = apply_gnss_errors(g, draw_gnss_errors(g, s, rng=np.random.default_rng(7), n_trials=n))
    code, letters = multi_clock.system_codes(g.system)
    _, drawn, _ = range_sigmas(g.elevation, g.system, s)
    chi2, dof = residual_chi2(g, epochs.pseudorange, drawn, code, len(letters))
    assert chi2.size >= 10_000
    u = stats.chi2.cdf(chi2, dof[:, None]).ravel()  # uniform under the model
    assert stats.kstest(u, "uniform").pvalue > 1e-3
    if model == "dfmc":  # the monitors are told C_int > C_acc: their normalised SSE is smaller
        assert np.mean(chi2) / np.mean(dof) == pytest.approx(1.0, abs=0.03)
    out = gps_raim(epochs, runway_frame(), IntegritySettings())
    sse = np.asarray(out.test_stat)  # (n, T)
    assert (out.n_used == g.visible.sum(-1)).all() and (out.reason == 0).all()
    p = stats.chi2.cdf(sse, (g.visible.sum(-1) - 6)[None, :]).ravel()
    if model == "seed":
        assert stats.kstest(p, "uniform").pvalue > 1e-3
    else:
        assert np.mean(sse) < 0.8 * np.mean(g.visible.sum(-1) - 6)


# ---------------------------------------------------------------------------------------------- clocks, faults


def test_inter_system_offsets_are_one_constant_per_constellation(sky3):
    s = GnssSettings(constellations=ALL, inter_system_bias_sigma_m=10.0)
    err = draw_gnss_errors(sky3, s, rng=np.random.default_rng(3), n_trials=4000)
    ep, tr = apply_gnss_errors(sky3, err)
    rest = ep.pseudorange - sky3.geometric_range - tr.clock_bias[..., None] - tr.noise
    vis = sky3.visible
    off = np.where(vis, rest, np.nan)
    g = sky3.system == "G"
    assert np.nanmax(np.abs(off[..., g])) < 1e-6
    for c in "EC":
        col = off[..., sky3.system == c].reshape(4000, -1)
        per_trial = np.nanmean(col, axis=1)
        assert np.nanmax(np.abs(col - per_trial[:, None])) < 1e-6  # one value per trial
        assert np.std(per_trial) == pytest.approx(10.0, rel=0.05)
    e_off, c_off = (off[:, 0, np.flatnonzero(sky3.system == c)[0]] for c in "EC")
    assert abs(np.corrcoef(e_off, c_off)[0, 1]) < 0.06  # independent between systems


def test_gps_only_draws_no_offset(truth):
    g = geometry(truth, terrain_masking=False)
    err = draw_gnss_errors(g, GnssSettings(), rng=np.random.default_rng(0), n_trials=3)
    assert err.system_offset is None


def test_constellation_fault_biases_that_system_only(sky3, frame):
    s = GnssSettings(constellations=ALL)
    err = draw_gnss_errors(sky3, s, rng=np.random.default_rng(5), n_trials=3)
    fault = ConstellationBias(kind="constellation_bias", system="galileo", bias_m=30.0, rate_m_s=0.5, onset_s=20.0)
    clean, _ = apply_gnss_errors(sky3, err)
    hit, tr = apply_gnss_errors(sky3, err, [fault])
    d = hit.pseudorange - clean.pseudorange
    E = sky3.system == "E"
    expected = np.where(sky3.t >= 20.0, 30.0 + 0.5 * (sky3.t - 20.0), 0.0)
    vis = sky3.visible
    np.testing.assert_allclose(np.where(vis[..., E], d[..., E], 0.0),
                               np.broadcast_to(np.where(vis[..., E], expected[:, None], 0.0), d[..., E].shape), atol=1e-6)
    assert np.nanmax(np.abs(d[..., ~E])) == 0.0
    assert (tr.faulty[..., E] == (sky3.t >= 20.0)[None, :, None]).all() and not tr.faulty[..., ~E].any()
    # a bias common to a constellation is that constellation's clock to a snapshot solution: the fix and
    # the test statistic do not move, the Galileo clock absorbs it
    st = IntegritySettings()
    a, b = gps_raim(clean, frame, st), gps_raim(hit, frame, st)
    np.testing.assert_allclose(b.pos_enu, a.pos_enu, atol=1e-6)
    np.testing.assert_allclose(b.test_stat, a.test_stat, atol=1e-6)


def test_faults_name_satellites_of_any_constellation(sky3):
    vis = sky3.visible
    rng = np.random.default_rng(0)

    def hit(**kw):
        bias = gnss_fault_bias([GpsStep(kind="gps_step", bias_m=5.0, **kw)], sky3.t, sky3.prn, vis, rng, sky3.system)
        return set(f"{c}{p:02d}" for c, p in zip(sky3.system[bias.any(0)], sky3.prn[bias.any(0)]))

    assert hit(sat="E11") == {"E11"}
    assert hit(prn=11) == {"G11"}  # an integer is a GPS PRN, as before
    assert hit(sat=["C59", "G05"]) == {"C59", "G05"}
    with pytest.raises(ValueError, match="E30"):
        hit(sat="E30")
    with pytest.raises(ValidationError, match="prn or sat"):
        GpsStep(kind="gps_step", bias_m=5.0, prn=3, sat="E11")
    with pytest.raises(ValidationError, match="RINEX 3"):
        GpsStep(kind="gps_step", bias_m=5.0, sat="R11")
    with pytest.raises(ValidationError, match="non-zero"):
        ConstellationBias(kind="constellation_bias", system="beidou")


# ---------------------------------------------------------------------------------------------- the solver


def brute_force_fit(anchor, z, w, mask, code, K, x):
    """The WLS fields at state x by selection of the used rows and np.linalg (one epoch)."""
    m = mask
    d = anchor[m] - x[:3]
    rho = np.linalg.norm(d, axis=1)
    present = np.unique(code[m])
    H = np.hstack([-d / rho[:, None], (code[m][:, None] == present).astype(float)])
    Wm = np.diag(w[m])
    J = np.linalg.inv(H.T @ Wm @ H)
    A = J @ H.T @ Wm
    r = z[m] - rho - x[3 + code[m]]
    ws = np.diag(Wm @ (np.eye(m.sum()) - H @ A))
    return {"sse": r @ Wm @ r, "hslope": np.hypot(A[0], A[1]) / np.sqrt(ws), "vslope": np.abs(A[2]) / np.sqrt(ws),
            "J3": J[:3, :3], "dof": m.sum() - H.shape[1]}


def test_multi_clock_fit_against_brute_force(sky3, frame):
    s = GnssSettings(constellations=ALL)
    ep, tr = apply_gnss_errors(sky3, draw_gnss_errors(sky3, s, rng=np.random.default_rng(11), n_trials=2))
    code, letters = multi_clock.system_codes(sky3.system)
    P = 2 * sky3.t.size
    anchor = frame.ecef_to_enu(ep.sat_pos_ecef.reshape(-1, 3)).reshape(P, -1, 3)
    mask = ep.visible.reshape(P, -1).copy()
    mask[::3, code == 1] = False  # some epochs without Galileo: its clock is not estimated there
    z = np.where(mask, ep.pseudorange.reshape(P, -1), 0.0)
    w = 1.0 / ep.sigma.reshape(P, -1) ** 2
    codes = np.broadcast_to(code, mask.shape)
    x, conv, iters, ft = multi_clock.fit_multi_clock(anchor, np.zeros((P, 3)), z, w, mask, codes, 3)
    assert conv.all() and (iters <= 6).all()
    truth_enu = frame.ecef_to_enu(np.broadcast_to(tr.antenna_pos_ecef, (2,) + tr.antenna_pos_ecef.shape).reshape(-1, 3))
    assert np.abs(x[:, :3] - truth_enu).max() < 10.0
    assert (x[::3, 4] == 0.0).all() and (ft.n_states[::3] == 5).all() and (ft.n_states[1::3] == 6).all()
    for p in range(0, P, 7):
        ref = brute_force_fit(anchor[p], z[p], w[p], mask[p], code, 3, x[p])
        assert ft.sse[p] == pytest.approx(ref["sse"], rel=1e-6)  # ranges of 2e7 m: 1e-8 m rounding
        np.testing.assert_allclose(ft.hslope[p][mask[p]], ref["hslope"], rtol=1e-9)
        np.testing.assert_allclose(ft.vslope[p][mask[p]], ref["vslope"], rtol=1e-9)
        np.testing.assert_allclose(ft.J[p][:3, :3], ref["J3"], rtol=1e-9, atol=1e-12)
        assert ft.dof[p] == ref["dof"]


def test_one_constellation_through_the_multi_clock_path_matches_the_kernel(truth, frame):
    """The numpy solver with K = 1 reproduces the compiled 4-state solve (a check of both)."""
    g = geometry(truth, terrain_masking=False)
    s = GnssSettings()
    ep, _ = apply_gnss_errors(g, draw_gnss_errors(g, s, rng=np.random.default_rng(2), n_trials=2))
    st = IntegritySettings()
    ref = gps_raim(ep, frame, st)
    P = 2 * g.t.size
    anchor = frame.ecef_to_enu(ep.sat_pos_ecef.reshape(-1, 3)).reshape(P, -1, 3)
    mask = ep.visible.reshape(P, -1)
    z = np.where(mask, ep.pseudorange.reshape(P, -1), 0.0)
    w = np.where(mask, 1.0 / ep.sigma.reshape(P, -1) ** 2, 0.0)
    x, conv, _, ft = multi_clock.fit_multi_clock(anchor, np.zeros((P, 3)), z, w, mask, np.zeros(mask.shape, int), 1)
    np.testing.assert_allclose(x[:, :3], ref.pos_enu.reshape(P, 3), atol=1e-4)
    np.testing.assert_allclose(ft.sse, ref.test_stat.reshape(P), rtol=1e-6, atol=1e-9)
    vs = np.nanmax(np.where(mask, ft.vslope, np.nan), axis=1)
    np.testing.assert_allclose(vs, ref.diagnostics.vslope.reshape(P, -1).max(-1, initial=0, where=mask), rtol=1e-6)


def test_raim_with_three_constellations_fixes_and_excludes(sky3, frame):
    s = GnssSettings(constellations=ALL)
    err = draw_gnss_errors(sky3, s, rng=np.random.default_rng(4), n_trials=3)
    up = np.flatnonzero((sky3.system == "E") & sky3.visible.all(0))
    slot = int(up[np.argmax(sky3.elevation[0, up])])  # the highest Galileo satellite, in view throughout
    sat = f"E{int(sky3.prn[slot]):02d}"
    ep, tr = apply_gnss_errors(sky3, err, [GpsStep(kind="gps_step", sat=sat, bias_m=80.0, onset_s=30.0)])
    out = gps_raim(ep, frame, IntegritySettings(fde=True))
    truth_enu = frame.ecef_to_enu(tr.antenna_pos_ecef)
    late = sky3.t >= 30.0
    assert (out.fde.detected[:, late]).all() and not out.fde.detected[:, ~late].any()
    assert (out.excluded[:, late] == slot).all()
    assert np.abs(out.pos_enu - truth_enu).max() < 10.0
    assert np.nanmax(out.vpl) < 20.0


# ---------------------------------------------------------------------------------------------- sky windows


@pytest.mark.parametrize("cons, bound_deg", [
    (["gps"], {"G": 0.05}),
    (["gps", "galileo"], {"G": 0.6, "E": 0.01}),
    (["gps", "beidou"], {"G": 0.5, "C": 0.2}),
    (ALL, {"G": 4.0, "E": 0.01, "C": 2.1}),
])
def test_sky_repeat_period_of_each_constellation_set(truth, cons, bound_deg):
    """The sky of a constellation set comes back after :func:`sky_repeat_s` (how far each system's elevations
    are then from the start's, measured); one sidereal day would leave Galileo and BeiDou far off."""
    P = sky_repeat_s(cons)
    g = gnss_geometry(truth.decimate(0.1), Mount(np.zeros(3)), GnssSettings(terrain_masking=False, constellations=cons),
                      start_utc="2026-03-01T04:00:00Z", offsets_s=[0.0, P, 86164.0905])
    off = np.degrees(np.abs(g.elevation[1] - g.elevation[0]))
    day = np.degrees(np.abs(g.elevation[2] - g.elevation[0]))
    for c, bound in bound_deg.items():
        assert off[:, g.system == c].max() < bound, c
        if c != "G":
            assert day[:, g.system == c].max() > 20.0, c  # not a daily repeat


# ---------------------------------------------------------------------------------------------- the loop


def test_gps_only_monitors_see_gps_satellites_alone(sky3):
    s = GnssSettings(constellations=ALL)
    ep, _ = apply_gnss_errors(sky3, draw_gnss_errors(sky3, s, rng=np.random.default_rng(0)))
    obs = gps_satellites(Observations(ep))
    g = obs.gnss
    other = sky3.system != "G"
    assert not g.visible[:, other].any() and np.isnan(g.pseudorange[:, other]).all()
    assert (g.reason[:, other][sky3.visible[:, other]] == NotVisible.EXCLUDED).all()
    assert (g.visible[:, ~other] == sky3.visible[:, ~other]).all()
    np.testing.assert_array_equal(g.pseudorange[:, ~other], ep.pseudorange[:, ~other])
    gps = Observations(replace_system(ep))
    assert gps_satellites(gps) is gps  # GPS alone: the very same observations


def replace_system(ep):
    return replace(ep, system=np.full(ep.system.shape, "G"))


def test_dfmc_flight_records_satellites_by_constellation(tmp_path):
    """The shipped DFMC approach flies with GPS RAIM over every satellite; the recording colours visible rays
    by constellation and labels a faulty Galileo satellite by its RINEX name."""
    run = run_approach("zunz-rwy05-dfmc", seed=1, rrd_path=tmp_path / "run.rrd", monitors=["gps_raim"],
                       faults=[{"kind": "gps_ramp", "sat": "E11", "rate_m_s": 2.0, "onset_s": 60.0}])
    g = run.loop.gnss
    assert set(g.system.tolist()) == {"G", "E", "C"}
    gps_vis = (np.asarray(g.visible) & (g.system == "G")).sum(-1)
    assert np.median(run.outputs["gps_raim"].n_used) > 2 * np.median(gps_vis)
    _, colours = readback.component_rows(run.rrd_path, "world/gnss/los", "LineStrips3D:colors")
    seen = {((int(c) >> 24) & 255, (int(c) >> 16) & 255, (int(c) >> 8) & 255) for row in colours for c in row}
    assert {COLOURS["visible"], COLOURS["visible_galileo"], COLOURS["visible_beidou"]} <= seen
    faulty = np.asarray(run.loop.gnss_truth.faulty) & np.asarray(g.visible)
    assert faulty.any()  # E11 is in view after the onset on 2026-03-01
    _, labels = readback.component_rows(run.rrd_path, "world/gnss/faulty", "LineStrips3D:labels")
    assert {tuple(lb) for lb in labels if lb} == {("faulty E11",)}


def test_geometry_dops_against_brute_force(sky3, frame):
    code, letters = multi_clock.system_codes(sky3.system)
    d = sky3.sat_pos_ecef - sky3.ant_pos_ecef[:, None, :]
    los = np.einsum("ij,tsj->tsi", frame.R, d / np.linalg.norm(d, axis=-1, keepdims=True))
    mask = sky3.visible.copy()
    mask[5, code == 2] = False  # an epoch without BeiDou: two clocks there
    dop = multi_clock.geometry_dops(los, mask, code, 3)
    for k in (0, 5, 30):
        m = mask[k]
        present = np.unique(code[m])
        H = np.hstack([-los[k, m], (code[m][:, None] == present).astype(float)])
        Q = np.linalg.inv(H.T @ H)
        assert dop["vdop"][k] == pytest.approx(np.sqrt(Q[2, 2]), rel=1e-9)
        assert dop["hdop"][k] == pytest.approx(np.sqrt(Q[0, 0] + Q[1, 1]), rel=1e-9)
    few = np.zeros_like(mask[0])
    few[np.flatnonzero(code == 0)[:3]] = True  # 3 rows, 4 unknowns: no fix
    assert np.isnan(multi_clock.geometry_dops(los[0], few, code, 3)["vdop"])


def test_sky_along_the_final_per_constellation_set():
    """Four start times over a day on zunz-rwy05-final: more constellations, more satellites and a smaller
    VDOP; the valley hides some of each; the study's table names every row."""
    from testbed.studies.constellation_sky import sky_along_final, table

    rows = sky_along_final(span_s=86400.0, step_s=21600.0, rate_hz=0.05)
    by = {(r["set"], r["valley"]): r for r in rows}
    for valley in (False, True):
        n = [by[(s, valley)]["n"] for s in ("GPS", "GPS+Galileo", "GPS+Galileo+BeiDou")]
        assert (n[0] < n[1]).all() and (n[1] < n[2]).all()
        v = [by[(s, valley)]["vdop_median"] for s in ("GPS", "GPS+Galileo", "GPS+Galileo+BeiDou")]
        assert v[0] > v[1] > v[2]
    for s in ("GPS", "GPS+Galileo+BeiDou"):
        assert (by[(s, True)]["n"] <= by[(s, False)]["n"]).all() and by[(s, True)]["n_median"] < by[(s, False)]["n_median"]
    assert by[("GPS+Galileo+BeiDou", True)]["n_min"] >= 10
    assert table(rows).count("\n") == len(rows) + 1


def test_geometry_joins_by_epoch_keep_per_satellite_arrays(truth):
    """Blocks whose epoch count equals the satellite count (24 and 24): ``system`` and ``prn`` stay (S,)."""
    from testbed.sim.slicing import geometry_concat, geometry_prefix

    g = geometry(truth.decimate(1.0).at_indices(np.arange(48)), terrain_masking=False)
    a, b = geometry_prefix(g, 24), geometry(truth.decimate(1.0).at_indices(np.arange(24, 48)), terrain_masking=False)
    assert a.t.size == 24 == a.system.size
    joined = geometry_concat(a, b)
    assert joined.system.shape == (24,) and joined.prn.shape == (24,)
    np.testing.assert_array_equal(joined.visible, g.visible)


@pytest.mark.slow
def test_export_rinex_of_the_dfmc_approach_reads_back_with_every_system(tmp_path, monkeypatch, capsys):
    """export-rinex of GPS + Galileo + BeiDou writes mixed RINEX 3.05 files (the ranges hold the drawn inter-system
    offsets); testbed monitor reads them back, uses all three systems with one clock each, and its fix is the
    truth within the noise."""
    monkeypatch.chdir(tmp_path)
    assert main(["export-rinex", "zunz-rwy05-dfmc", str(tmp_path / "rnx")]) == 0
    obs, nav, truth = (tmp_path / "rnx" / f"zunz-rwy05-dfmc.{x}" for x in ("obs", "nav", "truth.csv"))
    assert "3.05" in obs.read_text()[:20] and obs.is_file() and nav.is_file()
    capsys.readouterr()
    assert main(["monitor", str(obs), str(nav), "--reference", str(truth), "--out", str(tmp_path / "m")]) == 0
    rec = json.loads((tmp_path / "m" / "summary.json").read_text())
    assert rec["systems_used"] == ["G", "E", "C"] and rec["systems_skipped"] == {}
    raim = rec["monitors"]["gps_raim"]
    assert raim["reasons"] == {"ok": 150} and raim["mi_epochs"] == 0
    assert raim["hpe95_m"] < 3.0 and raim["vpe95_m"] < 5.0  # 0.90 m and 1.71 m measured


def test_the_campaign_sweeps_constellations_and_terrain_masking(tmp_path):
    """The constellation and open-sky axes set each cell's [gnss] (the tables of untracked constellations
    dropped, so every cell validates) and name the cells; a spec without them hashes as before."""
    from testbed.campaign.spec import expand_cells, load_spec

    loaded = load_spec("araim-constellations")
    cells = expand_cells(loaded)
    got = {(c.params["constellations"], c.params["terrain_masking"]) for c in cells}
    assert got == {(x, m) for x in ("gps", "gps+galileo", "gps+galileo+beidou") for m in (0, 1)}
    for c in cells:
        assert "+".join(c.config.gnss.constellations) == c.params["constellations"]
        assert c.config.gnss.terrain_masking == bool(c.params["terrain_masking"])
    spec = tmp_path / "s.toml"
    spec.write_text('name = "s"\napproaches = ["zunz-rwy05-dfmc"]\nmonitors = ["gps_raim"]\ntrials = 10\n'
                    '[sweep]\nconstellations = []\nterrain_masking = []\n')
    plain = tmp_path / "p.toml"
    plain.write_text('name = "s"\napproaches = ["zunz-rwy05-dfmc"]\nmonitors = ["gps_raim"]\ntrials = 10\n')
    assert load_spec(spec).hash == load_spec(plain).hash


def test_campaign_tables_name_the_faulty_satellite_with_its_system(tmp_path):
    """A random satellite fault over three constellations lands on Galileo and BeiDou satellites too; the trials
    table names each with its RINEX name, the PRN alone (``fault_target``) being ambiguous across systems; a fault on
    every satellite of a system is named by the system's letter."""
    import pyarrow.parquet as pq

    spec = tmp_path / "s.toml"
    spec.write_text('name = "s"\napproaches = ["zunz-rwy05-dfmc"]\nmonitors = ["gps_raim"]\ntrials = 24\n'
                    'duration_s = 2.0\nbase_seed = 5\n[[faults]]\nkind = "gps_step"\nmagnitudes = [30.0]\nonset_s = 0.0\n'
                    '[[faults]]\nkind = "constellation_bias"\nsystem = "galileo"\nmagnitudes = [30.0]\nonset_s = 0.0\n')
    assert main(["campaign", str(spec), "--out", str(tmp_path / "o"), "--workers", "1", "--no-report",
                 "--quiet"]) == 0
    table = pq.read_table(tmp_path / "o" / "trials.parquet", columns=["cell", "fault_target", "fault_satellite"])
    every = table.to_pylist()
    assert len(every) == 48
    assert {r["fault_satellite"] for r in every if r["cell"] == 1} == {"E"}  # every Galileo satellite: the system
    rows = [r for r in every if r["cell"] == 0]
    for r in rows:
        assert r["fault_satellite"][0] in "GEC" and int(r["fault_satellite"][1:]) == r["fault_target"], r
    assert {r["fault_satellite"][0] for r in rows} >= {"G", "E"}, rows  # 24 draws over 23 satellites of 3 systems


# ---------------------------------------------------------------------------------------------- orbits from a file

DFMC_START = utc_to_gps_seconds("2026-03-01T04:00:00Z")  # zunz-rwy05-dfmc's and va-raim-2015's start
FROM_FILE = ('\n[gnss.galileo]\norbit_source = "rinex_nav"\norbit_path = "{nav}"\n'
             '\n[gnss.beidou]\norbit_source = "rinex_nav"\norbit_path = "{nav}"\n')


def exported_nav(path, t0=DFMC_START):
    """The nominal Galileo + BeiDou slots written by the exporter's navigation writer (records every 2 h over the
    hour after ``t0``; the BeiDou GEOs as GEO-form records)."""
    return write_nav(nominal_constellations(["galileo", "beidou"], t0), (t0, t0 + 3600.0), path)


def test_galileo_and_beidou_fly_from_the_exporters_nav_file(tmp_path):
    """zunz-rwy05-dfmc with Galileo and BeiDou read from a RINEX 3.05 navigation file our exporter wrote (path
    relative to the approach file): every satellite where the nominal slots put it (the exporter's round trip,
    < 1 mm; 20 µm measured), the same satellites in view (22 median), and GPS RAIM and ARAIM run on it with the
    nominal run's protection levels (without an exclusion they depend on the geometry and the σ only)."""
    exported_nav(tmp_path / "gec.nav")
    final = (approaches_dir() / "zunz-rwy05-dfmc.toml").read_text() + "\n[flight]\nstart_distance_m = 6000.0\n"
    ap, nominal = tmp_path / "from-file.toml", tmp_path / "nominal.toml"
    ap.write_text(final + FROM_FILE.format(nav="gec.nav"))
    nominal.write_text(final)
    kw = dict(seed=0, rrd_path=None, monitors=["gps_raim", "araim"])
    run, ref = run_approach(ap, **kw), run_approach(nominal, **kw)
    g, r = run.loop.gnss, ref.loop.gnss
    ids, ref_ids = [np.char.add(x.system, np.char.zfill(x.prn.astype(str), 2)) for x in (g, r)]
    assert sorted(ids.tolist()) == sorted(ref_ids.tolist()) and len(ids) == 24 + 24 + 30
    at = np.array([np.flatnonzero(ids == i)[0] for i in ref_ids])  # the file's slot of each nominal satellite
    assert np.abs(g.sat_pos_ecef[:, at] - r.sat_pos_ecef).max() < 1e-3
    np.testing.assert_array_equal(g.visible[:, at], r.visible)
    assert (g.visible & (g.system == "C")).sum(-1).min() >= 6  # BeiDou in view, GEOs from GEO-form records
    for name in ("gps_raim", "araim"):
        out, want = run.outputs[name], ref.outputs[name]
        ok = (out.reason == 0) & (want.reason == 0)
        assert ok.mean() > 0.9, name
        same = ok & (out.n_used == want.n_used)
        assert same.mean() > 0.9, name
        np.testing.assert_allclose(out.vpl[same], want.vpl[same], rtol=0, atol=1e-4)  # 1 µm measured


def test_orbit_files_key_the_cached_sky_by_content(tmp_path):
    """The campaign's sky cache keys on the orbit file's content: an edited file is another sky, the same bytes
    under another path the same one; the campaign's input fingerprint lists the file."""
    a, b = exported_nav(tmp_path / "a.nav"), tmp_path / "b.nav"
    b.write_bytes(a.read_bytes())

    def key(p):
        return GnssSettings(constellations=ALL, galileo={"orbit_source": "rinex_nav", "orbit_path": p}).geometry_key()

    assert key(a) == key(b) != GnssSettings(constellations=ALL).geometry_key()
    b.write_text(b.read_text().replace("E01 2026", "E02 2026", 1))
    assert key(a) != key(b)
    s = GnssSettings(constellations=ALL, galileo={"orbit_source": "rinex_nav", "orbit_path": a},
                     beidou={"orbit_source": "rinex_nav", "orbit_path": a})
    assert s.orbit_files == [a] and GnssSettings().orbit_files == []


@pytest.mark.parametrize("kw, what", [
    ({"galileo": {"orbit_source": "rinex_nav"}}, "galileo.orbit_path: required"),
    ({"galileo": {"orbit_path": "x.nav"}}, "galileo.orbit_path: read only with orbit_source"),
    ({"beidou": {"orbit_source": "yuma", "orbit_path": "x.alm"}}, "'yuma' is a GPS almanac format"),
    ({"almanac_source": "yuma", "almanac_path": "a.alm", "gps": {"orbit_source": "rinex_nav", "orbit_path": "n"}},
     "both name GPS's orbits"),
])
def test_bad_orbit_source_settings_are_refused(kw, what):
    with pytest.raises(ValidationError, match=what):
        GnssSettings(constellations=ALL, **kw)


def _gps_only_nav(d):
    return (d / "gps.nav").write_text((REFS / "do229_gps_3.04.nav").read_text())


@pytest.mark.parametrize("make, value, what", [
    (_gps_only_nav, "gps.nav", "no Galileo records (it has GPS ones): expected a navigation file with Galileo"),
    (lambda d: exported_nav(d / "old.nav", DFMC_START - 3 * 86400.0), "old.nav",
     "nearest Galileo broadcast record is 70.0 h from 2026-03-01T04:00:00Z"),
    (lambda d: (d / "bin.nav").write_bytes(bytes(range(256)) * 8), "bin.nav", "could not be read"),
    (lambda d: None, "missing.nav", "could not be read"),
    (lambda d: (d / "a.al3").write_text("31 CURRENT.ALM\n 703 344064\n"), "a.al3", "announces 31 record(s)"),
])
def test_bad_orbit_file_exits_2_naming_file_key_and_value(tmp_path, monkeypatch, capsys, make, value, what):
    """A navigation file without the system's records, with records of another day, unreadable or missing, a
    truncated SEM almanac: one line naming the key, the file and what was expected, exit 2, nothing written."""
    inputs, work = tmp_path / "in", tmp_path / "work"
    inputs.mkdir()
    work.mkdir()
    make(inputs)
    p = inputs / "bad.toml"
    name, source = ("gps", "sem") if value.endswith(".al3") else ("galileo", "rinex_nav")
    p.write_text(SEED_APPROACH + '\n[gnss]\nconstellations = ["gps", "galileo"]\n'
                 + f'\n[gnss.{name}]\norbit_source = "{source}"\norbit_path = "{value}"\n')
    monkeypatch.chdir(work)
    code = main(["fly", str(p), "--no-record"])
    out = capsys.readouterr()
    text = out.err + out.out
    assert code == 2 and f"gnss.{name}.orbit_path" in text and value in text and what in text, text
    assert "Traceback" not in text
    assert list(work.iterdir()) == []


def test_campaign_sorties_beyond_the_broadcast_records_are_refused(tmp_path, monkeypatch, capsys):
    """Every sky window flies the records nearest the approach's start: sorties spread over a day on Galileo from a
    navigation file are refused before any work (exit 2, naming the key and the file); within the hour they pass."""
    exported_nav(tmp_path / "gec.nav")
    ap = tmp_path / "from-file.toml"
    ap.write_text(SEED_APPROACH + '\n[gnss]\nconstellations = ["gps", "galileo"]\n'
                  + '\n[gnss.galileo]\norbit_source = "rinex_nav"\norbit_path = "gec.nav"\n')
    spec = ('name = "s"\napproaches = ["from-file.toml"]\nmonitors = ["gps_raim"]\ntrials = 10\nblock_trials = 10\n'
            'chunk_trials = 10\nduration_s = 10.0\n[sorties]\nstart = "uniform"\nspan_s = {span}\n')
    (tmp_path / "day.toml").write_text(spec.format(span=86400.0))
    (tmp_path / "hour.toml").write_text(spec.format(span=3600.0))
    monkeypatch.chdir(tmp_path)
    assert len(expand_cells(load_spec(tmp_path / "hour.toml"))) == 1
    code = main(["campaign", str(tmp_path / "day.toml"), "--out", str(tmp_path / "out"), "--quiet"])
    text = "".join(capsys.readouterr())
    assert code == 2 and "gnss.galileo.orbit_path" in text and "gec.nav" in text and "24.0 h after the start" in text
    assert not (tmp_path / "out").exists()


def _records(path):
    """The header and the 8-line records of a RINEX 3 navigation file."""
    lines = path.read_text().splitlines(keepends=True)
    end = next(k for k, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    return lines[:end], [lines[k:k + 8] for k in range(end, len(lines), 8)]


def test_gps_from_its_table_or_almanac_source_and_stale_satellites_left_out(tmp_path):
    """[gnss.gps] orbit_source and [gnss] almanac_source read a file alike; a satellite whose only record is 5 h
    from the start is not tracked (the others are), and a file with no record within 2 h of the time is refused."""
    gps = nominal_constellations(["gps"], DFMC_START)
    head, now = _records(write_nav(gps, (DFMC_START, DFMC_START), tmp_path / "now.nav"))
    _, old = _records(write_nav(gps.take([0]), (DFMC_START - 5 * 3600.0,) * 2, tmp_path / "old.nav"))
    mixed = tmp_path / "mixed.nav"
    mixed.write_text("".join(head + [ln for r in now if not r[0].startswith("G01") for ln in r] + old[0]))
    a = tracked_constellations(GnssSettings(gps={"orbit_source": "rinex_nav", "orbit_path": mixed}), DFMC_START)
    b = tracked_constellations(GnssSettings(almanac_source="rinex_nav", almanac_path=mixed), DFMC_START)
    assert a.sat_id.tolist() == b.sat_id.tolist() == [f"G{p:02d}" for p in range(2, 25)]
    np.testing.assert_array_equal(a.m0, b.m0)
    with pytest.raises(StaleOrbits, match="nearest GPS broadcast record is 2.5 h from"):
        constellation_orbits("gps", "rinex_nav", tmp_path / "now.nav", DFMC_START + 2.5 * 3600.0)

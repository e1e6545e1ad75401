"""ARAIM core (testbed.integrity.araim) against what no one here wrote.

(a) the worked LPV-200 example of the ARAIM Airborne Design Document v3.1, Appendix D
    (tests/references/araim_add_appendix_d.json);
(b) sidereon (MIT, PyPI) on identical geometries, ISM and allocation where its algorithm is the ADD's
    (one fault event at a time, no exposure model: ``AraimSettings.add_v31()``);
(c) closed forms and brute force: every subset solved from scratch by least squares, the priors against
    explicit enumeration of the events, the protection-level equation by a generic root finder and a dense
    grid;
and degenerate epochs, which must come back unavailable with a reason, never an exception.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import optimize, stats

from test_integrity_core_helpers import sat_pos_ecef
from testbed.frames import enu_to_az_el
from testbed.integrity.araim import AraimEpochs, AraimReason, AraimRows, AraimSettings, ConstellationIsm, araim, araim_modes
from testbed.integrity.araim.error_model import row_variances, sigma_user
from testbed.integrity.araim.fault_modes import fault_events, fault_modes, fault_order, prob_at_least
from testbed.integrity.araim.protection import fa_multipliers, integrity_risk
from testbed.world.airport import runway_frame

REFERENCE = Path(__file__).parent / "references" / "araim_add_appendix_d.json"
GPS, GAL, BDS = 0, 1, 2
#: closed-form quantities (σ, b, T, EMT, σ_acc) are sums of products: equal to rounding
CLOSED_FORM_M = 1e-6
#: sidereon stops its vertical search at 1e-4 m and its horizontal at 5e-2 m per axis, returning low + tol
SIDEREON_VPL_M = 0.05
SIDEREON_HPL_M = 0.075


def los_from_az_el(az_deg, el_deg) -> np.ndarray:
    """(..., N, 3) receiver→satellite unit vectors in ENU from azimuth (from north) and elevation (deg)."""
    az, el = np.radians(az_deg), np.radians(el_deg)
    return np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)


def appendix_d_rows(ref: dict) -> AraimRows:
    G = np.array(ref["G_enu_clock"])
    n = len(G)
    return AraimRows(los_enu=-G[:, :3], system=(G[:, 3] - 1).astype(int), used=np.ones(n, bool),
                     c_int=np.array(ref["c_int_m2"]), c_acc=np.array(ref["c_acc_m2"]),
                     b_nom=np.full(n, ref["ism"]["b_nom_m"]), b_cont=np.full(n, ref["ism"]["b_cont_m"]))


def appendix_d_settings(ref: dict, **changes) -> AraimSettings:
    ism = ConstellationIsm(**ref["ism"])
    return AraimSettings.add_v31(ism={"GPS": ism, "Galileo": ism}, **(ref["allocation"] | changes))


# ---------------------------------------------------------------------------------------------------------
# (a) the ADD v3.1 Appendix D example
# ---------------------------------------------------------------------------------------------------------


def test_add_v31_appendix_d_worked_example():
    ref = json.loads(REFERENCE.read_text())
    pub, tol_pl, tol = ref["published"], ref["tolerance_pl_m"], ref["tolerance_other"]
    rows, settings = appendix_d_rows(ref), appendix_d_settings(ref)
    out = araim(rows, settings)
    assert out.reason == AraimReason.OK
    assert abs(out.vpl - pub["vpl_m"]) <= tol_pl, out.vpl
    assert abs(out.hpl - pub["hpl_m"]) <= tol_pl, out.hpl
    assert abs(out.emt - pub["emt_m"]) <= tol, out.emt
    assert abs(out.sigma_acc_v - pub["sigma_acc_v_m"]) <= tol, out.sigma_acc_v
    assert out.n_modes == pub["n_modes"]
    assert abs(out.k_fa[2] - pub["k_fa_vert"]) <= tol
    table = araim_modes(rows, settings)
    const_modes = [k for k, r in enumerate(table.removed) if len(r) == 5]
    cm = pub["constellation_modes"]
    np.testing.assert_allclose(table.sigma[const_modes, 2], cm["sigma_u_m"], atol=tol)
    np.testing.assert_allclose(table.sigma_ss[const_modes, 2], cm["sigma_ss_u_m"], atol=tol)
    np.testing.assert_allclose(table.bias[const_modes, 2], cm["bias_u_m"], atol=tol)
    assert out.available[list(out.service_levels).index("LPV-200")]


# ---------------------------------------------------------------------------------------------------------
# (b) sidereon
# ---------------------------------------------------------------------------------------------------------


def enu_to_ecef_rotation(lat: float, lon: float) -> np.ndarray:
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array([[-so, -sl * co, cl * co], [co, -sl * so, cl * so], [0.0, cl, sl]])


def sidereon_araim(sd, los_enu, system, c_int, c_acc, ism: dict[int, ConstellationIsm]):
    """sidereon.araim on one epoch, our per-row sigmas passed as its 'effective' sigmas (its own error model
    is not the ADD's), LPV-200 allocation. The receiver's position only orients ENU: any one will do when
    the lines of sight are rotated with it."""
    lat, lon = math.radians(29.3), math.radians(94.3)
    los_ecef = los_enu @ enu_to_ecef_rotation(lat, lon).T
    sys_of = {GPS: (sd.GnssSystem.GPS, "G"), GAL: (sd.GnssSystem.GALILEO, "E"), BDS: (sd.GnssSystem.BEIDOU, "C")}
    ids = [f"{sys_of[int(s)][1]}{i + 1:02d}" for i, s in enumerate(system)]
    el = np.arcsin(los_enu[:, 2])
    present = list(dict.fromkeys(int(s) for s in system))
    rows = [sd.AraimRow(ids[i], los_ecef[i], float(el[i]), sys_of[int(s)][0]) for i, s in enumerate(system)]
    geom = sd.AraimGeometry(rows, sd.Wgs84Geodetic(lat, lon, 2949.0), [sys_of[s][0] for s in present])
    sats = [sd.SatelliteIsm.new_with_effective_sigmas(ids[i], ism[int(s)].sigma_ura_m, ism[int(s)].sigma_ure_m,
                                                      ism[int(s)].b_nom_m, ism[int(s)].p_sat,
                                                      float(np.sqrt(c_int[i])), float(np.sqrt(c_acc[i])))
            for i, s in enumerate(system)]
    consts = [sd.ConstellationIsm(sys_of[s][0], ism[s].p_const,
                                  sd.SatelliteIsmModel(ism[s].sigma_ura_m, ism[s].sigma_ure_m, ism[s].b_nom_m,
                                                       ism[s].p_sat)) for s in present]
    res = sd.araim(geom, sd.Ism(consts, sats), sd.IntegrityAllocation.lpv_200())
    modes = []
    for fm in res.fault_modes[1:]:  # it lists every single event; one that removes every row is unmonitorable
        if fm.excluded_constellation is not None:
            c = [s for s in present if sys_of[s][0] == fm.excluded_constellation][0]
            modes.append(tuple(i for i, s in enumerate(system) if s == c))
        else:
            modes.append(tuple(sorted(ids.index(x) for x in fm.excluded)))
    monitorable = [fm.monitorable for fm in res.fault_modes[1:]]
    return res, modes, monitorable


def random_two_constellation_epochs(rng, n_epochs):
    """GPS + Galileo epochs of 5-11 satellites each (≤ 20 in all, so one fault event at a time is monitored),
    satellites uniform over the sky above 5°."""
    out = []
    for _ in range(n_epochs):
        n_g = int(rng.integers(5, 11))
        n_e = int(rng.integers(5, 21 - n_g))
        n = n_g + n_e
        az = rng.uniform(0.0, 360.0, n)
        el = np.degrees(np.arcsin(rng.uniform(math.sin(math.radians(5.0)), 1.0, n)))
        out.append((los_from_az_el(az, el), np.array([GPS] * n_g + [GAL] * n_e)))
    return out


def compare_with_sidereon(sd, los, system, settings: AraimSettings, ours=None, modes_too=True):
    """Differences ours − sidereon on one epoch (``ours``: this epoch's entry of a batched call, if made);
    with ``modes_too`` the mode lists must be equal and every mode's σ, b and T agree to rounding."""
    rows = AraimRows.from_elevation(los, system, np.ones(len(system), bool), settings)
    ours = araim(rows, settings) if ours is None else ours
    ism = {s: settings.system_ism(s) for s in set(system.tolist())}
    res, modes, monitorable = sidereon_araim(sd, los, system, rows.c_int, rows.c_acc, ism)
    assert res.available and ours.reason == AraimReason.OK
    if modes_too:
        table = araim_modes(rows, settings)
        assert sorted(table.removed[1:]) == sorted(m for m, ok in zip(modes, monitorable) if ok)
        by_rows = {m: k + 1 for k, m in enumerate(modes)}
        for k, removed in enumerate(table.removed):
            fm = res.fault_modes[by_rows[removed] if k else 0]
            np.testing.assert_allclose(table.sigma[k], fm.sigma_int_enu_m, atol=CLOSED_FORM_M)
            np.testing.assert_allclose(table.bias[k], fm.bias_enu_m, atol=CLOSED_FORM_M)
            np.testing.assert_allclose(table.threshold[k], fm.threshold_enu_m, atol=CLOSED_FORM_M)
            assert table.p[k] == pytest.approx(fm.prior, rel=1e-3)
    return dict(dv=float(ours.vpl - res.vpl_m), dh=float(ours.hpl - res.hpl_m), demt=float(ours.emt - res.emt_m),
                dacc_v=float(ours.sigma_acc_v - res.sigma_acc_v_m),
                dacc_h=math.hypot(*ours.sigma_acc_enu[:2]) - res.sigma_acc_h_m)


def padded_batch(epochs, width: int):
    """Epochs of different sizes as one batch: rows padded to ``width``, the padding not used."""
    los = np.zeros((len(epochs), width, 3))
    los[..., 2] = 1.0
    system = np.zeros((len(epochs), width), int)
    used = np.zeros((len(epochs), width), bool)
    for t, (l, s) in enumerate(epochs):
        los[t, :len(s)], system[t, :len(s)], used[t, :len(s)] = l, s, True
    return los, system, used


def assert_within_sidereon_tolerances(diffs: list[dict]):
    worst = {k: max(abs(d[k]) for d in diffs) for k in diffs[0]}
    assert worst["dv"] <= SIDEREON_VPL_M, worst
    assert worst["dh"] <= SIDEREON_HPL_M, worst
    for k in ("demt", "dacc_v", "dacc_h"):
        assert worst[k] <= CLOSED_FORM_M, worst
    return worst


def test_sidereon_on_the_worked_gps_galileo_geometry():
    sd = pytest.importorskip("sidereon", reason="sidereon (the independent ARAIM oracle) is not installed")
    az = [0, 60, 120, 180, 240, 300, 30, 90, 150, 210, 270, 330]
    el = [75, 20, 45, 15, 50, 25, 40, 10, 65, 30, 55, 12]
    d = compare_with_sidereon(sd, los_from_az_el(az, el), np.array([GPS] * 6 + [GAL] * 6), AraimSettings.add_v31())
    assert_within_sidereon_tolerances([d])


def _epoch(out: AraimEpochs, t: int) -> AraimEpochs:
    return AraimEpochs(**{f.name: (getattr(out, f.name)[t] if isinstance(getattr(out, f.name), np.ndarray)
                                   else getattr(out, f.name)) for f in dataclasses.fields(out)})


def test_sidereon_on_random_gps_galileo_epochs():
    """1000 random GPS+Galileo geometries in one batched call: PLs to the search tolerances, EMT and σ_acc to
    rounding; on the first 100 also the same fault-mode list and every mode's σ, b and T to rounding."""
    sd = pytest.importorskip("sidereon", reason="sidereon (the independent ARAIM oracle) is not installed")
    rng = np.random.default_rng(45)
    settings = AraimSettings.add_v31()
    epochs = random_two_constellation_epochs(rng, 1000)
    batch = araim(AraimRows.from_elevation(*padded_batch(epochs, 20), settings), settings)
    diffs = [compare_with_sidereon(sd, los, system, settings, ours=_epoch(batch, t), modes_too=t < 100)
             for t, (los, system) in enumerate(epochs)]
    assert_within_sidereon_tolerances(diffs)


def approach_geometries(n_epochs: int, mask_deg: float = 5.0):
    """GPS lines of sight (DO-229 almanac) from a point on the ZUNZ RWY05 final, epochs spread over a day."""
    frame = runway_frame()
    tow = 344063.0 + np.linspace(0.0, 86400.0, n_epochs, endpoint=False)
    rx = frame.enu_to_ecef(np.broadcast_to([-4000.0, -2800.0, 350.0], (n_epochs, 3)))
    los = frame.vec_ecef_to_enu(sat_pos_ecef(tow) - rx[:, None, :])
    los /= np.linalg.norm(los, axis=-1, keepdims=True)
    _, el = enu_to_az_el(los)
    return los, el > np.radians(mask_deg)


def test_sidereon_on_gps_only_approach_epochs():
    """GPS alone over the approach, 200 epochs over a day, without a constellation fault (P_const = 0; see
    the next test for P_const = 1e-8)."""
    sd = pytest.importorskip("sidereon", reason="sidereon (the independent ARAIM oracle) is not installed")
    settings = AraimSettings.add_v31(ism={"GPS": ConstellationIsm(p_const=0.0)})
    los, vis = approach_geometries(200)
    batch = araim(AraimRows.from_elevation(los, np.zeros(los.shape[1], int), vis, settings), settings)
    diffs = [compare_with_sidereon(sd, los[t][vis[t]], np.zeros(vis[t].sum(), int), settings, ours=_epoch(batch, t),
                                   modes_too=t % 10 == 0) for t in range(200)]
    assert_within_sidereon_tolerances(diffs)


def test_sidereon_counts_an_unmonitorable_mode_in_the_false_alert_split():
    """Where we differ on purpose: GPS alone with P_const = 1e-8, the constellation mode removes every row and
    cannot be monitored. Both leave its prior unmonitored, but sidereon still counts it in N_modes when it
    splits P_FA, so each of its thresholds is ours × K_fa(N + 1)/K_fa(N) exactly; we split P_FA over the
    tests actually made."""
    sd = pytest.importorskip("sidereon", reason="sidereon (the independent ARAIM oracle) is not installed")
    settings = AraimSettings.add_v31(ism={"GPS": ConstellationIsm(p_const=1e-8)})
    los, vis = approach_geometries(1)
    los, system = los[0][vis[0]], np.zeros(vis[0].sum(), int)
    rows = AraimRows.from_elevation(los, system, np.ones(len(system), bool), settings)
    out, table = araim(rows, settings), araim_modes(rows, settings)
    res, modes, monitorable = sidereon_araim(sd, los, system, rows.c_int, rows.c_acc, {GPS: settings.system_ism(0)})
    assert monitorable.count(False) == 1 and out.n_modes == len(modes) - 1
    assert float(out.p_unmonitored) == pytest.approx(res.p_unmonitored, rel=1e-3)
    ratio = fa_multipliers(len(modes), 9e-8, 3.9e-6, 1) / fa_multipliers(out.n_modes, 9e-8, 3.9e-6, 1)
    for k, removed in enumerate(table.removed[1:], start=1):
        np.testing.assert_allclose(table.threshold[k] * ratio, res.fault_modes[modes.index(removed) + 1]
                                   .threshold_enu_m, rtol=1e-9)


def test_batched_call_equals_epoch_by_epoch_calls():
    """One call over a day of approach epochs (visible sets changing) = the epochs one at a time, bit for bit,
    and = two blocks of the day."""
    settings = AraimSettings.add_v31(ism={"GPS": ConstellationIsm(p_const=1e-8)})
    los, vis = approach_geometries(48)
    system = np.zeros(los.shape[1], int)
    batch = araim(AraimRows.from_elevation(los, system, vis, settings), settings)
    for name in ("vpl", "hpl", "emt", "sigma_acc_enu", "reason", "n_modes"):
        one = np.stack([getattr(araim(AraimRows.from_elevation(los[t], system, vis[t], settings), settings), name)
                        for t in range(48)])
        np.testing.assert_array_equal(getattr(batch, name), one)
    halves = [araim(AraimRows.from_elevation(los[sl], system, vis[sl], settings), settings)
              for sl in (slice(0, 20), slice(20, None))]
    np.testing.assert_array_equal(batch.vpl, np.concatenate([h.vpl for h in halves]))


# ---------------------------------------------------------------------------------------------------------
# (c) closed forms and brute force
# ---------------------------------------------------------------------------------------------------------


def three_constellation_epoch(rng, counts=(8, 7, 1)):
    """Random sky with ``counts`` satellites of GPS, Galileo, BeiDou (BeiDou with one satellite by default:
    its clock column is left without a row when that satellite is removed)."""
    n = sum(counts)
    az = rng.uniform(0.0, 360.0, n)
    el = np.degrees(np.arcsin(rng.uniform(math.sin(math.radians(5.0)), 1.0, n)))
    system = np.repeat([GPS, GAL, BDS][:len(counts)], counts)
    return los_from_az_el(az, el), system


def brute_force_subset(los, system, c_int, keep):
    """The projection rows S (3, N) of the weighted least squares on the kept rows only, the clock columns of
    systems without a kept row left out, solved by numpy's lstsq on the whitened problem."""
    clocks = [s for s in dict.fromkeys(system.tolist()) if np.any(keep & (system == s))]
    G = np.concatenate([-los, (system[:, None] == np.array(clocks)[None, :]).astype(float)], -1)[keep]
    Wh = 1.0 / np.sqrt(c_int[keep])
    S = np.zeros((3, len(system)))
    # column j of the solution operator: the estimate for a unit measurement on kept row j
    S[:, keep] = np.linalg.lstsq(G * Wh[:, None], np.diag(Wh), rcond=None)[0][:3]
    return S


def test_every_subset_equals_brute_force_least_squares():
    """σ, b, σ_ss, b_ss and the separations of every monitored mode (3 constellations, one of them a single
    satellite, pairs of faults monitored) against the kept rows solved from scratch."""
    rng = np.random.default_rng(7)
    los, system = three_constellation_epoch(rng, counts=(10, 9, 1))
    settings = AraimSettings(ism={"GPS": ConstellationIsm(), "Galileo": ConstellationIsm(),
                                  "BeiDou": ConstellationIsm(b_cont_m=0.1)})
    residual = rng.normal(0.0, 1.0, len(system))
    rows = AraimRows.from_elevation(los, system, np.ones(len(system), bool), settings, residual=residual)
    table = araim_modes(rows, settings)
    assert any(len(r) == 2 for r in table.removed), "pairs should be monitored with three constellations"
    S0 = brute_force_subset(los, system, rows.c_int, np.ones(len(system), bool))
    for k, removed in enumerate(table.removed):
        keep = np.ones(len(system), bool)
        keep[list(removed)] = False
        if not table.observable[k]:
            continue
        S = brute_force_subset(los, system, rows.c_int, keep)
        np.testing.assert_allclose(table.sigma[k], np.sqrt((S ** 2) @ rows.c_int), atol=1e-9)
        np.testing.assert_allclose(table.bias[k], np.abs(S) @ rows.b_nom, atol=1e-9)
        np.testing.assert_allclose(table.sigma_ss[k], np.sqrt(((S - S0) ** 2) @ rows.c_acc), atol=1e-9)
        np.testing.assert_allclose(table.bias_ss[k], np.abs(S - S0) @ rows.b_cont, atol=1e-9)
        np.testing.assert_allclose(table.separation[k], (S - S0) @ residual, atol=1e-9)


def test_fault_order_and_priors_against_explicit_enumeration():
    """N_fault,max and the priors against all 2^E event combinations enumerated (8 GPS + 3 Galileo)."""
    system = np.array([GPS] * 8 + [GAL] * 3)
    settings = AraimSettings(ism={"GPS": ConstellationIsm(p_sat=3e-4), "Galileo": ConstellationIsm(p_const=3e-3)},
                             fc_thres=0.0)
    ev = fault_events(system, settings)
    E = len(ev.rows)
    by_size = np.zeros(E + 1)
    for mask in itertools.product([0, 1], repeat=E):
        m = np.array(mask, bool)
        by_size[m.sum()] += np.prod(np.where(m, ev.p_exp, 1.0 - ev.p_exp))
    for r in (1, 2, 3):
        assert prob_at_least(ev.p_exp, r) == pytest.approx(by_size[r:].sum(), rel=1e-9)
    order, _ = fault_order(ev.p_exp, settings)
    assert by_size[order + 1:].sum() <= settings.p_thres < by_size[order:].sum()
    modes = fault_modes(system, settings)
    # a mode's prior is the product of its events' priors: at least the probability of exactly those events,
    # at most that over Π(1 − p); so the priors and the unmonitored one bound every faulted combination
    faulted = modes.p_exp[1:].sum() + modes.p_unmonitored
    assert by_size[1:].sum() <= faulted <= by_size[1:].sum() / np.prod(1.0 - ev.p_exp)
    single = [k for k in range(1, len(modes.p)) if modes.removed[k].sum() == 1]
    row = modes.removed[single].argmax(-1)
    np.testing.assert_allclose(modes.p[single], np.where(system[row] == GPS, 3e-4, 1e-5), rtol=1e-15)


def test_protection_levels_tend_to_the_fault_free_bound():
    """No fault priors, no nominal bias: VPL = Q⁻¹(P_HMI,V/2)·σ_U, HPL = Q⁻¹(P_HMI,H/4)·√(σ_E² + σ_N²)."""
    ism = ConstellationIsm(p_sat=0.0, p_const=0.0, b_nom_m=0.0)
    settings = AraimSettings.add_v31(ism={"GPS": ism, "Galileo": ism}, tol_pl=1e-6)
    az = [0, 60, 120, 180, 240, 300, 30, 90, 150, 210, 270, 330]
    el = [75, 20, 45, 15, 50, 25, 40, 10, 65, 30, 55, 12]
    rows = AraimRows.from_elevation(los_from_az_el(az, el), np.array([GPS] * 6 + [GAL] * 6), np.ones(12, bool),
                                    settings)
    out = araim(rows, settings)
    sigma0 = araim_modes(rows, settings).sigma[0]
    assert out.n_modes == 0
    assert out.vpl == pytest.approx(stats.norm.isf(9.8e-8 / 2) * sigma0[2], abs=2e-6)
    assert out.hpl == pytest.approx(stats.norm.isf(2e-9 / 4) * math.hypot(sigma0[0], sigma0[1]), abs=2e-6)


def by_hand_risk(pl, table, k_axis, settings, p_nm):
    """The integrity-risk equation of one axis written out term by term with scipy's normal tail."""
    Qt = lambda x: 1.0 if x <= 0 else stats.norm.sf(x)  # noqa: E731
    risk = 2.0 * Qt((pl - table.bias[0, k_axis]) / table.sigma[0, k_axis])
    for k in range(1, len(table.p)):
        if table.observable[k]:
            z = (pl - table.threshold[k, k_axis] - table.bias[k, k_axis]) / table.sigma[k, k_axis]
            risk += table.p[k] * min(Qt(z), table.alpha[k])
    scale = 1.0 - p_nm / (settings.p_hmi_vert + settings.p_hmi_hor)
    budget = settings.p_hmi_vert * scale if k_axis == 2 else 0.5 * settings.p_hmi_hor * scale
    return risk - budget / settings.n_es_int


@pytest.mark.parametrize("which", ["single GPS", "three constellations, exposure"])
def test_protection_level_is_the_root_of_the_risk_equation(which):
    """Each axis's PL against brentq on the equation written out by hand: within [root, root + TOL_PL]."""
    rng = np.random.default_rng(3)
    if which == "single GPS":
        los, system = three_constellation_epoch(rng, counts=(9,))
        settings = AraimSettings.add_v31(ism={"GPS": ConstellationIsm(p_const=1e-8)})
    else:
        los, system = three_constellation_epoch(rng, counts=(9, 8, 8))
        settings = AraimSettings()  # T_EXP 150 s, N_ES 25, consolidation, capped missed detection
    rows = AraimRows.from_elevation(los, system, np.ones(len(system), bool), settings)
    out, table = araim(rows, settings), araim_modes(rows, settings)
    assert out.reason == AraimReason.OK
    for q in range(3):
        root = optimize.brentq(by_hand_risk, 0.0, 500.0, args=(table, q, settings, float(out.p_unmonitored)),
                               xtol=1e-9)
        assert root <= out.pl_enu[q] <= root + settings.tol_pl + 1e-9, (q, root, out.pl_enu[q])


def test_half_interval_search_against_a_dense_grid():
    """The App. D epoch at the document's tolerance: the first grid point (1 mm) where the risk falls to the
    budget lies within TOL_PL below each returned PL; tighter tolerances close in on it."""
    ref = json.loads(REFERENCE.read_text())
    rows, settings = appendix_d_rows(ref), appendix_d_settings(ref)
    table = araim_modes(rows, settings)
    grid = np.arange(0.0, 40.0, 1e-3)
    for tol in (0.05, 0.01, 1e-4):
        out = araim(rows, appendix_d_settings(ref, tol_pl=tol))
        for q in range(3):
            terms = np.stack([table.bias[0, q]] + [table.threshold[k, q] + table.bias[k, q]
                                                  for k in range(1, len(table.p))])
            risk = integrity_risk(grid, terms, np.r_[table.sigma[:, q]], np.r_[2.0, table.p[1:]],
                                  np.r_[1.0, table.alpha[1:]])
            budget = settings.p_hmi_vert if q == 2 else 0.5 * settings.p_hmi_hor
            budget *= 1.0 - float(out.p_unmonitored) / (settings.p_hmi_vert + settings.p_hmi_hor)
            first = grid[np.argmax(risk <= budget)]
            assert first - 1e-3 <= out.pl_enu[q] <= first + tol, (tol, q, first, out.pl_enu[q])


def test_accuracy_sigma_equals_integrity_difference_when_covariances_agree():
    """C_acc = C_int ⇒ σ_ss⁽ᵏ⁾² = σ⁽ᵏ⁾² − σ⁽⁰⁾² for every mode (nested weighted least squares)."""
    rng = np.random.default_rng(11)
    los, system = three_constellation_epoch(rng, counts=(8, 8))
    settings = AraimSettings.add_v31()
    rows = AraimRows.from_elevation(los, system, np.ones(16, bool), settings)
    rows = AraimRows(rows.los_enu, rows.system, rows.used, rows.c_int, rows.c_int, rows.b_nom, rows.b_cont)
    t = araim_modes(rows, settings)
    np.testing.assert_allclose(t.sigma_ss ** 2, t.sigma ** 2 - t.sigma[:1] ** 2, atol=1e-10)


def test_error_model_reproduces_the_published_user_sigmas():
    """σ_user at 5/15/45/90° for the three curves and C_int of the worked geometry's 75° GPS satellite."""
    el = np.radians([5.0, 15.0, 45.0, 90.0])
    np.testing.assert_allclose(sigma_user(el, "wgc_m3"), [1.492, 0.823, 0.525, 0.514], atol=5e-4)
    np.testing.assert_allclose(sigma_user(el, "add_v31"), [1.251, 0.719, 0.453, 0.441], atol=5e-4)
    np.testing.assert_allclose(sigma_user(el, "maast2_dfmc"), [0.754, 0.631, 0.537, 0.526], atol=5e-4)
    c_int, c_acc, _, _ = row_variances(np.radians([75.0]), np.array([GPS]), AraimSettings())
    assert np.sqrt(c_int[0]) == pytest.approx(0.9178, abs=1e-4)
    assert np.sqrt(c_acc[0]) == pytest.approx(0.7280, abs=1e-4)


@pytest.mark.parametrize("model", ["wgc_m3", "add_v31", "maast2_dfmc"])
def test_araim_row_sigmas_are_what_the_dfmc_sensor_tells_and_draws(model):
    """With the ISM equal to the receiver's settings (the defaults: σ_URA 0.75, σ_URE 0.50, b_nom 0.50 m, the
    same troposphere and σ_user curve), every row's √C_int is the σ the DFMC sensor tells the monitors, √C_acc
    the σ it draws the error with, and b_nom its b_nom, for each system and curve."""
    from testbed.sensors.gnss.errors import range_sigmas
    from testbed.sensors.gnss.settings import GnssSettings

    gnss = GnssSettings(constellations=["gps", "galileo", "beidou"], error_model="dfmc", user_error=model)
    settings = AraimSettings(user_error=model, tropo_zenith_m=gnss.sigma_tropo_zenith_m)
    for letter, name in zip("GEC", ("GPS", "Galileo", "BeiDou")):  # the ISM matches the receiver's settings
        sensor, ism = gnss.constellation(letter), settings.ism[name]
        assert (sensor.sigma_ura_m, sensor.sigma_ure_m, sensor.b_nom_m) == (ism.sigma_ura_m, ism.sigma_ure_m,
                                                                              ism.b_nom_m) == (0.75, 0.50, 0.50)
    rng = np.random.default_rng(45)
    letters = np.array(list("GGGGEEEECCCC"))
    el = np.radians(rng.uniform(2.0, 90.0, (50, letters.size)))
    told, drawn, b_nom = range_sigmas(el, letters, gnss)
    codes = np.array([GPS if c == "G" else GAL if c == "E" else BDS for c in letters])
    c_int, c_acc, b_nom_araim, _ = row_variances(el, np.broadcast_to(codes, el.shape), settings)
    np.testing.assert_allclose(np.sqrt(c_int), told, rtol=1e-13)
    np.testing.assert_allclose(np.sqrt(c_acc), drawn, rtol=1e-13)
    np.testing.assert_array_equal(b_nom_araim, b_nom)


def test_araim_user_sigma_is_the_sensor_curve(monkeypatch):
    """The σ_user curves exist once: ARAIM reads the sensor layer's, whatever the curve (a change there moves
    ARAIM's C_int with it)."""
    from testbed.sensors.gnss import errors

    el = np.radians([5.0, 30.0, 80.0])
    monkeypatch.setattr(errors, "user_error_components", lambda e, model="wgc_m3": (np.full(np.shape(e), 3.0),
                                                                                    np.full(np.shape(e), 4.0)))
    for model in errors.USER_ERROR_MODELS:
        np.testing.assert_allclose(sigma_user(el, model), 5.0)


# ---------------------------------------------------------------------------------------------------------
# degenerate epochs
# ---------------------------------------------------------------------------------------------------------


def test_degenerate_epochs_are_unavailable_with_a_reason():
    """One batched call with: a good epoch, a NaN in a used row, a NaN in an unused row, three satellites,
    a single constellation whose P_const cannot be monitored, coincident lines of sight, and a geometry whose
    fault order exceeds the cap. No exception; each gets its reason and ∞ PLs."""
    rng = np.random.default_rng(5)
    los, system = three_constellation_epoch(rng, counts=(8, 7))
    settings = AraimSettings.add_v31()
    n = len(system)
    base = AraimRows.from_elevation(los, system, np.ones(n, bool), settings)
    cases = {}
    cases["ok"] = np.ones(n, bool), base.c_int
    c = base.c_int.copy()
    c[3] = np.nan
    cases["nan used"] = np.ones(n, bool), c
    used = np.ones(n, bool)
    used[3] = False
    cases["nan unused"] = used, c
    used = np.zeros(n, bool)
    used[:3] = True
    cases["three satellites"] = used, base.c_int
    used = system == GPS
    cases["GPS alone, P_const 1e-4"] = used, base.c_int
    used = np.ones(n, bool)
    used[1:8] = False
    used[9:] = False
    cases["one GPS + one Galileo"] = used, base.c_int
    rows = AraimRows(np.broadcast_to(los, (len(cases), n, 3)), system, np.stack([u for u, _ in cases.values()]), np.stack([c for _, c in cases.values()]),
                     np.broadcast_to(base.c_acc, (len(cases), n)), np.broadcast_to(base.b_nom, (len(cases), n)),
                     np.broadcast_to(base.b_cont, (len(cases), n)))
    out = araim(rows, settings)
    expected = [AraimReason.OK, AraimReason.NAN_INPUT, AraimReason.OK, AraimReason.NO_POSITION,
                AraimReason.UNMONITORED, AraimReason.NO_POSITION]
    assert out.reason.tolist() == expected
    bad = out.reason != AraimReason.OK
    assert np.all(np.isinf(out.vpl[bad])) and np.all(np.isinf(out.hpl[bad])) and not out.available[bad].any()
    assert np.all(np.isfinite(out.vpl[~bad]))

    # coincident lines of sight: the all-in-view normal matrix is singular
    flat = np.broadcast_to(los[0], los.shape).copy()
    out = araim(AraimRows.from_elevation(flat, system, np.ones(n, bool), settings), settings)
    assert out.reason == AraimReason.SINGULAR and np.isinf(out.vpl)

    # three constellations, 30 satellites: the ADD rule asks for pairs, the cap allows singles only
    los3, sys3 = three_constellation_epoch(rng, counts=(10, 10, 10))
    capped = AraimSettings.add_v31(max_fault_order=1)
    out = araim(AraimRows.from_elevation(los3, sys3, np.ones(30, bool), capped), capped)
    assert out.reason == AraimReason.FAULT_ORDER and out.fault_order == 1


def test_a_constellation_of_one_satellite_is_protected_without_it():
    """A BeiDou satellite alone adds a row and a clock: it carries no position information, so the PLs equal
    those of the geometry without it, and removing it (its clock left without a row) raises nothing."""
    rng = np.random.default_rng(9)
    los, system = three_constellation_epoch(rng, counts=(8, 8, 1))
    settings = AraimSettings.add_v31()
    with_it = araim(AraimRows.from_elevation(los, system, np.ones(17, bool), settings), settings)
    without = araim(AraimRows.from_elevation(los[:16], system[:16], np.ones(16, bool), settings), settings)
    assert with_it.reason == without.reason == AraimReason.OK
    # its modes have zero separation and only add to N_modes (the thresholds' K_fa), so the PLs move little
    t = araim_modes(AraimRows.from_elevation(los, system, np.ones(17, bool), settings), settings)
    alone = [k for k, r in enumerate(t.removed) if r == (16,)]
    assert alone and np.allclose(t.sigma_ss[alone], 0.0, atol=1e-9)
    np.testing.assert_allclose(with_it.sigma_acc_enu, without.sigma_acc_enu, atol=1e-12)


def test_bad_inputs_are_refused_before_any_work():
    settings = AraimSettings.add_v31()
    los = los_from_az_el(np.arange(6) * 60.0, np.full(6, 40.0))
    with pytest.raises(ValueError, match="system code 7 has no ISM"):
        araim(AraimRows(los, np.full(6, 7), np.ones(6, bool), *np.ones((4, 6))), settings)
    with pytest.raises(ValueError, match=r"c_int expected \(6,\)"):
        araim(AraimRows(los, np.zeros(6, int), np.ones(6, bool), np.ones(5), *np.ones((3, 6))), settings)
    with pytest.raises(ValueError, match="los_enu expected"):
        araim(AraimRows(los[:, :2], np.zeros(6, int), np.ones(6, bool), *np.ones((4, 6))), settings)
    with pytest.raises(ValueError, match="unknown system"):
        AraimSettings(ism={"Beidou": ConstellationIsm()})
    with pytest.raises(ValueError, match="sigma_ure_m"):
        ConstellationIsm(sigma_ura_m=0.5, sigma_ure_m=0.75)


def test_a_mode_below_its_threshold_counts_in_full():
    """Q̃: a fault mode whose PL is at or below its threshold + bias counts p·min(1, α) — its error may sit
    anywhere up to the threshold undetected — not p·Q(negative) (< p). A single-mode risk equation by hand."""
    offset, sigma = np.array([[0.0, 10.0]]), np.array([[1.0, 2.0]])
    weight, cap = np.array([[2.0, 1e-4]]), np.array([[1.0, 1.0]])
    pl = np.array([9.0])
    expected = 2.0 * stats.norm.sf(9.0) + 1e-4
    assert integrity_risk(pl, offset, sigma, weight, cap)[0] == pytest.approx(expected, rel=1e-12)
    cap = np.array([[1.0, 0.4]])
    expected = 2.0 * stats.norm.sf(9.0) + 1e-4 * 0.4
    assert integrity_risk(pl, offset, sigma, weight, cap)[0] == pytest.approx(expected, rel=1e-12)
    pl = np.array([12.0])
    expected = 2.0 * stats.norm.sf(12.0) + 1e-4 * min(stats.norm.sf(1.0), 0.4)
    assert integrity_risk(pl, offset, sigma, weight, cap)[0] == pytest.approx(expected, rel=1e-12)


def test_protection_level_at_a_large_allocation_is_the_root():
    """A budget so large that a term of small prior gets a share target/(K·w) above 1 (P_HMI 10⁻² against priors
    of 10⁻⁵: the loosened operating points of a brute-force check): the search's upper end was Q⁻¹ of that
    share, NaN, and the PL with it. It is the root of eq. 16, found by scipy's brentq."""
    from testbed.integrity.araim.protection import solve_protection_level

    offset = np.array([0.0, 3.0, 4.0, 2.5])
    sigma = np.array([1.0, 1.4, 1.6, 1.2])
    weight = np.array([2.0, 1e-5, 1e-5, 1e-6])
    cap = np.ones(4)
    target = np.array(1e-2)
    pl, _ = solve_protection_level(offset, sigma, weight, cap, target, 1e-6)
    root = optimize.brentq(lambda x: integrity_risk(np.array(x), offset, sigma, weight, cap) - 1e-2, 0.0, 20.0)
    assert np.isfinite(pl) and pl == pytest.approx(root, abs=2e-6)

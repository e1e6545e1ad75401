"""The ``araim`` monitor (testbed.integrity.araim.monitor) in the monitor contract.

Its fix and protection levels against the library called on rows built here from the true geometry
(noise-free ranges: the fix is the truth); two constellations (a second one made by rotating the DO-229
GPS orbits, with its own clock offset); degenerate epochs; blocks = one call; same seed, same bytes;
exclusion of a stepped satellite; the fault-free false-alert rate against its allocation.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from test_integrity_core_helpers import make_gnss, sat_pos_ecef
from testbed.frames import LocalFrame
from testbed import monitors as registry
from testbed.integrity.araim import AraimReason, AraimRows, AraimSettings, ConstellationIsm, araim
from testbed.integrity.araim.error_model import row_variances
from testbed.integrity.araim.monitor import REASONS, araim_gnss
from testbed.integrity.araim.settings import AraimMonitorSettings
from testbed.integrity.monitor import Monitor, MonitorContext, Observations
from testbed.integrity.settings import IntegritySettings
from testbed.records import GnssEpochs, concat_epochs, take_epochs

FRAME = LocalFrame(29.30, 94.34, 2950.0)
T_WEEK0 = 345_600.0
#: the fix of noise-free ranges is the truth to the solve's tolerance (1 mm steps)
FIX_M = 2e-3
GAL_CLOCK_M = -37.0  # an inter-system offset the second clock absorbs
GPS_CLOCK_M = 1234.5


@dataclasses.dataclass(frozen=True)
class MixedEpochs(GnssEpochs):
    """GnssEpochs with the RINEX 3 system letter of each slot (the multi-constellation layer's field)."""

    system: np.ndarray = dataclasses.field(default=None)


def receiver_track(T: int) -> np.ndarray:
    """(T, 3) ENU m: an aircraft descending along a 3° path towards the frame origin at 70 m/s."""
    s = np.arange(T, dtype=float)
    return np.stack([-8000.0 + 70.0 * s * 0.8, -6000.0 + 70.0 * s * 0.6, 450.0 - 3.7 * s], -1)


def two_constellations(T: int, rng=None, batch=(), bias=None, rotate_deg: float = 40.0) -> tuple[MixedEpochs, np.ndarray]:
    """GPS (DO-229 almanac) plus a second constellation: the same orbits rotated about the pole by
    ``rotate_deg`` and scaled to Galileo's radius, with its own clock. Returns the epochs and the true track."""
    rx = receiver_track(T)
    t = T_WEEK0 + np.arange(T, dtype=float)
    gps, _, _ = make_gnss(FRAME, rx, t, rng, batch=batch, clock_m=GPS_CLOCK_M)
    a = np.radians(rotate_deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    gal_pos = sat_pos_ecef(t) @ Rz.T * (29_600e3 / 26_559.7e3)
    rx_ecef = FRAME.enu_to_ecef(rx)
    up = FRAME.vec_ecef_to_enu(gal_pos - rx_ecef[:, None, :])
    el = np.arcsin(up[..., 2] / np.linalg.norm(up, axis=-1))
    shape = batch + el.shape
    vis = np.broadcast_to(el > np.radians(5.0), shape)
    c_int, _, _, _ = row_variances(np.maximum(el, 0.01), np.ones(el.shape, int), AraimSettings())
    noise = 0.0 if rng is None else rng.standard_normal(shape) * np.sqrt(c_int)
    pr = np.linalg.norm(gal_pos - rx_ecef[:, None, :], axis=-1) + GAL_CLOCK_M + noise
    pr = np.where(vis, pr, np.nan)
    S1 = gps.prn.size
    sat = np.concatenate([np.broadcast_to(gps.sat_pos_ecef, shape[:-1] + (S1, 3)),
                          np.broadcast_to(gal_pos, shape + (3,))], -2)
    pr_all = np.concatenate([gps.pseudorange, pr], -1) + (0.0 if bias is None else bias)
    vis_all = np.concatenate([gps.visible, vis], -1)
    mixed = MixedEpochs(t=gps.t, t_gps=gps.t_gps, prn=np.concatenate([gps.prn, gps.prn]), sat_pos_ecef=sat,
                        sat_vel_ecef=np.zeros_like(sat), pseudorange=pr_all, range_rate=np.zeros_like(pr_all),
                        sigma=np.ones_like(pr_all), visible=vis_all, reason=np.zeros(vis_all.shape, np.int8),
                        antenna=gps.antenna, system=np.array(["G"] * S1 + ["E"] * S1))
    return mixed, rx


def rows_from_truth(gnss, rx: np.ndarray, settings: AraimSettings) -> AraimRows:
    """The rows the library monitors, built from the true receiver position (no solve involved)."""
    codes = np.array([{"G": 0, "E": 1}[c] for c in getattr(gnss, "system", ["G"] * gnss.prn.size)])
    los_ecef = np.asarray(gnss.sat_pos_ecef) - FRAME.enu_to_ecef(rx)[:, None, :]
    los = FRAME.vec_ecef_to_enu(los_ecef / np.linalg.norm(los_ecef, axis=-1, keepdims=True))
    return AraimRows.from_elevation(los, codes, np.asarray(gnss.visible), settings)


def test_the_monitor_is_registered_and_follows_the_protocol():
    ctx = MonitorContext(frame=FRAME, integrity=IntegritySettings())
    mon = registry.build_monitor("araim", ctx)
    assert isinstance(mon, Monitor) and "araim" in registry.monitor_names()
    assert mon.inputs == registry.monitor_inputs("araim") == frozenset({"gnss"})


def test_options_are_validated_with_the_key_named():
    ctx = MonitorContext(frame=FRAME, integrity=IntegritySettings())
    with pytest.raises(Exception, match="p_hmi_vert"):
        registry.build_monitor("araim", dataclasses.replace(ctx, options={"araim": {"p_hmi_vert": 2.0}}))
    with pytest.raises(Exception, match="ism_preset"):
        registry.build_monitor("araim", dataclasses.replace(ctx, options={"araim": {"ism_preset": "nope"}}))
    with pytest.raises(Exception, match="service_levels"):
        registry.build_monitor("araim", dataclasses.replace(ctx, options={"araim": {"service_levels": ["APV-I"]}}))
    # a system's ISM entry replaces the preset's for that system only
    mon = registry.build_monitor("araim", dataclasses.replace(
        ctx, options={"araim": {"ism": {"GPS": {"p_const": 1e-8}}}}))
    assert mon.settings.ism["GPS"].p_const == 1e-8 and mon.settings.ism["Galileo"].p_const == 1e-4


def test_noise_free_gps_fix_is_the_truth_and_pls_are_the_librarys():
    """GPS only with P_const = 1e-8 (monitorable): the fix is the true antenna and its clock, the PLs,
    EMT and σ_acc those of the library on rows built from the true geometry."""
    gnss, _, _ = make_gnss(FRAME, receiver_track(30), T_WEEK0 + np.arange(30.0), None)
    rx = receiver_track(30)
    ms = AraimMonitorSettings(ism={"GPS": {"p_const": 1e-8}})
    out = araim_gnss(gnss, FRAME, ms, IntegritySettings())
    assert (out.reason == 0).all()
    np.testing.assert_allclose(out.pos_enu, rx, atol=FIX_M)
    np.testing.assert_allclose(out.clock, GPS_CLOCK_M, atol=FIX_M)
    ref = araim(rows_from_truth(gnss, rx, ms.allocation(IntegritySettings().service_levels)),
                ms.allocation(IntegritySettings().service_levels))
    np.testing.assert_allclose(out.vpl, ref.vpl, atol=1e-3)
    np.testing.assert_allclose(out.hpl, ref.hpl, atol=1e-3)
    np.testing.assert_allclose(out.diagnostics.emt, ref.emt, atol=1e-6)
    np.testing.assert_allclose(out.diagnostics.sigma_acc_v, ref.sigma_acc_v, atol=1e-6)
    np.testing.assert_array_equal(out.available, ref.available)
    assert not out.alert.any() and np.nanmax(out.test_stat) < 1e-3  # noise-free: no separation
    np.testing.assert_array_equal(out.n_used, gnss.visible.sum(-1))


def test_gps_only_at_the_default_ism_is_unavailable_with_its_reason():
    """One constellation with P_const = 1e-4 cannot be monitored (no subset without it): ARAIM says so."""
    gnss, _, _ = make_gnss(FRAME, receiver_track(5), T_WEEK0 + np.arange(5.0), None)
    out = araim_gnss(gnss, FRAME)
    assert (out.reason == AraimReason.UNMONITORED).all() and np.isnan(out.vpl).all() and not out.available.any()
    np.testing.assert_allclose(out.pos_enu, receiver_track(5), atol=FIX_M)  # a fix, without protection
    assert "too few satellites" in out.reasons[AraimReason.UNMONITORED]


def test_two_constellations_get_two_clocks_and_the_librarys_protection():
    gnss, rx = two_constellations(20)
    out = araim_gnss(gnss, FRAME)
    assert (out.reason == 0).all()
    np.testing.assert_allclose(out.pos_enu, rx, atol=FIX_M)
    np.testing.assert_allclose(out.diagnostics.clock[:, :2], np.tile([GPS_CLOCK_M, GAL_CLOCK_M], (20, 1)),
                               atol=FIX_M)
    assert np.isnan(out.diagnostics.clock[:, 2:]).all()
    settings = AraimMonitorSettings().allocation(IntegritySettings().service_levels)
    ref = araim(rows_from_truth(gnss, rx, settings), settings)
    np.testing.assert_allclose(out.vpl, ref.vpl, atol=1e-3)
    np.testing.assert_allclose(out.hpl, ref.hpl, atol=1e-3)
    np.testing.assert_array_equal(out.diagnostics.n_modes, ref.n_modes)
    assert out.available[:, list(out.service_levels).index("LPV-200")].all()


def test_own_outputs_for_the_summary_table_the_campaign_and_the_recording():
    gnss, _ = two_constellations(12)
    out = araim_gnss(gnss, FRAME)
    d = out.diagnostics
    rows = d.summary_rows()
    emt = d.emt[np.isfinite(d.emt)]
    assert emt.size == 12 and rows["EMT max / p95"] == f"{emt.max():.2f} / {np.percentile(emt, 95):.2f} m"
    assert rows["fault modes (min-max)"] == f"{d.n_modes.min()}-{d.n_modes.max()}"
    batched = araim_gnss(two_constellations(12, batch=(3,))[0], FRAME).diagnostics.trial_columns(None)
    np.testing.assert_allclose(batched["max_emt"], emt.max())
    curves = d.plot_series()
    np.testing.assert_array_equal(curves["vertical/emt"][0], d.emt)
    assert (curves["vertical/sigma_acc_limit"][0] == 1.87).all()


def test_degenerate_epochs_get_reasons_never_an_exception():
    gnss, _ = two_constellations(4)
    pr, vis = gnss.pseudorange.copy(), gnss.visible.copy()
    S1 = gnss.prn.size // 2
    pr[0, np.flatnonzero(vis[0])[0]] = np.nan  # a NaN range on a visible satellite
    gal = np.flatnonzero(vis[1, S1:]) + S1
    vis[1, gal[1:]] = False  # a constellation of one satellite
    pr[1] = np.where(vis[1], pr[1], np.nan)
    vis[2, :] = False
    vis[2, np.flatnonzero(gnss.visible[2])[:4]] = True  # four satellites: fewer rows than states + 1
    vis[3, :] = False  # nothing at all
    out = araim_gnss(dataclasses.replace(gnss, pseudorange=pr, visible=vis), FRAME)
    got = [REASONS[r] for r in out.reason]
    # epoch 1: a GPS fault (P_const 1e-4) leaves one Galileo satellite: unmonitorable; epoch 2: four rows, four
    # states: no subset is observable
    unmonitored = AraimReason.UNMONITORED
    assert list(out.reason) == [AraimReason.NAN_INPUT, unmonitored, unmonitored, AraimReason.NO_POSITION], got
    bad = out.reason != 0
    assert np.isnan(out.vpl[bad]).all() and not out.available[bad].any() and not out.alert[bad].any()
    assert np.isnan(out.pos_enu[[0, 3]]).all()
    # with GPS's constellation fault below P_THRES the lone Galileo satellite's epoch is protected (its
    # constellation's fault removes it with its clock)
    gps_solid = AraimMonitorSettings(ism={"GPS": {"p_const": 1e-8}})
    again = araim_gnss(dataclasses.replace(gnss, pseudorange=pr, visible=vis), FRAME, gps_solid)
    assert again.reason[1] == 0 and again.n_used[1] == vis[1].sum() and np.isfinite(again.vpl[1])


def test_blocks_equal_one_call_and_the_same_seed_gives_the_same_bytes():
    gnss, _ = two_constellations(40, rng=np.random.default_rng(7), batch=(2,))
    ctx = MonitorContext(frame=FRAME, integrity=IntegritySettings(), threads=1)
    mon = registry.build_monitor("araim", ctx)
    whole, _ = mon.step(Observations(gnss), mon.initial_state())
    parts, state, k = [], mon.initial_state(), 0
    for n in (1, 13, 26):
        part, state = mon.step(Observations(take_epochs(gnss, slice(k, k + n))), state)
        parts.append(part)
        k += n
    joined = concat_epochs(parts)
    for f in ("pos_enu", "hpl", "vpl", "test_stat", "available", "reason"):
        np.testing.assert_array_equal(getattr(joined, f), getattr(whole, f), err_msg=f)
    np.testing.assert_array_equal(joined.diagnostics.emt, whole.diagnostics.emt)
    again, _ = registry.build_monitor("araim", dataclasses.replace(ctx, threads=2)).step(
        Observations(two_constellations(40, rng=np.random.default_rng(7), batch=(2,))[0]), None)
    for f in ("pos_enu", "hpl", "vpl", "test_stat"):
        assert getattr(again, f).tobytes() == getattr(whole, f).tobytes(), f


def test_a_stepped_satellite_alerts_and_exclusion_removes_it():
    """A 40 m step on one GPS satellite: the test fails at every epoch; with exclusion on, the faulty
    satellite is the one excluded, the alert is cleared and the reduced PLs (budget shared among the
    candidates) are larger than the reduced geometry's at the whole budget."""
    T = 10
    gnss, rx = two_constellations(T, rng=np.random.default_rng(3))
    slot = int(np.flatnonzero(gnss.visible.all(0))[2])
    bias = np.zeros(gnss.pseudorange.shape)
    bias[:, slot] = 40.0
    faulty = dataclasses.replace(gnss, pseudorange=gnss.pseudorange + bias)
    plain = araim_gnss(faulty, FRAME)
    assert (plain.reason == 0).all() and plain.alert.all() and plain.fde is None
    fde = araim_gnss(faulty, FRAME, AraimMonitorSettings(fde=True))
    assert (fde.excluded == slot).all() and not fde.alert.any() and fde.fde.detected.all()
    np.testing.assert_allclose(fde.pos_enu, rx, atol=5.0)
    assert (np.linalg.norm(fde.pos_enu - rx, axis=-1) < np.linalg.norm(plain.pos_enu - rx, axis=-1)).all()
    visible = faulty.visible.copy()
    visible[:, slot] = False
    reduced = araim_gnss(dataclasses.replace(faulty, visible=visible), FRAME)
    assert (fde.vpl > reduced.vpl).all() and (fde.hpl > reduced.hpl).all()
    np.testing.assert_allclose(fde.pos_enu, reduced.pos_enu, atol=1e-9)
    assert np.isfinite(fde.diagnostics.emt).all()
    # fault-free epochs pass through exclusion untouched
    clean = araim_gnss(gnss, FRAME, AraimMonitorSettings(fde=True))
    base = araim_gnss(gnss, FRAME)
    np.testing.assert_array_equal(clean.vpl, base.vpl)
    assert (clean.excluded == -1).all()


def test_a_bias_common_to_a_constellation_is_its_clock_and_an_uneven_one_alerts():
    """A constellation-wide fault that adds the same range error to every satellite of one system (the
    ``constellation_bias`` fault) is that system's clock to ARAIM's one-clock-per-system solutions: the fix, the
    separations, the PLs and the test do not move, only the clock does (so P(HMI | such a fault) is the
    fault-free one). The same 30 m spread unevenly over the constellation's satellites is caught."""
    T = 8
    gnss, rx = two_constellations(T, rng=np.random.default_rng(8))
    gal = gnss.system == "E"
    common = np.where(gal, 30.0, 0.0)
    base, hit = araim_gnss(gnss, FRAME), araim_gnss(dataclasses.replace(gnss, pseudorange=gnss.pseudorange + common),
                                                    FRAME)
    assert (base.reason == 0).all() and not base.alert.any() and not hit.alert.any()
    np.testing.assert_allclose(hit.pos_enu, base.pos_enu, atol=1e-6)
    np.testing.assert_allclose(hit.test_stat, base.test_stat, atol=1e-6)
    np.testing.assert_allclose(hit.vpl, base.vpl, atol=1e-9)
    np.testing.assert_allclose(hit.diagnostics.clock[:, 1] - base.diagnostics.clock[:, 1], 30.0, atol=1e-6)
    uneven = np.where(gal, 30.0 * np.random.default_rng(9).uniform(-1.0, 1.0, gal.size), 0.0)
    bad = araim_gnss(dataclasses.replace(gnss, pseudorange=gnss.pseudorange + uneven), FRAME)
    assert bad.alert.all() and (bad.test_stat > 1.0).all()


def test_fault_free_false_alerts_inside_the_binomial_interval_of_the_allocation():
    """At a loosened allocation (P_FA,V = 0.02, P_FA,H = 0.01) and a fixed two-constellation sky, residuals
    drawn from the accuracy model N(0, C_acc) the thresholds are set for: every epoch's alert equals the
    brute-force test (every subset solved here by least squares), and the alert rate sits inside
    [largest single test's share, the allocation] at 99 % (Clopper–Pearson): the union of the tests is
    at most their sum (eq. 14's split) and at least the likeliest one."""
    gnss, rx = two_constellations(1)
    settings = AraimSettings.add_v31(p_fa_vert=0.02, p_fa_hor=0.01,
                                     ism={"GPS": ConstellationIsm(p_const=1e-9), "Galileo": ConstellationIsm(p_const=1e-9)})
    rows = rows_from_truth(gnss, rx, settings)
    rows = dataclasses.replace(rows, system=np.broadcast_to(rows.system, rows.used.shape))
    used = rows.used[0]
    n_epochs = 40_000
    rng = np.random.default_rng(11)
    dy = np.where(used, rng.standard_normal((n_epochs, used.size)) * np.sqrt(rows.c_acc[0]), 0.0)
    batch = AraimRows(*(np.broadcast_to(getattr(rows, f)[0], (n_epochs,) + getattr(rows, f)[0].shape)
                        for f in ("los_enu", "system", "used", "c_int", "c_acc", "b_nom", "b_cont")), residual=dy)
    ep = araim(batch, settings)
    assert (ep.reason == 0).all()
    # brute force: the single-satellite subsets (the modes monitored here) solved from scratch
    idx = np.flatnonzero(used)
    G = np.concatenate([-rows.los_enu[0][idx], np.eye(2)[rows.system[0][idx]]], -1)
    W = np.diag(1.0 / rows.c_int[0][idx])
    S0 = np.linalg.solve(G.T @ W @ G, G.T @ W)[:3]
    n_modes = int(ep.n_modes[0])
    assert n_modes == idx.size
    k_h = stats.norm.isf(0.01 / (4 * n_modes))
    k_v = stats.norm.isf(0.02 / (2 * n_modes))
    alert = np.zeros(n_epochs, bool)
    for j in range(idx.size):
        keep = np.arange(idx.size) != j
        Sk = np.zeros_like(S0)
        Sk[:, keep] = np.linalg.solve(G[keep].T @ W[np.ix_(keep, keep)] @ G[keep], G[keep].T @ W[np.ix_(keep, keep)])[:3]
        dS = Sk - S0
        sigma_ss = np.sqrt((dS**2) @ rows.c_acc[0][idx])
        T = np.array([k_h, k_h, k_v]) * sigma_ss
        alert |= (np.abs(dy[:, idx] @ dS.T) > T).any(-1)
    np.testing.assert_array_equal(ep.alert, alert)
    k = int(alert.sum())
    lo, hi = stats.binomtest(k, n_epochs).proportion_ci(0.99)
    allocated = 0.02 + 0.01
    largest_single = 0.02 / n_modes
    print(f"false-alert rate {k / n_epochs:.5f}, 99 % interval [{lo:.5f}, {hi:.5f}], allocated {allocated}")
    assert lo <= allocated and hi >= largest_single, (k / n_epochs, lo, hi, allocated)
    assert k / n_epochs > 0.3 * allocated  # the split is not wildly conservative here (measured ~0.8)


@pytest.mark.slow
def test_araim_runs_in_the_loop_a_campaign_and_rinex_replay(tmp_path, capsys):
    """The monitor through every path that steps monitors: a flight (its summary rows), a campaign (its own
    trial columns, and its own epoch columns in epochs.parquet, whose EMT gives the trials' maximum) and the
    RINEX replay of the same flight (the same fix as GPS RAIM's to a centimetre)."""
    import pyarrow.parquet as pq

    from testbed.api import export_rinex, load_approach, print_run_summary, run_approach
    from testbed.campaign.runner import run_campaign
    from testbed.replay import monitor_rinex

    ap = load_approach("zunz-rwy05-final")
    ap = dataclasses.replace(ap, config=ap.config.model_copy(update={"monitors": ["gps_raim", "araim"]}))
    rrd = tmp_path / "a.rrd"
    run = run_approach(ap, seed=1, rrd_path=rrd)
    out, ref = run.outputs["araim"], run.outputs["gps_raim"]
    fixed = np.isfinite(out.pos_enu[:, 0]) & (ref.reason == 0)
    assert fixed.mean() > 0.9
    np.testing.assert_allclose(out.pos_enu[fixed], ref.pos_enu[fixed], atol=0.05)
    print_run_summary(run)
    text = capsys.readouterr().out
    assert "EMT max / p95" in text and "fault modes (min-max)" in text
    from testbed.viz.readback import entity_paths, scalar_series

    t, limit = scalar_series(rrd, "/integrity/araim/vertical/emt_limit")  # the recording tab's EMT panel
    np.testing.assert_allclose(t, out.t, atol=1e-9)  # the recording keeps times in nanoseconds
    assert (limit == 15.0).all()
    assert "/integrity/araim/vertical/sigma_acc_v" in entity_paths(rrd)

    spec = tmp_path / "a.toml"
    spec.write_text('name = "a"\napproaches = ["zunz-rwy05-final"]\nmonitors = ["araim"]\ntrials = 10\n'
                    'block_trials = 10\nchunk_trials = 10\nduration_s = 10.0\nper_epoch_trials = 3\n')
    run_campaign(spec, tmp_path / "camp", progress=False)
    trials = pq.read_table(tmp_path / "camp" / "trials.parquet").to_pydict()
    assert set(trials["monitor"]) == {"araim"} and len(trials["trial"]) == 10
    assert {"max_emt", "max_sigma_acc_v", "mean_fault_modes"} <= set(trials)
    epochs = pq.read_table(tmp_path / "camp" / "epochs.parquet").to_pandas()  # the monitor's own columns too
    assert {"emt_m", "sigma_acc_v_m", "fault_modes", "p_unmonitored", "clock_gps_m"} <= set(epochs)
    sizes = epochs.groupby("trial").size()
    assert len(sizes) == 3 and sizes.nunique() == 1 and np.isfinite(epochs["clock_gps_m"]).mean() > 0.9
    per_trial = epochs.groupby("trial")["emt_m"].max()  # NaN here: GPS alone is too few for its fault modes
    want = dict(zip(trials["trial"], trials["max_emt"]))
    np.testing.assert_allclose(per_trial.values, [want[t] for t in per_trial.index], rtol=1e-12)

    obs, nav = export_rinex(ap, tmp_path / "rnx", seed=1)
    replay = monitor_rinex(obs, nav, monitors=("gps_raim", "araim"), out_dir=tmp_path / "replay")
    got, want = replay.outputs["araim"], replay.outputs["gps_raim"]
    ok = np.isfinite(got.pos_enu[:, 0]) & (want.reason == 0)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(got.pos_enu[ok], want.pos_enu[ok], atol=0.05)


def test_araim_on_the_dfmc_approach_is_lpv200_available_and_bounds_the_error():
    """GPS + Galileo + BeiDou, iono-free, in the valley (zunz-rwy05-dfmc, seed 0): ARAIM protects every epoch at
    LPV-200 (HPL 11.0 m, VPL 14.9 m, EMT 5.5 m, σ_acc,v 0.99 m measured), with no alert and no misleading epoch,
    where with GPS alone (zunz-rwy05-final) it has too few satellites for its fault modes."""
    from testbed.api import run_approach

    s = run_approach("zunz-rwy05-dfmc", seed=0, rrd_path=None, monitors=["araim"]).summaries["araim"]
    assert s.availability["LPV-200"] == 1.0 and s.alert_epochs == 0 and s.mi_epochs == 0
    assert s.vpl_max < 35.0 and s.hpl_max < 40.0

"""The DPE monitor (the DPE paper) against closed forms, brute force and the Cramér-Rao bound (docs/design/dpe.md §10)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from dpe_scene import CLOCK_M, FRAME, TRUTH_ENU, context, scene
from testbed.correlation import CHIP_M, amplitude_sq, correlation, crb_delay_sigma, peak
from testbed.integrity.dpe.manifold import EpochManifold, box_nodes, manifold_numpy
from testbed.integrity.dpe.monitor import NAN_INPUT, NO_INIT, NOT_CALIBRATED, FEW, DpeSettings, DpeMonitor
from testbed.integrity.kernels.dpe import manifold_box, manifold_box_threads
from testbed.records import take_epochs
from testbed.sensors.gnss.correlators import synthesize_correlators
from testbed.sensors.gnss.settings import CorrelatorSettings, GnssSettings
from testbed.sim.evaluate import misleading, summarise_monitor

QUIET_SIS = dict(sigma_ura_m=0.0, sigma_tropo_zenith_m=0.0)


#: the scene's satellites (dpe_scene: docs/design/dpe.md §4.3's reference epoch, azimuths 17° + 45° k)
SCENE_EL = np.radians([75.0, 55.0, 40.0, 35.0, 25.0, 20.0, 15.0, 10.0])
SCENE_G = np.column_stack([-np.cos(SCENE_EL) * np.sin(np.radians(np.arange(8) * 45.0 + 17.0)),
                           -np.cos(SCENE_EL) * np.cos(np.radians(np.arange(8) * 45.0 + 17.0)),
                           -np.sin(SCENE_EL), np.ones(8)])


def monitor(**options) -> DpeMonitor:
    return DpeMonitor("dpe", context(), DpeSettings(**({"k_factor": 5.33} | options)))


def gnss(cn0_offset_db: float = 0.0, **kw) -> GnssSettings:
    corr = {"cn0_offset_db": cn0_offset_db} | {k: kw.pop(k) for k in list(kw) if k in CorrelatorSettings.model_fields}
    return GnssSettings(correlators=CorrelatorSettings(**corr), **kw)


def _noise_free_manifold(offset, rng):
    """An EpochManifold of 8 satellites' noise-free power, its centre ``offset`` from the truth.

    Every correlogram peaks at delay 0 (its reference is the true delay); the centre's delays are
    g_k·offset, so the truth is the candidate ξ = −offset.
    """
    S = 8
    el = np.radians(np.linspace(10, 80, S))
    az = rng.uniform(0, 2 * np.pi, S)
    g = np.column_stack([-np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az), -np.sin(el), np.ones(S)])
    delay = np.arange(-1000.0, 1000.0 + 1e-9, 2.0)
    table = 50 * 300.0 * np.broadcast_to(correlation(delay, 1.0) ** 2 * peak(1.0), (S, delay.size)) + 50
    return EpochManifold(g @ offset, g, np.ascontiguousarray(table), np.full(S, 50.0), -1000.0, 2.0)


def test_compiled_manifold_equals_the_numpy_reference():
    rng = np.random.default_rng(4)
    mf = _noise_free_manifold(np.array([8.0, -5.0, 12.0, 20.0]), rng)
    mf = dataclasses.replace(mf, table=mf.table + rng.normal(0, 30, mf.table.shape))
    for cubic in (True, False):
        for spacing, n in ((30.0, 9), (6.0, 9), (0.55, 5)):
            c, H = mf.index_units(np.zeros(4), np.eye(4))
            out = np.empty(n ** 4)
            manifold_box(c, H, mf.poly, mf.floor, spacing, n, cubic, out)
            ref = manifold_numpy(c, H, mf.table, mf.floor, box_nodes(spacing, n), cubic)
            assert np.max(np.abs(out - ref)) <= 1e-12 * np.max(np.abs(ref))
            threaded = np.empty(n ** 4)
            manifold_box_threads(c, H, mf.poly, mf.floor, spacing, n, cubic, threaded)
            np.testing.assert_array_equal(threaded, out)


def test_without_noise_the_manifold_peaks_at_the_truth_node():
    offset = np.array([-6.0, 12.0, 0.0, -18.0])  # a node of the 6 m box
    mf = _noise_free_manifold(offset, np.random.default_rng(1))
    c, H = mf.index_units(np.zeros(4), np.eye(4))
    out = np.empty(9 ** 4)
    manifold_box(c, H, mf.poly, mf.floor, 6.0, 9, True, out)
    np.testing.assert_allclose(box_nodes(6.0, 9)[np.argmax(out)], -offset)


def test_the_solution_attains_the_cramer_rao_bound():
    """T6: 200 epochs at 50 dB-Hz, N_b = 5, no SIS: var(Û)/J per axis inside the 95 % χ² band,
    the posterior sd equals √J_UU within 5 %, and z = e_U/sd_U is N(0, 1)."""
    gs = gnss(5.0, n_noncoherent=5, synthesis="exact", cn0_by_elevation={0.0: 45.0, 90.0: 45.0}, **QUIET_SIS)
    obs, _, truth = scene(200, gnss=gs, seed=3)
    out, _ = monitor().step(obs, monitor().initial_state())
    assert np.all(out.reason == 0)
    err = np.column_stack([out.pos_enu - truth, out.clock - CLOCK_M])
    d = out.diagnostics
    # the CRB from the true C/N0 (the monitor used its estimates, within 0.3 dB)
    a2 = amplitude_sq(50.0, 0.02)
    G = SCENE_G
    J = np.linalg.inv(G.T @ G) * float(crb_delay_sigma(a2, 5, 1.0)) ** 2
    ratio = err.var(axis=0, ddof=0) / np.diag(J)
    lo, hi = stats.chi2.ppf([0.025, 0.975], 200) / 200
    assert np.all((ratio > lo) & (ratio < hi)), ratio
    assert abs(np.mean(d.posterior_sd_u) / np.sqrt(J[2, 2]) - 1) < 0.05
    z = err[:, 2] / d.posterior_sd_u
    assert stats.kstest(z, "norm").pvalue > 0.01


def _linear_shift(k: int, bias: float) -> np.ndarray:
    from testbed.sensors.gnss.correlators import cn0_at

    G = SCENE_G
    w = 1.0 / crb_delay_sigma(amplitude_sq(cn0_at(SCENE_EL, CorrelatorSettings()) + 15.0, 0.02), 50, 1.0) ** 2
    A = np.linalg.solve(G.T @ (G * w[:, None]), (G * w[:, None]).T)
    return A[:, k] * bias


def test_a_code_phase_bias_moves_the_solution_as_weighted_least_squares_predicts():
    """T8: 10 m on the 35° satellite at high C/N0 shifts the solution by A_w[:, k]·10 (CRB weights)."""
    gs = gnss(15.0, **QUIET_SIS)
    nominal, _, truth = scene(2, gnss=gs, seed=5)
    biased, _, _ = scene(2, gnss=gs, seed=5, bias_m={3: 10.0})
    mon = monitor()
    a, _ = mon.step(nominal, mon.initial_state())
    b, _ = mon.step(biased, mon.initial_state())
    shift = np.column_stack([b.pos_enu - a.pos_enu, b.clock - a.clock])
    want = _linear_shift(3, 10.0)
    assert np.all(np.abs(shift - want) <= 0.05 * np.abs(want).max() + 0.02), (shift, want)


def test_a_satellite_biased_beyond_the_correlation_drops_out():
    """T8/T13: a 500 m (1.7 chip) bias leaves the other seven satellites' solution (error within 3σ)."""
    gs = gnss(0.0, **QUIET_SIS)
    obs, _, truth = scene(4, gnss=gs, seed=9, bias_m={3: 500.0})
    mon = monitor()
    out, _ = mon.step(obs, mon.initial_state())
    assert np.all(out.reason == 0)
    ve = np.abs(out.pos_enu[:, 2] - truth[:, 2])
    assert np.all(ve <= 3 * out.diagnostics.crb_sd_u * 1.2), (ve, out.diagnostics.crb_sd_u)


def test_vpl_is_k_sigma_plus_the_median_and_needs_a_k():
    obs, _, truth = scene(3, seed=2)
    out, _ = monitor(k_factor=5.0).step(obs, None)
    d = out.diagnostics
    np.testing.assert_allclose(out.vpl, 5.0 * np.hypot(d.sigma_ob, d.sigma_sis_u) + np.abs(d.median_m))
    assert np.all(np.isnan(out.hpl)) and out.dimensions == ("V",)
    assert np.all(out.available == (out.vpl[:, None] <= np.array([50.0, 35.0, 20.0])))
    none, _ = DpeMonitor("dpe", context(), DpeSettings()).step(obs, None)
    assert np.all(np.isnan(none.vpl)) and np.all(none.reason == NOT_CALIBRATED) and not none.available.any()
    bare, _ = monitor(sis="none").step(obs, None)
    np.testing.assert_allclose(bare.vpl, 5.33 * d.sigma_ob + np.abs(d.median_m))
    assert np.all(d.sigma_ob > 0.5 * d.crb_sd_u) and np.all(d.sigma_ob < 2.0 * d.crb_sd_u)


def test_the_overbound_of_the_marginal_is_close_to_the_posterior_sd():
    """On the reference epoch (docs/design/dpe.md §4.3: 8 satellites, 45 dB-Hz, N_b = 50) σ_ob / posterior sd
    is 1.01-1.06 (the marginal is near Gaussian; the overbound's inflation is small)."""
    obs, _, _ = scene(20, seed=3)
    out, _ = monitor().step(obs, None)
    r = out.diagnostics.sigma_ob / out.diagnostics.posterior_sd_u
    assert np.all((r >= 1.0) & (r <= 1.08)), r


def test_degenerate_inputs_are_unavailable_with_a_reason():
    mon = monitor()
    obs, _, _ = scene(2, seed=1)
    out, state = mon.step(obs, mon.initial_state())
    assert np.all(out.reason == 0)
    three, _, _ = scene(2, elevations=(70.0, 40.0, 20.0), seed=1)
    o3, _ = mon.step(three, mon.initial_state())
    assert np.all(o3.reason == NO_INIT)  # no GPS fix with 3 satellites and no earlier DPE fix
    o3, _ = mon.step(three, state)  # initialised from the previous DPE fix
    assert np.all(o3.reason == FEW)
    assert np.all(np.isnan(o3.vpl)) and not o3.available.any()
    stat = obs.correlators.stat.copy()
    stat[0, 2, 100] = np.nan
    bad = dataclasses.replace(obs, correlators=dataclasses.replace(obs.correlators, stat=stat))
    ob, _ = mon.step(bad, mon.initial_state())
    assert ob.reason[0] == NAN_INPUT and ob.reason[1] == 0
    assert "NaN" in ob.reasons[NAN_INPUT]


def test_block_by_block_equals_one_call_and_correlators_are_prefix_stable():
    obs, _, _ = scene(6, seed=8)
    mon = monitor()
    whole, _ = mon.step(obs, mon.initial_state())
    a, st = mon.step(take_obs(obs, slice(0, 2)), mon.initial_state())
    b, _ = mon.step(take_obs(obs, slice(2, 6)), st)
    np.testing.assert_array_equal(np.concatenate([a.vpl, b.vpl]), whole.vpl)
    np.testing.assert_array_equal(np.concatenate([a.pos_enu, b.pos_enu]), whole.pos_enu)
    # the sensor: epochs 2..5 synthesised alone (first_epoch = 2) equal the whole run's
    g, gt = obs.gnss, _truth_of(obs)
    words = np.random.SeedSequence(77).generate_state(4)
    from types import SimpleNamespace
    tr = SimpleNamespace(agl=np.full(6, 300.0), vel_enu=np.zeros((6, 3)))
    full, _ = synthesize_correlators(g, gt, tr, GnssSettings(), words)
    tail, _ = synthesize_correlators(take_epochs(g, slice(2, 6)), take_epochs(gt, slice(2, 6)),
                                     SimpleNamespace(agl=tr.agl[2:], vel_enu=tr.vel_enu[2:]), GnssSettings(), words,
                                     first_epoch=2)
    np.testing.assert_array_equal(tail.stat, full.stat[2:])
    again, _ = synthesize_correlators(g, gt, tr, GnssSettings(), words)
    np.testing.assert_array_equal(again.stat, full.stat)  # bit-identical for the same seed


def take_obs(obs, sl):
    return dataclasses.replace(obs, gnss=take_epochs(obs.gnss, sl), correlators=take_epochs(obs.correlators, sl))


def _truth_of(obs):
    """Rebuild the scene's GNSS truth (a static antenna) from its observations."""
    from testbed.records import GnssTruth

    g = obs.gnss
    ant = np.broadcast_to(FRAME.enu_to_ecef(TRUTH_ENU), (len(g.t), 3)).copy()
    rng = np.linalg.norm(g.sat_pos_ecef - ant[:, None], axis=-1)
    el = np.arcsin(np.clip(FRAME.vec_ecef_to_enu((g.sat_pos_ecef - ant[:, None]) / rng[..., None])[..., 2], -1, 1))
    T, S = rng.shape
    return GnssTruth(antenna_pos_ecef=ant, geometric_range=rng, clock_bias=np.full(T, CLOCK_M), noise=np.zeros((T, S)),
                     fault_bias=np.zeros((T, S)), faulty=np.zeros((T, S), bool), elevation=el, azimuth=np.zeros((T, S)))


def test_a_vertical_only_monitor_is_judged_on_the_vertical():
    """T12: a DPE output whose vertical error exceeds its VPL is misleading, though HPL is NaN."""
    obs, _, truth = scene(3, seed=6)
    out, _ = monitor().step(obs, None)
    wrong = truth + np.array([0.0, 0.0, 100.0])  # a reference 100 m off vertically
    s = summarise_monitor(out, wrong, reference="antenna")
    assert s.mi_epochs == 3 and s.hmi_epochs == 3
    assert summarise_monitor(out, truth, reference="antenna").mi_epochs == 0
    he, ve = np.zeros(3), np.array([1.0, 5.0, 1.0])
    nan = np.full(3, np.nan)
    assert misleading(he, ve, nan, np.full(3, 2.0), np.zeros(3, bool), ("V",)).tolist() == [False, True, False]
    assert not misleading(he, ve, nan, np.full(3, 2.0), np.zeros(3, bool)).any()  # ("H", "V") needs both PLs


def test_the_monitor_never_reads_correlator_truth():
    root = Path(__file__).resolve().parents[1] / "testbed" / "integrity"
    for p in root.rglob("*.py"):
        assert "CorrelatorTruth" not in p.read_text(), p
    assert np.isclose(CHIP_M, 293.052, atol=1e-3)


@pytest.mark.parametrize("delay", [0.0, 37.0])
def test_linearised_delays_equal_exact_ranges(delay):
    """T5: δ_k(0) + g_k·ξ against the exact range at 350 m offsets: ≤ 5 mm."""
    obs, _, _ = scene(1, seed=0)
    from testbed.integrity.dpe.manifold import epoch_manifold

    c = obs.correlators
    mf = epoch_manifold(FRAME, c.sat_pos_ecef[0], c.rho_ref[0], c.stat[0], TRUTH_ENU, CLOCK_M + delay,
                        stat_kind="pow", n_blocks=50, bandwidth_chips=1.0, delay0_m=c.delay0_m, step_m=c.delay_step_m)
    xi = np.array([200.0, -200.0, 200.0, 30.0])
    exact = (np.linalg.norm(c.sat_pos_ecef[0] - FRAME.enu_to_ecef(TRUTH_ENU + xi[:3]), axis=-1) + CLOCK_M + delay
             + xi[3] - c.rho_ref[0])
    assert np.max(np.abs(mf.delta0 + mf.g @ xi - exact)) < 5e-3


def test_with_exactly_four_satellites_raim_has_no_redundancy_and_dpe_still_gives_a_vpl():
    """docs/design/dpe.md F6: four satellites leave snapshot RAIM no redundancy (no test, no PL); the DPE's VPL stands
    (it bounds the fault-free error; it detects nothing either way)."""
    from testbed.integrity.lsq import Reason
    from testbed.integrity.raim import gps_raim

    obs, _, truth = scene(3, elevations=(70.0, 45.0, 30.0, 15.0), seed=12)
    raim = gps_raim(obs.gnss, FRAME)
    assert np.all(raim.reason == Reason.NO_REDUNDANCY) and np.all(np.isnan(raim.vpl))
    out, _ = monitor().step(obs, monitor().initial_state())
    assert np.all(out.reason == 0) and np.all(np.isfinite(out.vpl))
    assert np.all(np.abs(out.pos_enu[:, 2] - truth[:, 2]) < out.vpl)


def test_threaded_posterior_kernels_equal_the_serial_ones():
    """The posterior's moments and the vertical marginal on numba's threads: the serial kernels' numbers bit
    for bit (both add slab sums in slab order), for any thread count; and the moments against numpy."""
    import numba

    from testbed.integrity.kernels.dpe import (deposit_marginal, deposit_marginal_threads, posterior_moments,
                                               posterior_moments_threads)

    rng = np.random.default_rng(3)
    n = 17
    z = (np.indices((n,) * 4).reshape(4, -1).T - (n - 1) / 2) * 0.6875
    lam = -0.5 * np.einsum("qi,ij,qj->q", z, np.array([[1.0, 0.3, 0, 0], [0.3, 1.2, 0, 0.1], [0, 0, 0.8, 0],
                                                        [0, 0.1, 0, 1.1]]), z) + rng.normal(0, 0.01, n**4)
    w1, w2 = np.empty(n**4), np.empty(n**4)
    a = posterior_moments(lam, 0.6875, n, w1)
    b = posterior_moments_threads(lam, 0.6875, n, w2)
    np.testing.assert_array_equal(w1, w2)
    assert b[0] == a[0]
    np.testing.assert_array_equal(b[1], a[1])
    np.testing.assert_array_equal(b[2], a[2])
    w = np.exp(lam - lam.max())
    np.testing.assert_allclose(a[1], (w[:, None] * z).sum(0) / w.sum(), rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(a[2], np.einsum("q,qi,qj->ij", w, z, z) / w.sum(), rtol=1e-11, atol=1e-13)
    coef = np.array([0.2, -0.1, 1.3, 0.05])
    m1, m2 = np.empty(161), np.empty(161)
    deposit_marginal(w1, 0.6875, n, coef, 0.3, 0.25, m1)
    deposit_marginal_threads(w1, 0.6875, n, coef, 0.3, 0.25, m2)
    np.testing.assert_array_equal(m2, m1)
    assert abs(m1.sum() - w1.sum()) < 1e-9 * w1.sum()  # every weight deposited (the grid fits the bins)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        m3 = np.empty(161)
        deposit_marginal_threads(w1, 0.6875, n, coef, 0.3, 0.25, m3)
        c = posterior_moments_threads(lam, 0.6875, n, np.empty(n**4))
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(m3, m2)  # not the thread count's
    np.testing.assert_array_equal(c[1], b[1])

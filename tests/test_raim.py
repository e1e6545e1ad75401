"""GPS-only RAIM (testbed.integrity.raim) against distributions and binomial bounds.

Geometry: the RTCA DO-229 24-satellite almanac seen from the ZUNZ RWY05
approach, epochs spread over a day; noise from the VA-RAIM paper's eq. 27 sigma
model. Fixed seeds; every statistical check is a KS test or a binomial 99%
interval, so a correct implementation fails each with probability ≈ 1%.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from test_integrity_core_helpers import make_gnss
from testbed.integrity import lsq
from testbed.integrity.levels import SERVICE_LEVELS
from testbed.integrity.raim import gps_raim
from testbed.integrity.settings import IntegritySettings
from testbed.world.airport import runway_frame

FRAME = runway_frame()
RX_ENU = np.array([-4000.0, -2800.0, 350.0])
TOW0 = 344063.0
KS_ALPHA = 0.01


def day_epochs(n_epochs: int, n_trials: int, seed: int, bias=None, settings=None, mask_deg=5.0):
    """RAIM over ``n_epochs`` geometries spread over a day, ``n_trials`` noise draws each."""
    tow = TOW0 + np.linspace(0.0, 86400.0, n_epochs, endpoint=False)
    rx = np.broadcast_to(RX_ENU, (n_epochs, 3))
    gnss, rho0, sig = make_gnss(FRAME, rx, tow, np.random.default_rng(seed), batch=(n_trials,),
                                bias=bias, mask_deg=mask_deg)
    return gps_raim(gnss, FRAME, settings), gnss


def _prob_transform_ks(u):
    return stats.kstest(u.ravel(), "uniform").pvalue


def test_fault_free_sse_is_chi2_n_minus_4():
    out, _ = day_epochs(96, 60, seed=11)
    ok = out.reason == 0
    assert ok.mean() > 0.99
    dof = out.n_used - 4
    u = stats.chi2.cdf(out.test_stat[ok], dof[ok])  # mixes dofs: uniform iff each is χ²(n−4)
    assert _prob_transform_ks(u) > KS_ALPHA
    # and the position error is unbiased at the metre level
    err = out.pos_enu[ok] - RX_ENU
    assert np.all(np.abs(err.mean(0)) < 0.1)


def test_biased_sse_is_noncentral_chi2():
    """Step bias of 15 m on one satellite: SSE ~ χ²_nc(n−4, λ = b²(WS)ᵢᵢ), λ from a per-epoch plain solve."""
    n_epochs, n_trials = 48, 80
    clean, gnss = day_epochs(n_epochs, 1, seed=0)
    # fault the highest-elevation-order first visible satellite of each epoch
    vis = gnss.visible[0]
    i_fault = np.argmax(vis, axis=-1)
    bias = np.zeros((n_trials, n_epochs, vis.shape[-1]))
    bias[:, np.arange(n_epochs), i_fault] = 15.0
    out, gnss = day_epochs(n_epochs, n_trials, seed=12, bias=bias)
    # λ per epoch from an independent per-epoch textbook computation
    lam = np.empty(n_epochs)
    for k in range(n_epochs):
        m = vis[k]
        s = FRAME.ecef_to_enu(gnss.sat_pos_ecef[0, k][m])
        d = s - RX_ENU
        G = np.concatenate([-d / np.linalg.norm(d, axis=-1, keepdims=True), np.ones((m.sum(), 1))], -1)
        W = np.diag(1.0 / gnss.sigma[0, k][m] ** 2)
        S = np.eye(m.sum()) - G @ np.linalg.inv(G.T @ W @ G) @ G.T @ W
        b = bias[0, k][m]
        lam[k] = b @ W @ S @ b
    dof = out.n_used - 4
    u = stats.ncx2.cdf(out.test_stat, dof, np.broadcast_to(lam, out.test_stat.shape))
    assert _prob_transform_ks(u) > KS_ALPHA
    # and it is *not* central: the bias is seen
    assert _prob_transform_ks(stats.chi2.cdf(out.test_stat, dof)) < 1e-6


def test_false_alarm_rate_within_binomial_interval():
    st = IntegritySettings(p_fa=1e-2)
    out, _ = day_epochs(96, 200, seed=13, settings=st)
    ok = out.reason == 0
    n = int(ok.sum())
    lo, hi = stats.binom.interval(0.99, n, 1e-2)
    k = int(out.alert[ok].sum())
    assert lo <= k <= hi, (k, lo, hi, n)


def test_missed_detection_rate_at_pbias_bias():
    """Bias on the worst-slope satellite with λ = λ_det: P(SSE < T²) = P_MD within a binomial 99% interval."""
    p_md = 0.1
    st = IntegritySettings(p_fa=1e-3, p_md=p_md, pl_variant="pbias")
    n_epochs, n_trials = 96, 60
    clean, gnss = day_epochs(n_epochs, 1, seed=0, settings=st)
    hs = clean.diagnostics.hslope[0]
    worst = np.nanargmax(np.where(np.isnan(hs), -np.inf, hs), axis=-1)
    # (WS)_ii of the worst satellite from its slope definition: λ = b² (WS)_ii
    geom_ws = _ws_diag(gnss, clean)
    ws_i = geom_ws[np.arange(n_epochs), worst]
    lam = clean.diagnostics.lam_det[0]
    b_mag = np.sqrt(lam / ws_i)
    bias = np.zeros((n_trials, n_epochs, hs.shape[-1]))
    bias[:, np.arange(n_epochs), worst] = b_mag
    out, _ = day_epochs(n_epochs, n_trials, seed=14, bias=bias, settings=st)
    ok = out.reason == 0
    n = int(ok.sum())
    missed = int((~out.alert[ok]).sum())
    lo, hi = stats.binom.interval(0.99, n, p_md)
    assert lo <= missed <= hi, (missed, lo, hi, n)
    # the fault the pbias PL is built on moves the position by exactly HPL (noise-free);
    # with ~1 m noise against ~10 m PLs the median ratio stays within 10 %
    err_h = np.hypot(*(out.pos_enu[..., :2] - RX_ENU[:2]).transpose(2, 0, 1))
    assert abs(np.median(err_h / clean.hpl[0]) - 1.0) < 0.1


def _ws_diag(gnss, out):
    """(WS)_ii per epoch/slot, recomputed from the monitor's own slope and A (test-side)."""
    T, S = gnss.visible.shape[-2:]
    ws = np.full((T, S), np.nan)
    for k in range(T):
        m = gnss.visible[0, k]
        s = FRAME.ecef_to_enu(gnss.sat_pos_ecef[0, k][m])
        d = s - out.pos_enu[0, k]
        G = np.concatenate([-d / np.linalg.norm(d, axis=-1, keepdims=True), np.ones((m.sum(), 1))], -1)
        W = np.diag(1.0 / gnss.sigma[0, k][m] ** 2)
        S_ = np.eye(m.sum()) - G @ np.linalg.inv(G.T @ W @ G) @ G.T @ W
        ws[k, m] = np.diag(W @ S_)
    return ws


def test_availability_matches_alert_limits_and_shapes():
    out, _ = day_epochs(24, 3, seed=15)
    assert out.available.shape == (3, 24, 3) and out.service_levels == ("APV-I", "LPV-200", "APV-II")
    for k, name in enumerate(out.service_levels):
        lvl = SERVICE_LEVELS[name]
        np.testing.assert_array_equal(out.available[..., k], (out.hpl <= lvl.hal) & (out.vpl <= lvl.val))
    assert out.pos_enu.shape == (3, 24, 3) and out.hpl.shape == (3, 24)
    assert out.diagnostics.hslope.shape == (3, 24, 24)
    assert out.reasons[0] == "ok"


def test_degenerate_epochs_unavailable_rest_unchanged():
    tow = TOW0 + np.array([0.0, 600.0, 1200.0, 1800.0])
    rx = np.broadcast_to(RX_ENU, (4, 3))
    gnss, _, _ = make_gnss(FRAME, rx, tow, np.random.default_rng(16))
    ref = gps_raim(gnss, FRAME)
    vis = gnss.visible.copy()
    pr = gnss.pseudorange.copy()
    keep4 = np.flatnonzero(vis[1])[:4]
    vis[1] = False
    vis[1, keep4] = True  # 4 satellites: no redundancy
    pr[2, np.flatnonzero(vis[2])[0]] = np.nan  # a visible satellite with a NaN pseudorange
    from dataclasses import replace
    out = gps_raim(replace(gnss, visible=vis, pseudorange=pr), FRAME)
    R = lsq.Reason
    assert list(out.reason) == [R.OK, R.NO_REDUNDANCY, R.NAN_INPUT, R.OK]
    assert "no redundancy" in out.reasons[out.reason[1]]
    assert np.isnan(out.hpl[1:3]).all() and not out.available[1:3].any() and not out.alert[1:3].any()
    for k in (0, 3):
        np.testing.assert_allclose(out.pos_enu[k], ref.pos_enu[k], atol=1e-9)
        np.testing.assert_allclose(out.hpl[k], ref.hpl[k], rtol=1e-12)


def test_antenna_offset_moves_the_reported_point():
    tow = TOW0 + np.array([0.0, 600.0])
    off = np.array([1.0, -2.0, 3.0])
    gnss, _, _ = make_gnss(FRAME, np.broadcast_to(RX_ENU + off, (2, 3)), tow, None)
    out = gps_raim(gnss, FRAME, antenna_offset_enu=off)
    np.testing.assert_allclose(out.pos_enu, np.broadcast_to(RX_ENU, (2, 3)), atol=1e-6)
    assert out.diagnostics.converged.all()


@pytest.mark.parametrize("variant", ["seed", "pbias"])
def test_pl_variant_selected(variant):
    out, _ = day_epochs(8, 1, seed=17, settings=IntegritySettings(pl_variant=variant))
    np.testing.assert_array_equal(out.hpl, getattr(out.diagnostics, f"hpl_{variant}"))
    # both bound the fault-free horizontal error of this small sample
    err_h = np.hypot(*(out.pos_enu[..., :2] - RX_ENU[:2]).transpose(2, 0, 1))
    assert np.all(err_h < out.hpl)


def test_gps_raim_chunks_and_threads_are_bit_identical(monkeypatch):
    """Chunks of trials on two threads give exactly the one-piece numbers (NaN epochs included)."""
    from dataclasses import replace

    from test_va_raim import _assert_outputs_identical
    from test_va_raim_scenario import make_scenario

    from testbed.integrity import batching
    sc = make_scenario(np.random.default_rng(31), (7,), t0=40.0, t1=60.0)
    pr = sc.gnss.pseudorange.copy()
    pr[3, 4, :] = np.nan
    pr[5, 9:, np.flatnonzero(sc.gnss.visible[5, 9])[1]] += 80.0
    gnss = replace(sc.gnss, pseudorange=pr)
    whole = gps_raim(gnss, sc.frame, threads=1)
    monkeypatch.setattr(batching, "CHUNK_EPOCHS", 21)
    pieces = gps_raim(gnss, sc.frame, threads=2)
    _assert_outputs_identical(whole, pieces)
    assert np.any(whole.alert) and np.any(whole.reason != 0)

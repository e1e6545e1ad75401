"""GNSS error model: seed eq. 27 sigmas by hand, N(0,1) normalised errors, Gauss-Markov, clock."""

import numpy as np
import pytest
from scipy import stats

from testbed.flight.kinematic import straight_truth
from testbed.records import Mount
from testbed.sensors.gnss.errors import (IONO_FREE_FACTOR, receiver_clock, sigma_pseudorange, sigma_tropo,
                                         sigma_user, unit_gauss_markov)
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss
from testbed.world.airport import runway_frame

SIGMA_TOL_M = 1e-4  # hand values below are written to 5 significant figures or better
P_MIN = 1e-3  # KS / chi-square acceptance at fixed seeds


def test_iono_free_factor():
    # f1² = 1575.42² = 2 481 948.18 MHz², f5² = 1176.45² = 1 384 034.60 MHz²
    # f1⁴ + f5⁴ = 8.0756185e12, sqrt = 2 841 763.3; f1² − f5² = 1 097 913.57  ->  2.58833
    assert IONO_FREE_FACTOR == pytest.approx(2.58833, abs=1e-5)


@pytest.mark.parametrize("el_deg, tropo, sigma", [
    # θ = 90°: tropo = 0.12·1.001/sqrt(0.002001 + 1) = 0.12000
    #   σ_MP = 0.13 + 0.53·e^-9 = 0.130065, σ_n = 0.15 + 0.43·e^(-90/6.9) = 0.150001
    #   σ_user² = (0.130065² + 0.150001²)·2.58833² = 0.039418·6.69945 = 0.264074
    #   σ² = 0.5625 + 0.0144 + 0.264074 = 0.840974 -> σ = 0.917047
    (90.0, 0.12000, 0.917047),
    # θ = 30°: tropo = 0.12012/sqrt(0.252001) = 0.239284
    #   σ_MP = 0.13 + 0.53·e^-3 = 0.156387, σ_n = 0.15 + 0.43·e^(-30/6.9) = 0.155562
    #   σ_user² = (0.024457 + 0.024200)·6.69945 = 0.325972; σ² = 0.5625 + 0.057257 + 0.325972 -> σ = 0.972486
    (30.0, 0.239284, 0.972486),
    # θ = 10°: sin = 0.173648, tropo = 0.12012/sqrt(0.032155) = 0.669874
    #   σ_MP = 0.13 + 0.53·e^-1 = 0.324976, σ_n = 0.15 + 0.43·e^(-10/6.9) = 0.250938
    #   σ_user² = (0.105609 + 0.062970)·6.69945 = 1.129391; σ² = 0.5625 + 0.448731 + 1.129391 -> σ = 1.463087
    (10.0, 0.669874, 1.463087),
    # θ = 5°: sin = 0.0871557, tropo = 0.12012/sqrt(0.0095970) = 1.226153
    #   σ_MP = 0.13 + 0.53·e^-0.5 = 0.451461, σ_n = 0.15 + 0.43·e^(-5/6.9) = 0.358335
    #   σ_user² = (0.203817 + 0.128404)·6.69945 = 2.225701; σ² = 0.5625 + 1.503452 + 2.225701 -> σ = 2.071631
    (5.0, 1.226153, 2.071631),
])
def test_sigma_against_hand_values(el_deg, tropo, sigma):
    el = np.radians(el_deg)
    assert sigma_tropo(el) == pytest.approx(tropo, abs=SIGMA_TOL_M)
    assert sigma_pseudorange(el) == pytest.approx(sigma, abs=SIGMA_TOL_M)
    # batched call gives the same
    assert sigma_pseudorange(np.full((2, 3), el)) == pytest.approx(np.full((2, 3), sigma), abs=SIGMA_TOL_M)


def test_sigma_user_seed_radian_form():
    # the seed writes exp(−18θ/π) and exp(−180θ/(6.9π)) with θ in rad: the same numbers
    th = np.radians(np.array([5.0, 20.0, 60.0]))
    seed = np.hypot(0.13 + 0.53 * np.exp(-18 * th / np.pi), 0.15 + 0.43 * np.exp(-180 * th / (6.9 * np.pi)))
    np.testing.assert_allclose(sigma_user(th), seed * IONO_FREE_FACTOR, rtol=1e-12)


@pytest.fixture(scope="module")
def approach_geometry():
    frame = runway_frame()
    truth = straight_truth(frame, [-9000.0, -6400.0, 650.0], [-3000.0, -2100.0, 200.0], 60.0, rate_hz=1.0)
    s = GnssSettings(terrain_masking=False)
    return gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc="2024-03-15T06:00:00Z")


@pytest.mark.parametrize("kw", [{}, {"multipath_tau_s": 20.0, "ura_tropo_tau_s": 300.0}])
def test_normalised_errors_are_standard_normal(approach_geometry, kw):
    s = GnssSettings(terrain_masking=False, **kw)
    ep, tr = sample_gnss(approach_geometry, s, rng=np.random.default_rng(11), n_trials=400)
    vis = ep.visible
    z = (ep.pseudorange - tr.geometric_range - tr.clock_bias[..., None])[vis] / ep.sigma[vis]
    if kw:  # correlated in time: use one epoch per trial (trials are independent)
        z = ((ep.pseudorange - tr.geometric_range - tr.clock_bias[..., None]) / ep.sigma)[:, 30][vis[:, 30]]
    assert z.size > 2500
    assert stats.kstest(z, "norm").pvalue > P_MIN
    # and the variance alone, chi-square: (n−1)s² ~ χ²(n−1)
    n = z.size
    q = (n - 1) * z.var(ddof=1)
    assert stats.chi2.ppf(P_MIN / 2, n - 1) < q < stats.chi2.ppf(1 - P_MIN / 2, n - 1)


def test_gauss_markov_autocorrelation():
    tau, dt = 10.0, 1.0
    u = unit_gauss_markov(np.random.default_rng(5), (3000, 120), dt, tau, axis=-1)
    # stationary unit variance at the start and at the end
    for k in (0, 119):
        n = u.shape[0]
        q = (n - 1) * u[:, k].var(ddof=1)
        assert stats.chi2.ppf(P_MIN / 2, n - 1) < q < stats.chi2.ppf(1 - P_MIN / 2, n - 1)
    for lag in (1, 5, 10, 30):
        r = np.mean(u[:, 50] * u[:, 50 + lag])
        expected = np.exp(-lag * dt / tau)
        se = np.sqrt((1 + expected**2) / u.shape[0])  # std error of a product-moment of unit normals
        assert abs(r - expected) < 4 * se, (lag, r, expected)
    w = unit_gauss_markov(np.random.default_rng(5), (3000, 50), dt, None, axis=-1)
    assert abs(np.mean(w[:, 10] * w[:, 11])) < 4 / np.sqrt(3000)


def test_clock_variance_growth():
    """Var b(t) = σb0² + σd0² t² + S_f t + S_g t³/3 (two-state model, closed form)."""
    t = np.arange(0.0, 121.0, 1.0)
    kw = dict(bias0_sigma_m=3.0, drift0_sigma_m_s=0.2, sf_m2_s=0.5, sg_m2_s3=0.05)
    b, d = receiver_clock(np.random.default_rng(9), t, (4000,), **kw)
    n = b.shape[0]
    for k in (0, 60, 120):
        tt = t[k]
        var_b = 9.0 + 0.04 * tt**2 + 0.5 * tt + 0.05 * tt**3 / 3
        var_d = 0.04 + 0.05 * tt
        for x, v in ((b[:, k], var_b), (d[:, k], var_d)):
            q = (n - 1) * x.var(ddof=1) / v
            assert stats.chi2.ppf(P_MIN / 2, n - 1) < q < stats.chi2.ppf(1 - P_MIN / 2, n - 1), (k, x.var(), v)


def test_range_rate_is_derivative_of_range():
    """Geometric range rate vs finite differences of the light-time-solved range (0.1 s steps)."""
    frame = runway_frame()
    truth = straight_truth(frame, [-6000.0, -4000.0, 500.0], [-5000.0, -3300.0, 440.0], 20.0, rate_hz=10.0)
    s = GnssSettings(terrain_masking=False, rate_hz=10.0)
    g = gnss_geometry(truth, Mount(np.array([2.0, 0.5, -1.5])), s, start_utc="2024-03-15T06:00:00Z")
    fd = (g.geometric_range[2:] - g.geometric_range[:-2]) / (g.t[2:] - g.t[:-2])[:, None]
    np.testing.assert_allclose(g.geometric_range_rate[1:-1], fd, atol=0.01)  # 1 cm/s
    # and the pseudorange geometry identity the monitor uses
    np.testing.assert_allclose(np.linalg.norm(g.sat_pos_ecef - g.ant_pos_ecef[:, None], axis=-1),
                               g.geometric_range, rtol=0, atol=1e-6)

"""The correlator sensor against what no one here wrote (docs/design/dpe.md §2, §10 T1-T4, T8).

The band-limited correlation against numerical integration and against a sample-level
C/A-code simulation (Gold codes from their shift registers, an FFT brick-wall filter);
the synthesised noise's covariance against R_B with Monte Carlo bounds; the fast
synthesis against the exact one in distribution; a ground echo's peak against brute force.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, stats

from testbed.correlation import CHIP_M, amplitude_sq, correlation, crb_delay_sigma, peak
from testbed.sensors.gnss.correlators import (epoch_statistic, cn0_at, cn0_estimate, delay_grid, draw_noise,
                                              noise_spectrum, tabulated_correlation)
from testbed.sensors.gnss.settings import CorrelatorSettings


@pytest.mark.parametrize("b", [0.5, 1.0, 2.0, 8.0])
def test_the_closed_form_equals_quadrature(b):
    for x in (0.0, 0.13, 0.5, 0.99, 1.0, 1.37, 2.6):
        ref = integrate.quad(lambda f: np.sinc(f) ** 2 * np.cos(2 * np.pi * f * x), -b, b, limit=400,
                             epsabs=1e-14, epsrel=1e-12)[0]
        assert abs(float(correlation(x * CHIP_M, b)) - ref) <= 1e-12


def test_peak_values_and_the_infinite_bandwidth_triangle():
    # docs/design/dpe.md §2.3's values, 5 digits
    for b, r0 in ((0.5, 0.77370), (1.0, 0.90282), (2.0, 0.94994), (8.0, 0.98734)):
        assert round(peak(b), 5) == r0
    x = np.linspace(-1.5, 1.5, 31) * CHIP_M
    np.testing.assert_allclose(correlation(x, np.inf), np.maximum(1 - np.abs(x) / CHIP_M, 0), atol=1e-15)
    assert np.max(np.abs(correlation(x, 50.0) - correlation(x, np.inf))) < 0.01


def test_the_table_the_sensor_reads_equals_the_closed_form():
    d = np.random.default_rng(0).uniform(-3000, 3000, 20000)
    assert np.max(np.abs(tabulated_correlation(d, 1.0) - correlation(d, 1.0))) < 1e-6


def _ca_code(prn_taps: tuple[int, int]) -> np.ndarray:
    """The 1023-chip C/A code from the G1/G2 shift registers (IS-GPS-200 Table 3-Ia phase taps), ±1."""
    g1, g2 = [1] * 10, [1] * 10
    out = np.empty(1023)
    for i in range(1023):
        out[i] = g1[9] ^ g2[prn_taps[0] - 1] ^ g2[prn_taps[1] - 1]
        f1 = g1[2] ^ g1[9]
        f2 = g2[1] ^ g2[2] ^ g2[5] ^ g2[7] ^ g2[8] ^ g2[9]
        g1, g2 = [f1] + g1[:9], [f2] + g2[:9]
    return 1.0 - 2.0 * out


def test_a_sampled_ca_code_through_a_brick_wall_filter_correlates_like_the_model():
    """T3: PRN 1 at 16 samples/chip, 1 ms, filtered to ±1.023 MHz, correlated with the unfiltered replica."""
    code = _ca_code((2, 6))  # PRN 1
    assert code[:10].tolist() == [-1, -1, 1, 1, -1, 1, 1, 1, 1, 1]  # first chips 1100100000 (octal 1440) -> ±1
    n = 16
    s = np.repeat(code, n)
    f = np.fft.fftfreq(s.size, d=1.0 / n)  # in chip rates
    filtered = np.fft.ifft(np.fft.fft(s) * (np.abs(f) <= 1.0)).real
    corr = np.fft.ifft(np.fft.fft(filtered) * np.conj(np.fft.fft(s))).real / s.size  # circular correlation
    lags = np.arange(-24, 25)  # ±1.5 chip
    got = corr[lags % s.size]
    want = correlation(lags / n * CHIP_M, 1.0)
    assert np.max(np.abs(got - want)) <= 0.005 * want.max()  # the model neglects the code's own spectrum lines


def test_noise_has_the_correlation_as_covariance_and_no_pseudo_covariance():
    cs = CorrelatorSettings()
    g = delay_grid(cs)
    spec = noise_spectrum(g.step_m, g.size, 1.0)
    assert -1e-4 < spec.min_ratio < 0.0  # the embedding's only approximation, clipped
    N = 4000
    w = draw_noise(np.random.default_rng(7), spec, (N,))
    r0 = peak(1.0)
    for lag in (0, 5, 20, 60, 100, 147, 200, 400):
        c = np.mean(w[:, 300] * np.conj(w[:, 300 + lag]))
        assert abs(c.real - float(correlation(lag * g.step_m, 1.0))) <= 4 * r0 / np.sqrt(2 * N)
        assert abs(np.mean(w[:, 300] * w[:, 300 + lag])) <= 4 * r0 / np.sqrt(N)


def _stats(synthesis: str, n: int, alpha: float, seed0: int = 0):
    cs = CorrelatorSettings(synthesis=synthesis)
    g = delay_grid(cs)
    A = np.sqrt(amplitude_sq(np.full(4, 43.0), cs.coherent_s))
    phase = np.tile(np.linspace(0, 4, cs.n_noncoherent), (4, 1))
    return np.concatenate([epoch_statistic(np.random.default_rng(seed0 + i), cs, g, A, np.full(4, 3.3), np.full(4, 60.0),
                                       np.full(4, alpha), phase) for i in range(n)]), g


@pytest.mark.parametrize("alpha", [0.0, 0.3])
def test_fast_synthesis_equals_exact_in_distribution(alpha):
    exact, g = _stats("exact", 150, alpha)
    fast, _ = _stats("fast", 150, alpha, seed0=10_000)
    for j in (500, 502, 530, 560, 700):  # peak, shoulder, slope, edge of the lobe, noise only
        assert stats.ks_2samp(exact[:, j], fast[:, j]).pvalue > 0.01, j
        assert abs(exact[:, j].mean() - fast[:, j].mean()) < 4 * exact[:, j].std() / np.sqrt(300)


@pytest.mark.parametrize("synthesis", ["fast", "exact"])
def test_the_expected_statistic_is_the_mean_of_the_draws_with_a_ground_echo(synthesis):
    """The statistic with no draws (``rng=None``: A²·RᵀHR + N_b·R_B(0), the pilot of the DPE's importance sampler,
    docs/design/dpe.md §6.8) against the mean of 3000 draws (the exact synthesis: 400) at every lag of the grid,
    within 4.5 standard errors, with an echo of amplitude 0.3 at 40 m whose phase turns over the blocks; and
    against the blocks' noise-free power summed by brute force, plus the noise's."""
    cs = CorrelatorSettings(synthesis=synthesis)
    g = delay_grid(cs)
    n = 3000 if synthesis == "fast" else 400
    A, delay, echo, alpha = np.full(n, 6.0), np.full(n, 3.3), np.full(n, 40.0), np.full(n, 0.3)
    phase = np.tile(0.4 + 2.0 * np.pi * 0.07 * np.arange(cs.n_noncoherent), (n, 1))
    draws = epoch_statistic(np.random.default_rng(3), cs, g, A, delay, echo, alpha, phase)
    mean = epoch_statistic(None, cs, g, A[:1], delay[:1], echo[:1], alpha[:1], phase[:1])[0]
    se = draws.std(0) / np.sqrt(n)
    assert np.max(np.abs(draws.mean(0) - mean) / se) < 4.5
    d = g.offsets - delay[0]
    blocks = np.abs(correlation(d, 1.0)[None, :] + alpha[0] * np.exp(1j * phase[0])[:, None]
                    * correlation(d - echo[0], 1.0)[None, :]) ** 2
    np.testing.assert_allclose(mean, A[0] ** 2 * blocks.sum(0) + cs.n_noncoherent * peak(1.0), rtol=1e-5)


def test_the_expected_statistic_is_refused_where_it_has_no_closed_form_or_draws_to_tilt():
    from testbed.sensors.gnss.correlators import synthesize_correlators

    cs = CorrelatorSettings(synthesis="exact", statistic="mag")
    one = np.ones(1)
    with pytest.raises(ValueError, match="statistic = 'pow' only"):
        epoch_statistic(None, cs, delay_grid(cs), one, one, one, 0 * one, np.zeros((1, cs.n_noncoherent)))
    with pytest.raises(ValueError, match="no draws to tilt"):
        synthesize_correlators(None, None, None, None, np.zeros(4, np.uint32), sis_shift=np.zeros((1, 1)),
                               expected=True)


def test_a_ground_echo_moves_the_peak_where_brute_force_puts_it():
    cs = CorrelatorSettings()
    g = delay_grid(cs)
    A = np.full(1, 1e4)  # noise negligible against the signal
    delay, echo, alpha = np.full(1, 0.0), np.full(1, 0.25 * CHIP_M), np.full(1, 0.5)
    phase = np.zeros((1, cs.n_noncoherent))  # in phase with the direct signal
    st = epoch_statistic(np.random.default_rng(0), cs, g, A, delay, echo, alpha, phase)[0]
    d = g.offsets
    brute = np.abs(correlation(d, 1.0) + alpha[0] * correlation(d - echo[0], 1.0)) ** 2
    assert np.argmax(st) == np.argmax(brute)
    assert d[np.argmax(st)] > 0.0  # an in-phase late echo pulls the peak late


def test_cn0_table_and_estimate():
    cs = CorrelatorSettings()
    np.testing.assert_allclose(cn0_at(np.radians([5.0, 30.0, 90.0, 2.0]), cs), [38.0, 43.5, 45.5, 38.0])
    g = delay_grid(cs)
    A = np.sqrt(amplitude_sq(np.full(200, 45.0), cs.coherent_s))
    st = epoch_statistic(np.random.default_rng(3), cs, g, A, np.zeros(200), np.zeros(200), np.zeros(200),
                     np.zeros((200, cs.n_noncoherent)))
    est = cn0_estimate(st, cs)
    assert abs(np.median(est) - 45.0) < 0.2


def test_crb_matches_the_notes_figures():
    a2 = amplitude_sq(45.0, 0.02)
    assert abs(float(crb_delay_sigma(a2, 1, 1.0)) - 4.1) < 0.05
    assert abs(float(crb_delay_sigma(a2, 50, 1.0)) - 0.58) < 0.01


def test_a_residual_doppler_lowers_the_coherent_amplitude_by_its_sinc():
    """25 Hz left by the carrier loop over T = 20 ms: the receiver's C/N0 estimate from the correlograms falls by
    −20·log10|sinc(0.5)| = 3.92 dB (medians over 8 satellites × 40 epochs, within 0.15 dB); 0 Hz changes
    nothing."""
    from dpe_scene import scene

    from testbed.sensors.gnss.settings import GnssSettings

    def est(hz):
        gs = GnssSettings(correlators=CorrelatorSettings(residual_doppler_hz=hz))
        obs, _, _ = scene(40, gnss=gs, seed=4)
        return np.asarray(obs.correlators.cn0_est_dbhz)

    base, slow = est(0.0), est(25.0)
    drop = np.median(base - slow)
    assert abs(drop - (-20 * np.log10(np.sinc(0.5)))) < 0.15, drop
    np.testing.assert_array_equal(est(0.0), base)


@pytest.mark.parametrize("statistic", ["pow", "mag"])
def test_the_exact_synthesis_in_pieces_draws_what_one_piece_draws(statistic, monkeypatch):
    """The exact synthesis bounds its working memory by running satellites a piece at a time; the noise is
    drawn in satellite order, so any piece size gives the one-piece numbers bit for bit."""
    import testbed.sensors.gnss.correlators as corr

    cs = CorrelatorSettings(synthesis="exact", statistic=statistic)
    grid = delay_grid(cs)
    n = 40
    A = float(np.sqrt(amplitude_sq(45.0, cs.coherent_s)))

    def run():
        rng = np.random.default_rng(3)
        return epoch_statistic(rng, cs, grid, np.full(n, A), rng.uniform(-3, 3, n), np.full(n, 30.0),
                               np.full(n, 0.3), rng.uniform(0, 6, (n, cs.n_noncoherent)))

    monkeypatch.setattr(corr, "_EXACT_BYTES", 2**40)
    whole = run()
    monkeypatch.setattr(corr, "_EXACT_BYTES", 40 * 2**20)  # three satellites a piece
    assert 1 < corr._EXACT_BYTES // (16 * cs.n_noncoherent * corr.noise_spectrum(
        grid.step_m, grid.size, cs.bandwidth_chips).amplitude.size * 8) < n
    np.testing.assert_array_equal(run(), whole)

"""Correlator outputs on a code-delay grid, the DPE monitor's observations (docs/design/dpe.md §2).

No IF samples: per satellite and coherent block b, after carrier and data wipe-off,
the normalised correlator output at delay δ (m, relative to the channel's reference) is

    y_b(δ) = A·Σ_m c_bm·R_B(δ − δ_k − Δ_m) + w_b(δ),   w_b ~ CN(0, R_B(δ₁ − δ₂)),   A² = (C/N0)·T,

m = 0 the direct signal (c_b0 = e^{jθ_b}, θ_b uniform, new per block), m ≥ 1 echoes
(c_bm = α_m·e^{j(θ_b + φ_bm)}); a residual carrier frequency Δf left by tracking scales A by
|sinc(Δf·T)| (``residual_doppler_hz``); δ_k = geometric range + receiver clock + SIS error +
fault − reference. Blocks are disjoint in time (independent noise); satellites are
independent (Gold cross-correlation, ≤ −24 dB, neglected).

The noise is drawn on the delay axis by circulant embedding (Cholesky fails: the
covariance is near-singular): for a grid of M delays, L ≥ M + 6 chips of padding,
eigenvalues λ = DFT of the periodised covariance, w = DFT(√(λ/L)·z)[:M], z ~ CN(0, I).

Two syntheses of the same statistics:

* ``exact``: N_b draws per satellite; reports ``pow`` = Σ_b|y_b|² or ``mag`` = (1/N_b)Σ_b|y_b|.
* ``fast`` (``pow`` only): Σ_b|y_b|² = A²·RᵀHR + 2A·Re Σ_m R_m·V_m + Σ_b|w_b|², with
  H = CᴴC the blocks' Gram matrix of the path coefficients, V = H^{1/2}·U from
  (1 + echoes) independent unit processes, and Σ_b|w_b|² drawn as its mean N_b·R_B(0)
  plus a Gaussian process of covariance N_b·R_B(δ₁ − δ₂)² (exact second moments; only
  the χ² skew 2/√N_b is lost, tests/test_correlators.py compares both).

Every epoch's draws come from its own generator, ``SeedSequence(words, spawn_key=(epoch,))``,
so a block synthesises only its new epochs and any prefix is reproduced bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from testbed.correlation import L1_WAVELENGTH_M, CHIP_M, amplitude_sq, correlation, peak
from testbed.records import CorrelatorEpochs, CorrelatorTruth, GnssEpochs, GnssTruth, Truth
from testbed.sensors.gnss.errors import sigma_tropo
from testbed.sensors.gnss.settings import CorrelatorSettings, GnssSettings
from testbed.sensors.streams import epoch_generator


@dataclass(frozen=True)
class DelayGrid:
    """The correlogram's delay axis: offsets ``delay0_m + j·step_m``, j < ``size``."""

    delay0_m: float
    step_m: float
    size: int

    @property
    def offsets(self) -> NDArray:
        return self.delay0_m + self.step_m * np.arange(self.size)


def delay_grid(settings: CorrelatorSettings) -> DelayGrid:
    half = int(round(settings.half_window_m / settings.delay_step_m))
    return DelayGrid(-half * settings.delay_step_m, settings.delay_step_m, 2 * half + 1)


@dataclass(frozen=True)
class NoiseSpectrum:
    """Circulant-embedding factor of a stationary covariance on a delay grid.

    amplitude : (L,) √(λ/L).  size : M, the delays kept.  min_ratio : min λ / max λ before
    clipping the negative eigenvalues (the embedding's error; ≈ −4e-5 for R_B at Δ = 2 m).
    """

    amplitude: NDArray
    size: int
    min_ratio: float


@lru_cache(maxsize=16)
def noise_spectrum(step_m: float, size: int, bandwidth_chips: float, squared: bool = False) -> NoiseSpectrum:
    """The factor drawing CN(0, R_B(δ₁ − δ₂)) (``squared``: covariance R_B²) on ``size`` delays."""
    pad = 2 * int(np.ceil(3.0 * CHIP_M / step_m))
    L = 1 << int(np.ceil(np.log2(size + pad)))
    lag = np.minimum(np.arange(L), L - np.arange(L)) * step_m
    c = correlation(lag, bandwidth_chips)
    if squared:
        c = c * c
    lam = np.fft.fft(c).real
    ratio = float(lam.min() / lam.max())
    return NoiseSpectrum(np.sqrt(np.clip(lam, 0.0, None) / L), size, ratio)


def draw_noise(rng: np.random.Generator, spec: NoiseSpectrum, lead: tuple[int, ...], tilt=None) -> NDArray:
    """(lead..., M) complex draws of the stationary process ``spec`` factors (E[w wᵀ] = 0).

    tilt : None, or ``(shift, seen)``: ``shift`` (lead..., L) is added to the standard complex draws z
        (CN(0, 1) each) before they are coloured, and ``seen(z)`` is given the draws as tilted (an importance
        sampler's hook, docs/design/dpe.md §6.8)."""
    L = spec.amplitude.size
    z = rng.standard_normal(lead + (L, 2)).view(np.complex128)[..., 0] * np.sqrt(0.5)
    if tilt is not None:
        z = z + tilt[0]
        tilt[1](z)
    return np.fft.fft(spec.amplitude * z, axis=-1)[..., : spec.size]


#: the tabulated correlation's span (m) and step (linear interpolation error < 1e-6 of the peak)
_TABLE_SPAN_M, _TABLE_STEP_M = 8000.0, 0.05


@lru_cache(maxsize=8)
def _correlation_table(bandwidth_chips: float) -> NDArray:
    return correlation(np.arange(-_TABLE_SPAN_M, _TABLE_SPAN_M + _TABLE_STEP_M / 2, _TABLE_STEP_M), bandwidth_chips)


def tabulated_correlation(delay_m: NDArray, bandwidth_chips: float) -> NDArray:
    """R_B at delays (m) from a cached fine table (the closed form costs Si per point); exact outside it."""
    d = np.asarray(delay_m, float)
    table = _correlation_table(float(bandwidth_chips))
    pos = (np.clip(d, -_TABLE_SPAN_M, _TABLE_SPAN_M) + _TABLE_SPAN_M) / _TABLE_STEP_M
    i = np.minimum(pos.astype(np.intp), table.size - 2)
    f = pos - i
    out = table[i] * (1.0 - f) + table[i + 1] * f
    far = np.abs(d) > _TABLE_SPAN_M
    if far.any():
        out[far] = correlation(d[far], bandwidth_chips)
    return out


def cn0_at(elevation_rad: NDArray, settings: CorrelatorSettings) -> NDArray:
    """C/N0 (dB-Hz) from the elevation table (linear between its points, held outside) + offset."""
    el = np.asarray(list(settings.cn0_by_elevation), float)
    cn0 = np.asarray(list(settings.cn0_by_elevation.values()), float)
    return np.interp(np.degrees(elevation_rad), el, cn0) + settings.cn0_offset_db


def _path_gram(alpha: NDArray, phase: NDArray, n_b: int) -> NDArray:
    """(S, 2, 2) H = CᴴC of the direct + one echo over the blocks (the direct phase cancels)."""
    h01 = alpha * np.exp(1j * phase).sum(axis=-1)
    H = np.empty(alpha.shape + (2, 2), complex)
    H[..., 0, 0] = n_b
    H[..., 0, 1] = h01
    H[..., 1, 0] = np.conj(h01)
    H[..., 1, 1] = alpha * alpha * n_b
    return H


def _sqrt_psd(H: NDArray) -> NDArray:
    """A square root K (K·Kᴴ = H) of Hermitian PSD matrices; rank-deficient ones too."""
    w, Q = np.linalg.eigh(H)
    return Q * np.sqrt(np.clip(w, 0.0, None))[..., None, :]


#: working memory of one piece of the exact synthesis (its complex temporaries), bytes
_EXACT_BYTES = 256 * 2**20


def epoch_statistic(rng: np.random.Generator | None, settings: CorrelatorSettings, grid: DelayGrid, A: NDArray,
                    delay: NDArray, echo_delay: NDArray, alpha: NDArray, echo_phase: NDArray, tilt=None) -> NDArray:
    """(S, M) statistic of one epoch's tracked satellites (A, delays, echoes per satellite).

    rng : None for the statistic's expectation over the thermal noise (no draws; the power statistic only).
    tilt : None, or an object whose ``shift(K, spec)`` gives the (S, 2, L) shift of the standard draws of the
        processes U (fast synthesis; K the paths' Gram root, V = K U) and whose ``seen(z)`` is given them
        as tilted (docs/design/dpe.md §6.8)."""
    b, n_b = settings.bandwidth_chips, settings.n_noncoherent
    d = grid.offsets[None, :] - delay[:, None]
    R0 = tabulated_correlation(d, b)
    R1 = tabulated_correlation(d - echo_delay[:, None], b)
    spec = noise_spectrum(grid.step_m, grid.size, b)
    S = delay.size
    H = _path_gram(alpha, echo_phase, n_b)
    # E Σ_b|y_b|² = A²·RᵀHR + N_b·R_B(0) in either synthesis: the blocks' paths' Gram matrix and the noise's power
    signal = A[:, None] ** 2 * (R0 * R0 * H[:, 0, 0, None].real + 2.0 * R0 * R1 * H[:, 0, 1, None].real
                                + R1 * R1 * H[:, 1, 1, None].real)
    if rng is None:
        if settings.statistic != "pow":
            raise ValueError("correlators: the expected statistic has a closed form for statistic = 'pow' only")
        return signal + n_b * peak(b)
    if settings.synthesis == "exact":
        if tilt is not None:
            raise ValueError("correlators: a noise tilt needs synthesis = 'fast' (the exact synthesis draws every block)")
        theta = rng.uniform(0.0, 2.0 * np.pi, (S, n_b))
        c0 = np.exp(1j * theta)
        c1 = alpha[:, None] * np.exp(1j * (theta + echo_phase))
        out = np.empty((S, grid.size))
        # satellites a few at a time: y is (S, N_b, M) complex, 9 GB for 2000 channels at once. The noise
        # is drawn in satellite order, so the pieces' draws are the whole array's, bit for bit.
        step = max(1, _EXACT_BYTES // (16 * n_b * spec.amplitude.size * 8))
        for lo in range(0, S, step):
            k = slice(lo, lo + step)
            w = draw_noise(rng, spec, (min(S, lo + step) - lo, n_b))
            y = A[k, None, None] * (c0[k, :, None] * R0[k, None, :] + c1[k, :, None] * R1[k, None, :]) + w
            mag = np.abs(y)
            out[k] = (mag * mag).sum(axis=1) if settings.statistic == "pow" else mag.mean(axis=1)
        return out
    K = _sqrt_psd(H)
    U = draw_noise(rng, spec, (S, 2), None if tilt is None else (tilt.shift(K, spec), tilt.seen))
    V = np.einsum("smn,snj->smj", K, U)
    cross = 2.0 * A[:, None] * (R0 * V[:, 0] + R1 * V[:, 1]).real
    g = np.sqrt(2.0) * draw_noise(rng, noise_spectrum(grid.step_m, grid.size, b, squared=True), (S,)).real
    return signal + cross + n_b * peak(b) + np.sqrt(n_b) * g


def cn0_estimate(stat: NDArray, settings: CorrelatorSettings) -> NDArray:
    """The receiver's C/N0 (dB-Hz) from the correlogram peak (no truth): Â² from E[peak]."""
    R0 = peak(settings.bandwidth_chips)
    top = np.max(stat, axis=-1)
    if settings.statistic == "pow":
        a2 = (top / settings.n_noncoherent - R0) / (R0 * R0)
    else:  # E|y| ≈ √(A²R0² + R0) for a strong signal
        a2 = (top * top - R0) / (R0 * R0)
    return 10.0 * np.log10(np.maximum(a2, 1e-3) / settings.coherent_s)


def sis_sigma(elevation_rad: NDArray, settings: GnssSettings) -> NDArray:
    """σ_SIS of each satellite (m): σ_URA ⊕ the residual troposphere at its elevation (docs/design/dpe.md eq. 2.10)."""
    return np.hypot(settings.sigma_ura_m, sigma_tropo(elevation_rad, settings.sigma_tropo_zenith_m))


def synthesize_correlators(gnss: GnssEpochs, gnss_truth: GnssTruth, truth: Truth, settings: GnssSettings,
                           seed_words: NDArray, first_epoch: int = 0, sis_shift: NDArray | None = None,
                           noise_tilt=None, expected: bool = False) -> tuple[CorrelatorEpochs, CorrelatorTruth]:
    """Correlograms of every tracked satellite at ``gnss``'s epochs (one trial, unbatched).

    truth : at the same epochs (AGL height and climb rate for the ground echo).
    seed_words : the run's correlator seed words; ``first_epoch`` the index of ``gnss``'s first
        epoch in the flight (each epoch's generator is keyed by its index).
    sis_shift : (T, S) added to the standard-normal SIS draws before they are scaled by σ_SIS (an importance
        sampler's tilt, docs/design/dpe.md §6.8; None: the error model itself). Every other draw is unchanged.
    noise_tilt : None, or ``noise_tilt(i, k, A, delay, grid, echo_delay)`` giving epoch i's tilt of the thermal
        noise draws of its tracked slots k (see :func:`epoch_statistic`), or None for no tilt at that epoch.
    expected : each correlogram's expectation over the SIS and thermal draws instead of a draw (no SIS error;
        the signal with its echo and the noise's power): what the ground echo alone does to a solution.
    """
    if expected and (sis_shift is not None or noise_tilt is not None):
        raise ValueError("correlators: the expected correlograms have no draws to tilt")
    cs = settings.correlators
    grid = delay_grid(cs)
    T, S = np.shape(gnss.pseudorange)
    vis = np.asarray(gnss.visible, bool)
    rho_ref = np.where(vis, np.round(np.asarray(gnss.pseudorange) / grid.step_m) * grid.step_m, np.nan)
    el = np.asarray(gnss_truth.elevation, float)
    cn0 = cn0_at(el, cs)
    # a residual carrier frequency Δf turns the phasor by 2πΔf·T over a block: the coherent sum keeps |sinc(Δf·T)|
    A = np.sqrt(amplitude_sq(cn0, cs.coherent_s)) * abs(np.sinc(cs.residual_doppler_hz * cs.coherent_s))
    sig_sis = sis_sigma(el, settings)
    shift = np.zeros((T, S)) if sis_shift is None else np.asarray(sis_shift, float)
    fault = np.asarray(gnss_truth.fault_bias, float)
    clean = np.asarray(gnss_truth.geometric_range) + np.asarray(gnss_truth.clock_bias)[:, None] + fault
    sin_el = np.sin(np.maximum(el, 0.0))
    ground = cs.multipath == "ground"
    echo_delay = 2.0 * np.maximum(np.asarray(truth.agl, float), 0.0)[:, None] * sin_el if ground else np.zeros((T, S))
    echo_rate = 2.0 * np.asarray(truth.vel_enu, float)[:, 2, None] * sin_el
    alpha = np.full((T, S), 10.0 ** (cs.ground_echo_db / 20.0) if ground else 0.0)
    t_block = (np.arange(cs.n_noncoherent) + 0.5) * cs.coherent_s
    t_block = t_block - t_block.mean()
    stat = np.full((T, S, grid.size), np.nan, np.float32)
    sis = np.zeros((T, S))
    delay = np.full((T, S), np.nan)
    for i in range(T):
        g_sis, g_noise = (None, None) if expected else epoch_generator(seed_words, first_epoch + i).spawn(2)
        sis[i] = 0.0 if expected else sig_sis[i] * (g_sis.standard_normal(S) + shift[i])
        k = np.flatnonzero(vis[i])
        if not k.size:
            continue
        delay[i, k] = clean[i, k] + sis[i, k] - rho_ref[i, k]
        phase = (2.0 * np.pi * (echo_delay[i, k, None] + echo_rate[i, k, None] * t_block) / L1_WAVELENGTH_M + np.pi)
        tilt = None if noise_tilt is None else noise_tilt(i, k, A[i, k], delay[i, k], grid, echo_delay[i, k])
        stat[i, k] = epoch_statistic(g_noise, cs, grid, A[i, k], delay[i, k], echo_delay[i, k], alpha[i, k], phase,
                                     tilt)
    with np.errstate(invalid="ignore"):
        est = np.where(vis, cn0_estimate(np.nan_to_num(stat, nan=0.0), cs), np.nan)
    epochs = CorrelatorEpochs(t=np.asarray(gnss.t), prn=np.asarray(gnss.prn), sat_pos_ecef=np.asarray(gnss.sat_pos_ecef),
                              rho_ref=rho_ref, stat=stat, cn0_est_dbhz=est, visible=vis, delay0_m=grid.delay0_m,
                              delay_step_m=grid.step_m, coherent_s=cs.coherent_s, n_noncoherent=cs.n_noncoherent,
                              bandwidth_chips=cs.bandwidth_chips, stat_kind=cs.statistic, antenna=gnss.antenna)
    ctruth = CorrelatorTruth(delay_m=delay, sis_m=np.where(vis, sis, np.nan), fault_m=fault, cn0_dbhz=cn0,
                             echo_delay_m=echo_delay, echo_amplitude=alpha)
    return epochs, ctruth

"""Pseudoranges from the correlograms: what a receiver's code loop reports from the same signal the DPE sees.

``[gnss.correlators] pseudorange_source = "correlator"`` replaces the modelled
pseudoranges (seed eq. 27 draws) by the delay each channel's correlogram
puts its peak at: the grid maximum within ±1 chip of the channel's reference,
refined by the parabola through it and its two neighbours. For the power
statistic Σ_b|y_b(δ)|² this is the non-coherent maximum-likelihood delay (at
the noise levels of interest); ``tests/test_code_tracking.py`` measures its
spread against the Cramér-Rao bound and its interpolation bias (< 1 cm).

So GPS RAIM and the DPE read one signal: the same SIS error, the same code
fault, the same ground echo (whose bias reaches the pseudorange as a real
receiver's would), the same thermal noise.

The 1σ the monitor is told: σ² = σ_URA² + σ_tropo² (the SIS the correlators
draw) + σ_code² (the Cramér-Rao delay bound at the channel's *estimated*
C/N0 and N_b) + σ_MP² (the airborne multipath term of the VA-RAIM paper on one frequency:
the echo is in the signal, so it stays in the budget).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from testbed.correlation import CHIP_M, amplitude_sq, crb_delay_sigma
from testbed.records import CorrelatorEpochs, GnssEpochs, GnssTruth, NotVisible
from testbed.sensors.gnss.errors import sigma_multipath, sigma_tropo
from testbed.sensors.gnss.settings import GnssSettings


def peak_delays(corr: CorrelatorEpochs, search_m: float = CHIP_M) -> NDArray:
    """(T, S) delay (m, relative to ``rho_ref``) of each correlogram's peak within ±``search_m``; NaN where none."""
    stat = np.asarray(corr.stat, float)
    M = stat.shape[-1]
    offsets = corr.delay0_m + corr.delay_step_m * np.arange(M)
    inside = np.abs(offsets) <= search_m
    masked = np.where(inside, np.nan_to_num(stat, nan=-np.inf), -np.inf)
    j = np.clip(np.argmax(masked, axis=-1), 1, M - 2)
    take = lambda k: np.take_along_axis(stat, k[..., None], -1)[..., 0]  # noqa: E731
    p0, p1, p2 = take(j - 1), take(j), take(j + 1)
    curv = p0 - 2.0 * p1 + p2
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(curv < 0, 0.5 * (p0 - p2) / curv, 0.0)
    delay = offsets[j] + np.clip(frac, -0.5, 0.5) * corr.delay_step_m
    return np.where(np.asarray(corr.visible, bool) & np.isfinite(p1), delay, np.nan)


def code_sigma(corr: CorrelatorEpochs, elevation: NDArray, settings: GnssSettings) -> NDArray:
    """(T, S) the 1σ a monitor is told for a correlator pseudorange (see the module doc)."""
    a2 = amplitude_sq(np.asarray(corr.cn0_est_dbhz, float), corr.coherent_s)
    code = crb_delay_sigma(a2, corr.n_noncoherent, corr.bandwidth_chips)
    sis2 = settings.sigma_ura_m**2 + sigma_tropo(elevation, settings.sigma_tropo_zenith_m) ** 2
    return np.sqrt(sis2 + code**2 + sigma_multipath(elevation) ** 2)


def correlator_pseudoranges(gnss: GnssEpochs, gnss_truth: GnssTruth, corr: CorrelatorEpochs,
                            settings: GnssSettings) -> tuple[GnssEpochs, GnssTruth]:
    """``gnss`` (one trial) with its pseudoranges and sigmas taken from the correlograms ``corr``,
    and its truth with ``noise`` the error they carry (pseudorange − range − clock − fault).

    A channel whose correlogram has no peak inside the search window (or a NaN) is
    dropped (not visible); everything else (geometry, range rates) is kept.
    """
    elevation = np.asarray(gnss_truth.elevation, float)
    delay = peak_delays(corr)
    pr = np.asarray(corr.rho_ref, float) + delay
    sigma = code_sigma(corr, elevation, settings)
    ok = np.asarray(gnss.visible, bool) & np.isfinite(pr) & np.isfinite(sigma)
    lost = np.asarray(gnss.visible, bool) & ~ok
    pr = np.where(ok, pr, np.nan)
    noise = pr - np.asarray(gnss_truth.geometric_range) - np.asarray(gnss_truth.clock_bias)[..., None] - np.asarray(
        gnss_truth.fault_bias)
    return (replace(gnss, pseudorange=pr, sigma=np.where(ok, sigma, np.nan), visible=ok,
                    range_rate=np.where(ok, gnss.range_rate, np.nan),
                    reason=np.where(lost, NotVisible.NOT_OBSERVED, gnss.reason).astype(np.int8)),
            replace(gnss_truth, noise=np.where(ok, noise, 0.0)))

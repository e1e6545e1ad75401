"""GPS L1 C/A code correlation after a band-limited front end (docs/design/dpe.md §2.3): shared physics.

Both the correlator sensor (which synthesises correlograms) and the DPE monitor
(which interprets them) need the same correlation function and Cramér-Rao bound,
so they live here, below both.

With a brick-wall front end of one-sided bandwidth b chip rates, the replica
correlation of the filtered code, normalised so the infinite-bandwidth peak is 1, is

    R_B(x) = −½F(x) + ¼F(1 + x) + ¼F(1 − x),   x = delay / T_c,
    F(a) = (4|a|/π)·[Si(2π|a|b) − (1 − cos 2π|a|b)/(2π|a|b)],   F(0) = 0,

the closed form of ∫_{−b}^{b} sinc²(f)·e^{j2πfx} df (checked against quadrature in
tests/test_correlators.py); b → ∞ gives the triangle (1 − |x|)₊. The same R_B is the
noise covariance of the correlator outputs across delays (white noise shaped by |H|²).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import sici

from testbed.frames import C_LIGHT

CHIP_RATE_HZ = 1.023e6
#: one C/A chip in metres (293.05 m)
CHIP_M = C_LIGHT / CHIP_RATE_HZ
L1_WAVELENGTH_M = C_LIGHT / 1575.42e6


def _F(a: NDArray, b: float) -> NDArray:
    a = np.abs(a)
    x = 2.0 * np.pi * a * b
    with np.errstate(invalid="ignore", divide="ignore"):
        v = (4.0 * a / np.pi) * (sici(x)[0] - (1.0 - np.cos(x)) / x)
    return np.where(a == 0.0, 0.0, v)


def correlation(delay_m: ArrayLike, bandwidth_chips: float) -> NDArray:
    """R_B at code delays (m), one-sided bandwidth ``bandwidth_chips`` chip rates (inf: triangle)."""
    x = np.asarray(delay_m, float) / CHIP_M
    if np.isinf(bandwidth_chips):
        return np.maximum(1.0 - np.abs(x), 0.0)
    b = float(bandwidth_chips)
    return -0.5 * _F(x, b) + 0.25 * _F(1.0 + x, b) + 0.25 * _F(1.0 - x, b)


def peak(bandwidth_chips: float) -> float:
    """R_B(0): the fraction of the signal power a band-limited correlator keeps at the peak."""
    return float(correlation(0.0, bandwidth_chips))


def crb_delay_sigma(amplitude_sq: ArrayLike, n_blocks: int, bandwidth_chips: float) -> NDArray:
    """Cramér-Rao 1σ of one channel's code delay (m) from N_b blocks of A² = (C/N0)·T.

    σ_δ = T_c / √(8·A²·N_b·[b − sin(2πb)/(2π)])  (the mean-square bandwidth of the
    band-limited C/A spectrum; 45 dB-Hz, 20 ms, b = 1: 4.1 m for one block, 0.58 m for 50).
    """
    b = float(bandwidth_chips)
    gabor = b - np.sin(2.0 * np.pi * b) / (2.0 * np.pi)
    a2 = np.asarray(amplitude_sq, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return CHIP_M / np.sqrt(8.0 * a2 * n_blocks * gabor)


def amplitude_sq(cn0_dbhz: ArrayLike, coherent_s: float) -> NDArray:
    """A² = (C/N0)·T, the post-correlation signal-to-noise of one coherent block."""
    return 10.0 ** (np.asarray(cn0_dbhz, float) / 10.0) * coherent_s

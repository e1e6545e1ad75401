"""Atmospheric delay models for a single-frequency user, and the residual error the monitors are told.

* :func:`klobuchar_delay` — the GPS broadcast ionosphere (IS-GPS-200 §20.3.3.5.2.5,
  Figure 20-4), L1 delay in metres.
* :func:`klobuchar_sigma` — the residual 1σ of that correction (RTCA DO-229
  Appendix J.2.3: σ² = max((T_iono/5)², (F·τ_vert)²), τ_vert 9 / 4.5 / 6 m by
  geomagnetic latitude of the pierce point).
* :func:`saastamoinen_delay` — Saastamoinen's zenith hydrostatic + wet delay
  with a standard atmosphere at the receiver height (1013.25 hPa, 15 °C and 70 %
  relative humidity at sea level, lapse −6.5 K/km), mapped by 1/cos z. The
  same model RTKLIB applies with ``tropopt=saas``: ``tests/test_rinex.py`` (test_real_receiver_file_agrees_with_rtklib)
  compares the two.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.frames import C_LIGHT

_SEMI = np.pi  # rad per semicircle


def _pierce_point(lat: NDArray, lon: NDArray, el: NDArray, az: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Semicircle quantities of the ionospheric pierce point: (E, φ_i, λ_i, φ_m) — IS-GPS-200 Figure 20-4."""
    E = el / _SEMI
    psi = 0.0137 / (E + 0.11) - 0.022
    phi_i = np.clip(lat / _SEMI + psi * np.cos(az), -0.416, 0.416)
    lam_i = lon / _SEMI + psi * np.sin(az) / np.cos(phi_i * _SEMI)
    phi_m = phi_i + 0.064 * np.cos((lam_i - 1.617) * _SEMI)
    return E, phi_i, lam_i, phi_m


def klobuchar_delay(alpha: ArrayLike, beta: ArrayLike, lat: ArrayLike, lon: ArrayLike, el: ArrayLike,
                    az: ArrayLike, tow_s: ArrayLike) -> NDArray:
    """Broadcast-model L1 ionospheric delay (m). Angles in rad (geodetic lat/lon of the user), any broadcastable shape."""
    a, b = np.asarray(alpha, float), np.asarray(beta, float)
    E, _, lam_i, phi_m = _pierce_point(*(np.asarray(x, float) for x in (lat, lon, el, az)))
    t = np.mod(4.32e4 * lam_i + np.asarray(tow_s, float), 86400.0)
    F = 1.0 + 16.0 * (0.53 - E) ** 3
    amp = np.maximum(a[0] + phi_m * (a[1] + phi_m * (a[2] + phi_m * a[3])), 0.0)
    per = np.maximum(b[0] + phi_m * (b[1] + phi_m * (b[2] + phi_m * b[3])), 72000.0)
    x = 2.0 * np.pi * (t - 50400.0) / per
    day = np.abs(x) < 1.57
    T = F * (5e-9 + np.where(day, amp * (1.0 - x * x / 2.0 + x**4 / 24.0), 0.0))
    return C_LIGHT * T


def klobuchar_sigma(lat: ArrayLike, lon: ArrayLike, el: ArrayLike, az: ArrayLike, delay_m: ArrayLike) -> NDArray:
    """Residual 1σ (m) of the broadcast correction, DO-229 J.2.3."""
    E, _, _, phi_m = _pierce_point(*(np.asarray(x, float) for x in (lat, lon, el, az)))
    F = 1.0 + 16.0 * (0.53 - E) ** 3
    deg = np.abs(phi_m) * 180.0
    tau_vert = np.where(deg <= 20.0, 9.0, np.where(deg <= 55.0, 4.5, 6.0))
    return np.sqrt(np.maximum((np.asarray(delay_m, float) / 5.0) ** 2, (F * tau_vert) ** 2))


def saastamoinen_delay(lat: ArrayLike, h: ArrayLike, el: ArrayLike, humidity: float = 0.7) -> NDArray:
    """Tropospheric delay (m) by Saastamoinen's model and a standard atmosphere; 0 below the horizon
    and outside heights −100 m .. 10 km (where the standard atmosphere is not meant to hold)."""
    lat, h, el = (np.asarray(x, float) for x in (lat, h, el))
    hgt = np.clip(h, 0.0, None)
    pres = 1013.25 * (1.0 - 2.2557e-5 * hgt) ** 5.2568
    temp = 15.0 - 6.5e-3 * hgt + 273.16
    e = 6.108 * humidity * np.exp((17.15 * temp - 4684.0) / (temp - 38.45))
    cos_z = np.cos(np.pi / 2 - el)
    with np.errstate(divide="ignore", invalid="ignore"):
        dry = 0.0022768 * pres / (1.0 - 0.00266 * np.cos(2.0 * lat) - 0.00028 * hgt / 1e3) / cos_z
        wet = 0.002277 * (1255.0 / temp + 0.05) * e / cos_z
    ok = (el > 0) & (h >= -100.0) & (h <= 1e4)
    return np.where(ok, dry + wet, 0.0)

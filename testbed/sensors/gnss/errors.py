"""GNSS pseudorange error model (docs/design/integrity.md §1; the VA-RAIM paper, eq. 27) and receiver clock.

σᵢ² = σ_URA² + σ_tropo,i² + σ_user,i² with the airborne dual-frequency
(L1/L5 iono-free) user term. Time correlation, when asked for, uses
first-order Gauss-Markov processes whose stationary variance is exactly the
model's, so the marginal distribution of every error stays N(0, σᵢ²).

The DFMC model (docs/design/gnss.md §3) splits the signal-in-space term per
constellation: the monitors are told C_int = σ_URA² + σ_tropo² + σ_user², the
error drawn has C_acc = σ_URE² + σ_tropo² + σ_user² (:func:`range_sigmas`).
"""

from __future__ import annotations

from typing import Literal, get_args

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import lfilter

F_L1 = 1575.42e6  # Hz
F_L5 = 1176.45e6  # Hz
F_L2 = 1227.60e6  # Hz
#: σ-multiplier of the iono-free L1/L5 combination: sqrt(f1⁴ + f5⁴) / (f1² − f5²) ≈ 2.59.
IONO_FREE_FACTOR = float(np.sqrt(F_L1**4 + F_L5**4) / (F_L1**2 - F_L5**2))
SIGMA_URA_M = 0.75
#: The airborne multipath + noise curves (:func:`user_error_components`): the one list the GNSS settings and
#: the ARAIM monitor's settings both name.
UserErrorModel = Literal["wgc_m3", "add_v31", "maast2_dfmc"]
USER_ERROR_MODELS: tuple[str, ...] = get_args(UserErrorModel)
#: The two carriers of each system's iono-free pair (Hz): L1/L5, E1/E5a, B1C/B2a (the same frequencies).
IONO_FREE_CARRIERS = {"G": (F_L1, F_L5), "E": (1575.42e6, 1176.45e6), "C": (1575.42e6, 1176.45e6)}


def iono_free_variance_factor(f1: float, f2: float) -> float:
    """γ: the variance multiplier of the iono-free combination (f1²ρ1 − f2²ρ2)/(f1² − f2²) for independent
    equal-variance code errors on the two carriers, (f1⁴ + f2⁴)/(f1² − f2²)² (6.6995 for L1/L5)."""
    return (f1**4 + f2**4) / (f1**2 - f2**2) ** 2


def sigma_tropo(elevation: ArrayLike, zenith_m: float = 0.12) -> NDArray:
    """Residual troposphere 1σ (m): 0.12·1.001/sqrt(0.002001 + sin²θ), θ elevation (rad)."""
    s = np.sin(np.asarray(elevation, float))
    return zenith_m * 1.001 / np.sqrt(0.002001 + s * s)


def sigma_multipath(elevation: ArrayLike) -> NDArray:
    """Airborne multipath 1σ on one frequency (m): 0.13 + 0.53·exp(−θ/10°)."""
    return 0.13 + 0.53 * np.exp(-np.degrees(np.asarray(elevation, float)) / 10.0)


def sigma_noise(elevation: ArrayLike) -> NDArray:
    """Receiver noise 1σ on one frequency (m): 0.15 + 0.43·exp(−θ/6.9°)."""
    return 0.15 + 0.43 * np.exp(-np.degrees(np.asarray(elevation, float)) / 6.9)


def sigma_user(elevation: ArrayLike) -> NDArray:
    """Iono-free user 1σ (m): sqrt(σ_MP² + σ_noise²) · IONO_FREE_FACTOR."""
    return np.hypot(sigma_multipath(elevation), sigma_noise(elevation)) * IONO_FREE_FACTOR


def user_error_components(elevation: ArrayLike, model: str = "wgc_m3") -> tuple[NDArray, NDArray]:
    """Iono-free airborne multipath and noise 1σ (m) of a named curve; σ_user = hypot of the two.

    ``wgc_m3``: γ^½·(0.13 + 0.53e^(−θ/10°)) and γ^½·(0.15 + 0.43e^(−θ/6.9°)) (eq. 27's, :func:`sigma_user`);
    ``add_v31``: the same multipath, noise γ^½·(0.11 + 0.13e^(−θ/6.9°)); ``maast2_dfmc``: multipath
    0.34 + 0.40e^(−θ/14°) and noise √(0.4² + (40/(261 + θ²) + 0.018)²), θ in degrees, both already at
    iono-free level (docs/design/gnss.md §3 gives the sources).
    """
    el = np.asarray(elevation, float)
    deg = np.degrees(el)
    if model == "wgc_m3":
        return IONO_FREE_FACTOR * sigma_multipath(el), IONO_FREE_FACTOR * sigma_noise(el)
    if model == "add_v31":
        return IONO_FREE_FACTOR * sigma_multipath(el), IONO_FREE_FACTOR * (0.11 + 0.13 * np.exp(-deg / 6.9))
    if model == "maast2_dfmc":
        return 0.34 + 0.40 * np.exp(-deg / 14.0), np.hypot(0.4, 40.0 / (261.0 + deg * deg) + 0.018)
    raise ValueError(f"user_error: expected one of {', '.join(map(repr, USER_ERROR_MODELS))}, got {model!r}")


def range_sigmas(elevation: ArrayLike, system: ArrayLike, settings) -> tuple[NDArray, NDArray, NDArray]:
    """Per (epoch, slot): the 1σ the monitors are told, the 1σ of the error drawn, and b_nom (m).

    ``elevation`` (..., S) rad, ``system`` (S,) letters, ``settings`` a GnssSettings. 'seed': eq. 27 with
    ``settings.sigma_ura_m`` for every system, told = drawn, b_nom 0. 'dfmc': each constellation's σ_URA
    (told), σ_URE (drawn) and b_nom with σ_tropo and the ``user_error`` curve.
    """
    el = np.asarray(elevation, float)
    if settings.error_model == "seed":
        sigma = sigma_pseudorange(el, settings.sigma_ura_m, settings.sigma_tropo_zenith_m)
        return sigma, sigma, np.zeros(el.shape)
    system = np.asarray(system)
    ura, ure, b_nom = (np.array([getattr(settings.constellation(str(c)), f) for c in system], float)
                       for f in ("sigma_ura_m", "sigma_ure_m", "b_nom_m"))
    common = sigma_tropo(el, settings.sigma_tropo_zenith_m) ** 2 + sigma_air_user(el, settings.user_error) ** 2
    return np.sqrt(ura**2 + common), np.sqrt(ure**2 + common), np.broadcast_to(b_nom, el.shape)


def sigma_air_user(elevation: ArrayLike, model: str = "wgc_m3") -> NDArray:
    """σ_user (m) of a named curve (:func:`user_error_components`)."""
    return np.hypot(*user_error_components(elevation, model))


def sigma_pseudorange(elevation: ArrayLike, sigma_ura_m: float = SIGMA_URA_M,
                      tropo_zenith_m: float = 0.12) -> NDArray:
    """Total pseudorange 1σ (m) at elevations (rad), any shape (the VA-RAIM paper, eq. 27)."""
    return np.sqrt(sigma_ura_m**2 + sigma_tropo(elevation, tropo_zenith_m)**2 + sigma_user(elevation)**2)


def unit_gauss_markov(rng: np.random.Generator, shape: tuple[int, ...], dt: float, tau_s: float | None,
                      axis: int = -2) -> NDArray:
    """Stationary unit-variance first-order Gauss-Markov samples along ``axis``.

    u_k = a·u_{k−1} + sqrt(1 − a²)·w_k, a = exp(−dt/τ), u_0 ~ N(0, 1), so
    corr(u_k, u_{k+m}) = exp(−m·dt/τ). ``tau_s`` None gives white N(0, 1).
    Runs the recursion in C (scipy.signal.lfilter), not a Python loop.
    """
    w = rng.standard_normal(shape)
    if tau_s is None:
        return w
    a = float(np.exp(-dt / tau_s))
    b = np.sqrt(1.0 - a * a)
    if b == 0.0:  # τ ≫ dt beyond float resolution: a constant per series
        return np.take(w, [0], axis=axis).repeat(shape[axis], axis=axis)
    w = np.moveaxis(w, axis, -1)
    w[..., 0] /= b  # so that u_0 = w_0 ~ N(0,1): stationary start
    u = lfilter([b], [1.0, -a], w, axis=-1)
    return np.moveaxis(u, -1, axis)


def receiver_clock(rng: np.random.Generator, t: ArrayLike, batch: tuple[int, ...] = (), *,
                   bias0_sigma_m: float, drift0_sigma_m_s: float, sf_m2_s: float,
                   sg_m2_s3: float) -> tuple[NDArray, NDArray]:
    """Two-state receiver clock (bias b, drift d in m, m/s), the GNSS/vision/INS paper, eq. 16
    (docs/design/integrity.md §1, eq. 1.7).

    x(k+1) = [[1, Δt], [0, 1]] x(k) + η(k), with the discretised white-FM /
    random-walk-FM noise Q = [[S_f Δt + S_g Δt³/3, S_g Δt²/2], [S_g Δt²/2, S_g Δt]]
    (Brown & Hwang). x(0) ~ N(0, diag(σ_b0², σ_d0²)).

    Returns
    -------
    bias : (*batch, T) m.   drift : (*batch, T) m/s.
    """
    t = np.asarray(t, float)
    T = t.size
    dt = np.diff(t)  # (T-1,)
    z = rng.standard_normal(batch + (T, 2))
    q11 = sf_m2_s * dt + sg_m2_s3 * dt**3 / 3.0
    q12 = sg_m2_s3 * dt**2 / 2.0
    q22 = sg_m2_s3 * dt
    # 2x2 Cholesky per step, written out (vectorised over steps).
    l11 = np.sqrt(q11)
    l21 = np.divide(q12, l11, out=np.zeros_like(q12), where=l11 > 0)
    l22 = np.sqrt(np.maximum(q22 - l21**2, 0.0))
    eta_b = l11 * z[..., 1:, 0]
    eta_d = l21 * z[..., 1:, 0] + l22 * z[..., 1:, 1]
    d0 = drift0_sigma_m_s * z[..., 0, 1]
    b0 = bias0_sigma_m * z[..., 0, 0]
    drift = np.concatenate([d0[..., None], d0[..., None] + np.cumsum(eta_d, axis=-1)], axis=-1)
    bias = np.concatenate([b0[..., None],
                           b0[..., None] + np.cumsum(drift[..., :-1] * dt + eta_b, axis=-1)], axis=-1)
    return bias, drift

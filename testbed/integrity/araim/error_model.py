"""ARAIM ranging error model: the integrity and accuracy variances of each row (docs/design/araim.md §2).

    C_int,i = σ²_URA + σ²_tropo,i + σ²_user,i      (eq. 1, integrity: the weights)
    C_acc,i = σ²_URE + σ²_tropo,i + σ²_user,i      (accuracy and continuity: never weights)

σ_tropo and the default σ_user are the GPS error model's (:mod:`testbed.sensors.gnss.errors`); the other
σ_user curves are selectable by name. Every function takes elevations of any shape ``(...)`` in radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.integrity.araim.settings import AraimSettings
from testbed.sensors.gnss import errors


def sigma_user(elevation: ArrayLike, model: str = "wgc_m3") -> NDArray:
    """Airborne iono-free multipath + noise 1σ (m) at elevations (rad), shape ``(...)``.

    ``wgc_m3``: √(σ²_MP + σ²_noise)·γ^½ with σ_noise = 0.15 + 0.43e^(−θ/6.9°) (eq. 2; the testbed's GPS model).
    ``add_v31``: the same with σ_noise = 0.11 + 0.13e^(−θ/6.9°) (eq. 3), the curve that reproduces the C_int of
    the ADD v3.1 Appendix D example. ``maast2_dfmc``: √(0.4² + (0.34 + 0.40e^(−θ/14°))² + (40/(261 + θ²) +
    0.018)²), θ in degrees, already at iono-free level (eq. 4).
    """
    el = np.asarray(elevation, float)
    if model == "wgc_m3":
        return errors.sigma_user(el)
    deg = np.degrees(el)
    if model == "add_v31":
        noise = 0.11 + 0.13 * np.exp(-deg / 6.9)
        return np.hypot(errors.sigma_multipath(el), noise) * errors.IONO_FREE_FACTOR
    if model == "maast2_dfmc":
        mp = 0.34 + 0.40 * np.exp(-deg / 14.0)
        tail = 40.0 / (261.0 + deg * deg) + 0.018
        return np.sqrt(0.4**2 + mp * mp + tail * tail)
    raise ValueError(f"sigma_user model: expected one of ('wgc_m3', 'add_v31', 'maast2_dfmc'), got {model!r}")


def row_variances(elevation: ArrayLike, constellation: ArrayLike, settings: AraimSettings
                  ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """C_int, C_acc (m²), b_nom, b_cont (m) of each row from its elevation and system (eq. 1).

    Parameters
    ----------
    elevation : (..., N) rad.  constellation : (..., N) int, system codes (index into ``SYSTEMS``).

    Returns
    -------
    c_int, c_acc, b_nom, b_cont : (..., N).
    """
    el = np.asarray(elevation, float)
    system = np.broadcast_to(np.asarray(constellation), el.shape)
    common = errors.sigma_tropo(el, settings.tropo_zenith_m) ** 2 + sigma_user(el, settings.user_error) ** 2
    ura2, ure2, b_nom, b_cont = (np.zeros(el.shape) for _ in range(4))
    for code in np.unique(system):
        ism = settings.system_ism(int(code))
        rows = system == code
        ura2[rows], ure2[rows] = ism.sigma_ura_m**2, ism.sigma_ure_m**2
        b_nom[rows], b_cont[rows] = ism.b_nom_m, ism.b_cont_m
    return ura2 + common, ure2 + common, b_nom, b_cont

"""ARAIM ranging error model: the integrity and accuracy variances of each row (docs/design/araim.md §2).

    C_int,i = σ²_URA + σ²_tropo,i + σ²_user,i      (eq. 1, integrity: the weights)
    C_acc,i = σ²_URE + σ²_tropo,i + σ²_user,i      (accuracy and continuity: never weights)

σ_tropo and every σ_user curve are the GNSS sensor's (:mod:`testbed.sensors.gnss.errors`), so the variances
ARAIM assumes are, term by term, those the DFMC error model tells the monitors (C_int) and draws (C_acc) when
the ISM matches the receiver's settings. Every function takes elevations of any shape ``(...)`` in radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.integrity.araim.settings import AraimSettings
from testbed.sensors.gnss import errors


def sigma_user(elevation: ArrayLike, model: str = "wgc_m3") -> NDArray:
    """Airborne iono-free multipath + noise 1σ (m) at elevations (rad), shape ``(...)``: the sensor's curve
    ``model`` (:func:`testbed.sensors.gnss.errors.user_error_components`; eq. 2-4)."""
    return errors.sigma_air_user(elevation, model)


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

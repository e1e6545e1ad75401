"""Aviation service levels and the integrity constants of the monitors.

Figures from the VA-RAIM paper's Table 1 ("The performance requirements for aviation",
after ICAO Annex 10 / RTCA DO-229): alert limits, 95% accuracy and time to
alert of the three approach operations the testbed evaluates against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class ServiceLevel:
    """One approach operation's requirements (the VA-RAIM paper's Table 1).

    name : e.g. "LPV-200".  hal, val : m, horizontal/vertical alert limits.
    ha95, va95 : m, 95% horizontal/vertical accuracy.  tta : s, time to alert.
    """

    name: str
    hal: float
    val: float
    ha95: float
    va95: float
    tta: float


APV_I = ServiceLevel("APV-I", hal=40.0, val=50.0, ha95=16.0, va95=20.0, tta=10.0)
LPV_200 = ServiceLevel("LPV-200", hal=40.0, val=35.0, ha95=16.0, va95=4.0, tta=6.2)
APV_II = ServiceLevel("APV-II", hal=40.0, val=20.0, ha95=16.0, va95=8.0, tta=6.0)

#: All levels the testbed knows, by name, in Table 1 order.
SERVICE_LEVELS: dict[str, ServiceLevel] = {s.name: s for s in (APV_I, LPV_200, APV_II)}

#: Defaults (docs/design/integrity.md §3; the VA-RAIM paper states no values).
DEFAULT_P_FA = 1e-5
DEFAULT_P_MD = 1e-3


def service_level(name: str) -> ServiceLevel:
    """Look up a level by name ("APV-I", "LPV-200", "APV-II")."""
    try:
        return SERVICE_LEVELS[name]
    except KeyError:
        raise ValueError(f"service level: expected one of {list(SERVICE_LEVELS)}, got {name!r}") from None


def strictest_limits(names) -> tuple[float, float]:
    """(HAL, VAL) of the most demanding of the service levels ``names``: the smallest of each, which the plots
    draw and the campaign tables judge hazardous errors against."""
    levels = [service_level(n) for n in names]
    return min(lv.hal for lv in levels), min(lv.val for lv in levels)


def availability(hpl: ArrayLike, vpl: ArrayLike, levels: tuple[ServiceLevel, ...] | list[ServiceLevel],
                 ok: ArrayLike | None = None) -> NDArray:
    """Per-level availability ``HPL ≤ HAL and VPL ≤ VAL`` (and the epoch usable).

    Parameters
    ----------
    hpl, vpl : (...) m, NaN where no protection level (-> unavailable).
    levels : K service levels.
    ok : (...) bool, extra condition (e.g. reason == ok); default all True.

    Returns
    -------
    (..., K) bool.
    """
    hpl = np.asarray(hpl, float)
    vpl = np.asarray(vpl, float)
    hal = np.array([s.hal for s in levels])
    val = np.array([s.val for s in levels])
    # NaN comparisons are False: an epoch without a PL is never available
    av = (hpl[..., None] <= hal) & (vpl[..., None] <= val)
    if ok is not None:
        av &= np.asarray(ok, bool)[..., None]
    return av

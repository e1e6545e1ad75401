"""The monitors that stay GPS-only read GPS satellites only, explicitly (docs/design/gnss.md §5).

VA-RAIM, the pixel-domain monitor, the navigation filter and DPE were written, and their
error models and clock states sized, for one constellation. With several constellations
tracked, :func:`gps_satellites` hands them the same observations with every other
system's satellites marked not visible (EXCLUDED, no range): they never mix systems
silently, and their outputs say how many satellites they used (``n_used``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from testbed.integrity.monitor import Observations
from testbed.records import GnssEpochs, NotVisible

#: The monitors that call :func:`gps_satellites` first (their summaries say "GPS only").
GPS_ONLY_MONITORS = frozenset({"va_raim", "pixel", "ekf", "dpe"})


def gps_satellites(obs: Observations) -> Observations:
    """``obs`` with only the GPS satellites in view (unchanged, the same object, when GPS is all there is)."""
    g = obs.gnss
    other = np.asarray(g.system) != "G"
    if not other.any():
        return obs
    return replace(obs, gnss=only_gps(g, other))


def only_gps(g: GnssEpochs, other: np.ndarray) -> GnssEpochs:
    """``g`` with the slots ``other`` (S,) out of view (EXCLUDED) and without ranges."""
    vis = np.asarray(g.visible, bool) & ~other
    return replace(g, visible=vis, pseudorange=np.where(other, np.nan, g.pseudorange),
                   range_rate=np.where(other, np.nan, g.range_rate), sigma=np.where(other, np.nan, g.sigma),
                   reason=np.where(other & (np.asarray(g.reason) == 0), np.int8(NotVisible.EXCLUDED),
                                   g.reason).astype(np.int8))

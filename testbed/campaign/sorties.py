"""When each sortie of a campaign flies, and which computed sky it shares (``[sorties]``).

Pure functions of the spec and the trial index (so a trial is the same whatever the
chunking or the workers): :func:`sortie_offsets` gives each trial's start offset after
the approach's start time, :func:`sky_windows` the window of the sky's repeat period whose
geometry it uses, :func:`window_offsets` the start offset at which that window's geometry is computed.
See :class:`~testbed.campaign.spec.SortieStarts` for the model and its error bound.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.campaign.spec import SKY_REPEAT_S, CampaignSpec

#: First spawn-key entry of the uniform start-time draws: no draw block of a cell
#: (spawn key (cell, block) or (block,)) can share it.
_START_KEY = 2**31 - 1


def sortie_length_s(spec: CampaignSpec) -> float | None:
    """The sortie spacing/length of the spec (``sorties.sortie_s``, else ``duration_s``)."""
    so = spec.sorties
    return so.sortie_s if so.sortie_s is not None else spec.duration_s


def sortie_offsets(spec: CampaignSpec, trials: ArrayLike) -> NDArray:
    """Start offset (s after the approach's start time) of each trial (n,)."""
    k = np.asarray(trials, np.int64)
    so = spec.sorties
    if so.start == "fixed":
        return np.zeros(k.shape)
    length = float(sortie_length_s(spec))
    if so.start == "consecutive":
        return k * length
    out = np.empty(k.shape)
    hi = float(so.span_s) - length
    blocks = k // spec.block_trials
    for b in np.unique(blocks):  # one generator per draw block: a trial's start depends on its index only
        u = np.random.default_rng(np.random.SeedSequence(spec.base_seed, spawn_key=(_START_KEY, int(b)))).random(
            spec.block_trials)
        sel = blocks == b
        out[sel] = hi * u[k[sel] % spec.block_trials]
    return out


#: Sky repeat periods (s) of the constellation sets other than GPS alone (:data:`SKY_REPEAT_S`): the nominal
#: Galileo slots come back over the same ground after 17 revolutions in 10 sidereal days (best repeat
#: 861 575 s, measured with :func:`~testbed.sensors.gnss.constellations.repeat_period`: 1.3 m), the BeiDou-3
#: MEO after 13 in 7 (603 116 s: the two-body nominal orbit is 32 s short of 7 sidereal days; its IGSO and
#: GEO repeat daily), the three together after 70 sidereal days (7 Galileo periods, 6 031 025 s).
#: docs/design/gnss.md §6 gives how far each system's sky is then from its repeat.
GALILEO_REPEAT_S = 861_575.0
BEIDOU_REPEAT_S = 603_116.0
ALL_REPEAT_S = 6_031_025.0


def sky_repeat_s(constellations=("gps",)) -> float:
    """The period after which the sky of ``constellations`` repeats (what a sky window is reduced modulo)."""
    with_e, with_c = "galileo" in constellations, "beidou" in constellations
    if with_e and with_c:
        return ALL_REPEAT_S
    if with_e:
        return GALILEO_REPEAT_S
    if with_c:
        return BEIDOU_REPEAT_S
    return SKY_REPEAT_S


def n_windows(window_s: float, repeat_s: float = SKY_REPEAT_S) -> int:
    """Windows of one repeat period (the last may be up to ``window_s / 2`` shorter or longer)."""
    return max(1, int(round(repeat_s / window_s)))


def sky_windows(offsets_s: ArrayLike, window_s: float, repeat_s: float = SKY_REPEAT_S) -> NDArray:
    """The sky window (n,) int of start offsets: ``round((offset mod repeat_s) / window_s)``; ``repeat_s``
    the sky's repeat period (:func:`sky_repeat_s`; default GPS's)."""
    phase = np.mod(np.asarray(offsets_s, float), repeat_s)
    return np.mod(np.rint(phase / window_s).astype(np.int64), n_windows(window_s, repeat_s))


def window_offsets(windows: ArrayLike, window_s: float) -> NDArray:
    """Start offset (s) at which a window's geometry is computed."""
    return np.asarray(windows, np.int64) * float(window_s)

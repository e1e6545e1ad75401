"""Per-epoch random streams: the one mechanism that makes a sensor's draws independent of how the
flight is cut into blocks.

Epoch k's draws come from its own generator, ``SeedSequence(words, spawn_key=(k,))``: the first k epochs
never depend on later ones, and a block starting at epoch k0 draws exactly what one pass over the whole
flight draws there.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def epoch_generator(seed_words: NDArray, epoch: int) -> np.random.Generator:
    """The generator of epoch ``epoch`` (its index in the flight) of the stream ``seed_words``."""
    return np.random.default_rng(np.random.SeedSequence(seed_words, spawn_key=(int(epoch),)))

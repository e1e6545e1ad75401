"""The named stream tree: where every random draw of a run or of a campaign block comes from.

A run (one flight in the loop) and a campaign's draw block (its trials, drawn in one batch) each own one
root ``SeedSequence``; every sensor component draws from its own named child of that root, never from a
positional ``spawn`` whose order could shift when a component is added. Child ``name`` of the root
``(entropy, key)`` is ``SeedSequence(entropy, spawn_key=key + (index,))``, with ``index`` its place in
:data:`STREAMS`: new components are appended, so the existing ones keep their numbers.

The loop's root is ``SeedSequence(seed)``; a campaign block's is ``SeedSequence(base_seed,
spawn_key=(cell, block))`` (``(block,)`` with common random numbers). A flight flown with the tree of a
one-trial campaign's block therefore draws exactly what that trial draws (``tests/test_pipeline.py``).

Each call returns a fresh generator or word set: ``Generator.spawn`` advances the ``SeedSequence`` it came
from, so a generator made once and drawn from again after every block of the loop would give other numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The named children of a stream tree, in the order of their spawn-key index (append only).
STREAMS = (
    "gnss",  # pseudorange noise, receiver clock, range-rate noise, GNSS fault targets
    "vision",  # camera dithering, attitude reference, detection noise, vision fault targets
    "survey",  # the landmark survey errors (one survey per tree: a flight, or a campaign block)
    "correlators",  # the correlograms' noise, one grandchild per trial
    "imu",  # IMU turn-on biases, in-run instabilities, white noise
    "alignment",  # the inertial filter's initial error
    "features",  # the ground-feature tracker's noise
    "sampling",  # an importance-sampling campaign's choice of proposal component per trial
)


@dataclass(frozen=True)
class StreamTree:
    """The root of one run's or one block's random streams (module doc)."""

    entropy: int | tuple[int, ...]
    key: tuple[int, ...] = ()

    @classmethod
    def of_run(cls, seed: int) -> "StreamTree":
        """The tree of a flight flown with ``seed``."""
        return cls(int(seed))

    @classmethod
    def of_block(cls, base_seed: int, cell: int, block: int, common: bool) -> "StreamTree":
        """The tree of a campaign's draw block: keyed by the block alone with common random numbers (every cell
        of a sweep draws the same numbers), else by cell and block."""
        return cls(int(base_seed), (int(block),) if common else (int(cell), int(block)))

    def seed(self, name: str, *sub: int) -> np.random.SeedSequence:
        """A fresh ``SeedSequence`` of child ``name`` (``sub``: a grandchild, e.g. a trial's correlators)."""
        return np.random.SeedSequence(self.entropy, spawn_key=self.key + (STREAMS.index(name),)
                                      + tuple(int(s) for s in sub))

    def generator(self, name: str, *sub: int) -> np.random.Generator:
        """A fresh generator of child ``name``."""
        return np.random.default_rng(self.seed(name, *sub))

    def words(self, name: str, *sub: int) -> np.ndarray:
        """Seed words of child ``name``: for the components drawn per epoch (:mod:`testbed.sensors.streams`)."""
        return self.seed(name, *sub).generate_state(4)

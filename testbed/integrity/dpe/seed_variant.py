"""The DPE paper's method as written (docs/design/dpe.md §4.2, variant `seed`), kept for reproduction.

* grid: PyGNSS ``generate_spread_grid`` — per axis {0, ±1..±7, ±10, ±13, ±16, ±19, ±22} steps of
  5 m (E, N, U: ±110 m) and 6 m (clock: ±132 m), 25⁴ = 390 625 candidates about the initialisation;
* statistic: M(ξ) = Σ_k f_k, f_k = ((1/N_b)·Σ_b|y_kb|)^p, p = 1, looked up linearly;
* solution: the M-weighted mean of all candidates, the grid recentred on it, ``passes`` times
  (mean shift; 50 in the seed's receiver);
* slice: the conditional line M(Ê, N̂, Û + u, b̂) at the grid's U offsets, read as a CDF by the
  seed's literal ``sum`` of values (or ``density``), then the same overbound as the default.

What running it shows (docs/design/dpe.md F1, F2; reproduced by ``tests/test_dpe_seed.py``): on this grid the weighted
mean barely leaves the initialisation (a correlation triangle is ≥ 293 m wide in height, the grid
±110 m, so the weights are nearly flat: F1), and σ_ob is set by the grid's extent, not by the
signal (F2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.integrity.dpe.manifold import EpochManifold
from testbed.integrity.kernels.dpe import manifold_product, weighted_mean_product

_STEPS = np.array([0, 1, 2, 3, 4, 5, 6, 7, 10, 13, 16, 19, 22], float)
#: the spread grid's offsets per axis in steps (25 values)
SPREAD_STEPS = np.concatenate([-_STEPS[:0:-1], _STEPS])
SPREAD_M = np.array([5.0, 5.0, 5.0, 6.0])  # E, N, U, clock


@dataclass(frozen=True)
class SeedSolution:
    """x_mean (4,) offsets of the solution from the initialisation; slice_u (25,) the U offsets and
    slice_values (25,) M there; used (S,) satellites kept (all: the seed drops none)."""

    x_mean: NDArray
    slice_u: NDArray
    slice_values: NDArray
    used: NDArray


def spread_axes() -> list[NDArray]:
    return [np.ascontiguousarray(SPREAD_STEPS * s) for s in SPREAD_M]


def solve_epoch_seed(mf: EpochManifold, passes: int = 50, power: float = 1.0) -> SeedSolution:
    """The seed's DPE of one epoch (module doc), offsets from the initialisation (ξ = 0)."""
    poly = mf.poly if power == 1.0 else EpochManifold(mf.delta0, mf.g, mf.table ** power, mf.floor ** power,
                                                     mf.delay0_m, mf.step_m).poly
    floor = mf.floor ** power
    axes = spread_axes()
    out = np.empty(25 ** 4)
    centre = np.zeros(4)
    for _ in range(passes):
        c, H = mf.index_units(centre, np.eye(4))
        manifold_product(c, H, poly, floor, *axes, False, out)
        centre = centre + weighted_mean_product(out, *axes)
    c, H = mf.index_units(centre, np.eye(4))
    zero = np.zeros(1)
    line = np.empty(axes[2].size)
    manifold_product(c, H, poly, floor, zero, zero, axes[2], zero, False, line)
    return SeedSolution(x_mean=centre, slice_u=axes[2].copy(), slice_values=line, used=np.ones(mf.g.shape[0], bool))

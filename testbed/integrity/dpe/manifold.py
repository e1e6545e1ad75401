"""The DPE likelihood manifold of one epoch: geometry, correlogram lookups, grids (docs/design/dpe.md §3).

A candidate ξ = [dE, dN, dU, db] (m) offsets the grid centre (position p_c, clock b_c).
Satellite k expects its code at δ_k(ξ) = ‖s_k − p_c − dp‖ + b_c + db − ρ_ref,k ≈ δ_k(0) + g_kᵀξ,
g_k = [−e_kᵀ, 1] (linearisation error ≤ |dp|²/(2‖s_k − p‖) ≈ 3 mm at 350 m). With the power
statistic the log-likelihood, maximised over each block's unknown complex amplitude, is
Λ(ξ) = Σ_k Σ_b |y_kb(δ_k(ξ))|²/R_B(0) (the GLRT DPE cost, Closas 2007).

:func:`manifold_numpy` is the plain reference of the compiled kernels
(:mod:`testbed.integrity.kernels.dpe`); tests hold them equal.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from testbed.correlation import peak
from testbed.frames import LocalFrame
from testbed.integrity.kernels.dpe import interval_polynomials


@dataclass(frozen=True)
class EpochManifold:
    """One epoch's manifold inputs (S used satellites).

    delta0 : (S,) δ_k(0), m.  g : (S, 4) ENU + clock partials.  table : (S, M) the statistic in
    likelihood units.  floor : (S,) the table's noise level.  delay0_m, step_m : the delay grid.
    """

    delta0: NDArray
    g: NDArray
    table: NDArray
    floor: NDArray
    delay0_m: float
    step_m: float

    @cached_property
    def poly(self) -> NDArray:
        """(S, M, 4) the tables as the kernels read them (Keys' cubic per interval)."""
        return interval_polynomials(self.table)

    def index_units(self, centre: NDArray, axes: NDArray) -> tuple[NDArray, NDArray]:
        """(c, H) of the kernels for candidates ``centre + axes @ z``: delay index = c + H·z."""
        c = (self.delta0 + self.g @ centre - self.delay0_m) / self.step_m
        return c, (self.g @ axes) / self.step_m

    def reaches(self, centre: NDArray, axes: NDArray, half_extent: float) -> NDArray:
        """(S,) bool: every candidate of the box |z_a| ≤ half_extent stays inside satellite k's window."""
        c, H = self.index_units(centre, axes)
        span = np.abs(H).sum(axis=1) * half_extent
        return (c - span >= 2.0) & (c + span <= self.table.shape[1] - 4.0)


def epoch_manifold(frame: LocalFrame, sat_ecef: NDArray, rho_ref: NDArray, stat: NDArray, centre_enu: NDArray,
                   clock_m: float, *, stat_kind: str, n_blocks: int, bandwidth_chips: float, delay0_m: float,
                   step_m: float) -> EpochManifold:
    """The manifold of the satellites given (rows of sat_ecef (S, 3), rho_ref (S,), stat (S, M))."""
    p = frame.enu_to_ecef(np.asarray(centre_enu, float))
    d = sat_ecef - p
    rng = np.linalg.norm(d, axis=-1)
    e_enu = frame.vec_ecef_to_enu(d / rng[:, None])
    g = np.concatenate([-e_enu, np.ones((rng.size, 1))], axis=1)
    stat = np.asarray(stat, float)
    if stat_kind == "pow":
        table = stat / peak(bandwidth_chips)
        floor = np.full(rng.size, float(n_blocks))
    else:
        table = stat
        floor = np.median(stat, axis=1)
    return EpochManifold(rng + clock_m - rho_ref, g, table, floor, delay0_m, step_m)


def box_nodes(spacing: float, n: int) -> NDArray:
    """(n⁴, 4) the product grid the kernels enumerate (C order, last axis fastest)."""
    a = (np.arange(n) - (n - 1) / 2.0) * spacing
    return np.stack(np.meshgrid(a, a, a, a, indexing="ij"), -1).reshape(-1, 4)


def _keys_weights(t: NDArray) -> NDArray:
    t2, t3 = t * t, t * t * t
    return np.stack([-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0, -1.5 * t3 + 2.0 * t2 + 0.5 * t,
                     0.5 * t3 - 0.5 * t2], -1)


def manifold_numpy(c: NDArray, H: NDArray, table: NDArray, floor: NDArray, X: NDArray, cubic: bool = True) -> NDArray:
    """Σ_k f_k(c_k + H_k·X[n]) in plain numpy (the kernels' reference; index units)."""
    pos = c[None, :] + X @ H.T  # (N, S)
    M = table.shape[1]
    inside = (pos >= 1.0) & (pos < M - 3.0)
    p = np.where(inside, pos, 1.0)
    i = p.astype(np.intp)
    t = p - i
    k = np.arange(c.size)[None, :]
    if cubic:
        w = _keys_weights(t)
        v = sum(w[..., j] * table[k, i + j - 1] for j in range(4))
    else:
        v = (1.0 - t) * table[k, i] + t * table[k, i + 1]
    return np.where(inside, v, floor[None, :]).sum(axis=1)

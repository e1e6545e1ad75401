"""The ARAIM all-in-view position: iterated weighted least squares with one receiver clock per system.

The state is [E, N, U, c_GPS, c_Galileo, c_BeiDou, c_GLONASS] in the run's world frame (a clock of a
system with no used row at an epoch is pinned: it does not move the others). The weights are the
integrity variances of :mod:`testbed.integrity.araim.error_model` (W = C_int⁻¹, eq. 9 with no row
removed), recomputed from the line of sight at each iterate. At the solution the ranging rows (line of
sight, variances, post-fit residuals) are what :func:`testbed.integrity.araim.araim` monitors: the
solution separations are linear in the residuals, so they hold at whatever point the residuals are
taken, and the all-in-view correction S⁽⁰⁾Δy is zero there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.integrity.araim.core import AraimRows
from testbed.integrity.araim.settings import SYSTEMS, AraimSettings
from testbed.integrity.araim.subsets import checked_inverse

#: the state: position E, N, U then one clock per system of :data:`SYSTEMS`
N_STATES = 3 + len(SYSTEMS)


@dataclass(frozen=True)
class AllInViewFix:
    """The iterated all-in-view solution of P epochs.

    x : (P, 7) [E, N, U (m), one clock per system (m)], NaN where unsolved.  converged : (P,) the last step
    moved the position less than the tolerance.  iterations : (P,) steps taken.  rows : the ranging rows at
    the solution (line of sight, variances, post-fit residuals), what ARAIM monitors.
    """

    x: NDArray
    converged: NDArray
    iterations: NDArray
    rows: AraimRows


def _rows_at(p_enu: NDArray, clocks: NDArray, sat_enu: NDArray, pseudorange: NDArray, system: NDArray,
             used: NDArray, settings: AraimSettings) -> tuple[AraimRows, NDArray]:
    """The rows at state (p_enu (P, 3), clocks (P, C)) and the geometry matrix G (P, N, 3 + C)."""
    d = sat_enu - p_enu[:, None, :]
    rng = np.linalg.norm(d, axis=-1)
    los = d / rng[..., None]
    clock = np.take_along_axis(clocks, system, -1)
    residual = np.where(used, pseudorange - rng - clock, 0.0)
    rows = AraimRows.from_elevation(los, system, used, settings, residual)
    G = np.concatenate([-los, (system[..., None] == np.arange(len(SYSTEMS))).astype(float)], -1)
    return rows, G


def all_in_view_fix(sat_enu: NDArray, pseudorange: NDArray, system: NDArray, used: NDArray,
                    settings: AraimSettings, max_iter: int, tol_m: float, max_cond: float) -> AllInViewFix:
    """Gauss–Newton from the frame origin (clocks 0) to the weighted least-squares fix, every epoch at once.

    Parameters
    ----------
    sat_enu : (P, N, 3) m satellite positions in the world frame (at transmit time, in the receive-time frame).
    pseudorange : (P, N) m.  system : (P, N) int codes (index into :data:`SYSTEMS`).  used : (P, N) bool
        (a used row must be finite).  max_iter, tol_m : iterations and the position step that stops them.
    max_cond : largest accepted condition number of the Jacobi-scaled normal matrix (else the epoch is
        unsolved: NaN state, not converged).
    """
    P, N = pseudorange.shape
    C = len(SYSTEMS)
    sat_enu = np.where(used[..., None], sat_enu, 1.0e7)  # unused rows: any finite point, weight 0
    pseudorange = np.where(used, pseudorange, 0.0)
    x = np.zeros((P, N_STATES))
    converged = np.zeros(P, bool)
    iterations = np.zeros(P, int)
    has_clock = np.stack([(used & (system == s)).any(-1) for s in range(C)], -1)  # (P, C)
    pin = np.zeros((P, N_STATES, N_STATES))
    pin[:, np.arange(3, N_STATES), np.arange(3, N_STATES)] = ~has_clock
    solvable = used.sum(-1) >= 3 + has_clock.sum(-1)  # rows for every state (else ARAIM's reason says why)
    for _ in range(max_iter):
        active = solvable & ~converged
        if not active.any():
            break
        a = np.flatnonzero(active)
        rows, G = _rows_at(x[a, :3], x[a, 3:], sat_enu[a], pseudorange[a], system[a], used[a], settings)
        w = np.where(used[a], 1.0 / rows.c_int, 0.0)
        Gw = G * w[..., None]
        inv, ok = checked_inverse(np.swapaxes(Gw, -1, -2) @ G + pin[a], max_cond)  # (GᵀWG)⁻¹ (eq. 9)
        dx = np.einsum("pij,pj->pi", inv, np.einsum("pni,pn->pi", Gw, rows.residual))
        x[a] = np.where(ok[:, None], x[a] + dx, np.nan)
        solvable[a] = ok
        iterations[a] += 1
        converged[a] = ok & (np.linalg.norm(dx[:, :3], axis=-1) < tol_m)
    x[~solvable] = np.nan
    x_at = np.where(solvable[:, None], x, 0.0)
    rows, _ = _rows_at(x_at[:, :3], x_at[:, 3:], sat_enu, pseudorange, system, used, settings)
    return AllInViewFix(x, converged & solvable, iterations, rows)

"""Subset solutions of the ARAIM fault modes and their statistics (docs/design/araim.md §4).

For fault mode k (rows ``removed[k]`` out), the weighted least squares on the kept rows

    S⁽ᵏ⁾ = (Gᵀ W_k G)⁻¹ Gᵀ W_k,   W_k = diag(keep_k / C_int)                      (eq. 9)

with a clock column that has no kept row dropped (its state pinned by a unit diagonal, which leaves the
other states' solution unchanged). Then per position axis q = E, N, U (eq. 10-13)

    σ_q⁽ᵏ⁾² = Σ_i (S_qi⁽ᵏ⁾)² C_int,i          b_q⁽ᵏ⁾ = Σ_i |S_qi⁽ᵏ⁾| b_nom,i
    σ_ss,q⁽ᵏ⁾² = Σ_i (S_qi⁽ᵏ⁾ − S_qi⁽⁰⁾)² C_acc,i   b_ss,q⁽ᵏ⁾ = Σ_i |S_qi⁽ᵏ⁾ − S_qi⁽⁰⁾| b_cont,i

Every subset is solved in a compiled kernel (:mod:`testbed.integrity.araim.kernels`): its normal matrix is
the all-in-view one less the removed rows' outer products, inverted with the conditioning test of
:func:`checked_inverse`, on batches of epochs that share one row structure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from testbed.integrity.araim.kernels import subset_stats_epochs
from testbed.integrity.kernels import kernel_input

#: elements of the temporaries of one chunk of epochs
CHUNK_ELEMENTS = 1 << 21
#: epochs × modes below which a batch runs on one thread: a few milliseconds of work, where waking numba's
#: threads (beside busy neighbours, waiting for one that is not scheduled) costs more than it saves
PARALLEL_MIN_WORK = 20_000


def run_kernel(kernel, work: int, *args) -> None:
    """``kernel(*args)`` (a parallel kernel) on numba's threads when ``work`` (epochs × modes) is at least
    :data:`PARALLEL_MIN_WORK`, else on one (the same per-epoch code: the same results)."""
    if work >= PARALLEL_MIN_WORK:
        kernel(*args)
        return
    threads = numba.get_num_threads()
    numba.set_num_threads(1)  # this thread's setting only
    try:
        kernel(*args)
    finally:
        numba.set_num_threads(threads)


@dataclass(frozen=True)
class SubsetStats:
    """Per epoch and mode: observable (E, M) bool; sigma, bias, sigma_ss, bias_ss, separation (E, M, 3) m in
    E, N, U (separation = x̂⁽ᵏ⁾ − x̂⁽⁰⁾, NaN without residuals); s0 (E, 3, N), the all-in-view S rows of the
    position."""

    observable: NDArray
    sigma: NDArray
    bias: NDArray
    sigma_ss: NDArray
    bias_ss: NDArray
    separation: NDArray
    s0: NDArray


def checked_inverse(A: NDArray, max_cond: float) -> tuple[NDArray, NDArray]:
    """Inverses of symmetric (..., n, n) ``A`` and whether each is well conditioned (1-norm condition number of
    the Jacobi-scaled matrix ≤ ``max_cond``). An ill-conditioned or singular one gets NaN, never an exception."""
    d = np.sqrt(np.diagonal(A, axis1=-2, axis2=-1))
    As = A / (d[..., :, None] * d[..., None, :])
    try:
        inv_s = np.linalg.inv(As)
    except np.linalg.LinAlgError:  # an exactly singular subset somewhere in the batch: one at a time
        inv_s = np.full_like(As, np.nan)
        for idx in np.ndindex(As.shape[:-2]):
            try:
                inv_s[idx] = np.linalg.inv(As[idx])
            except np.linalg.LinAlgError:
                pass
    with np.errstate(invalid="ignore"):
        cond = np.abs(As).sum(-2).max(-1) * np.abs(inv_s).sum(-2).max(-1)
        ok = np.isfinite(cond) & (cond <= max_cond)
    inv = inv_s / (d[..., :, None] * d[..., None, :])
    return np.where(ok[..., None, None], inv, np.nan), ok


def subset_stats(G: NDArray, c_int: NDArray, c_acc: NDArray, b_nom: NDArray, b_cont: NDArray, removed: NDArray,
                 clock_of_row: NDArray, max_cond: float, residual: NDArray | None = None) -> SubsetStats:
    """Statistics of every mode's subset solution (eq. 9-13).

    Parameters
    ----------
    G : (E, N, n) geometry rows [−LOS_ENU | clock one-hot], n = 3 + clocks.
    c_int, c_acc : (E, N) m² row variances.  b_nom, b_cont : (E, N) m.
    removed : (M, N) bool rows each mode removes (mode 0 removes none).
    clock_of_row : (N,) clock column (0 … n−4) of each row, or (N, n−3) bool: the non-position states each
        row observes (a state no kept row observes is pinned: a clock, or the camera rotation of the vision rows).
    residual : (E, N) prefit residuals Δy at the linearisation point (m), or None.
    """
    E, N, n = G.shape
    M = removed.shape[0]
    keep = ~removed
    incidence = np.asarray(clock_of_row)
    incidence = incidence if incidence.ndim == 2 else np.eye(n - 3)[incidence]
    clock_rows = keep.astype(float) @ incidence.astype(float)  # (M, C): kept rows per clock
    empty_clock = clock_rows == 0
    structurally_ok = keep.sum(1) >= 3 + (~empty_clock).sum(1)  # rows ≥ states left
    observable = np.empty((E, M), bool)
    sigma, bias, sigma_ss, bias_ss, separation = (np.empty((E, M, 3)) for _ in range(5))
    s0 = np.empty((E, 3, N))
    ro = lambda a, dt=np.float64: kernel_input(a, np.shape(a), dtype=dt)  # noqa: E731
    res = np.zeros((E, N)) if residual is None else residual
    run_kernel(subset_stats_epochs, E * M, ro(G), ro(c_int), ro(c_acc), ro(b_nom), ro(b_cont),
               ro(res), residual is not None, ro(removed, np.bool_), ro(empty_clock, np.bool_),
               ro(structurally_ok, np.bool_), float(max_cond), observable, sigma, bias, sigma_ss, bias_ss, separation,
               s0)
    return SubsetStats(observable, sigma, bias, sigma_ss, bias_ss, separation, s0)


def chunk_epochs(E: int, M: int, N: int, n: int) -> int:
    """Epochs per chunk so a chunk's per-mode arrays (about eight of (epochs, M, 3) in the caller) and its
    rows stay about :data:`CHUNK_ELEMENTS`."""
    return max(1, min(E, CHUNK_ELEMENTS // max(24 * M + 4 * N * n, 1)))

"""Importance sampling aimed at ARAIM's solution-separation tests: its fault-free false alerts.

ARAIM alerts when one of its tests, mode ``k`` and axis ``q``, sees ``|x̂⁽ᵏ⁾_q − x̂⁽⁰⁾_q| > T_k,q``. The
separation is linear in the pseudorange errors, ``Δ_kq = d_kq · z`` with ``z`` the standard-normal draws
(``noise = σ·z``) and ``d_kq = (S⁽ᵏ⁾ − S⁽⁰⁾)_q · diag(σ)``: the test's row of the monitor, in the units of the
draws. Each test's alert is a pair of half-spaces, and the false alert their union. Scaling the whole parity
space (``proposal = "scale"``) fails on ARAIM's ~21 dimensions: the likelihood ratio of a scaling is a product
over every dimension, and the weights collapse. The ``separation`` proposal is a mixture of mean shifts
instead, one per test and sign, each to the nearest point of its half-space (its dominating point,
``z* = ±T_k,q · d_kq/|d_kq|²``, the least-norm error that makes that separation reach its threshold), drawn in
proportion to the test's own Gaussian tail ``Q(T_k,q/|d_kq|)`` (its share of the union bound) beside the
defensive share drawn from the error model itself (:mod:`testbed.campaign.sampling`).

The rows ``d_kq`` come from the ARAIM core itself, probed like the monitor's position: its mode table
(:func:`~testbed.integrity.araim.core.araim_modes`) at an epoch's rows, with a unit residual on one row at a
time, gives ``(S⁽ᵏ⁾ − S⁽⁰⁾)`` column by column (exact: the separations are linear in the residuals). The
rows of an epoch (lines of sight, σ drawn, systems) are those of the monitor's linear model
(:class:`~testbed.campaign.sampling.LinearModel`): its design columns are the unit lines of sight over σ.

A flight has ~150 epochs of ~270 modes on three constellations: ~2·10⁵ signed tests. Components whose tails
together carry less than :data:`DROPPED_MASS` of the union bound are left to the defensive share (their
events still count, at their plain rate: the estimate stays unbiased).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special, stats

from testbed.integrity.araim.core import AraimRows, araim_modes
from testbed.integrity.araim.monitor import SYSTEM_CODES
from testbed.integrity.araim.settings import AraimSettings

#: the share of the union bound's tail mass whose components are left to the defensive share
DROPPED_MASS = 1e-6


@dataclass(frozen=True)
class SeparationTests:
    """One epoch's monitored solution-separation tests, one row per (mode, axis).

    rows : (J, N) the separation per unit draw of each used row (``(S⁽ᵏ⁾ − S⁽⁰⁾)_q · σ``).  threshold : (J,) m
    ``T_k,q``.  mode, axis : (J,) the mode's index in the table and the axis (0 E, 1 N, 2 U).  slots : (N,) the
    slots of the rows.  prior : (J,) the mode's prior (``p_k``).  removed : per mode, the slots it removes.
    """

    rows: np.ndarray
    threshold: np.ndarray
    mode: np.ndarray
    axis: np.ndarray
    slots: np.ndarray
    prior: np.ndarray
    removed: tuple[tuple[int, ...], ...]
    s0: np.ndarray  # (3, N) the all-in-view position error per unit draw of each row (S⁽⁰⁾ · σ)
    los_enu: np.ndarray  # (N, 3) the rows' lines of sight

    @property
    def tail(self) -> np.ndarray:
        """(J,) log of each test's one-sided Gaussian tail ``Q(T/|d|)`` (its false alert is twice that)."""
        with np.errstate(divide="ignore"):
            return stats.norm.logsf(self.threshold / np.linalg.norm(self.rows, axis=1))


def epoch_rows(los_enu: np.ndarray, system: np.ndarray, settings: AraimSettings) -> AraimRows:
    """The ARAIM rows of one epoch's used satellites (``los_enu`` (N, 3) receiver→satellite, ``system`` (N,)
    codes), the variances from the elevation as the monitor builds them; zero residuals."""
    return AraimRows.from_elevation(los_enu, system, np.ones(len(system), bool), settings,
                                    residual=np.zeros(len(system)))


def separation_matrix(rows: AraimRows, settings: AraimSettings):
    """The mode table of ``rows`` (one epoch) and its separations per metre of each row's residual:
    ``(table, D (M, 3, N))``, ``D[k, q, i] = (S⁽ᵏ⁾ − S⁽⁰⁾)_{q,i}`` probed by a unit residual on row i
    (None, None: no modes)."""
    N = rows.used.shape[-1]
    table = araim_modes(rows, settings)
    if table is None:
        return None, None
    D = np.empty(table.separation.shape + (N,))
    for i in range(N):
        unit = np.zeros(N)
        unit[i] = 1.0
        D[..., i] = araim_modes(AraimRows(rows.los_enu, rows.system, rows.used, rows.c_int, rows.c_acc, rows.b_nom,
                                          rows.b_cont, unit), settings).separation
    return table, D


def epoch_tests(los_enu: np.ndarray, system: np.ndarray, sigma: np.ndarray, slots: np.ndarray,
                settings: AraimSettings) -> SeparationTests | None:
    """The monitored tests of one epoch (:class:`SeparationTests`) whose used rows are ``slots`` with lines of
    sight ``los_enu`` (N, 3), system codes ``system`` (N,) and drawn σ ``sigma`` (N,); None: no modes."""
    rows = epoch_rows(los_enu, system, settings)
    table, D = separation_matrix(rows, settings)
    if table is None:
        return None
    monitored = np.asarray(table.observable, bool).copy()
    monitored[0] = False
    k, q = np.nonzero(monitored[:, None] & np.ones(3, bool))
    # S⁽⁰⁾ by the same probe: the fault-free mode's solution moves by S⁽⁰⁾ε; (S⁽ᵏ⁾ − S⁽⁰⁾) of a mode that keeps
    # every row is 0, so S⁽⁰⁾ is read from the weighted fix directly
    W = 1.0 / rows.c_int
    G = np.concatenate([-los_enu, (system[:, None] == np.unique(system)[None, :]).astype(float)], 1)
    s0 = np.linalg.solve(G.T @ (G * W[:, None]), G.T * W)[:3]
    return SeparationTests(rows=D[k, q] * sigma, threshold=np.asarray(table.threshold)[k, q], mode=k, axis=q,
                           slots=np.asarray(slots), prior=np.asarray(table.p)[k],
                           removed=tuple(tuple(int(slots[i]) for i in m) for m in table.removed),
                           s0=s0 * sigma, los_enu=np.asarray(los_enu, float))


def model_tests(model, system_letters, frame_R: np.ndarray, settings: AraimSettings,
                epochs=None) -> list[SeparationTests | None]:
    """:func:`epoch_tests` at every epoch (or those of ``epochs``; None elsewhere) of a
    :class:`~testbed.campaign.sampling.LinearModel` with a solution: the used slots, their lines of sight and σ
    drawn read from its design columns (unit lines of sight in ECEF over σ), the systems from
    ``system_letters`` (S,), rotated to ENU by ``frame_R``."""
    codes = np.array([SYSTEM_CODES.get(str(c), -1) for c in system_letters])
    wanted = set(range(model.used.shape[0]) if epochs is None else epochs)
    out = []
    for t in range(model.used.shape[0]):
        u = np.flatnonzero(model.used[t])
        if t not in wanted or u.size == 0 or not np.isfinite(model.vpl[t]):
            out.append(None)
            continue
        per_sigma = model.design[t, u, :3]  # los / σ
        inv = np.linalg.norm(per_sigma, axis=1)
        out.append(epoch_tests((per_sigma / inv[:, None]) @ frame_R.T, codes[u], 1.0 / inv, u, settings))
    return out


def separation_components(tests: list[SeparationTests | None], S: int, tail_shares: bool):
    """The ``separation`` proposal's components over the epochs' tests: ``(epoch (K,), shift (K, S),
    log_share (K,) or None)``, two per test (±), the tests carrying together less than :data:`DROPPED_MASS`
    of the union bound dropped; drawn in proportion to their tails (``tail_shares``) or uniformly."""
    epochs, shifts, tails = [], [], []
    for t, tt in enumerate(tests):
        if tt is None or tt.rows.shape[0] == 0:
            continue
        norm2 = np.einsum("jn,jn->j", tt.rows, tt.rows)
        ok = norm2 > 0
        z = np.zeros((int(ok.sum()), S))
        z[:, tt.slots] = (tt.threshold[ok] / norm2[ok])[:, None] * tt.rows[ok]
        for sign in (1.0, -1.0):
            epochs.append(np.full(z.shape[0], t))
            shifts.append(sign * z)
            tails.append(tt.tail[ok])
    if not epochs:
        return np.zeros(0, np.int64), np.zeros((0, S)), None
    epoch, shift, tail = np.concatenate(epochs), np.concatenate(shifts), np.concatenate(tails)
    order = np.argsort(-tail, kind="stable")
    share = np.exp(tail[order] - special.logsumexp(tail))
    keep = order[: int(np.searchsorted(np.cumsum(share), 1.0 - DROPPED_MASS)) + 1]
    keep = np.sort(keep)
    log_share = tail[keep] - special.logsumexp(tail[keep]) if tail_shares else None
    return epoch[keep], shift[keep], log_share


def shift_mixture_log_density(z: np.ndarray, epoch: np.ndarray, shift: np.ndarray,
                              log_share: np.ndarray | None) -> np.ndarray:
    """(m,) ``log Σ_k π_k q_k(z)/p(z)`` of a mixture of mean shifts (component k shifts epoch ``epoch[k]``'s
    draws by ``shift[k]``) at the draws ``z`` (m, T, S), one epoch at a time: memory in m·K, not m·K·S."""
    K = epoch.size
    log_pi = np.full(K, -np.log(K)) if log_share is None else log_share
    ell = np.empty((z.shape[0], K))
    for t in np.unique(epoch):
        k = np.flatnonzero(epoch == t)
        sk = shift[k]
        ell[:, k] = z[:, t] @ sk.T - 0.5 * np.einsum("ks,ks->k", sk, sk)
    return special.logsumexp(ell + log_pi, axis=1)


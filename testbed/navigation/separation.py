"""Solution separation for the GNSS/vision/INS filter (docs/design/nav-filter.md §8.3): a bank of sub-filters,
each blind to one measurement mode, and the protection levels and detection test built on their separations.

**The bank.** Sub-filter r is trial ``trial[r]`` without mode ``mode[r]``: ``j < S`` without satellite slot j's
pseudorange and range rate; for vision either ``S + 1 + l`` without landmark l's pixel pair (``per_landmark``,
each landmark a fault mode as each satellite is — the threat of a misidentified landmark, as in the pixel
monitor), or ``S`` without every vision row (a single camera mode: it also covers a camera-wide fault,
and with one satellite left its sub-filter is GNSS/INS dead reckoning, whose PL is tens of metres). One block of
B rows (one per trial) per mode, in the order the modes were spawned.

**Linearised about the main filter.** A sub-filter is an error-state Kalman filter on the main filter's
trajectory: it carries its offset δ_i from the main's nominal state and its own covariance P_i, and uses the main's
transition Φ (the product over the IMU steps between aiding epochs, from the compiled predict), the main's
process noise (``Q = P₀⁺ − ΦP₀Φᵀ``) and the main's measurement rows (``ν_i = ν₀ − H₀δ_i``). After each main
update the offsets are re-referenced to the main's new nominal (``δ_i ← δ_i − dx₀``). So the bank is the linear
Kalman filter bank, in which ``cov(x̂₀ − x̂_i) = P_i − P₀`` holds exactly; sub-filters with their own nominal
(a bank of EKFs) break it: their separations ran to 2× the σ this formula gives on the valley approach, and the
test raised false alarms at 1/10 of its budget's threshold. Each sub-filter costs one 17×17 step per aiding
epoch, not per IMU step.

**Lazy spawning is exact.** A mode's sub-filter is spawned as a copy of the mains (δ = 0, P = P₀) just before the
first update in which any trial uses that mode's measurements: up to then the main filter *is* the filter without
them. Only the modes a flight actually sees cost anything, and for a trial that never uses a mode its sub-filter
repeats the main bit for bit (P_i − P₀ stays exactly 0: the difference is what is propagated).

**The statistics.** Per mode i and axis q ∈ {E, N, U}: Δ_iq = x̂₀q − x̂_iq = −δ_iq, σ²_Δ,iq = (P_i − P₀)_qq. The
test alerts on any |Δ_iq| > T_iq = K_fa σ_Δ,iq with ``K_fa = Φ⁻¹(1 − P_FA,ss / (2 · 3 · N_modes))``: the test's
false-alarm share split over every mode *and* axis (a split over modes only would spend up to three
times the share). Protection level per axis ``PL_q = max(K_ff σ₀q, max_i(T_iq + K_md σ_iq))``,
``HPL = √(PL_E² + PL_N²)``, ``VPL = PL_U``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from testbed.navigation.ekf import N, gain_update

#: the mode of the sub-filter without any satellite's rows (a constellation-wide fault)
GNSS_MODE = -1


@dataclass(frozen=True)
class Bank:
    """The sub-filters of B trials (see the module docstring): R = M·B rows."""

    trial: NDArray  # (R,) int
    mode: NDArray  # (R,) int
    dx: NDArray  # (R, n) offset from the trial's main nominal state (n = 17, or with slam.py's static block)
    P: NDArray  # (R, n, n)
    n_trials: int
    vision_mode: int  # = S, the satellite slots' count: the camera mode (landmark l is S + 1 + l)
    per_landmark: bool = True
    gnss_mode: bool = False  # also a sub-filter without every satellite (:data:`GNSS_MODE`)
    camera_mode: bool = False  # with per_landmark, also one without every pixel row (mode S)
    #: the mains' transition and covariance since the last aiding epoch, when a block ended between epochs
    #: (the sub-filters are propagated at the next epoch, by the same product a single pass forms)
    pending: tuple[NDArray, NDArray] | None = None

    @classmethod
    def empty(cls, n_trials: int, n_slots: int, per_landmark: bool = True, n: int = N, gnss_mode: bool = False,
              camera_mode: bool = False) -> Bank:
        return cls(np.zeros(0, int), np.zeros(0, int), np.zeros((0, n)), np.zeros((0, n, n)), n_trials, n_slots,
                   per_landmark, gnss_mode, camera_mode)

    def vision_modes(self, landmarks: NDArray) -> NDArray:
        """The modes of landmark indices ``landmarks`` (any shape)."""
        landmarks = np.asarray(landmarks)
        return self.vision_mode + 1 + landmarks if self.per_landmark else np.full(landmarks.shape, self.vision_mode)

    @property
    def modes(self) -> NDArray:
        """The spawned modes, in bank order (M,)."""
        return self.mode[::self.n_trials]

    def removes(self, mode: NDArray, row_mode: NDArray) -> NDArray:
        """Whether sub-filters of modes ``mode`` (R, 1) skip rows of modes ``row_mode`` (1, M): their own rows, for
        :data:`GNSS_MODE` every satellite's, and for the camera mode beside the landmarks' every pixel row."""
        S = self.vision_mode
        return ((row_mode == mode) | ((mode == GNSS_MODE) & (row_mode >= 0) & (row_mode < S))
                | (self.camera_mode & (mode == S) & (row_mode >= S)))


def spawn(bank: Bank, P_main: NDArray, used_modes: NDArray) -> Bank:
    """Append a sub-filter per trial for every mode in ``used_modes`` the bank does not hold yet."""
    held = set(bank.modes.tolist())
    used = np.unique(used_modes)
    if bank.gnss_mode and np.any((used >= 0) & (used < bank.vision_mode)):
        used = np.append(used, GNSS_MODE)
    if bank.camera_mode and np.any(used >= bank.vision_mode):
        used = np.append(used, bank.vision_mode)
    new = [int(m) for m in used if int(m) not in held]
    if not new:
        return bank
    B, k = bank.n_trials, len(new)
    return replace(bank, trial=np.concatenate([bank.trial, np.tile(np.arange(B), k)]),
                   mode=np.concatenate([bank.mode, np.repeat(np.asarray(new, int), B)]),
                   dx=np.concatenate([bank.dx, np.zeros((k * B, bank.dx.shape[-1]))]),
                   P=np.concatenate([bank.P, np.tile(P_main, (k, 1, 1))]))


def propagate(bank: Bank, Phi: NDArray, P0_before: NDArray, P0_after: NDArray) -> Bank:
    """Through the main's transition Φ (B, n, n) and noise: ``P_i ← P₀⁺ + Φ(P_i − P₀)Φᵀ``, ``δ_i ← Φδ_i``."""
    if not bank.trial.size:
        return bank
    F = Phi[bank.trial]
    D = F @ (bank.P - P0_before[bank.trial]) @ np.swapaxes(F, -1, -2)
    P = P0_after[bank.trial] + 0.5 * (D + np.swapaxes(D, -1, -2))
    return replace(bank, P=P, dx=np.einsum("rij,rj->ri", F, bank.dx))


def settle(bank: Bank, P0_after: NDArray) -> Bank:
    """Propagate the sub-filters through the pending transition, to the mains' covariance now."""
    if bank.pending is None:
        return bank
    Phi, P0_before = bank.pending
    return replace(propagate(bank, Phi, P0_before, P0_after), pending=None)


def update(bank: Bank, nu0: NDArray, H0: NDArray, R0: NDArray, mask0: NDArray, row_mode: NDArray,
           dx0: NDArray) -> Bank:
    """One update stage of the sub-filters with the main's rows: ν₀, H₀, R₀, mask₀ (B, M, ...), each row's mode
    (M,) (a sub-filter skips the rows of its own mode), and the main's correction dx₀ (B, n) to re-reference to."""
    if not bank.trial.size:
        return bank
    t = bank.trial
    H = H0[t]
    mask = mask0[t] & ~bank.removes(bank.mode[:, None], row_mode[None, :])
    nu = nu0[t] - np.einsum("rmn,rn->rm", H, bank.dx)
    # the main's own form: Joseph for the 17-state core, P − KHP with slam.py's static block
    dx, P, _, _ = gain_update(bank.P, nu, H, R0[t], mask, joseph=bank.dx.shape[-1] == N)
    return replace(bank, dx=bank.dx + dx - dx0[t], P=P)


def augment(bank: Bank, trials: NDArray, cols: slice, A: NDArray, noise: NDArray | None = None) -> Bank:
    """A slot of the static block (slam.py) set, for the sub-filters of ``trials`` (b,), to the linear map A (b, k, n)
    of each one's own error state plus independent noise (b, k, k): rows ``A P_i``, block ``A P_i Aᵀ + noise``,
    offset ``A δ_i`` — what the main's slot got, through the same map (A zero: the slot cleared)."""
    if not bank.trial.size or not np.size(trials):
        return bank
    pos = np.full(bank.n_trials, -1)
    pos[np.asarray(trials)] = np.arange(np.size(trials))
    r = np.flatnonzero(pos[bank.trial] >= 0)
    if not r.size:
        return bank
    Ar = A[pos[bank.trial[r]]]
    P, dx = bank.P.copy(), bank.dx.copy()
    rows = Ar @ P[r]
    diag = rows @ np.swapaxes(Ar, -1, -2) + (0.0 if noise is None else noise[pos[bank.trial[r]]])
    rows[:, :, cols] = diag
    P[r, cols, :] = rows
    P[r, :, cols] = np.swapaxes(rows, -1, -2)
    dx[r, cols] = np.einsum("rkn,rn->rk", Ar, bank.dx[r])
    return replace(bank, P=P, dx=dx)


@dataclass(frozen=True)
class Separation:
    """The solution-separation products per trial and epoch (B, T[, 3])."""

    pl_enu: NDArray  # per-axis PL (B, T, 3)
    ratio: NDArray  # max_iq |Δ_iq| / T_iq (B, T); > 1 is the separation test's alert
    n_modes: NDArray  # modes with a non-zero separation (B, T)


def stack_subs(dp: list[NDArray], Pp: list[NDArray], P_main: NDArray, B: int) -> tuple[NDArray, NDArray]:
    """Per-epoch sub-filter position offsets (R_k, 3) and blocks (R_k, 3, 3), R_k growing, into (R, T, ...):
    a mode's epochs before its spawn are its mains' (zero offset, the main's block). ``P_main`` (B, T, 3, 3)."""
    R, T = dp[-1].shape[0], len(dp)
    out_d, out_P = np.zeros((R, T, 3)), np.tile(P_main, (R // B, 1, 1, 1))
    for k, (d, P) in enumerate(zip(dp, Pp)):
        out_d[:d.shape[0], k] = d
        out_P[:d.shape[0], k] = P
    return out_d, out_P


def separation(P_main: NDArray, sub_dp: NDArray, sub_Pp: NDArray, p_fa_share: float, p_md: float,
               p_ff: float) -> Separation:
    """The test and PLs from the mains' position blocks (B, T, 3, 3) and the sub-filters' offsets (R, T, 3) and
    blocks (R, T, 3, 3) (M blocks of B rows)."""
    B, T = P_main.shape[:2]
    M = sub_dp.shape[0] // B
    var0 = np.maximum(np.diagonal(P_main, axis1=-2, axis2=-1), 0.0)
    k_ff = stats.norm.isf(p_ff / 2)
    if M == 0:
        return Separation(k_ff * np.sqrt(var0), np.zeros((B, T)), np.zeros((B, T), np.int64))
    var_i = np.diagonal(sub_Pp, axis1=-2, axis2=-1).reshape(M, B, T, 3)
    var_d = np.maximum(var_i - var0, 0.0)
    active = var_d.sum(-1) > 0.0  # (M, B, T): the mode's measurements have reached the main filter
    n_modes = active.sum(0)
    k_fa = stats.norm.isf(p_fa_share / (2 * 3 * np.maximum(n_modes, 1)))
    thr = k_fa[None, ..., None] * np.sqrt(var_d)
    delta = np.abs(sub_dp.reshape(M, B, T, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(thr > 0, delta / thr, 0.0)  # an axis the mode adds nothing to carries no separation
    r = np.where(active[..., None], r, 0.0)
    k_md = stats.norm.isf(p_md / 2)
    bound = np.where(active[..., None], thr + k_md * np.sqrt(np.maximum(var_i, 0.0)), 0.0)
    return Separation(np.maximum(k_ff * np.sqrt(var0), bound.max(0)), r.max(axis=(0, -1)), n_modes)


__all__ = ["GNSS_MODE", "Bank", "Separation", "augment", "propagate", "separation", "settle", "spawn", "stack_subs", "update"]

"""ARAIM's integrity budget over the filter: the sub-filter bank and the IMU-free snapshot as fault modes, with the
ADD's thresholds and protection-level equation (docs/design/nav-filter.md §8.4).

**Modes.** Each a solution that leaves one fault event's measurements out, over the whole flight:

* a satellite (the bank's sub-filter without its rows; prior P_sat of the GPS ISM);
* every satellite (the sub-filter without GNSS, :data:`~.separation.GNSS_MODE`: the constellation-wide fault, P_const;
  it also covers any combination of satellite faults);
* a landmark (the sub-filter without its pixel pair; P_landmark), with ``ss_vision = "landmark"``;
* the camera (the sub-filter without any pixel row: prior P_camera; with ``ss_vision = "camera"`` also P_landmark for
  each landmark seen so far, whose faults it then covers alone);
* the IMU (the epoch's pseudoranges alone, :mod:`.snapshot`; prior P_inertia). Its attitude also aims the camera, so
  the snapshot leaves the pixels out too. Below four satellites it is unobservable and its prior goes unmonitored.

**Unmonitored prior.** Two or more events at once, except combinations inside the GNSS or inside the vision group:
``P(≥2) − P(≥2 in G, none outside) − P(≥2 in V, none outside)`` over the exposure priors (eq. 5-6). A group's
combinations are its widest mode's to remove (the sub-filter without any satellite, or without any pixel row), so
they join that mode's prior, as the ARAIM core folds a constellation's modes into its own. Above P_THRES the epoch
needs dual-event modes the bank does not hold: "unavailable", with the reason. The IMU's mode is taken to cover the
IMU alone, though its subset also leaves the pixels out (conservative). Modes are then selected as the core selects
them (eq. 8; :func:`select_modes`): an exposure prior above 1e-7 is monitored, and the others are monitored, fewest
rows removed first, only while the unmonitored prior exceeds P_THRES. So GPS's P_const of 1e-8 leaves the GNSS-wide
mode out, whose coasting sub-filter would otherwise set the horizontal protection level. A chosen mode that is
unobservable (the IMU's below four satellites) adds its prior after.

**Statistics.** Per mode k and axis q: the separation Δ = x̂⁽ᵏ⁾ − x̂⁽⁰⁾ with σ²_ss = (P_k − P_0)_qq, the threshold
``T = K_fa,q σ_ss`` (eq. 14-15: P_FA over modes and axes), the protection level by eq. 16 (fault-free σ from P_0,
mode σ from P_k; the filter's own noise model, no nominal-bias term), EMT (eq. 17) and availability (eq. 19) with
σ_acc,v the filter's vertical σ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.integrity.araim import AraimSettings
from testbed.integrity.araim.fault_modes import P_MUST_MONITOR
from testbed.integrity.araim.protection import fa_multipliers, q_tilde, solve_protection_level
from testbed.navigation.separation import GNSS_MODE

#: reason codes of the filter's ARAIM variant (the monitor's reason table extends its own with these)
FILTER_ARAIM_REASONS = (
    "unavailable: dual-event modes needed (two simultaneous faults outside one group exceed P_THRES; the bank holds "
    "single events)",
    "unavailable: the unmonitored prior exhausts the integrity budget (with it the priors of unobservable modes: the "
    "IMU's below four satellites)",
)
OK, FAULT_ORDER, UNMONITORED = 0, 1, 2


@dataclass(frozen=True)
class FilterAraim:
    """Per trial and epoch (B, T[, 3])."""

    pl_enu: NDArray  # ∞ where unavailable
    ratio: NDArray  # max over modes and axes |Δ| / T; > 1 alerts
    emt: NDArray
    n_modes: NDArray
    p_unmonitored: NDArray
    reason: NDArray  # 0 ok, else 1 + index into FILTER_ARAIM_REASONS
    #: the integrity risk eq. 16 gives the vision modes (camera, landmarks) and the IMU's at the protection levels,
    #: per axis over the exposure (× N_ES,int): (B, T, 2, 3), NaN where unavailable
    risk_aid_enu: NDArray


def _exposure(p: float, mfd_h: float, settings: AraimSettings) -> float:
    return p * settings.exposure_factor(mfd_h)


def _at_least_two(log_none: NDArray, q_sum: NDArray) -> NDArray:
    """P(≥ 2 events) = 1 − P(none)(1 + Σ p/(1 − p)), without the cancellation of 1 − (1 − ε)."""
    return -np.expm1(log_none + np.log1p(q_sum))


def dual_events(n_sat: NDArray, gnss: NDArray, n_landmarks: NDArray, settings: AraimSettings, exposure: bool = True
                ) -> tuple[NDArray, dict[str, NDArray]]:
    """P(≥ 2 fault events at once) (eq. 5-6; over the exposure, or at an instant), and per group ("gnss", "vision")
    the part with every event inside it (which the group's widest mode removes), per element of the inputs:
    ``n_sat`` satellites in the filter, ``gnss`` its constellation event present, ``n_landmarks`` landmarks seen;
    the IMU is always one event."""
    ism = settings.system_ism(0)
    pr = (lambda p, mfd_h: _exposure(p, mfd_h, settings)) if exposure else (lambda p, mfd_h: p)  # noqa: E731
    groups = {  # per group: (count, prior) of its events
        "gnss": [(n_sat, pr(ism.p_sat, ism.mfd_sat_h)), (gnss.astype(float), pr(ism.p_const, ism.mfd_const_h))],
        "vision": [(n_landmarks, pr(settings.landmark.p, settings.landmark.mfd_h)),
                   ((n_landmarks > 0).astype(float), pr(settings.camera.p, settings.camera.mfd_h))],
        "inertia": [(np.ones(np.shape(n_sat)), pr(settings.inertia.p, settings.inertia.mfd_h))],
    }
    log_none = {g: sum(n * np.log1p(-p) for n, p in ev) for g, ev in groups.items()}
    q_sum = {g: sum(n * p / (1.0 - p) for n, p in ev) for g, ev in groups.items()}
    total_log = sum(log_none.values())
    inside = {g: np.exp(total_log - log_none[g]) * _at_least_two(log_none[g], q_sum[g]) for g in ("gnss", "vision")}
    return _at_least_two(total_log, sum(q_sum.values())), inside


def select_modes(candidate: NDArray, p_exp: NDArray, rank: NDArray, base: NDArray, p_thres: float
                 ) -> tuple[NDArray, NDArray]:
    """The ADD's selection (eq. 8), as the ARAIM core's :func:`~testbed.integrity.araim.fault_modes.fault_modes`
    makes it, over K candidate modes (K, ...): a mode whose exposure prior exceeds
    :data:`~testbed.integrity.araim.fault_modes.P_MUST_MONITOR` is monitored; the others start unmonitored, their
    priors added to ``base``, and are monitored in order — ``rank`` (K,) first (the rows a mode removes: fewest
    first), then the larger prior — while the unmonitored prior exceeds ``p_thres``. Returns the monitored mask
    (K, ...) and the unmonitored prior (...)."""
    optional = candidate & (p_exp <= P_MUST_MONITOR)
    leave = np.where(optional, p_exp, 0.0)
    unmonitored = base + leave.sum(0)
    monitored = candidate & ~optional
    order = np.lexsort((-leave, np.broadcast_to(np.reshape(rank, (-1,) + (1,) * (leave.ndim - 1)), leave.shape)),
                       axis=0)
    for r in range(leave.shape[0]):
        k = order[r:r + 1]
        take = np.take_along_axis(optional, k, 0)[0] & (unmonitored > p_thres)
        unmonitored = unmonitored - np.where(take, np.take_along_axis(leave, k, 0)[0], 0.0)
        np.put_along_axis(monitored, k, np.take_along_axis(monitored, k, 0) | take[None], 0)
    return monitored, np.maximum(unmonitored, 0.0)


def _mode_priors(modes: NDArray, vision_mode: int, per_landmark: bool, n_landmarks: NDArray,
                 settings: AraimSettings) -> tuple[NDArray, NDArray]:
    """Instantaneous and exposure priors (M, B, T) of the bank's modes ``modes`` (M,)."""
    ism = settings.system_ism(0)
    p, p_exp = [], []
    for m in modes.tolist():
        if m == GNSS_MODE:
            a, b = ism.p_const, _exposure(ism.p_const, ism.mfd_const_h, settings)
        elif m < vision_mode:
            a, b = ism.p_sat, _exposure(ism.p_sat, ism.mfd_sat_h, settings)
        elif m > vision_mode:
            a, b = settings.landmark.p, _exposure(settings.landmark.p, settings.landmark.mfd_h, settings)
        else:  # the camera mode: the camera, and without landmark modes each landmark seen
            lm, cam, n = settings.landmark, settings.camera, 0.0 if per_landmark else n_landmarks
            a = cam.p + n * lm.p
            b = _exposure(cam.p, cam.mfd_h, settings) + n * _exposure(lm.p, lm.mfd_h, settings)
        p.append(np.broadcast_to(a, n_landmarks.shape))
        p_exp.append(np.broadcast_to(b, n_landmarks.shape))
    shape = (0,) + n_landmarks.shape
    return (np.stack(p) if p else np.zeros(shape)), (np.stack(p_exp) if p_exp else np.zeros(shape))


def filter_araim(p0: NDArray, P0: NDArray, modes: NDArray, vision_mode: int, per_landmark: bool, sub_dp: NDArray,
                 sub_Pp: NDArray, snap_p: NDArray, snap_P: NDArray, n_landmarks: NDArray, settings: AraimSettings
                 ) -> FilterAraim:
    """ARAIM over the bank of B trials and T epochs: the main filter's position p0 (B, T, 3) and block P0 (B, T, 3, 3);
    the bank's modes (M,) (:class:`~.separation.Bank` numbering, ``vision_mode`` its camera mode, ``per_landmark``
    whether it holds landmark modes) with their offsets
    (M·B, T, 3) and blocks (M·B, T, 3, 3); the IMU-free snapshot (B, T, 3), (B, T, 3, 3) (NaN where unobservable);
    the landmarks seen so far (B, T)."""
    B, T = p0.shape[:2]
    M = modes.size
    var0 = np.maximum(np.diagonal(P0, axis1=-2, axis2=-1), 0.0)
    var_i = np.diagonal(sub_Pp, axis1=-2, axis2=-1).reshape(M, B, T, 3)
    delta = -sub_dp.reshape(M, B, T, 3)
    active = (var_i - var0).sum(-1) > 0.0  # (M, B, T): the mode's rows have reached the filter
    snap_ok = np.isfinite(snap_p).all(-1)
    var_snap = np.where(snap_ok[..., None], np.diagonal(np.nan_to_num(snap_P), axis1=-2, axis2=-1), 0.0)
    var_i = np.concatenate([var_i, var_snap[None]])
    delta = np.concatenate([delta, np.nan_to_num(snap_p - p0)[None]])
    active = np.concatenate([active, snap_ok[None]])
    ins = settings.inertia
    p_m, p_exp_m = _mode_priors(modes, vision_mode, per_landmark, n_landmarks, settings)
    p_k = np.concatenate([p_m, np.full((1, B, T), ins.p)])
    p_exp_k = np.concatenate([p_exp_m, np.full((1, B, T), _exposure(ins.p, ins.mfd_h, settings))])

    is_sat = (modes >= 0) & (modes < vision_mode)
    n_sat = active[:M][is_sat].sum(0)
    gnss = active[:M][modes == GNSS_MODE].any(0)
    total, inside = dual_events(n_sat, gnss, n_landmarks, settings)
    _, inside_now = dual_events(n_sat, gnss, n_landmarks, settings, exposure=False)
    # a group's dual events are its widest mode's to remove: they join that mode's prior (as the core folds a
    # constellation's modes into its own), and leave the unmonitored prior only where it is monitored
    wide = {"gnss": np.r_[modes == GNSS_MODE, False], "vision": np.r_[modes == vision_mode, False]}
    for g, w in wide.items():
        p_k = p_k + np.where(w[:, None, None] & active, inside_now[g][None], 0.0)
        p_exp_k = p_exp_k + np.where(w[:, None, None] & active, inside[g][None], 0.0)
    covered = sum(np.where((active & w[:, None, None]).any(0), inside[g], 0.0) for g, w in wide.items())
    dual = np.maximum(total - covered, 0.0)  # what no mode removes
    # the selection is structural, as the core's: the IMU's mode is a candidate whether or not its snapshot exists
    # now; chosen but unobservable, its prior is added after (the core's unobservable modes)
    candidate = np.concatenate([active[:M], np.ones((1, B, T), bool)])
    rank = np.r_[np.where(modes == GNSS_MODE, 3, np.where(modes == vision_mode, 2, 0)), 1]
    chosen, p_nm = select_modes(candidate, p_exp_k, rank, dual, settings.p_thres)
    p_nm = p_nm + np.where(chosen[-1] & ~snap_ok, p_exp_k[-1], 0.0)
    active = chosen & active
    n_modes = active.sum(0)
    k_fa = fa_multipliers(n_modes, settings.p_fa_hor, settings.p_fa_vert, settings.n_es_cont)  # (B, T, 3)
    sigma_ss = np.sqrt(np.maximum(var_i - var0, 0.0))
    threshold = np.where(active[..., None], k_fa * sigma_ss, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(active[..., None] & (threshold > 0.0), np.abs(delta) / threshold, 0.0)
    ratio = r.max(axis=(0, -1))

    budget_total = settings.p_hmi_vert + settings.p_hmi_hor
    scale = 1.0 - p_nm / budget_total
    reason = np.where(dual > settings.p_thres, FAULT_ORDER, np.where(scale <= 0.0, UNMONITORED, OK))
    ok = reason == OK
    budget = np.stack([0.5 * settings.p_hmi_hor * scale] * 2 + [settings.p_hmi_vert * scale], -1)
    target = np.where(ok[..., None], budget, 1.0) / settings.n_es_int
    n_es = settings.n_es_int if settings.max_pmd else 1
    alpha = np.minimum(1.0, p_exp_k / (p_k * n_es))
    # eq. 16's terms along the last axis: the fault-free solution (weight 2, no cap), then every mode
    mv = lambda a: np.moveaxis(a, 0, -1)  # noqa: E731  (K, B, T, 3) → (B, T, 3, K)
    w_k = np.where(active, p_k, 0.0)[..., None] * np.ones(3)
    offset = np.concatenate([np.zeros((B, T, 3, 1)), mv(threshold)], -1)
    sigma = np.concatenate([np.sqrt(var0)[..., None], mv(np.sqrt(np.maximum(var_i, 0.0)))], -1)
    weight = np.concatenate([np.full((B, T, 3, 1), 2.0), mv(w_k)], -1)
    cap = np.concatenate([np.ones((B, T, 3, 1)), mv(alpha[..., None] * np.ones(3))], -1)
    pl, _ = solve_protection_level(offset, np.where(weight > 0.0, sigma, 1.0), weight, cap, target, settings.tol_pl)
    pl = np.where(ok[..., None], pl, np.inf)
    emt_modes = active & (p_k >= settings.p_emt)
    emt = np.where(ok, np.where(emt_modes, threshold[..., 2], 0.0).max(0, initial=0.0), np.nan)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        z = (pl[None] - threshold) / np.where(var_i > 0.0, np.sqrt(var_i), 1.0)
        terms = np.where(active[..., None], p_k[..., None] * np.minimum(q_tilde(z), alpha[..., None]), 0.0)
    vision = np.r_[modes >= vision_mode, False]
    risk = np.stack([terms[vision].sum(0), terms[-1]], -2) * settings.n_es_int  # (B, T, 2, 3)
    return FilterAraim(pl, ratio, emt, n_modes, p_nm, reason, np.where(ok[..., None, None], risk, np.nan))


__all__ = ["FILTER_ARAIM_REASONS", "FilterAraim", "dual_events", "filter_araim", "select_modes"]

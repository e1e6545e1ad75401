"""The ``araim`` monitor: ARAIM multiple-hypothesis solution separation in the loop (docs/design/araim.md §10).

Per epoch (and trial): the used satellites (visible, a finite pseudorange, a system with an ISM), the
all-in-view fix with one clock per system (:mod:`.solution`), then :func:`testbed.integrity.araim.araim` at
that fix: HPL, VPL, the solution-separation test (its largest normalised separation against 1), EMT,
σ_acc and the availability per service level (LPV-200 with its EMT and σ_acc,v criteria). Optional
exclusion (``fde``) runs through the testbed's one FDE mechanism (:mod:`testbed.integrity.fde`).
No state: every epoch stands alone. An epoch that cannot be protected gets NaN PLs and a reason.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from testbed.frames import LocalFrame
from testbed.integrity.araim.fault_modes import AID_GROUPS, AID_LANDMARK
from testbed.integrity.araim.core import ARAIM_REASONS, AraimEpochs, AraimReason, AraimRows, araim
from testbed.integrity.araim.protection import EMT_LIMITS, SIGMA_ACC_V_LIMITS
from testbed.integrity.araim.settings import SYSTEMS, AraimMonitorSettings, AraimSettings
from testbed.integrity.araim.solution import AllInViewFix, all_in_view_fix
from testbed.integrity.araim.vision_rows import CameraEpochs, camera_epochs, camera_rows
from testbed.integrity.batching import map_trial_chunks
from testbed.integrity.fde import EXCLUDED, Verdict, exclude
from testbed.integrity.monitor import ANTENNA, MonitorContext, MonitorDefaults, Observations
from testbed.integrity.settings import IntegritySettings
from testbed.records import (Diagnostics, GnssEpochs, MonitorOutput, VisionEpochs, epoch_array, largest_text,
                             max_p95_text, span_text)

#: RINEX 3 system letter -> system code (index into :data:`SYSTEMS`)
SYSTEM_CODES = {"G": 0, "E": 1, "C": 2, "R": 3}
#: the monitor's reasons: ARAIM's, then the position solve's own
REASONS: tuple[str, ...] = ARAIM_REASONS + ("unavailable: the all-in-view position did not converge",)
NOT_CONVERGED = len(ARAIM_REASONS)
VISION = list(AID_GROUPS).index("vision")


@dataclass(frozen=True)
class AraimDiagnostics(Diagnostics):
    """The ARAIM monitor's per-epoch outputs beyond the contract's (B..., T[, ...]); NaN where unavailable.

    emt : effective monitor threshold (m).  sigma_acc_v, sigma_acc_h : accuracy sigmas of the all-in-view
    solution (m).  n_modes : fault modes monitored.  fault_order : N_fault,max.  p_unmonitored : the
    unmonitored prior.  k_fa_v : the vertical threshold multiplier.  clock : (B..., T, 4) m, one receiver
    clock per system of :data:`SYSTEMS` (NaN for a system not used).  residual : (B..., T, S) m post-fit
    residuals per satellite slot (NaN on unused slots).  converged, n_iter : the all-in-view solve.
    With ``vision`` (docs/design/araim.md §11): n_landmarks, the landmarks whose pixels are rows;
    n_modes_vision, the monitored modes that remove vision rows; risk_vision_v, risk_vision_h, the integrity
    risk those modes take at the VPL and HPL (over the exposure); vision : whether the options asked for them.
    """

    emt: NDArray = epoch_array()
    sigma_acc_v: NDArray = epoch_array()
    sigma_acc_h: NDArray = epoch_array()
    n_modes: NDArray = epoch_array()
    fault_order: NDArray = epoch_array()
    p_unmonitored: NDArray = epoch_array()
    k_fa_v: NDArray = epoch_array()
    clock: NDArray = epoch_array(1)
    residual: NDArray = epoch_array(1)
    converged: NDArray = epoch_array()
    n_iter: NDArray = epoch_array()
    n_landmarks: NDArray = epoch_array()
    n_modes_vision: NDArray = epoch_array()
    risk_vision_v: NDArray = epoch_array()
    risk_vision_h: NDArray = epoch_array()
    vision: bool = False

    def trial_columns(self, vision_truth) -> dict[str, NDArray]:
        """Per trial: the largest EMT and σ_acc,v and the mean number of fault modes over its epochs."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a trial with no protected epoch: NaN
            return {"max_emt": np.nanmax(self.emt, -1), "max_sigma_acc_v": np.nanmax(self.sigma_acc_v, -1),
                    "mean_fault_modes": np.mean(self.n_modes, -1)}

    def summary_rows(self) -> dict[str, str]:
        """EMT and σ_acc,v (largest and 95th percentile over the protected epochs) and the fault modes."""
        rows = {"EMT max / p95": max_p95_text(self.emt), "σ_acc,v max / p95": max_p95_text(self.sigma_acc_v),
                "fault modes (min-max)": span_text(self.n_modes)}
        if self.vision:
            rows |= {"landmarks in ARAIM (min-max)": span_text(self.n_landmarks),
                     "vision fault modes (min-max)": span_text(self.n_modes_vision),
                     "vision integrity risk V / H (max)": f"{largest_text(self.risk_vision_v)} / "
                                                          f"{largest_text(self.risk_vision_h)}"}
        return rows

    def epoch_columns(self) -> dict[str, NDArray]:
        """EMT, σ_acc,v and σ_acc,h (m; NaN where unprotected), the fault modes monitored, N_fault,max, the
        unmonitored prior, the vertical threshold multiplier and each used system's receiver clock (m)."""
        cols = {"emt_m": self.emt, "sigma_acc_v_m": self.sigma_acc_v, "sigma_acc_h_m": self.sigma_acc_h,
                "fault_modes": self.n_modes, "fault_order": self.fault_order, "p_unmonitored": self.p_unmonitored,
                "k_fa_v": self.k_fa_v}
        clock = np.asarray(self.clock, float)
        for k, system in enumerate(SYSTEMS):
            if np.isfinite(clock[..., k]).any():  # a system some epoch used
                cols[f"clock_{system.lower()}_m"] = clock[..., k]
        return cols

    def plot_series(self) -> dict[str, tuple[NDArray, str]]:
        """EMT and σ_acc,v on the vertical panel, each with its LPV-200 limit."""
        n = np.shape(self.emt)[-1]
        return {"vertical/emt": (self.emt, "EMT"),
                "vertical/emt_limit": (np.full(n, EMT_LIMITS["LPV-200"]), "EMT limit (LPV-200)"),
                "vertical/sigma_acc_v": (self.sigma_acc_v, "σ_acc,v"),
                "vertical/sigma_acc_limit": (np.full(n, SIGMA_ACC_V_LIMITS["LPV-200"]), "σ_acc,v limit (LPV-200)")}


def system_codes(gnss: GnssEpochs) -> NDArray:
    """(S,) int system code of each satellite slot: from ``gnss.system`` (RINEX 3 letters) when the
    observations carry it, GPS otherwise; -1 for a system ARAIM has no code for (never used)."""
    letters = getattr(gnss, "system", None)  # multi-constellation observations carry it; GPS-only ones need not
    S = np.shape(gnss.prn)[-1]
    if letters is None:
        return np.zeros(S, int)
    return np.array([SYSTEM_CODES.get(str(c), -1) for c in np.asarray(letters).reshape(-1)[-S:]], int)


@dataclass(frozen=True)
class _Solved:
    """One ARAIM solve of P flat epochs: the fix, ARAIM's outputs and the reason codes of :data:`REASONS`."""

    fix: AllInViewFix
    epochs: AraimEpochs
    reason: NDArray
    pos_enu: NDArray
    clock: NDArray


def _solve(sat_enu: NDArray, pr: NDArray, system: NDArray, used: NDArray, allocation: AraimSettings,
           integrity: IntegritySettings, budget_share: NDArray | float = 1.0, camera: CameraEpochs | None = None,
           max_landmarks: int = 1) -> _Solved:
    """The all-in-view fix and ARAIM at it, for P epochs of N compacted rows (the reduced solves too); with
    ``camera`` the landmark pixel rows join at the GNSS fix (docs/design/araim.md §11)."""
    fix = all_in_view_fix(sat_enu, pr, system, used, allocation, integrity.max_iter, integrity.tol_m,
                          integrity.max_cond)
    if camera is not None:
        fix = replace(fix, rows=replace(fix.rows, **camera_rows(camera, fix.x[:, :3], max_landmarks)))
    ep = araim(fix.rows, allocation, budget_share)
    reason = ep.reason.astype(np.int8)
    reason = np.where((reason == AraimReason.OK) & ~np.isfinite(fix.x[:, 0]), AraimReason.SINGULAR, reason)
    reason = np.where((reason == AraimReason.OK) & ~fix.converged, NOT_CONVERGED, reason).astype(np.int8)
    # a position wherever the fix stands, protected or not (FAULT_ORDER, UNMONITORED: no PLs, a fix)
    fixed = ~np.isin(reason, (AraimReason.NAN_INPUT, AraimReason.NO_POSITION, AraimReason.SINGULAR, NOT_CONVERGED))
    pos = np.where(fixed[:, None], fix.x[:, :3] + np.nan_to_num(ep.dx_enu), np.nan)  # S⁽⁰⁾Δy: 0 at the fix
    first = np.argmax([(used & (system == s)).any(-1) for s in range(len(SYSTEMS))], 0)  # the first system's clock
    clock = np.where(fixed, np.take_along_axis(fix.x[:, 3:], first[:, None], -1)[:, 0], np.nan)
    return _Solved(fix, ep, reason, pos, clock)


def _compact(used: NDArray) -> tuple[NDArray, int]:
    """Slot index of the used rows first (stable) and the width N = most used rows at any epoch (≥ 1)."""
    N = max(int(used.sum(-1).max(initial=0)), 1)
    return np.argsort(~used, axis=-1, kind="stable")[..., :N], N


def araim_gnss(gnss: GnssEpochs, frame: LocalFrame, settings: AraimMonitorSettings | None = None,
               integrity: IntegritySettings | None = None, name: str = "araim",
               threads: int | None = None, vision: VisionEpochs | None = None) -> MonitorOutput:
    """The ARAIM monitor's output at every epoch (and trial) of ``gnss``.

    Parameters
    ----------
    gnss : GnssEpochs, pseudorange (B..., T, S), sat_pos_ecef (B..., T, S, 3), visible (B..., T, S);
        ``gnss.system`` (S,) RINEX 3 letters when present, GPS otherwise. Used rows: visible, a finite
        pseudorange and satellite position, a system with an ISM in ``settings``.
    frame : the world frame of the position.  settings : the monitor's options (default: all defaults).
    integrity : the run's shared settings: its service levels, the solve's iterations, tolerance and
        conditioning (default: all defaults).
    threads : chunks of trials on this many threads (bit-identical whatever the count).
    vision : the camera's landmark detections at the same epochs; read only with ``settings.vision`` (then
        required): each tracked landmark's pixels become rows with their own fault modes (§11).

    Returns
    -------
    MonitorOutput: position at the antenna, HPL/VPL (NaN where unavailable), ``test_stat`` the largest
    |x̂⁽ᵏ⁾ − x̂⁽⁰⁾| / T_k,q over modes and axes against ``threshold`` 1, the availability per service level
    of ``integrity`` (LPV-200 with EMT ≤ 15 m and σ_acc,v ≤ 1.87 m), :class:`AraimDiagnostics`.
    """
    ms = settings or AraimMonitorSettings()
    ist = integrity or IntegritySettings()
    pr = np.asarray(gnss.pseudorange, float)
    bt = pr.shape[:-1]
    sat = np.broadcast_to(np.asarray(gnss.sat_pos_ecef, float), pr.shape + (3,))
    vis = np.broadcast_to(np.asarray(gnss.visible, bool), pr.shape)
    codes = system_codes(gnss)
    allocation = ms.allocation(tuple(ist.service_levels))
    known = np.array([c >= 0 and SYSTEMS[c] in allocation.ism for c in codes], bool)
    camera = None
    if ms.vision:
        if vision is None:
            raise ValueError(f"{name}: [monitor.araim] vision = true but no vision observations were given (a run "
                             "synthesises them for this monitor; a caller of araim_gnss passes them as vision=)")
        if len(vision.t) != len(gnss.t) or not np.allclose(vision.t, gnss.t, atol=1e-6):
            raise ValueError(f"{name}: {len(gnss.t)} GNSS epochs but {len(vision.t)} vision epochs at other times "
                             "(resample one onto the other first)")
        camera = camera_epochs(vision, frame, gnss.antenna.lever_arm_body, bt, ms.sigma_px)

    def chunk(sl: slice) -> MonitorOutput:
        cam = None if camera is None else camera.take(_flat_rows(bt, sl))
        return _araim_chunk(pr[sl], sat[sl], vis[sl], codes, known, np.asarray(gnss.t), frame, ms, allocation, ist,
                            name, cam)

    return map_trial_chunks(chunk, bt, threads)


def _flat_rows(bt: tuple, sl: slice) -> NDArray:
    """The flat epoch indices (into prod(bt)) of the trial chunk ``sl`` of batch shape ``bt``."""
    return np.arange(int(np.prod(bt, dtype=np.int64))).reshape(bt)[sl].reshape(-1)


def _araim_chunk(pr: NDArray, sat: NDArray, vis: NDArray, codes: NDArray, known: NDArray, t: NDArray,
                 frame: LocalFrame, ms: AraimMonitorSettings, allocation: AraimSettings, ist: IntegritySettings,
                 name: str, camera: CameraEpochs | None = None) -> MonitorOutput:
    bt, S = pr.shape[:-1], pr.shape[-1]
    P = int(np.prod(bt, dtype=np.int64))
    pr, sat, vis = pr.reshape(P, S), sat.reshape(P, S, 3), vis.reshape(P, S)
    used_s = vis & known & np.isfinite(pr) & np.isfinite(sat).all(-1)
    idx, N = _compact(used_s)
    used = np.take_along_axis(used_s, idx, -1)
    sat_enu = frame.ecef_to_enu(np.where(used_s[..., None], sat, 0.0))
    sat_enu = np.take_along_axis(sat_enu, idx[..., None], 1)
    z = np.take_along_axis(np.where(used_s, pr, 0.0), idx, -1)
    fallback = next(c for c in range(len(SYSTEMS)) if SYSTEMS[c] in allocation.ism)  # any code with an ISM
    system = np.where(used, codes[idx], fallback)
    sv = _solve(sat_enu, z, system, used, allocation, ist, camera=camera, max_landmarks=ms.max_landmarks)
    bad = (vis & known & ~(np.isfinite(pr) & np.isfinite(sat).all(-1))).any(-1)  # as GPS RAIM: no guessing
    if bad.any():
        sv = replace(sv, reason=np.where(bad, AraimReason.NAN_INPUT, sv.reason).astype(np.int8),
                     pos_enu=np.where(bad[:, None], np.nan, sv.pos_enu), clock=np.where(bad, np.nan, sv.clock))
    out = _output(name, t, bt, S, idx, used, sv, allocation, ms.vision)
    if not ms.fde:
        return out
    return _exclusion(out, bt, idx, used, sat_enu, z, system, ms, allocation, ist, camera)


def _landmarks_used(rows) -> NDArray:
    """(P,) landmarks whose pixel rows are in the solution."""
    if rows.n_aid == 0:
        return np.zeros(np.shape(rows.used)[0], np.int16)
    pix = np.asarray(rows.aid_label)[:, 0] == AID_LANDMARK
    return (np.asarray(rows.aid_used)[:, pix].sum(-1) // 2).astype(np.int16)


def _output(name: str, t: NDArray, bt: tuple, S: int, idx: NDArray, used: NDArray, sv: _Solved,
            allocation: AraimSettings, vision: bool = False) -> MonitorOutput:
    ep, ok = sv.epochs, sv.reason == AraimReason.OK
    shape = lambda a: np.asarray(a).reshape(bt + np.shape(a)[1:])  # noqa: E731
    nan_where_not = lambda a: np.where(ok, a, np.nan)  # noqa: E731
    ratio = nan_where_not(ep.test_ratio)
    with np.errstate(invalid="ignore"):
        alert = ok & (ratio > 1.0)
    residual = _scatter(sv.fix.rows.residual, idx, used & np.isfinite(sv.pos_enu[:, :1]), S)
    present = np.stack([(used & (sv.fix.rows.system == s)).any(-1) for s in range(len(SYSTEMS))], -1)
    diag = AraimDiagnostics(
        emt=shape(nan_where_not(ep.emt)), sigma_acc_v=shape(nan_where_not(ep.sigma_acc_enu[:, 2])),
        sigma_acc_h=shape(nan_where_not(np.hypot(ep.sigma_acc_enu[:, 0], ep.sigma_acc_enu[:, 1]))),
        n_modes=shape(ep.n_modes.astype(np.int16)), fault_order=shape(ep.fault_order.astype(np.int8)),
        p_unmonitored=shape(ep.p_unmonitored), k_fa_v=shape(nan_where_not(ep.k_fa[:, 2])),
        clock=shape(np.where(present & np.isfinite(sv.pos_enu[:, :1]), sv.fix.x[:, 3:], np.nan)),
        residual=shape(residual),
        converged=shape(sv.fix.converged), n_iter=shape(sv.fix.iterations.astype(np.int16)),
        n_landmarks=shape(_landmarks_used(sv.fix.rows)),
        n_modes_vision=shape(ep.n_modes_aid[:, VISION].astype(np.int16)),
        risk_vision_v=shape(ep.risk_aid_enu[:, VISION, 2]), risk_vision_h=shape(ep.risk_aid_enu[:, VISION, :2].sum(-1)),
        vision=vision)
    return MonitorOutput(
        name=name, t=t, pos_enu=shape(sv.pos_enu), clock=shape(sv.clock), hpl=shape(nan_where_not(ep.hpl)),
        vpl=shape(nan_where_not(ep.vpl)), test_stat=shape(ratio), threshold=shape(np.where(ok, 1.0, np.nan)),
        alert=shape(alert), available=shape(ep.available & ok[:, None]),
        service_levels=tuple(allocation.service_levels), n_used=shape(used.sum(-1).astype(np.int16)),
        excluded=shape(np.full(ok.shape, -1, np.int16)), reason=shape(sv.reason), reasons=REASONS, diagnostics=diag)


def _scatter(values: NDArray, idx: NDArray, mask: NDArray, S: int) -> NDArray:
    """(P, N) compacted row values back to their (P, S) slots, NaN on every slot not in ``mask``."""
    out = np.full((idx.shape[0], S), np.nan)
    rows, cols = np.nonzero(mask)
    out[rows, idx[rows, cols]] = values[rows, cols]
    return out


def _exclusion(out: MonitorOutput, bt: tuple, idx: NDArray, used: NDArray, sat_enu: NDArray, z: NDArray,
               system: NDArray, ms: AraimMonitorSettings, allocation: AraimSettings,
               ist: IntegritySettings, camera: CameraEpochs | None = None) -> MonitorOutput:
    """``out`` after exclusion on its alerted epochs (:func:`testbed.integrity.fde.exclude`): a unit is one
    used satellite; a candidate passes when its reduced geometry's own ARAIM tests all pass. The reduced
    PLs get 1/(n_candidates + 1) of the integrity budget: the exclusion may be the wrong one of them."""
    N = used.shape[-1]
    n_sat = used.sum(-1)
    n_cand = n_sat + (n_sat * (n_sat - 1) // 2 if ms.fde_max_excluded >= 2 else 0)
    share = 1.0 / (n_cand + 1.0)

    def reduced(sel: NDArray, keep: NDArray) -> _Solved:
        return _solve(sat_enu[sel], z[sel], system[sel], used[sel] & keep, allocation, ist, share[sel],
                      None if camera is None else camera.take(sel), ms.max_landmarks)

    def solve_without(sel: NDArray, keep: NDArray) -> Verdict:
        sv = reduced(sel, keep)
        ok = sv.reason == AraimReason.OK
        x = np.concatenate([sv.pos_enu, sv.clock[:, None]], -1)
        return Verdict(x=x, test_stat=np.where(ok, sv.epochs.test_ratio, np.nan), threshold=np.ones(sel.size),
                       dof=np.ones(sel.size, int), hpl=np.where(ok, sv.epochs.hpl, np.nan),
                       vpl=np.where(ok, sv.epochs.vpl, np.nan), ok=ok,
                       n_used=(used[sel] & keep).sum(-1).astype(np.int16))

    fde_settings = ist.model_copy(update={"fde": True, "fde_rule": ms.fde_rule,
                                          "fde_max_excluded": ms.fde_max_excluded})
    label = np.where(used, idx, -1).reshape(bt + (N,))
    out = exclude(out, np.eye(N, dtype=bool), label, solve_without, fde_settings)
    # the excluded epochs' availability and diagnostics are the reduced geometry's (LPV-200 reads EMT, σ_acc)
    outcome = np.asarray(out.fde.outcome).reshape(-1)
    at = np.flatnonzero(outcome == EXCLUDED)
    if not at.size:
        return out
    gone = np.asarray(out.fde.excluded).reshape(-1, 2)[at]
    keep = used[at] & ~(idx[at, :, None] == gone[:, None, :]).any(-1)
    sv = reduced(at, keep)
    ep = sv.epochs
    flat = lambda a: np.array(a).reshape((-1,) + np.shape(a)[len(bt):])  # noqa: E731
    available = flat(out.available)
    available[at] = ep.available & (sv.reason == AraimReason.OK)[:, None]
    d = out.diagnostics
    fields = {k: flat(getattr(d, k)) for k in ("emt", "sigma_acc_v", "sigma_acc_h", "n_modes", "p_unmonitored",
                                               "k_fa_v", "fault_order")}
    fields["emt"][at], fields["sigma_acc_v"][at] = ep.emt, ep.sigma_acc_enu[:, 2]
    fields["sigma_acc_h"][at] = np.hypot(ep.sigma_acc_enu[:, 0], ep.sigma_acc_enu[:, 1])
    fields["n_modes"][at], fields["p_unmonitored"][at], fields["k_fa_v"][at] = ep.n_modes, ep.p_unmonitored, ep.k_fa[:, 2]
    fields["fault_order"][at] = ep.fault_order
    shaped = {k: v.reshape(bt + v.shape[1:]) for k, v in fields.items()}
    return replace(out, available=available.reshape(bt + available.shape[1:]), diagnostics=replace(d, **shaped))


@dataclass(frozen=True)
class AraimMonitor(MonitorDefaults):
    """ARAIM as a loop monitor: the receiver's own MHSS, at the antenna. No state."""

    name: str
    context: MonitorContext
    settings: AraimMonitorSettings
    reference: ClassVar[str] = ANTENNA
    compiles_kernels: ClassVar[bool] = True

    @property
    def inputs(self) -> frozenset[str]:
        return inputs(self.settings)

    def prepare(self) -> None:
        """Compile (or load from numba's cache) the subset and PL kernels before the first epoch: one call on
        a small sky of two systems."""
        az = np.radians(np.arange(8) * 45.0)
        el = np.radians(np.array([15.0, 60.0, 35.0, 80.0, 25.0, 50.0, 20.0, 70.0]))
        los = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
        rows = AraimRows.from_elevation(los, np.arange(8) % 2, np.ones(8, bool), AraimSettings(),
                                        residual=np.zeros(8))
        araim(rows, AraimSettings())

    def initial_state(self) -> None:
        return None

    def step(self, obs: Observations, state: None) -> tuple[MonitorOutput, None]:
        c = self.context
        return araim_gnss(obs.gnss, c.frame, self.settings, c.integrity, name=self.name, threads=c.threads,
                          vision=obs.vision), None


def inputs(options: AraimMonitorSettings) -> frozenset[str]:
    """The pseudoranges, and the camera's detections when the vision fault modes are on."""
    return frozenset({"gnss", "vision"}) if options.vision else frozenset({"gnss"})


def build_monitor(context: MonitorContext, options: AraimMonitorSettings) -> AraimMonitor:
    """The ``araim`` monitor with the approach's ``[monitor.araim]`` options."""
    return AraimMonitor("araim", context, options)

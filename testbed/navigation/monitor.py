"""The Won et al. paper's GNSS/vision/INS filter as a loop monitor (``ekf``): a peer of the snapshot monitors,
with state.

Reads GNSS, vision and IMU observations and the alignment (``Observations.init``,
given with the first block); steps the EKF core (:mod:`.ekf`, :mod:`.run`)
through each block's IMU intervals and updates at its GNSS epochs with
whatever satellites and surveyed landmarks are in view — 0 to 3 satellites
included. Its output per GNSS epoch:

* position and clock of the IMU point (the CG with the default zero lever arm);
* the **tests** (docs/design/nav-filter.md §8), P_FA split equally between those enabled: the
  innovation χ² test (NIS of all rows used at the epoch against χ²⁻¹(1 − share; rows)),
  the windowed test (the NIS summed over the last ``window_s``, for slow ramps), and
  with ``pl_variant = "ss"`` the solution-separation test (:mod:`.separation`);
  ``test_stat`` is the NIS, ``alert`` any of them;
* **protection levels**: ``ss`` (default) the solution-separation PLs, which bound the
  error under a fault of any one satellite or of the vision rows as a whole; ``araim`` ARAIM's budget over
  the bank, the IMU a fault mode of its own (:mod:`.filter_araim`: its separation test is then the only alert,
  the χ² tests diagnostics); ``covariance``
  ``HPL = K_ff √λ_max(P_EN)``, ``VPL = K_ff σ_U`` with ``K_ff = Φ⁻¹(1 − P_ff/2)``: the
  fault-free bound only, **not fault tolerant**;
* availability per service level on those PLs.

With tracked ground features in the observations (``[vision.features]`` enabled, ``features = true``) the
filter is the SLAM one (:mod:`.slam`): the same core, tests and PLs, plus feature states by delayed
initialisation; its bank's vision modes are each landmark (``ss_vision = "landmark"``) and the features as
one mode, or one camera mode for every pixel row (``"camera"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator
from scipy import stats

from testbed.integrity.araim import AraimSettings
from testbed.integrity.araim.protection import EMT_LIMITS, araim_availability
from testbed.integrity.levels import availability, service_level
from testbed.integrity.gps_only import gps_satellites
from testbed.integrity.monitor import MonitorContext, MonitorCost, MonitorDefaults, Observations, REFERENCE_POINT
from testbed.navigation.ekf import CameraNoise, ImuNoise, NavState, predict_compiled
from testbed.navigation.filter_araim import FILTER_ARAIM_REASONS, filter_araim
from testbed.navigation.run import ClockNoise, filter_epochs, state_from_init
from testbed.navigation.separation import Bank, separation
from testbed.navigation.slam import FeatureSettings, SlamState, run_slam, start
from testbed.records import Diagnostics, MonitorOutput, epoch_array, largest_text, max_p95_text, span_text
from testbed.schema import StrictModel

#: the filter's reason texts
EKF_REASONS: tuple[str, ...] = ("ok", "unavailable: the filter is not initialised (no alignment yet)",
                                 *FILTER_ARAIM_REASONS)
NOT_INITIALISED = 1
#: where the ARAIM variant's reasons start in :data:`EKF_REASONS`
ARAIM_REASON_BASE = 1


#: ARAIM settings the filter's variant does not read (refused when set), and the ISM keys likewise
ARAIM_UNREAD = frozenset({"user_error", "tropo_zenith_m", "fc_thres", "min_fault_order", "max_fault_order", "max_cond",
                          "service_levels"})
ISM_UNREAD = frozenset({"sigma_ura_m", "sigma_ure_m", "b_nom_m", "b_cont_m"})


class EkfSettings(StrictModel):
    """Options of the ``ekf`` monitor (``[monitor.ekf]`` in an approach file)."""

    p_ff: float = Field(1e-7, gt=0.0, lt=1.0,
                        description="fault-free risk of the protection levels: K_ff = Φ⁻¹(1 − P_ff/2) multiplies the "
                                    "position sigmas ('covariance') and the full filter's share of the separation "
                                    "bound ('ss')")
    pl_variant: Literal["ss", "covariance", "araim"] = Field(
        "ss", description="protection levels: 'ss' = solution separation over sub-filters without each satellite "
                          "and without the vision rows (fault tolerant); 'araim' = ARAIM's fault modes, thresholds "
                          "and protection-level equation over sub-filters without each satellite, without every "
                          "satellite, without each landmark (ss_vision) and without the camera, and the IMU as a fault mode of its own (its subset: the "
                          "epoch's pseudoranges alone); 'covariance' = K_ff·σ (fault-free only, not fault tolerant)")
    araim: AraimSettings = Field(default_factory=AraimSettings,
                                 description="with pl_variant = 'araim': the allocation and priors (GPS's ISM priors "
                                             "for satellites and the constellation; landmark, camera and inertia "
                                             "priors); the filter's own noise model replaces the ISM's σ and b_nom")
    ss_vision: Literal["landmark", "camera"] = Field(
        "landmark", description="solution separation's vision fault modes: 'landmark' = a sub-filter without each "
                                "landmark (a misidentified landmark, the pixel monitor's threat); 'camera' = one "
                                "without every vision row (also a camera-wide fault; with one satellite its "
                                "sub-filter is GNSS/INS dead reckoning)")
    window_s: float = Field(10.0, ge=0.0, le=600.0, description="the windowed χ² test's span (s): the NIS summed "
                                                                 "over the epochs of the last window_s; 0 = off")
    vision: bool = Field(True, description="update with the surveyed landmarks' pixels")
    dither_sigma_px: float = Field(0.0, ge=0.0, description="extra white pixel 1σ per row (px), beside the "
                                                            "published dithering (modelled as the camera's "
                                                            "rotation, common to a frame's pixels)")
    landmark_survey_sigma_m: float = Field(0.05, ge=0.0, description="landmark survey error 1σ per axis the filter "
                                                                     "assumes (m)")
    range_rate: bool = Field(True, description="a range-rate (Doppler) row beside each pseudorange row")
    range_rate_sigma_m_s: float = Field(0.05, gt=0.0, le=100.0, description="the range-rate 1σ the filter assumes "
                                                                           "(m/s; the sensor's default "
                                                                           "gnss.range_rate_sigma_m_s)")
    features: bool = Field(True, description="update with the tracked unsurveyed ground features when the approach "
                                             "synthesises them ([vision.features] enabled): SLAM states by delayed "
                                             "initialisation (testbed/navigation/slam.py)")
    feature_slots: int = Field(7, ge=1, le=30, description="feature states the filter holds")
    feature_clones: int = Field(2, ge=1, le=10, description="pose clones waiting for parallax (features being "
                                                            "initialised at once)")
    parallax_deg: float = Field(3.0, gt=0.0, lt=90.0, description="a feature is triangulated once its two "
                                                                  "bearings are this far apart")
    max_wait_frames: int = Field(30, ge=1, le=10_000, description="a clone without parallax after this many "
                                                                  "GNSS epochs is dropped")
    lost_frames: int = Field(5, ge=0, le=10_000, description="a feature unseen for this many GNSS epochs is "
                                                            "marginalised")

    @model_validator(mode="after")
    def _araim_reads_its_own(self):
        """The ARAIM variant's table is read only with it, and it runs without SLAM features."""
        if self.pl_variant != "araim":
            if "araim" in self.model_fields_set:
                raise ValueError(f"araim: read only with pl_variant = 'araim' (pl_variant = {self.pl_variant!r})")
            return self
        if "features" in self.model_fields_set and self.features:
            raise ValueError("features = true: pl_variant = 'araim' runs the filter without SLAM features "
                             "(expected false or unset)")
        unread = sorted(self.araim.model_fields_set & ARAIM_UNREAD)
        gps = self.araim.ism.get("GPS")
        unread += [f"ism.{k}" for k in self.araim.ism if k != "GPS" and "ism" in self.araim.model_fields_set]
        unread += [f"ism.GPS.{k}" for k in sorted(gps.model_fields_set & ISM_UNREAD)] if gps is not None else []
        if unread:
            raise ValueError(f"araim: {', '.join(unread)} not read by the filter's variant (its covariances are the "
                             "filter's noise model, its satellites GPS's, its modes single events, its levels the "
                             "run's: docs/design/nav-filter.md §8.4)")
        return self

    @property
    def araim_variant(self) -> bool:
        return self.pl_variant == "araim"

    def feature_settings(self) -> FeatureSettings:
        return FeatureSettings(self.feature_slots, self.feature_clones, self.parallax_deg, self.max_wait_frames,
                               self.lost_frames)


@dataclass(frozen=True)
class EkfDiagnostics(Diagnostics):
    """The filter at its GNSS epochs (B..., T[, ...])."""

    sigma_enu: NDArray = epoch_array(1)
    cov_enu: NDArray = epoch_array(2)  # the position covariance (B..., T, 3, 3), m²
    nis: NDArray = epoch_array()
    dof: NDArray = epoch_array()
    accel_bias: NDArray = epoch_array(1)
    gyro_bias: NDArray = epoch_array(1)
    clock_drift: NDArray = epoch_array()
    window_stat: NDArray = epoch_array()
    window_threshold: NDArray = epoch_array()
    ss_ratio: NDArray = epoch_array()
    n_modes: NDArray = epoch_array()
    n_features: NDArray = epoch_array()  # features in the filter's state (0 without [vision.features])
    emt: NDArray = epoch_array()  # 'araim': the effective monitor threshold (m), NaN otherwise
    p_unmonitored: NDArray = epoch_array()  # 'araim': the exposure prior left unmonitored, NaN otherwise
    #: 'araim': the integrity risk the vision modes and the IMU's mode take in the PL equation at the PLs, per axis
    #: over the exposure (B..., T, 2, 3): [vision, inertia] × [E, N, U]; NaN otherwise
    risk_aid_enu: NDArray = epoch_array(2)
    k_ff: float = 0.0
    araim: bool = False  # the options asked for pl_variant = 'araim'

    def summary_rows(self) -> dict[str, str]:
        """With the ARAIM variant: EMT (largest and 95th percentile over the protected epochs), the fault modes, the
        largest unmonitored prior and the vision modes' and the IMU mode's largest vertical integrity risk."""
        if not self.araim:
            return {}

        risk_v = np.asarray(self.risk_aid_enu, float)[..., 2]
        return {"EMT max / p95": max_p95_text(self.emt), "fault modes (min-max)": span_text(self.n_modes),
                "unmonitored prior (max)": largest_text(self.p_unmonitored),
                "vision / IMU integrity risk V (max)": f"{largest_text(risk_v[..., 0])} / "
                                                       f"{largest_text(risk_v[..., 1])}"}

    def epoch_columns(self) -> dict[str, NDArray]:
        """With the ARAIM variant: EMT (m), the unmonitored prior and the vision and IMU modes' vertical risk."""
        if not self.araim:
            return {}
        risk = np.asarray(self.risk_aid_enu, float)
        return {"emt_m": self.emt, "p_unmonitored": self.p_unmonitored, "fault_modes": self.n_modes,
                "risk_vision_v": risk[..., 0, 2], "risk_inertia_v": risk[..., 1, 2]}

    def plot_series(self) -> dict[str, tuple[NDArray, str]]:
        """With the ARAIM variant: EMT on the vertical panel with its LPV-200 limit."""
        if not self.araim:
            return {}
        n = np.shape(self.emt)[-1]
        return {"vertical/emt": (self.emt, "EMT"),
                "vertical/emt_limit": (np.full(n, EMT_LIMITS["LPV-200"]), "EMT limit (LPV-200)")}


@dataclass(frozen=True)
class EkfState:
    """The filter's carry between blocks: None before the alignment; the sub-filter bank (ss); the last
    epochs' NIS and dof within the window (their times (W,), values (B, W)); with ground features the
    SLAM filter instead of ``nav`` and ``bank`` (it holds its own bank); the landmarks seen so far (B, L) (araim)."""

    nav: NavState | None = None
    bank: Bank | None = None
    window: tuple[NDArray, NDArray, NDArray] | None = None
    slam: SlamState | None = None
    seen: NDArray | None = None


@dataclass(frozen=True)
class EkfMonitor(MonitorDefaults):
    name: str
    context: MonitorContext
    settings: EkfSettings
    inputs: ClassVar[frozenset[str]] = frozenset({"gnss", "vision", "imu", "features"})
    reference: ClassVar[str] = REFERENCE_POINT
    compiles_kernels: ClassVar[bool] = True
    several_tests: ClassVar[bool] = True  # its alert is the innovation, windowed and separation tests

    def prepare(self) -> None:
        """Compile the predict kernel (numba caches it beside the package) before the first epoch."""
        s = state_from_init(_dummy_init())
        predict_compiled(s, np.zeros((1, 3)), np.zeros((1, 3)), 0.01, self.context.frame,
                         ImuNoise(0.0, 0.0, 0.0, 0.0, 1.0, 1.0), ClockNoise())

    def initial_state(self) -> EkfState:
        return EkfState()

    def step(self, obs: Observations, state: EkfState) -> tuple[MonitorOutput, EkfState]:
        obs = gps_satellites(obs)  # the filter stays GPS-only (docs/design/gnss.md §5)
        g = obs.gnss
        lead = np.shape(g.pseudorange)[:-2]
        T = len(g.t)
        nav, bank, slam = state.nav, state.bank, state.slam
        araim = self.settings.araim_variant
        ss = self.settings.pl_variant == "ss" or araim
        if nav is None and slam is None and obs.init is not None:
            nav = state_from_init(obs.init, None if not lead else lead[0])
            S, per_landmark = np.shape(g.prn)[0], self.settings.ss_vision == "landmark"
            if self.settings.features and obs.features is not None and not araim:
                slam, nav = start(nav, self.settings.feature_settings(), S if ss else None, per_landmark), None
            elif ss:
                bank = Bank.empty(nav.p.shape[0], S, per_landmark, gnss_mode=araim, camera_mode=araim and per_landmark)
        if (nav is None and slam is None) or obs.imu is None:
            return self._unavailable(g.t, lead, T), EkfState(nav, bank, state.window, slam, state.seen)
        vis = obs.vision if self.settings.vision else None
        # one camera: its dithering turns every pixel of a frame together (landmarks and features)
        sig = obs.vision.dither_sigma if obs.vision is not None else np.zeros(3)
        camera = CameraNoise(self.settings.dither_sigma_px, tuple(float(x) for x in np.asarray(sig, float)))
        noise = ImuNoise.from_figures(obs.imu.figures)
        rr = self.settings.range_rate_sigma_m_s if self.settings.range_rate else None
        if slam is not None:
            trace, slam = run_slam(slam, obs.imu, self.context.frame, noise, self.settings.feature_settings(),
                                   tracks=obs.features, gnss=g, t_aid=g.t, range_rate_sigma_m_s=rr, vision=vis,
                                   camera=camera, survey_sigma_m=self.settings.landmark_survey_sigma_m,
                                   through_end=True)
            bank = slam.bank
        else:
            trace, nav, bank = filter_epochs(
                nav, obs.imu, self.context.frame, noise, g, vis, ClockNoise(), camera=camera,
                survey_sigma_m=self.settings.landmark_survey_sigma_m, through_end=True, range_rate_sigma_m_s=rr,
                bank=bank, snapshot=araim)
        seen, n_landmarks = landmarks_seen(vis, state.seen, trace.p.shape[0], T)
        out, window = self._output(trace, bank, lead, state.window, n_landmarks)
        return out, EkfState(nav, None if slam is not None else bank, window, slam, seen)

    def _test_share(self) -> float:
        """P_FA split equally between the enabled tests (a union bound keeps their joint rate within P_FA)."""
        n = 1 + (self.settings.window_s > 0) + (self.settings.pl_variant == "ss")
        return self.context.integrity.p_fa / n

    def _output(self, tr, bank: Bank | None, lead: tuple, window, n_landmarks: NDArray
                ) -> tuple[MonitorOutput, tuple]:
        st = self.context.integrity
        share = self._test_share()
        k_ff = float(stats.norm.isf(self.settings.p_ff / 2))
        P = tr.P_pos
        sig = np.sqrt(np.maximum(np.diagonal(P, axis1=-2, axis2=-1), 0.0))
        nis_raw, dof = tr.nis, tr.dof
        with np.errstate(invalid="ignore"):
            thr = np.where(dof > 0, stats.chi2.isf(share, np.maximum(dof, 1)), np.nan)
            nis = np.where(dof > 0, nis_raw, np.nan)
            alert = nis > thr
        w_stat, w_thr, window = windowed_chi2(tr.t, nis_raw, dof, window, self.settings.window_s, share)
        with np.errstate(invalid="ignore"):
            alert |= w_stat > w_thr
        nan = np.full(nis.shape, np.nan)
        emt, p_nm, reason = nan, nan, np.zeros(nis.shape, np.int8)
        risk_aid = np.full(nis.shape + (2, 3), np.nan)
        levels = tuple(service_level(s) for s in st.service_levels)
        if self.settings.araim_variant:
            allocation = self.settings.araim.model_copy(update={"service_levels": tuple(st.service_levels)})
            fa = filter_araim(tr.p, P, bank.modes, bank.vision_mode, bank.per_landmark, tr.sub_dp, tr.sub_Pp,
                              tr.snap_p, tr.snap_P, n_landmarks, allocation)
            hpl, vpl = np.hypot(fa.pl_enu[..., 0], fa.pl_enu[..., 1]), fa.pl_enu[..., 2]
            alert = fa.ratio > 1.0  # ARAIM's tests are the alert; the χ² tests stay diagnostics
            ratio, n_modes, emt, p_nm, risk_aid = fa.ratio, fa.n_modes, fa.emt, fa.p_unmonitored, fa.risk_aid_enu
            reason = np.where(fa.reason > 0, ARAIM_REASON_BASE + fa.reason, 0).astype(np.int8)
            avail = araim_availability(hpl, vpl, emt, sig[..., 2], allocation.service_levels)
        elif bank is not None:
            sep = separation(P, tr.sub_dp, tr.sub_Pp, share, st.p_md, self.settings.p_ff)
            hpl, vpl = np.hypot(sep.pl_enu[..., 0], sep.pl_enu[..., 1]), sep.pl_enu[..., 2]
            alert |= sep.ratio > 1.0
            ratio, n_modes = sep.ratio, sep.n_modes
        else:
            lam = np.linalg.eigvalsh(P[..., :2, :2])[..., -1]
            hpl, vpl = k_ff * np.sqrt(np.maximum(lam, 0.0)), k_ff * sig[..., 2]
            ratio, n_modes = np.full(hpl.shape, np.nan), np.zeros(hpl.shape, np.int64)
        if not self.settings.araim_variant:  # ARAIM's availability adds EMT and σ_acc,v (set above)
            avail = availability(hpl, vpl, levels)
        shape = lambda a: a.reshape(lead + a.shape[1:]) if lead else a[0]  # noqa: E731
        n_feat = getattr(tr, "n_features", np.zeros(nis.shape, np.int64))
        diag = EkfDiagnostics(sigma_enu=shape(sig), cov_enu=shape(P), nis=shape(nis), dof=shape(dof),
                              accel_bias=shape(tr.ba), gyro_bias=shape(tr.bg), clock_drift=shape(tr.cd),
                              window_stat=shape(w_stat), window_threshold=shape(w_thr), ss_ratio=shape(ratio),
                              n_modes=shape(n_modes), n_features=shape(n_feat), emt=shape(emt),
                              p_unmonitored=shape(p_nm), risk_aid_enu=shape(risk_aid), k_ff=k_ff,
                              araim=self.settings.araim_variant)
        hpl, vpl = shape(hpl), shape(vpl)
        T = tr.t.size
        return MonitorOutput(
            name=self.name, t=np.asarray(tr.t), pos_enu=shape(tr.p), clock=shape(tr.cb), hpl=hpl, vpl=vpl,
            test_stat=shape(nis), threshold=shape(thr), alert=shape(alert), available=shape(avail),
            service_levels=tuple(st.service_levels), n_used=shape(dof).astype(np.int16),
            excluded=np.full(lead + (T,), -1, np.int16), reason=shape(reason), reasons=EKF_REASONS,
            diagnostics=diag), window

    def _unavailable(self, t: NDArray, lead: tuple, T: int) -> MonitorOutput:
        st = self.context.integrity
        nan = np.full(lead + (T,), np.nan)
        z = lambda *tail: np.full(lead + (T,) + tail, np.nan)  # noqa: E731
        diag = EkfDiagnostics(sigma_enu=z(3), cov_enu=z(3, 3), nis=nan, dof=np.zeros(lead + (T,), np.int64), accel_bias=z(3),
                              gyro_bias=z(3), clock_drift=nan, window_stat=nan, window_threshold=nan, ss_ratio=nan,
                              n_modes=np.zeros(lead + (T,), np.int64), n_features=np.zeros(lead + (T,), np.int64),
                              emt=nan, p_unmonitored=nan, risk_aid_enu=z(2, 3), k_ff=float(stats.norm.isf(self.settings.p_ff / 2)),
                              araim=self.settings.araim_variant)
        return MonitorOutput(
            name=self.name, t=np.asarray(t), pos_enu=z(3), clock=nan, hpl=nan, vpl=nan, test_stat=nan, threshold=nan,
            alert=np.zeros(lead + (T,), bool), available=np.zeros(lead + (T, len(st.service_levels)), bool),
            service_levels=tuple(st.service_levels), n_used=np.zeros(lead + (T,), np.int16),
            excluded=np.full(lead + (T,), -1, np.int16), reason=np.full(lead + (T,), NOT_INITIALISED, np.int8),
            reasons=EKF_REASONS, diagnostics=diag)


def landmarks_seen(vision, seen: NDArray | None, B: int, T: int) -> tuple[NDArray | None, NDArray]:
    """The landmarks detected so far per trial (B, L), carried across blocks, and their count at each epoch (B, T)
    (zeros without vision)."""
    if vision is None:
        return seen, np.zeros((B, T)) if seen is None else np.broadcast_to(seen.sum(-1)[:, None], (B, T)).astype(float)
    det = np.broadcast_to(np.asarray(vision.detected, bool), (B,) + np.shape(vision.detected)[-2:])
    before = np.zeros((B, det.shape[-1]), bool) if seen is None else seen
    cum = np.logical_or.accumulate(det, axis=1) | before[:, None, :]
    return (cum[:, -1] if T else before), cum.sum(-1).astype(float)


def windowed_chi2(t: NDArray, nis: NDArray, dof: NDArray, carry, span: float, p_fa: float):
    """The windowed test (docs/design/nav-filter.md §8.1, (8.3)): ``Q_k = Σ q_i`` over the epochs in
    (t_k − span, t_k] against χ²⁻¹(1 − p_fa; Σ m_i), carried across blocks. Returns the statistic and threshold (B, T) and the carry
    (the last span's times (W,), NIS and dof (B, W)). Each sum is over its own slice, so where the blocks
    split the flight does not change a bit."""
    B, T = nis.shape
    if span <= 0:
        return np.full((B, T), np.nan), np.full((B, T), np.nan), None
    t_w, n_w, d_w = carry if carry is not None else (np.zeros(0), np.zeros((B, 0)), np.zeros((B, 0), np.int64))
    t_all = np.concatenate([t_w, t])
    n_all, d_all = np.concatenate([n_w, nis], 1), np.concatenate([d_w, dof], 1)
    q, m = np.empty((B, T)), np.empty((B, T), np.int64)
    for k in range(T):
        i = t_w.size + k
        j = int(np.searchsorted(t_all, t_all[i] - span + 1e-6, side="left"))
        q[:, k], m[:, k] = n_all[:, j:i + 1].sum(-1), d_all[:, j:i + 1].sum(-1)
    with np.errstate(invalid="ignore"):
        thr = np.where(m > 0, stats.chi2.isf(p_fa, np.maximum(m, 1)), np.nan)
        q = np.where(m > 0, q, np.nan)
    keep = t_all > t_all[-1] - span + 1e-6 if t_all.size else np.zeros(0, bool)
    return q, thr, (t_all[keep], n_all[:, keep], d_all[:, keep])


def _dummy_init():
    from testbed.records import NavInit

    return NavInit(t=0.0, C=np.eye(3), v=np.zeros(3), p=np.zeros(3), clock_bias=np.zeros(()), clock_drift=np.zeros(()),
                   sigma=np.ones(17))


def build_monitor(context: MonitorContext, options: EkfSettings) -> EkfMonitor:
    """The filter with the approach's ``[monitor.ekf]`` options."""
    return EkfMonitor("ekf", context, options)


def cost(options: EkfSettings) -> MonitorCost:
    """Per trial-epoch, measured alone on zunz-rwy05-ekf, the draws subtracted; the tracked ground features'
    SLAM states on zunz-rwy05-slam."""
    return MonitorCost((25e3, 0.0, 0.0), (0.75e-3, 0.0, 0.0), features=(4.3e3, 3.8e-3))


__all__ = ["EKF_REASONS", "EkfMonitor", "EkfSettings", "EkfState", "build_monitor", "windowed_chi2"]

"""The seed-002 filter as a loop monitor (``ekf``): a peer of the snapshot monitors, with state.

Reads GNSS, vision and IMU observations and the alignment (``Observations.init``,
given with the first block); steps the EKF core (:mod:`.ekf`, :mod:`.run`)
through each block's IMU intervals and updates at its GNSS epochs with
whatever satellites and surveyed landmarks are in view — 0 to 3 satellites
included. Its output per GNSS epoch:

* position and clock of the IMU point (the CG with the default zero lever arm);
* the **innovation χ² test**: NIS of all rows used at the epoch against
  χ²⁻¹(1 − P_FA; rows) (no test at a dead-reckoning epoch);
* **covariance protection levels** ``HPL = K_ff √λ_max(P_EN)``, ``VPL = K_ff σ_U``
  with ``K_ff = Φ⁻¹(1 − P_ff/2)``: the fault-free bound only, **not fault tolerant**
  (a satellite fault the test misses is not in them; NAV_FILTER.md §7's solution
  separation is the next step), and they grow along unobservable directions;
* availability per service level on those PLs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field
from scipy import stats

from testbed.integrity.levels import availability, service_level
from testbed.integrity.monitor import REFERENCE_POINT, MonitorContext, Observations
from testbed.navigation.ekf import ImuNoise, NavState, predict_compiled
from testbed.navigation.run import ClockNoise, filter_epochs, state_from_init
from testbed.records import Diagnostics, MonitorOutput, epoch_array
from testbed.schema import StrictModel

#: the filter's reason texts
EKF_REASONS: tuple[str, ...] = ("ok", "unavailable: the filter is not initialised (no alignment yet)")
NOT_INITIALISED = 1


class EkfSettings(StrictModel):
    """Options of the ``ekf`` monitor (``[ekf]`` in an approach file)."""

    pl_variant: Literal["covariance"] = Field(
        "covariance", description="protection levels: 'covariance' = K_ff·σ (fault-free only, not fault tolerant)")
    vision: bool = Field(True, description="update with the surveyed landmarks' pixels")
    dither_sigma_px: float = Field(0.0, ge=0.0, description="extra pixel 1σ for camera dithering (px); "
                                                            "added to the published dithering's f·σ")
    landmark_survey_sigma_m: float = Field(0.05, ge=0.0, description="landmark survey error 1σ per axis the filter "
                                                                     "assumes (m)")
    range_rate: bool = Field(True, description="a range-rate (Doppler) row beside each pseudorange row")
    range_rate_sigma_m_s: float = Field(0.05, gt=0.0, le=100.0, description="the range-rate 1σ the filter assumes "
                                                                           "(m/s; the sensor's default "
                                                                           "gnss.range_rate_sigma_m_s)")


@dataclass(frozen=True)
class EkfDiagnostics(Diagnostics):
    """The filter at its GNSS epochs (B..., T[, ...])."""

    sigma_enu: NDArray = epoch_array(1)
    nis: NDArray = epoch_array()
    dof: NDArray = epoch_array()
    accel_bias: NDArray = epoch_array(1)
    gyro_bias: NDArray = epoch_array(1)
    clock_drift: NDArray = epoch_array()
    k_ff: float = 0.0


@dataclass(frozen=True)
class EkfState:
    """The filter's carry between blocks: None before the alignment."""

    nav: NavState | None = None


@dataclass(frozen=True)
class EkfMonitor:
    name: str
    context: MonitorContext
    settings: EkfSettings
    inputs: ClassVar[frozenset[str]] = frozenset({"gnss", "vision", "imu"})
    reference: ClassVar[str] = REFERENCE_POINT

    def prepare(self) -> None:
        """Compile the predict kernel (numba caches it beside the package) before the first epoch."""
        s = state_from_init(_dummy_init())
        predict_compiled(s, np.zeros((1, 3)), np.zeros((1, 3)), 0.01, self.context.frame,
                         ImuNoise(0.0, 0.0, 0.0, 0.0, 1.0, 1.0), ClockNoise())

    def initial_state(self) -> EkfState:
        return EkfState()

    def step(self, obs: Observations, state: EkfState) -> tuple[MonitorOutput, EkfState]:
        g = obs.gnss
        lead = np.shape(g.pseudorange)[:-2]
        T = len(g.t)
        nav = state.nav
        if nav is None and obs.init is not None:
            nav = state_from_init(obs.init, None if not lead else lead[0])
        if nav is None or obs.imu is None:
            return self._unavailable(g.t, lead, T), EkfState(nav)
        vis = obs.vision if self.settings.vision else None
        dither = 0.0
        if vis is not None:
            f = float(np.asarray(vis.K)[0, 0])
            dither = float(np.hypot(self.settings.dither_sigma_px, f * np.max(np.asarray(vis.dither_sigma))))
        trace, nav = filter_epochs(nav, obs.imu, self.context.frame, ImuNoise.from_figures(obs.imu.figures), g, vis,
                                   ClockNoise(), dither_sigma_px=dither,
                                   survey_sigma_m=self.settings.landmark_survey_sigma_m, through_end=True,
                                   range_rate_sigma_m_s=self.settings.range_rate_sigma_m_s if self.settings.range_rate
                                   else None)
        return self._output(trace, lead), EkfState(nav)

    def _output(self, tr, lead: tuple) -> MonitorOutput:
        st = self.context.integrity
        k_ff = float(stats.norm.isf(st.p_ff / 2))
        P = tr.P
        sig = np.sqrt(np.maximum(np.diagonal(P[..., :3, :3], axis1=-2, axis2=-1), 0.0))
        lam = np.linalg.eigvalsh(P[..., :2, :2])[..., -1]
        hpl, vpl = k_ff * np.sqrt(np.maximum(lam, 0.0)), k_ff * sig[..., 2]
        dof = tr.dof
        with np.errstate(invalid="ignore"):
            thr = np.where(dof > 0, stats.chi2.isf(st.p_fa, np.maximum(dof, 1)), np.nan)
            nis = np.where(dof > 0, tr.nis, np.nan)
            alert = nis > thr
        levels = tuple(service_level(s) for s in st.service_levels)
        shape = lambda a: a.reshape(lead + a.shape[1:]) if lead else a[0]  # noqa: E731
        diag = EkfDiagnostics(sigma_enu=shape(sig), nis=shape(nis), dof=shape(dof), accel_bias=shape(tr.ba),
                              gyro_bias=shape(tr.bg), clock_drift=shape(tr.cd), k_ff=k_ff)
        hpl, vpl = shape(hpl), shape(vpl)
        T = tr.t.size
        return MonitorOutput(
            name=self.name, t=np.asarray(tr.t), pos_enu=shape(tr.p), clock=shape(tr.cb), hpl=hpl, vpl=vpl,
            test_stat=shape(nis), threshold=shape(thr), alert=shape(alert), available=availability(hpl, vpl, levels),
            service_levels=tuple(st.service_levels), n_used=shape(dof).astype(np.int16),
            excluded=np.full(lead + (T,), -1, np.int16), reason=np.zeros(lead + (T,), np.int8), reasons=EKF_REASONS,
            diagnostics=diag)

    def _unavailable(self, t: NDArray, lead: tuple, T: int) -> MonitorOutput:
        st = self.context.integrity
        nan = np.full(lead + (T,), np.nan)
        z = lambda *tail: np.full(lead + (T,) + tail, np.nan)  # noqa: E731
        diag = EkfDiagnostics(sigma_enu=z(3), nis=nan, dof=np.zeros(lead + (T,), np.int64), accel_bias=z(3),
                              gyro_bias=z(3), clock_drift=nan, k_ff=float(stats.norm.isf(st.p_ff / 2)))
        return MonitorOutput(
            name=self.name, t=np.asarray(t), pos_enu=z(3), clock=nan, hpl=nan, vpl=nan, test_stat=nan, threshold=nan,
            alert=np.zeros(lead + (T,), bool), available=np.zeros(lead + (T, len(st.service_levels)), bool),
            service_levels=tuple(st.service_levels), n_used=np.zeros(lead + (T,), np.int16),
            excluded=np.full(lead + (T,), -1, np.int16), reason=np.full(lead + (T,), NOT_INITIALISED, np.int8),
            reasons=EKF_REASONS, diagnostics=diag)


def _dummy_init():
    from testbed.records import NavInit

    return NavInit(t=0.0, C=np.eye(3), v=np.zeros(3), p=np.zeros(3), clock_bias=np.zeros(()), clock_drift=np.zeros(()),
                   sigma=np.ones(17))


def build_monitor(context: MonitorContext, options) -> EkfMonitor:
    return EkfMonitor("ekf", context, EkfSettings.model_validate(dict(options)))


__all__ = ["EKF_REASONS", "EkfMonitor", "EkfSettings", "EkfState", "build_monitor"]

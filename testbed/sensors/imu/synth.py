"""IMU synthesis: error-free increments by inverse strapdown of the truth, then the error model.

:func:`true_increments` is a pure function of the truth (``testbed.inertial``'s
equations, so the navigation mechanisation reproduces the truth from them);
:class:`ImuErrorStream` draws the errors of a batch of trials interval by
interval, time-major, so any chunking of the intervals gives bit-identical
draws and, for one trial, the first k intervals never depend on later ones
(prefix stability, as the other sensors); :func:`apply_faults` adds the injected
IMU faults (:mod:`testbed.sensors.faults`, deterministic: no draw); :func:`sample_imu`
puts them together.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from testbed.frames import LocalFrame
from testbed.inertial import body_to_world, earth_rate_world, inverse_strapdown, local_to_world
from testbed.records import ImuSamples, ImuTruth, Truth
from testbed.sensors.faults import imu_fault_increments

from .settings import ImuSettings


def _decimation(truth: Truth, rate_hz: float) -> int:
    """Truth samples per IMU interval (the IMU rate must divide the truth rate)."""
    dt = float(np.median(np.diff(truth.t))) if len(truth.t) > 1 else 1.0 / rate_hz
    step = 1.0 / (rate_hz * dt)
    k = int(round(step))
    if k < 1 or abs(step - k) > 1e-6 * step:
        raise ValueError(f"imu.rate_hz = {rate_hz:g}: expected a divisor of the truth rate {1.0 / dt:g} Hz "
                         f"(e.g. {1.0 / dt:g}, {0.5 / dt:g}, {0.25 / dt:g})")
    return k


def true_increments(truth: Truth, settings: ImuSettings) -> tuple[NDArray, NDArray, NDArray, float]:
    """Error-free (t (K,), Δθ (K, 3), Δv (K, 3), Δt) of an IMU at ``settings.lever_arm_body_m`` from the CG.

    The truth is taken every ``truth rate / rate_hz`` samples; the pose there is the world-frame
    attitude C_b^w, the IMU point's position p + C l and Earth-relative velocity
    v + C((ω − Cᵀω_ie) × l).
    """
    k = _decimation(truth, settings.rate_hz)
    idx = np.arange(0, len(truth.t), k)
    frame = LocalFrame(*map(float, truth.frame_origin))
    p = np.asarray(truth.pos_enu, float)[idx]
    C = body_to_world(frame, p, np.asarray(truth.q_body_to_enu, float)[idx])
    v = local_to_world(frame, p, np.asarray(truth.vel_enu, float)[idx])
    lever = np.asarray(settings.lever_arm_body_m, float)
    if np.any(lever):
        w_ie = earth_rate_world(frame, settings.earth_rotation)
        w_eb = np.asarray(truth.omega_body, float)[idx] - np.einsum("tji,j->ti", C, w_ie)
        p = p + np.einsum("tij,j->ti", C, lever)
        v = v + np.einsum("tij,tj->ti", C, np.cross(w_eb, lever))
    t = np.asarray(truth.t, float)[idx]
    dt = 1.0 / settings.rate_hz  # nominal: any stretch of the flight gives the same increments, bit for bit
    dtheta, dvel = inverse_strapdown(frame, C, v, p, dt, settings.earth_rotation)
    return t[1:], dtheta, dvel, dt


class ImuErrorStream:
    """The error processes of a batch of IMUs, drawn interval by interval (module doc).

    Children of ``rng`` (one per purpose, in this order): turn-on gyro and accel biases,
    gyro and accel scale factors, the in-run Gauss–Markov starts and driving noise, the
    white noise of each sensor.
    """

    def __init__(self, settings: ImuSettings, dt: float, rng: np.random.Generator, n_trials: int | None = None):
        f = settings.figures()
        self.batch = () if n_trials is None else (int(n_trials),)
        self.dt = dt
        kids = rng.spawn(8)
        shape = self.batch + (3,)
        self.b0 = {"g": kids[0].standard_normal(shape) * f["gyro_bias"],
                   "a": kids[1].standard_normal(shape) * f["accel_bias"]}
        sf = settings.scale_factor_ppm * 1e-6
        self.scale = {"g": kids[2].standard_normal(shape) * sf, "a": kids[3].standard_normal(shape) * sf}
        self.a = {"g": float(np.exp(-dt / f["tau_gyro"])), "a": float(np.exp(-dt / f["tau_accel"]))}
        self.sigma_gm = {"g": f["gyro_inrun"], "a": f["accel_inrun"]}
        self.gm_rng = {"g": kids[4], "a": kids[5]}
        # the stationary start of each in-run bias, then its driving noise from the same child
        self.beta = {s: self.gm_rng[s].standard_normal(shape) * self.sigma_gm[s] for s in "ga"}
        self.white = {"g": (kids[6], f["arw"] * np.sqrt(dt)), "a": (kids[7], f["vrw"] * np.sqrt(dt))}

    def draw(self, k: int) -> dict[str, NDArray]:
        """Biases in force over the next ``k`` intervals and their white noise, each (B..., k, 3)."""
        out = {}
        if k == 0:
            empty = np.zeros(self.batch + (0, 3))
            return {f"{kind}_{s}": empty for kind in ("bias", "white") for s in "ga"}
        for s in "ga":
            xi = self.gm_rng[s].standard_normal((k,) + self.batch + (3,))  # time-major
            a = self.a[s]
            gain = self.sigma_gm[s] * np.sqrt(1.0 - a * a)
            beta, _ = signal.lfilter([gain], [1.0, -a], xi, axis=0, zi=(a * self.beta[s])[None])
            self.beta[s] = beta[-1]
            g, scale = self.white[s]
            white = g.standard_normal((k,) + self.batch + (3,)) * scale
            out[f"bias_{s}"] = np.moveaxis(self.b0[s] + beta, 0, -2)
            out[f"white_{s}"] = np.moveaxis(white, 0, -2)
        return out


def apply_errors(dtheta: NDArray, dvel: NDArray, stream: ImuErrorStream, errors: dict[str, NDArray]
                 ) -> tuple[NDArray, NDArray]:
    """Measured increments (B..., k, 3) from error-free ones (k, 3) and one :meth:`ImuErrorStream.draw`."""
    dt = stream.dt
    sg, sa = stream.scale["g"][..., None, :], stream.scale["a"][..., None, :]
    dth = (1.0 + sg) * dtheta + errors["bias_g"] * dt + errors["white_g"]
    dv = (1.0 + sa) * dvel + errors["bias_a"] * dt + errors["white_a"]
    return dth, dv


def apply_faults(t: NDArray, dtheta: NDArray, dvel: NDArray, dt: float, faults) -> tuple[NDArray, NDArray]:
    """Increments (B..., K, 3) of the intervals ending at ``t`` (K,) with the IMU faults of ``faults`` added
    (:func:`~testbed.sensors.faults.imu_fault_increments`: the same for every trial); unchanged without one."""
    add_th, add_v = imu_fault_increments(list(faults), t, dt)
    if not (add_th.any() or add_v.any()):
        return dtheta, dvel
    return dtheta + add_th, dvel + add_v


def sample_imu(truth: Truth, settings: ImuSettings, rng: np.random.Generator, n_trials: int | None = None,
               faults=()) -> tuple[ImuSamples, ImuTruth]:
    """IMU increments along a flight (``n_trials`` independent IMUs when given: a leading trial axis), with the
    IMU faults of ``faults`` (a fault schedule; its other kinds are ignored)."""
    t, dtheta, dvel, dt = true_increments(truth, settings)
    stream = ImuErrorStream(settings, dt, rng, n_trials)
    err = stream.draw(t.size)
    dth, dv = apply_errors(dtheta, dvel, stream, err)
    dth, dv = apply_faults(t, dth, dv, dt, faults)
    fault_th, fault_v = imu_fault_increments(list(faults), t, dt)
    lever = np.asarray(settings.lever_arm_body_m, float)
    samples = ImuSamples(t=t, dtheta=dth, dvel=dv, dt=dt, lever_arm_body=lever, earth_rotation=settings.earth_rotation,
                         figures=settings.figures())
    itruth = ImuTruth(t=t, dtheta=dtheta, dvel=dvel, gyro_bias=err["bias_g"], accel_bias=err["bias_a"],
                      fault_dtheta=fault_th, fault_dvel=fault_v,
                      gyro_scale=stream.scale["g"], accel_scale=stream.scale["a"])
    return samples, itruth

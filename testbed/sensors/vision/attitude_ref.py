"""The navigation side's attitude reference: truth plus an AHRS/IRS-like error.

The monitors of the pixel-domain model (docs/design/integrity.md §10) and the
lever-arm correction (§2 there) need the aircraft attitude; they get this reference, never
the truth. Error model per Euler angle (roll, pitch, heading)::

    ε_k(t) = b_k + w_k(t),   b_k ~ N(0, bias_sigma_k²) once per flight,
                              w_k(t) ~ N(0, noise_sigma_k²) white per epoch.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from testbed.frames import R_NED_TO_ENU, q_to_R

from .settings import AttitudeRefSettings


def q_to_euler(q_body_to_enu: ArrayLike) -> NDArray:
    """Body->ENU quaternions ``(..., 4)`` to Euler angles ``(..., 3)`` rad (roll, pitch, heading)."""
    q = np.asarray(q_body_to_enu, float)
    R_b2ned = R_NED_TO_ENU @ q_to_R(q)
    zyx = Rotation.from_matrix(R_b2ned.reshape(-1, 3, 3)).as_euler("ZYX").reshape(q.shape[:-1] + (3,))
    return zyx[..., ::-1]


def euler_to_q_fast(euler: ArrayLike) -> NDArray:
    """(roll, pitch, heading) ``(..., 3)`` rad to body->ENU quaternions ``(..., 4)`` (scalar last).

    Closed form (same result as :func:`testbed.frames.euler_to_q_body_to_enu`, up to
    the quaternion sign, which the tests check) because the campaign calls it on
    millions of epochs: q_b2ned = qz(ψ) ⊗ qy(θ) ⊗ qx(φ), then the NED->ENU swap, a
    180° rotation about (1, 1, 0)/√2, i.e. q = [1/√2, 1/√2, 0, 0].
    """
    e = np.asarray(euler, float) / 2.0
    cr, sr = np.cos(e[..., 0]), np.sin(e[..., 0])
    cp, sp = np.cos(e[..., 1]), np.sin(e[..., 1])
    cy, sy = np.cos(e[..., 2]), np.sin(e[..., 2])
    w = cr * cp * cy + sr * sp * sy
    x = sr * cp * cy - cr * sp * sy
    y = cr * sp * cy + sr * cp * sy
    z = cr * cp * sy - sr * sp * cy
    # [a, 0] ⊗ [v, w] with a = (1, 1, 0)/√2 (scalar 0): vector = a w + a × v, scalar = -a·v
    k = 1.0 / np.sqrt(2.0)
    return np.stack([k * (w + z), k * (w - z), k * (y - x), -k * (x + y)], axis=-1)


def attitude_reference(q_body_to_enu: ArrayLike, settings: AttitudeRefSettings, rng: np.random.Generator,
                       n_trials: int | None = None) -> tuple[NDArray, NDArray, NDArray]:
    """The attitude the navigation system reports.

    Parameters
    ----------
    q_body_to_enu : (T, 4) true body->local ENU quaternions (scalar last).
    settings : error model.
    rng : random source (bias first, then the white noise).
    n_trials : leading trial axis (independent errors per trial) when given.

    Returns
    -------
    q_ref : (B..., T, 4) body->ENU reference quaternions.
    err_euler : (B..., T, 3) rad, the drawn (roll, pitch, heading) errors (truth side).
    sigma : (3,) rad, total 1-sigma per axis, sqrt(bias² + noise²) (what the monitor is told).
    """
    return attitude_reference_from_euler(q_to_euler(q_body_to_enu), settings, rng, n_trials)


def attitude_reference_from_euler(euler_true: ArrayLike, settings: AttitudeRefSettings, rng: np.random.Generator,
                                  n_trials: int | None = None) -> tuple[NDArray, NDArray, NDArray]:
    """:func:`attitude_reference` from the true Euler angles ``(T, 3)`` rad (roll, pitch, heading),
    i.e. ``q_to_euler(q_body_to_enu)`` (the truth-only part, computed once per epoch).

    The bias ``(B..., 1, 3)`` is drawn before the time-major noise ``(B..., T, 3)``, so
    without ``n_trials`` the first k epochs do not depend on T (prefix stable).
    Returns ``(q_ref, err_euler, sigma)`` as :func:`attitude_reference`.
    """
    eul_true = np.asarray(euler_true, float)
    batch = () if n_trials is None else (int(n_trials),)
    z_bias, z_noise = attitude_draws(rng, batch, eul_true.shape[:-1])
    return attitude_reference_from_draws(eul_true, settings, z_bias, z_noise)


def attitude_draws(rng: np.random.Generator, batch: tuple, epochs: tuple) -> tuple[NDArray, NDArray]:
    """The standard-normal draws of the reference's errors: the bias ``(B..., 1, 3)`` first, then the time-major
    white noise ``(B..., T, 3)`` (prefix stable without a batch)."""
    return rng.standard_normal(batch + (1, 3)), rng.standard_normal(batch + tuple(epochs) + (3,))


def attitude_reference_from_draws(euler_true: ArrayLike, settings: AttitudeRefSettings, z_bias: NDArray,
                                  z_noise: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """:func:`attitude_reference_from_euler` from the standard-normal draws of :func:`attitude_draws` (an
    importance-sampling proposal may have moved them)."""
    sb = np.radians(settings.bias_sigma_deg)
    sn = np.radians(settings.noise_sigma_deg)
    err = z_bias * sb + z_noise * sn
    q_ref = euler_to_q_fast(np.asarray(euler_true, float) + err)
    return q_ref, err, np.sqrt(sb**2 + sn**2)

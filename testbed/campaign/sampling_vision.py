"""The vision part of an importance-sampling proposal: which camera draws it moves, as columns beside the
pseudorange draws (:mod:`testbed.campaign.sampling`).

A monitor that reads the camera (the pixel monitor, VA-RAIM) has a position error linear, to first order, in the
standard-normal draws of the vision error model as well as in the pseudorange draws. Per epoch the proposal sees
the draws as one vector, the pseudorange slots (``S``) followed by the vision columns of :class:`VisionColumns`:

* the detection error of each landmark's pixel, ``u`` and ``v`` (``2L``: the DE and the per-landmark blur, drawn
  per epoch);
* the frame's blur rotation (1: ``blur_model = "rotation"``, one rotation per frame along the camera's rate);
* the attitude reference's white noise (3: roll, pitch, heading, per epoch);
* the dithering's band-limited noise at the epoch (3: camera axes), over its σ: ``ζ_t = g_t·w/|g_t|`` of the
  filter's white grid ``w``, moved through that grid (``w += δ g_t/|g_t|``), so the dithering stays the filter's
  and the likelihood ratio is that of ``ζ_t`` alone (the samples at other epochs move by their correlation with
  it, ~e⁻²² one second apart at the default 5 Hz bandwidth);
* the attitude reference's bias (3: drawn once per sortie). Its columns repeat the same draws at every epoch:
  a component that shifts one epoch moves the sortie's bias too, and its likelihood ratio ``exp(m·z − |m|²/2)``
  reads it once, from that epoch's row.

Left as drawn (``p = q`` for them, out of the weight): the dithering's tones (their phases are uniform, not
Gaussian), the landmark survey (one per block, shared by its sorties: a per-trial weight cannot
tilt it), the vision faults' targets. The linear model is measured as for the pseudoranges, by a probe per column
(:func:`probe_tilt`): the error-free scene (no detection error, no blur, no attitude error, no dithering tones, the
dithering noise's standard values 0 at the epochs, the landmarks where they stand) and :data:`PROBE_Z` standard deviations on one column at every epoch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.sensors.vision.detect import VisionDraws

#: the probe on one vision column, in standard deviations of its draw (0.1 px of a 1 px detection error, 0.35 mrad
#: of a 3.5 mrad heading bias: the pixel model's curvature over it is far below the fit's convergence)
PROBE_Z = 0.1


@dataclass(frozen=True)
class VisionColumns:
    """The per-epoch columns of the vision draws with ``landmarks`` landmark slots (module doc)."""

    landmarks: int

    @property
    def detection(self) -> slice:
        return slice(0, 2 * self.landmarks)

    @property
    def blur(self) -> int:
        return 2 * self.landmarks

    @property
    def attitude_noise(self) -> slice:
        return slice(2 * self.landmarks + 1, 2 * self.landmarks + 4)

    @property
    def dither_noise(self) -> slice:
        return slice(2 * self.landmarks + 4, 2 * self.landmarks + 7)

    @property
    def attitude_bias(self) -> slice:
        return slice(2 * self.landmarks + 7, 2 * self.landmarks + 10)

    @property
    def size(self) -> int:
        return 2 * self.landmarks + 10

    def names(self, landmark_ids) -> list[str]:
        """A name per column (for messages and tables)."""
        px = [f"{i}:{axis}" for i in landmark_ids for axis in ("u", "v")]
        return px + ["blur rotation"] + [f"attitude noise {a}" for a in ("roll", "pitch", "heading")] \
            + [f"dithering noise {a}" for a in ("x", "y", "z")] \
            + [f"attitude bias {a}" for a in ("roll", "pitch", "heading")]

    def stack(self, d: VisionDraws) -> np.ndarray:
        """(n, T, size) the draws ``d`` (trial axis first) as columns, the bias repeated at every epoch."""
        n, T = d.detection.shape[:2]
        return np.concatenate([d.detection.reshape(n, T, -1), d.blur[..., None], d.attitude_noise, d.dither_noise,
                               np.broadcast_to(d.attitude_bias, (n, T, 3))], axis=-1)

    def shifted(self, d: VisionDraws, shift: np.ndarray) -> VisionDraws:
        """``d`` moved by ``shift`` (n, T, size) (standard units); the bias by the sum over the epochs of its
        columns (a component shifts one epoch)."""
        n, T = d.detection.shape[:2]
        return VisionDraws(detection=d.detection + shift[..., self.detection].reshape(d.detection.shape),
                           blur=d.blur + shift[..., self.blur],
                           attitude_noise=d.attitude_noise + shift[..., self.attitude_noise],
                           attitude_bias=d.attitude_bias + shift[..., self.attitude_bias].sum(1, keepdims=True),
                           dither_noise=d.dither_noise + shift[..., self.dither_noise],
                           dither_tone_angle=d.dither_tone_angle, dither_tone_rate=d.dither_tone_rate)


def probe_tilt(cols: VisionColumns, first: int, probes: int):
    """The ``tilt`` of :func:`~testbed.sensors.vision.detect.sample_vision` for a monitor's probe: trial ``j``
    of each group of ``probes`` (trials ``w·probes + j``) is the error-free scene, with :data:`PROBE_Z` on vision
    column ``j − first`` at every epoch when ``first ≤ j < first + cols.size`` (the other trials probe the
    pseudoranges, or none)."""

    def tilt(d: VisionDraws) -> VisionDraws:
        n, T = d.detection.shape[:2]
        z = np.zeros((n, T, cols.size))
        j = np.arange(n) % probes - first
        on = (j >= 0) & (j < cols.size)
        z[np.flatnonzero(on), :, j[on]] = PROBE_Z
        zero = VisionDraws(detection=np.zeros_like(d.detection), blur=np.zeros_like(d.blur),
                           attitude_bias=np.zeros_like(d.attitude_bias),
                           attitude_noise=np.zeros_like(d.attitude_noise), dither_noise=np.zeros_like(d.dither_noise),
                           dither_tone_angle=np.zeros_like(d.dither_tone_angle),
                           dither_tone_rate=np.zeros_like(d.dither_tone_rate))
        return cols.shifted(zero, _bias_once(cols, z))

    return tilt


def _bias_once(cols: VisionColumns, z: np.ndarray) -> np.ndarray:
    """``z`` with the bias columns kept at the first epoch only (:meth:`VisionColumns.shifted` sums them)."""
    z = z.copy()
    z[:, 1:, cols.attitude_bias] = 0.0
    return z


class TiltRecorder:
    """A vision ``tilt`` that moves the draws by ``shift`` (n, T, size) and keeps the moved draws' columns
    (``z``), where the caller evaluates the likelihood ratio."""

    def __init__(self, cols: VisionColumns, shift: np.ndarray):
        self.cols, self.shift, self.z = cols, shift, None

    def __call__(self, d: VisionDraws) -> VisionDraws:
        moved = self.cols.shifted(d, self.shift)
        self.z = self.cols.stack(moved)
        return moved

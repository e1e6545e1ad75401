"""Fault schedules: what goes wrong, when, on which satellite or landmark.

A schedule is a list of fault models (a tagged union on ``kind``), read from
the ``[[faults]]`` tables of an approach file or built in code. Faults are
applied *after* nominal noise, and the truth side of every sensor output
records them, so evaluation can tell faulty measurements apart.

GNSS faults are turned into a bias array here (:func:`gnss_fault_bias`);
vision faults are applied by the vision sensor, which owns the geometry they
perturb, using :func:`active` for the time window.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

import numpy as np
from numpy.typing import NDArray
from pydantic import AfterValidator, Field, model_validator

from testbed.schema import StrictModel

def _some_satellite(v):
    if isinstance(v, list) and not v:
        raise ValueError("expected a PRN, a list of at least 1 PRN, or 'random' (got an empty list)")
    return v


SatSelector = Annotated[Union[int, list[int], Literal["random"]], AfterValidator(_some_satellite)]


class _Timed(StrictModel):
    onset_s: float = Field(0.0, ge=0.0, le=7200.0, description="fault starts at this time since approach start (s)")
    end_s: float | None = Field(None, le=7200.0, description="fault ends (exclusive); None = to the end")

    @model_validator(mode="after")
    def _window(self):
        if self.end_s is not None and self.end_s <= self.onset_s:
            raise ValueError(f"end_s ({self.end_s}) must be after onset_s ({self.onset_s})")
        return self


class GpsStep(_Timed):
    """A constant pseudorange bias on the selected satellite(s)."""

    kind: Literal["gps_step"] = Field(..., description="fault kind")
    prn: SatSelector = Field("random", description="PRN, list of PRNs, or 'random' (a visible one at onset)")
    bias_m: float = Field(..., ge=-1e6, le=1e6, description="pseudorange bias (beyond 1000 km a receiver rejects "
                                                               "the range)")


class GpsRamp(_Timed):
    """A pseudorange error growing linearly from the onset."""

    kind: Literal["gps_ramp"] = Field(..., description="fault kind")
    prn: SatSelector = Field("random", description="PRN, list of PRNs, or 'random' (a visible one at onset)")
    rate_m_s: float = Field(..., ge=-1e4, le=1e4, description="growth rate of the pseudorange error")


class GpsClockRunoff(_Timed):
    """A satellite clock run-off: error = drift·τ + ½·accel·τ², τ = t − onset."""

    kind: Literal["gps_clock"] = Field(..., description="fault kind")
    prn: SatSelector = Field("random", description="PRN, list of PRNs, or 'random' (a visible one at onset)")
    drift_m_s: float = Field(0.0, ge=-1e4, le=1e4, description="clock error rate at the onset")
    accel_m_s2: float = Field(0.05, ge=-1e3, le=1e3, description="clock error acceleration")


class PixelBias(_Timed):
    """A bias on one landmark's detected pixel (polar: magnitude, direction in the image)."""

    kind: Literal["pixel_bias"] = Field(..., description="fault kind")
    landmark: str | Literal["random"] = Field("random", description="landmark id, or 'random' (one detected "
                                                                     "at onset, drawn per trial)")
    magnitude_px: float = Field(..., ge=0.0, le=1e4, description="bias magnitude")
    angle_deg: float = Field(0.0, ge=-360.0, le=360.0, description="bias direction in the image, from the u "
                                                                   "axis (right) towards v (down)")


class LandmarkMoved(_Timed):
    """The real landmark stands at surveyed + delta (the survey says otherwise)."""

    kind: Literal["landmark_moved"] = Field(..., description="fault kind")
    landmark: str | Literal["random"] = Field("random", description="landmark id, or 'random' (one detected "
                                                                     "at onset, drawn per trial)")
    delta_enu_m: tuple[Annotated[float, Field(ge=-1e4, le=1e4)], Annotated[float, Field(ge=-1e4, le=1e4)],
                       Annotated[float, Field(ge=-1e4, le=1e4)]] = Field(
        ..., description="where the real landmark stands relative to its surveyed position, ENU")


class Misassociation(_Timed):
    """Two landmarks' detections are swapped by the matcher."""

    kind: Literal["misassociation"] = Field(..., description="fault kind")
    landmarks: tuple[str, str] = Field(..., description="ids of the two landmarks whose detections the matcher "
                                                         "swaps")

    @model_validator(mode="after")
    def _two(self):
        if self.landmarks[0] == self.landmarks[1]:
            raise ValueError(f"landmarks: expected two different landmarks, got {list(self.landmarks)}")
        return self


Fault = Annotated[Union[GpsStep, GpsRamp, GpsClockRunoff, PixelBias, LandmarkMoved, Misassociation],
                  Field(discriminator="kind")]
GNSS_KINDS = ("gps_step", "gps_ramp", "gps_clock")
VISION_KINDS = ("pixel_bias", "landmark_moved", "misassociation")


def active(fault: _Timed, t: NDArray) -> NDArray:
    """Boolean mask ``(T,)``: where the fault is active at times ``t``."""
    t = np.asarray(t, float)
    on = t >= fault.onset_s
    if fault.end_s is not None:
        on &= t < fault.end_s
    return on


def fault_profile(fault: GpsStep | GpsRamp | GpsClockRunoff, t: NDArray) -> NDArray:
    """Error added to the faulty pseudorange at times ``t`` ``(T,)``, m (0 when inactive)."""
    tau = np.asarray(t, float) - fault.onset_s
    if isinstance(fault, GpsStep):
        e = np.full_like(tau, fault.bias_m)
    elif isinstance(fault, GpsRamp):
        e = fault.rate_m_s * tau
    else:
        e = fault.drift_m_s * tau + 0.5 * fault.accel_m_s2 * tau**2
    return np.where(active(fault, t), e, 0.0)


def select_satellites(fault, t: NDArray, prn: NDArray, visible: NDArray,
                      rng: np.random.Generator) -> NDArray:
    """Slot mask ``(S,)`` of the satellites a GNSS fault hits.

    ``visible`` is ``(T, S)``. "random" draws one satellite visible at the
    first active epoch (uniformly, from ``rng``); if none is visible, none is hit.
    """
    prn = np.asarray(prn)
    sel = fault.prn
    if sel == "random":
        on = np.flatnonzero(active(fault, t))
        hit = np.zeros(prn.shape, bool)
        if on.size == 0:
            return hit
        cands = np.flatnonzero(visible[on[0]])
        if cands.size:
            hit[rng.choice(cands)] = True
        return hit
    wanted = [sel] if isinstance(sel, int) else list(sel)
    missing = sorted(set(wanted) - set(prn.tolist()))
    if missing:
        raise ValueError(f"fault {fault.kind}: PRN(s) {missing} not in the constellation {sorted(prn.tolist())}")
    return np.isin(prn, wanted)


def gnss_fault_bias(faults: list, t: NDArray, prn: NDArray, visible: NDArray,
                    rng: np.random.Generator) -> NDArray:
    """Total injected pseudorange error ``(T, S)`` from the GNSS faults of a schedule.

    Non-GNSS faults are ignored. ``rng`` is used only for "random" selections;
    each fault gets its own child generator (spawned in schedule order), so a
    fault's choice does not depend on whether another fault's onset is inside
    ``t`` yet: the result is stable when ``t`` grows (the closed loop relies on it).
    """
    t = np.asarray(t, float)
    bias = np.zeros((t.size, len(prn)))
    for f, g in zip(faults, rng.spawn(len(faults))):
        if f.kind not in GNSS_KINDS:
            continue
        hit = select_satellites(f, t, prn, np.asarray(visible, bool), g)
        bias[:, hit] += fault_profile(f, t)[:, None]
    return bias

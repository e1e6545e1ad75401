"""The monitor contract: every integrity monitor is a plug-in of this shape.

A monitor is built from its settings and the run's frame (:class:`MonitorContext`),
declares which observations it reads (:attr:`Monitor.inputs`) and steps over a
block of epochs with an explicit, typed state::

    state = monitor.initial_state()
    for obs in blocks:                          # or one call on the whole flight
        out, state = monitor.step(obs, state)   # MonitorOutput of the block's epochs

Stepping block by block gives the same output as one call on all epochs (the
state carries exactly what later epochs need, nothing of the past beyond that).
The registry (:mod:`testbed.integrity.registry`) maps names to builders; the
loop, the campaign runner, the sinks and the API iterate over it and never name a
monitor.

Writing one::

    @dataclass(frozen=True)
    class PlainLsq:
        name: str
        context: MonitorContext
        inputs: ClassVar[frozenset[str]] = frozenset({"gnss"})
        reference: ClassVar[str] = ANTENNA

        def initial_state(self):
            return None

        def step(self, obs, state):
            return my_least_squares(obs.gnss, self.context.frame), state

    register("plain_lsq", lambda ctx, options: PlainLsq("plain_lsq", ctx))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping, Protocol, runtime_checkable

from testbed.frames import LocalFrame
from testbed.integrity.settings import IntegritySettings
from testbed.records import (CorrelatorEpochs, FeatureTracks, GnssEpochs, ImuSamples, MonitorOutput, NavInit,
                             VisionEpochs)

#: what a monitor's position estimate refers to (evaluation picks the matching truth)
ANTENNA = "antenna"
REFERENCE_POINT = "reference point (CG)"

#: observation kinds a monitor may declare in ``inputs``
INPUT_KINDS = frozenset({"gnss", "vision", "imu", "correlators", "features"})


@dataclass(frozen=True)
class Observations:
    """One block of what the sensors report (no truth), batch-first, at the monitor epochs.

    gnss : GnssEpochs (B..., T, S).  vision : VisionEpochs at the same epochs, or None
    when no monitor of the run reads vision.  imu : the IMU intervals of the block (None
    unless a monitor reads "imu").  init : the alignment (:class:`~testbed.records.NavInit`),
    with the first block only.  correlators : the correlograms at the GNSS epochs (None unless
    a monitor reads "correlators").  features : the tracked unsurveyed ground features at the GNSS
    epochs (None unless a monitor reads "features" and the approach's ``[vision.features]`` is enabled).
    """

    gnss: GnssEpochs
    vision: VisionEpochs | None = None
    imu: ImuSamples | None = None
    init: NavInit | None = None
    correlators: CorrelatorEpochs | None = None
    features: FeatureTracks | None = None

    @property
    def t(self):
        return self.gnss.t


@dataclass(frozen=True)
class MonitorContext:
    """What every monitor is built from: the run's world frame and the shared integrity settings.

    options : the approach file's per-monitor tables (``[va_raim]``...), by table name;
        a builder validates its own.
    threads : worker threads a monitor may use on a batch (None: one per core).
    """

    frame: LocalFrame
    integrity: IntegritySettings
    options: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    threads: int | None = None


@runtime_checkable
class Monitor(Protocol):
    """An integrity monitor in the loop (see the module doc)."""

    name: str
    inputs: ClassVar[frozenset[str]]
    reference: ClassVar[str]

    def initial_state(self) -> Any:
        """The state before the first epoch (typed, serialisable; None for a snapshot monitor)."""

    def step(self, obs: Observations, state: Any) -> tuple[MonitorOutput, Any]:
        """The output at ``obs``'s epochs and the state after them."""


def provided_output(provider: Monitor, provider_out: MonitorOutput, wanted: Monitor) -> MonitorOutput | None:
    """``wanted``'s output if ``provider`` computed it on the way (None otherwise).

    A monitor may define ``provides(other, its_output) -> MonitorOutput | None``: VA-RAIM's
    step 1 *is* GPS RAIM, so a campaign running both solves it once. Whatever a
    provider returns must equal ``wanted.step`` on the same observations (each
    provider has a test that says so).
    """
    fn = getattr(provider, "provides", None)
    return fn(wanted, provider_out) if fn is not None else None

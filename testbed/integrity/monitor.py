"""The monitor contract: every integrity monitor is a plug-in of this shape.

A monitor is built from its settings and the run's frame (:class:`MonitorContext`),
declares which observations it reads (:attr:`Monitor.inputs`) and steps over a
block of epochs with an explicit, typed state::

    state = monitor.initial_state()
    for obs in blocks:                          # or one call on the whole flight
        out, state = monitor.step(obs, state)   # MonitorOutput of the block's epochs

Stepping block by block gives the same output as one call on all epochs (the
state carries exactly what later epochs need, nothing of the past beyond that).
The registry (:mod:`testbed.monitors`) maps names to builders and option models;
the loop, the campaign runner, the sinks and the API iterate over it and never name
a monitor.

Writing one::

    @dataclass(frozen=True)
    class PlainLsq(MonitorDefaults):
        name: str
        context: MonitorContext
        inputs: ClassVar[frozenset[str]] = frozenset({"gnss"})
        reference: ClassVar[str] = ANTENNA

        def initial_state(self):
            return None

        def step(self, obs, state):
            return my_least_squares(obs.gnss, self.context.frame), state

    register("plain_lsq", lambda ctx, options: PlainLsq("plain_lsq", ctx), {"gnss"})  # testbed.monitors
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Mapping, Protocol, runtime_checkable

from testbed.frames import LocalFrame
from testbed.integrity.settings import IntegritySettings
from testbed.schema import StrictModel
from testbed.records import (CorrelatorEpochs, FeatureTracks, GnssEpochs, ImuSamples, MonitorOutput, NavInit,
                             VisionEpochs)

#: what a monitor's position estimate refers to (evaluation picks the matching truth)
ANTENNA = "antenna"
REFERENCE_POINT = "reference point (CG)"

#: observation kinds a monitor may declare in ``inputs``
INPUT_KINDS = frozenset({"gnss", "vision", "imu", "correlators", "features"})


@dataclass(frozen=True)
class MonitorCost:
    """What a monitor costs per trial-epoch, measured (the resource estimate of a run, :mod:`testbed.sim.budget`):
    its working arrays (bytes) and one thread's time (s), each a constant, a part per landmark it weighs and a
    part per pair of them.

    landmark_cap : at most this many landmarks weighed (None: every detected one).
    features : (bytes, seconds) more when it tracks ground features (it reads "features" and the run has a scene).
    provides : monitors whose output it computes on the way (they cost no time beside it).
    """

    bytes: tuple[float, float, float]
    seconds: tuple[float, float, float]
    landmark_cap: int | None = None
    features: tuple[float, float] = (0.0, 0.0)
    provides: tuple[str, ...] = ()

    def at(self, landmarks: int) -> tuple[float, float]:
        """(bytes, seconds) with ``landmarks`` in view."""
        used = min(landmarks, self.landmark_cap) if self.landmark_cap else landmarks
        x = (1.0, used, used * (used - 1) / 2)
        return sum(a * b for a, b in zip(self.bytes, x)), sum(a * b for a, b in zip(self.seconds, x))


class NoOptions(StrictModel):
    """The options table of a monitor that takes none (any key in it is an error)."""


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


def compute(key: tuple, make: Callable[[], Any], guard: object = None) -> Any:
    """No sharing: ``make()`` (the default of :attr:`MonitorContext.share`)."""
    return make()


@dataclass(frozen=True)
class MonitorContext:
    """What every monitor is built from: the run's world frame and the shared integrity settings.

    options : the approach file's per-monitor tables (``[monitor.<name>]``), by monitor name, validated
        by each monitor's options model (a builder receives its own).
    threads : worker threads a monitor may use on a batch (None: one per core).
    share : ``share(key, make, guard)`` returns ``make()``, or the value an earlier call with the same key made:
        a monitor hands it the parts of its work that other runs may have done alike (VA-RAIM's GPS step, its
        vision ranges). The caller decides whether anything is shared (a campaign shares between the cells of a
        sweep, :mod:`testbed.memo`); by default nothing is.
    """

    frame: LocalFrame
    integrity: IntegritySettings
    options: Mapping[str, Any] = field(default_factory=dict)
    threads: int | None = None
    share: Callable[..., Any] = compute


@runtime_checkable
class Monitor(Protocol):
    """An integrity monitor in the loop (see the module doc). Every member a caller uses is declared here;
    :class:`MonitorDefaults` gives the optional ones their defaults."""

    name: str
    #: the observation kinds it reads (:data:`INPUT_KINDS`): the run synthesises only what some monitor reads
    inputs: ClassVar[frozenset[str]]
    #: the true point its position is judged against: :data:`ANTENNA` or :data:`REFERENCE_POINT`
    reference: ClassVar[str]
    #: the position dimensions its protection levels bound: ("H", "V"), or ("V",) for a vertical-only monitor
    dimensions: ClassVar[tuple[str, ...]]
    #: its alert is several tests (plotted each over its threshold), not one statistic against one threshold
    several_tests: ClassVar[bool]
    #: :meth:`prepare` compiles kernels (the first run announces it)
    compiles_kernels: ClassVar[bool]
    #: :meth:`provides` may return another monitor's output (a campaign steps such monitors first)
    provides_others: ClassVar[bool]

    def initial_state(self) -> Any:
        """The state before the first epoch (typed, serialisable; None for a snapshot monitor)."""

    def step(self, obs: Observations, state: Any) -> tuple[MonitorOutput, Any]:
        """The output at ``obs``'s epochs and the state after them."""

    def prepare(self) -> None:
        """Compile or load what the first step would (before the flight, not in its first epochs)."""

    def provides(self, other: "Monitor", its_output: MonitorOutput) -> MonitorOutput | None:
        """``other``'s output when this monitor computed it on the way (VA-RAIM's step 1 is GPS RAIM), else None.
        Whatever it returns must equal ``other.step`` on the same observations."""


class MonitorDefaults:
    """The defaults of the contract's optional members: a monitor class derives from this and defines
    ``name``, ``inputs``, ``reference``, ``initial_state`` and ``step``."""

    dimensions: ClassVar[tuple[str, ...]] = ("H", "V")
    several_tests: ClassVar[bool] = False
    compiles_kernels: ClassVar[bool] = False
    provides_others: ClassVar[bool] = False

    def prepare(self) -> None:
        return None

    def provides(self, other: Monitor, its_output: MonitorOutput) -> MonitorOutput | None:
        return None


#: every member of the contract, for the registry's check of a built monitor
CONTRACT = ("name", "inputs", "reference", "dimensions", "several_tests", "compiles_kernels", "provides_others",
            "initial_state", "step", "prepare", "provides")


def contract_problems(monitor: object) -> list[str]:
    """The members of the contract ``monitor`` lacks (empty when it has them all)."""
    return [m for m in CONTRACT if not hasattr(monitor, m)]


def provided_output(provider: Monitor, provider_out: MonitorOutput, wanted: Monitor) -> MonitorOutput | None:
    """``wanted``'s output if ``provider`` computed it on the way (None otherwise): a campaign running VA-RAIM and
    GPS RAIM solves GPS RAIM once (each provider has a test that its output equals ``wanted.step``)."""
    return provider.provides(wanted, provider_out)

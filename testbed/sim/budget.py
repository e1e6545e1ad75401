"""What a command will cost, estimated before any work: peak resident memory and wall time, and the refusal
above a limit (``--allow-large`` overrides it).

The estimate is a small model of the arrays that dominate, with constants measured on the development machine
(2 cores; ``benchmarks/bench_budget.py --fit`` measures them, and without ``--fit`` prints the predicted
against the measured peak resident memory and wall time of whole campaigns):

* a **draw block** holds, per trial and epoch, the GNSS draw (bytes per satellite of the constellation), the
  camera frames (bytes per landmark) and each monitor's working arrays (bytes per trial-epoch, measured per
  monitor with its shipped scene, the vision monitors' scaled by the landmarks they weigh);
* **correlograms** are synthesised one trial at a time (its T x S x M statistic and temporaries; the exact
  synthesis works in pieces of ``_EXACT_BYTES``);
* the **ground-feature scene** (points per km² of the corridor) costs its points while it is built, and the
  tracker's view search a block of epochs times every point;
* the process itself (interpreter, packages, compiled kernels) and the per-sortie flight.

Time is seconds per trial-epoch per monitor and per sensor draw, spread over the cores the command uses.
The model is not a promise: measured against it, whole runs came within a factor 2 (the benchmark's table).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

from testbed.flight.fly import approach_geometry
from testbed.integrity.monitor import MonitorCost
from testbed.monitors import monitor_cost, reads
from testbed.schema import ConfigError
from testbed.sensors.gnss.constellations import tracked_constellations
from testbed.sensors.gnss.correlators import _EXACT_BYTES, delay_grid
from testbed.sensors.gnss.timebase import utc_to_gps_seconds
from testbed.sensors.vision.features import corridor_size
from testbed.sensors.vision.landmarks import build_landmarks
from testbed.sim.preflight import flight_duration_bound

GB = 1e9

# ----------------------------------------------------------------------------- measured constants
# benchmarks/bench_budget.py --fit on the development machine (2 cores, Python 3.11, numpy with OpenBLAS);
# bytes are traced numpy allocations (tracemalloc) of a draw block, seconds one thread's.

#: resident memory of a command's process before its work: interpreter, packages, compiled kernels (`testbed
#: check` peaks at 0.37 GB)
BASE_BYTES = 0.40 * GB
#: the GNSS draw of a block, bytes per trial-epoch and satellite of the constellation (observations, truth), and
#: one thread's seconds per trial-epoch and satellite
GNSS_BYTES_PER_SAT = 50.0
DRAW_SECONDS_PER_SAT = 0.12e-6
#: the camera frames of a block, per trial-epoch and landmark
VISION_BYTES_PER_LANDMARK = 700.0


#: a monitor whose cost was not measured (one registered by a user without a cost): the filter's figures, the
#: costliest per epoch of the shipped monitors but the DPE's
UNKNOWN_MONITOR = MonitorCost((25e3, 0.0, 0.0), (0.75e-3, 0.0, 0.0))

#: correlograms, one pass (the pseudoranges' or a monitor's that reads them): bytes of one trial's synthesis per epoch,
#: satellite and delay (the float32 statistic, its float64 temporaries), and seconds per trial-epoch and delay
#: (zunz-rwy05-dpe with GPS RAIM alone, its one pass: 2.23 ms a trial-epoch over 1001 delays, the satellites the
#: valley leaves in view); the exact synthesis takes this many times longer per block N_b (459 ms against 7.4 ms
#: an epoch of 10 satellites at N_b = 50)
CORRELATOR_BYTES_PER_DELAY = 28.0
CORRELATOR_SECONDS_PER_DELAY = 2.23e-6
EXACT_SECONDS_PER_BLOCK = 1.25
#: the ground-feature scene: bytes per point while it is built (kept: 24; `testbed check` peaked at 5.7 GB on
#: 25 million points when it still built it), per point and epoch of the tracker's view search (blocks of 256
#: epochs; 104 traced at 0.17 and 0.68 million points), seconds per point and epoch of that search (1.3 us)
FEATURE_BUILD_BYTES = 215.0
FEATURE_VIEW_BYTES_PER_EPOCH = 104.0
FEATURE_VIEW_EPOCHS = 256
FEATURE_SECONDS_PER_POINT_EPOCH = 1.3e-6
#: the flight dynamics: seconds per second of flight (the flight with its guidance ran 128x real time) and
#: bytes per full-rate step kept (the truth record)
FLIGHT_SECONDS_PER_S = 1 / 128
FLIGHT_BYTES_PER_STEP = 400.0
#: blocks or processes side by side on p cores run 1 + (p - 1) * this faster than one
PARALLEL_EFFICIENCY = 0.8

# ----------------------------------------------------------------------------- limits

#: refuse above this fraction of the memory the machine has available when the command starts
MEMORY_FRACTION = 0.8
#: refuse above this estimated wall time (s): beyond an afternoon's run a user says so (--allow-large)
WALL_LIMIT_S = 4 * 3600.0
#: print the estimate when the work is estimated to take longer than this (s)
ANNOUNCE_S = 10.0
OVERRIDE = "--allow-large"


@dataclass(frozen=True)
class Limits:
    memory_bytes: float
    wall_s: float


def available_memory_bytes() -> float | None:
    """Memory the machine can give a new process now (Linux MemAvailable), else its physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return float(os.sysconf("SC_PHYS_PAGES")) * float(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return None


def default_limits() -> Limits:
    avail = available_memory_bytes()
    return Limits(math.inf if avail is None else MEMORY_FRACTION * avail, WALL_LIMIT_S)


# ----------------------------------------------------------------------------- the estimate


@dataclass(frozen=True)
class Estimate:
    """A command's estimated cost: named parts of its peak memory (bytes) and of its wall time (s), and how
    to shrink it."""

    what: str
    memory: dict[str, float]
    time: dict[str, float]
    shrink: tuple[str, ...] = ()
    cores: int = 1

    @property
    def peak_bytes(self) -> float:
        return sum(self.memory.values())

    @property
    def wall_s(self) -> float:
        return sum(self.time.values())

    def dominant(self, parts: dict[str, float]) -> str:
        return max(parts, key=parts.get) if parts else "-"

    def summary(self) -> str:
        mem, t = self.memory, self.time
        return (f"estimate for {self.what}: peak ~{fmt_bytes(self.peak_bytes)} resident (most: "
                f"{self.dominant(mem)}, {fmt_bytes(mem.get(self.dominant(mem), 0))}), ~{fmt_seconds(self.wall_s)} "
                f"on {self.cores} core{'s' if self.cores > 1 else ''} (most: {self.dominant(t)}, "
                f"{fmt_seconds(t.get(self.dominant(t), 0))})")


def fmt_bytes(b: float) -> str:
    return f"{b / GB:.1f} GB" if b >= 0.1 * GB else f"{b / 1e6:.0f} MB"


def fmt_seconds(s: float) -> str:
    if s >= 2 * 86400:
        return f"{s / 86400:.0f} days"
    if s >= 5400:
        return f"{s / 3600:.1f} h"
    if s >= 90:
        return f"{s / 60:.0f} min"
    return f"{s:.0f} s"


def check_budget(est: Estimate, *, allow_large: bool = False, limits: Limits | None = None,
                 say=None) -> None:
    """Refuse ``est`` (a ConfigError: exit 2) when it exceeds ``limits`` (default: :func:`default_limits`) and
    ``allow_large`` is not given; otherwise tell ``say`` the estimate when the work is long enough to matter."""
    limits = limits or default_limits()
    over = []
    if est.peak_bytes > limits.memory_bytes:
        over.append(f"estimated peak memory {fmt_bytes(est.peak_bytes)} is above the limit "
                    f"{fmt_bytes(limits.memory_bytes)} ({MEMORY_FRACTION:.0%} of the memory available now); "
                    f"most of it: {est.dominant(est.memory)} ({fmt_bytes(est.memory[est.dominant(est.memory)])})")
    if est.wall_s > limits.wall_s:
        over.append(f"estimated wall time {fmt_seconds(est.wall_s)} on {est.cores} core"
                    f"{'s' if est.cores > 1 else ''} is above the limit {fmt_seconds(limits.wall_s)}; most of it: "
                    f"{est.dominant(est.time)} ({fmt_seconds(est.time[est.dominant(est.time)])})")
    if over and not allow_large:
        hints = [f"to shrink it: {h}" for h in est.shrink]
        raise ConfigError(est.what, [est.summary(), *over, *hints,
                                     f"to run it anyway: add {OVERRIDE} (the estimate is within a factor ~2)"])
    if say is not None and (over or est.wall_s >= ANNOUNCE_S):
        say(est.summary() + (f" (above the limits: {OVERRIDE} given)" if over else ""))


# ----------------------------------------------------------------------------- what a sortie holds


@dataclass(frozen=True)
class Shape:
    """The sizes the costs of one sortie of an approach scale with."""

    epochs: int  # GNSS (monitor) epochs of the sortie
    flight_s: float  # the flight's duration bound (the whole approach is flown, whatever the segment)
    flight_steps: int  # flight-dynamics steps of the whole flight
    satellites: int  # satellites of the constellation (the S axis of the GNSS arrays)
    landmarks: int
    vision_epochs: int  # camera frames of the sortie (0 without a vision monitor)
    features: int  # ground-feature scene points (0: no scene)
    correlator_delays: int  # correlogram delays M (0: no correlators synthesised)
    correlator_passes: int  # syntheses per trial-epoch (the pseudoranges and a monitor reading correlators each make one)
    correlator_monitors: tuple[str, ...]  # the monitors that read the correlograms
    exact_blocks: int  # N_b of the exact synthesis (0: the fast one)
    monitors: tuple[str, ...]
    costs: dict = field(default_factory=dict)  # monitor -> its MonitorCost with the run's options

    def monitor_cost(self, name: str) -> tuple[float, float]:
        """(bytes, seconds) per trial-epoch of monitor ``name``."""
        c = self.costs.get(name) or UNKNOWN_MONITOR
        b, s = c.at(self.landmarks)
        if self.features:
            b, s = b + c.features[0], s + c.features[1]
        if any(name in (self.costs.get(m) or UNKNOWN_MONITOR).provides for m in self.monitors if m != name):
            s = 0.0  # computed on the way by another (no second solve)
        return b, s


def sortie_shape(approach, duration_s: float | None = None) -> Shape:
    """The :class:`Shape` of one sortie of ``approach`` (a loaded :class:`~testbed.config.Approach`; a campaign
    cell's, or the one ``testbed fly`` flies), ``duration_s`` of it (None: the whole flight). Reads only the
    settings, the planned path and the constellation file: nothing is flown or drawn."""

    c = approach.config
    frame, path = approach_geometry(approach.flight_plan)
    flight_s = flight_duration_bound(approach, path)
    if not math.isfinite(flight_s):
        flight_s = c.flight.max_duration_s
    sortie_s = flight_s if duration_s is None else min(duration_s, flight_s)
    g = c.gnss
    eph = tracked_constellations(g, utc_to_gps_seconds(c.start_time_utc))
    monitors = tuple(dict.fromkeys(c.monitors))
    vision = reads("vision", monitors, c.monitor)
    scene = c.vision.features
    features = corridor_size(path.sample(200.0)[0], scene) if scene.enabled and reads("features", monitors, c.monitor) else 0
    passes = int(reads("correlators", monitors, c.monitor)) + int(g.correlator_pseudoranges)
    cs = g.correlators
    return Shape(epochs=int(sortie_s * g.rate_hz) + 1, flight_s=flight_s, flight_steps=int(flight_s / c.flight.dt_s),
                 satellites=int(len(set(eph.sat_id.tolist()))), landmarks=len(build_landmarks(c.landmarks)),
                 vision_epochs=int(sortie_s * c.vision.rate_hz) + 1 if vision else 0, features=features,
                 correlator_delays=delay_grid(cs).size if passes else 0, correlator_passes=passes,
                 correlator_monitors=tuple(m for m in monitors if reads("correlators", (m,), c.monitor)),
                 exact_blocks=cs.n_noncoherent if cs.synthesis == "exact" else 0, monitors=monitors,
                 costs={m: monitor_cost(m, c.monitor) for m in monitors})


def trial_epoch_bytes(shape: Shape) -> dict[str, float]:
    """Bytes a draw block holds per trial-epoch, by part."""
    parts = {"GNSS draw": GNSS_BYTES_PER_SAT * shape.satellites}
    if shape.vision_epochs:
        parts["camera frames"] = VISION_BYTES_PER_LANDMARK * shape.landmarks * shape.vision_epochs / shape.epochs
    for m in shape.monitors:
        parts[f"{m} monitor"] = shape.monitor_cost(m)[0]
    return parts


def trial_epoch_seconds(shape: Shape) -> dict[str, float]:
    """One thread's seconds per trial-epoch, by part."""
    parts = {f"{m} monitor": shape.monitor_cost(m)[1] for m in shape.monitors}
    parts["sensor draws"] = DRAW_SECONDS_PER_SAT * shape.satellites
    if shape.correlator_passes:
        parts["correlograms"] = correlator_seconds(shape)
    return parts


def unshared_parts(shape: Shape) -> set[str]:
    """The parts of :func:`trial_epoch_seconds` that each campaign cell computes for itself, whatever it has in
    common with the others (:mod:`testbed.memo` shares no correlogram, nor the output of a monitor that reads
    them: they depend on the cell's faulted pseudoranges and echo)."""
    return {"correlograms"} | {f"{m} monitor" for m in shape.correlator_monitors}


def correlator_seconds(shape: Shape) -> float:
    """Seconds per trial-epoch of the correlogram syntheses."""
    exact = EXACT_SECONDS_PER_BLOCK * shape.exact_blocks if shape.exact_blocks else 1.0
    return CORRELATOR_SECONDS_PER_DELAY * shape.correlator_delays * exact * shape.correlator_passes


def correlator_trial_bytes(shape: Shape) -> float:
    """Bytes one trial's correlograms hold while they are synthesised and read."""
    if not shape.correlator_passes:
        return 0.0

    exact = _EXACT_BYTES if shape.exact_blocks else 0
    return CORRELATOR_BYTES_PER_DELAY * shape.epochs * shape.satellites * shape.correlator_delays + exact


def feature_bytes(shape: Shape) -> float:
    """Peak bytes of the ground-feature scene: its build, or the tracker's view search over it."""
    return shape.features * max(FEATURE_BUILD_BYTES, FEATURE_VIEW_BYTES_PER_EPOCH * min(FEATURE_VIEW_EPOCHS,
                                                                                         shape.epochs))


def feature_seconds(shape: Shape) -> float:
    return FEATURE_SECONDS_PER_POINT_EPOCH * shape.features * shape.epochs


def flight_estimate(approach, *, sensors: bool = True, block_s: float = 5.0) -> Estimate:
    """``testbed fly``: one sortie of the whole approach, in blocks of ``block_s`` simulated seconds (the
    outputs and records of every epoch are kept; a block's correlograms are synthesised, recorded and dropped).
    ``sensors`` False: the flight alone (``--flight-only``)."""
    s = sortie_shape(approach)
    memory = {"process": BASE_BYTES, "flight record": FLIGHT_BYTES_PER_STEP * s.flight_steps}
    time = {"flight": FLIGHT_SECONDS_PER_S * s.flight_s}
    if sensors:
        memory["outputs and sensor records"] = sum(trial_epoch_bytes(s).values()) * s.epochs
        time["sensors and monitors"] = sum(trial_epoch_seconds(s).values()) * s.epochs
        if s.features:
            memory["ground-feature scene"] = feature_bytes(s)
            time["ground-feature tracking"] = feature_seconds(s)
        if s.correlator_passes:
            block_epochs = min(s.epochs, max(int(block_s * approach.config.gnss.rate_hz), 1))
            memory["correlograms"] = correlator_trial_bytes(s) / s.epochs * block_epochs
    shrink = ["a shorter approach (flight.max_duration_s, flight.start_distance_m) or lower rates (gnss.rate_hz, "
              "vision.rate_hz)"]
    if sensors and s.features:
        shrink.append("a sparser or narrower feature scene (vision.features.density_per_km2, half_width_m, beyond_m)")
    if sensors and s.correlator_passes:
        shrink.append("a smaller correlogram (gnss.correlators.half_window_m, delay_step_m; synthesis = 'fast')")
    return Estimate(f"fly {approach.name}", memory, time, tuple(shrink), cores=1)


def guarded(make):
    """``make()``'s estimate, or None when the inputs it reads cannot be read yet: the command's own checks,
    which run next, name the file and key (an estimate never replaces their message)."""
    try:
        return make()
    except Exception:  # an unreadable almanac or the like, a ConfigError of a file it names: the checks report it
        return None


def add_allow_large(parser) -> None:
    """The override, one name on every command that estimates."""
    parser.add_argument(OVERRIDE, dest="allow_large", action="store_true",
                        help="run even when the estimated peak memory is above 80%% of the memory available or "
                             "the estimated wall time above 4 h (the estimate is printed either way)")


def budget_gate(make, allow_large: bool, say=print) -> None:
    """Estimate (``make()``) and refuse or announce, before any work (:func:`check_budget`)."""
    est = guarded(make)
    if est is not None:
        check_budget(est, allow_large=allow_large, say=lambda text: say(text, flush=True))

"""Configuration: approach and aircraft TOML files, validated into typed models.

Section models live beside the code they configure; this module composes
them, resolves names and relative paths, and turns every problem into a
:class:`~testbed.schema.ConfigError` that names the file, the key path and
what was expected. Paths inside a file are relative to that file.
"""

from __future__ import annotations

import datetime as dt
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError, field_validator, model_validator

from testbed.flight.settings import (
    AircraftSettings,
    FlightPlan,
    FlightSettings,
    FrameSettings,
    Gusts,
    PathSettings,
    VerticalSettings,
    Wind,
)
from testbed.integrity.settings import IntegritySettings
from testbed.monitors import MonitorName, monitor_names, options_tables, reads
from testbed.sensors.imu.settings import ImuSettings
from testbed.resources import aircraft_dir, approaches_dir, campaigns_dir, shipped_or_path
from testbed.schema import ConfigError, FileName, StrictModel, format_validation_error
from testbed.sensors.faults import Fault
from testbed.sensors.gnss.settings import CONSTELLATION_SYSTEMS, GnssSettings
from testbed.sensors.vision.settings import LandmarkSettings, VisionSettings
from testbed.world.settings import TerrainSettings

MONITORS = ("gps_raim", "va_raim", "pixel")
GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.timezone.utc)
LAST_START = dt.datetime(2100, 1, 1, tzinfo=dt.timezone.utc)


class ApproachConfig(StrictModel):
    """One approach file (``approaches/<name>.toml``)."""

    name: FileName = Field(..., description="approach name; it names the default outputs (`runs/<name>-seed0.rrd`): "
                                            "no slash or backslash, not starting with a dot, at most 100 "
                                            "printable characters")
    description: str = Field(..., description="shown by `testbed approaches` (its first line)")
    illustrative: bool = Field(False, description="True when the procedure is not a published one")
    aircraft: str = Field("b737", description="aircraft folder name under aircraft/, or a path to an aircraft.toml")
    start_time_utc: dt.datetime = Field(dt.datetime(2026, 3, 1, 4, 0, tzinfo=dt.timezone.utc),
                                        description="time of the start of the approach, UTC with an offset "
                                                    "(e.g. 2026-03-01T04:00:00Z), from the GPS epoch (1980-01-06) "
                                                    "to 2100: it sets the satellites' sky")
    frame: FrameSettings = Field(..., description="origin of the world frame (local ENU)")
    path: PathSettings = Field(..., description="lateral path: legs in flying order, ending at the threshold")
    vertical: VerticalSettings = Field(VerticalSettings(), description="vertical profile: a glide path or "
                                                                      "altitude constraints")
    flight: FlightSettings = Field(FlightSettings(), description="JSBSim step, start, rates and overrides of "
                                                               "the aircraft's approach configuration")
    wind: Wind = Field(Wind(), description="steady wind")
    gusts: Gusts = Field(Gusts(), description="gust model")
    terrain: TerrainSettings = Field(TerrainSettings(), description="terrain model")
    gnss: GnssSettings = Field(GnssSettings(), description="GNSS sensor: constellations (GPS, Galileo, BeiDou), "
                                                         "masks, error model, correlators")
    vision: VisionSettings = Field(default_factory=VisionSettings,
                                   description="camera sensor; its mount defaults to the aircraft's camera")
    landmarks: LandmarkSettings = Field(LandmarkSettings(), description="the surveyed landmarks the camera "
                                                                       "detects, and their survey error")
    integrity: IntegritySettings = Field(IntegritySettings(), description="integrity risk allocation, PL "
                                                                          "variant, service levels, FDE and "
                                                                          "solver tolerances, shared by the "
                                                                          "monitors")
    imu: ImuSettings = Field(default_factory=ImuSettings, description="the IMU (read when a monitor uses it)")
    monitor: dict[str, Any] = Field(default_factory=dict,
                                    description="each monitor's own options, `[monitor.<name>]`, validated by the "
                                                "model the monitor declares; a table for a monitor not listed in "
                                                "`monitors` is checked too")
    monitors: list[MonitorName] = Field(default_factory=lambda: list(MONITORS), min_length=1,
                                description="monitor names: those `testbed fly --help` lists under --monitors, or "
                                            "one registered with testbed.monitors.register")
    faults: list[Fault] = Field(default_factory=list, description="fault schedule ([[faults]] tables)")

    @model_validator(mode="before")
    @classmethod
    def _moved_tables(cls, data):
        """A monitor's options were a top-level table named after it; they are ``[monitor.<name>]`` now."""
        if isinstance(data, dict):
            moved = [f"[{k}] moved to [monitor.{k}]" for k in data if k in monitor_names()]
            if moved:
                raise ValueError("; ".join(moved))
        return data

    @field_validator("monitor", mode="before")
    @classmethod
    def _monitor_tables(cls, v):
        if not isinstance(v, dict):
            return v  # the dict type reports it
        tables = options_tables().model_validate(v)
        return {name: table for name, table in tables if table is not None}

    def reads(self, kind: str) -> bool:
        """Whether a monitor of the run, with its options, reads observations of ``kind`` (the run synthesises
        only those)."""
        return reads(kind, self.monitors, self.monitor)

    @field_validator("start_time_utc")
    @classmethod
    def _utc(cls, v: dt.datetime) -> dt.datetime:
        if v.tzinfo is None:
            raise ValueError("expected a UTC time with an offset, e.g. 2026-03-01T04:00:00Z")
        v = v.astimezone(dt.timezone.utc)
        if not GPS_EPOCH <= v <= LAST_START:
            raise ValueError(f"expected a time between the GPS epoch {GPS_EPOCH:%Y-%m-%d} and {LAST_START:%Y}")
        return v


@dataclass(frozen=True)
class Approach:
    """A loaded approach: its validated config, its aircraft and where it came from."""

    config: ApproachConfig
    aircraft: AircraftSettings
    source: Path
    aircraft_source: Path

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def flight_plan(self) -> FlightPlan:
        """What the flight room needs of this approach (it never sees the rest)."""
        c = self.config
        return FlightPlan(name=c.name, source=self.source, frame=c.frame, path=c.path, vertical=c.vertical,
                          flight=c.flight, wind=c.wind, gusts=c.gusts, aircraft=self.aircraft)


def read_toml(path: Path) -> dict:
    """Read a TOML file; syntax errors become a ConfigError naming the file and line."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(path, ["is a folder: expected a TOML file"])
    if not path.is_file():
        raise ConfigError(path, ["file not found"])
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(path, [f"not valid TOML: {exc}"]) from None
    except UnicodeDecodeError as exc:
        raise ConfigError(path, [f"not a text (UTF-8 TOML) file: byte {exc.start} is not UTF-8"]) from None
    except OSError as exc:
        raise ConfigError(path, [f"cannot be read: {exc.strerror or exc}"]) from None


def validate(model: type[StrictModel], data: dict, source: Path, prefix: str = "") -> Any:
    """Validate ``data`` with ``model``; errors name ``source`` and the key path."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise ConfigError(source, [prefix + p for p in format_validation_error(err, data)]) from None


def resolve_approach(name_or_path: str | Path) -> Path:
    """A shipped approach name (``zunz-rwy05-final``) or a path to a TOML file."""
    return shipped_or_path(name_or_path, approaches_dir(), "approach")


def resolve_aircraft(ref: str, base: Path) -> Path:
    p = Path(ref)
    if "/" in ref or p.suffix == ".toml":
        p = (base / p) if not p.is_absolute() else p
        return p / "aircraft.toml" if p.is_dir() else p
    return aircraft_dir() / ref / "aircraft.toml"


def load_aircraft(path: Path) -> AircraftSettings:
    return validate(AircraftSettings, read_toml(path), path)


def load_approach(name_or_path: str | Path) -> Approach:
    """Load, validate and resolve an approach file (and its aircraft)."""
    src = resolve_approach(name_or_path)
    cfg = _relative_to(validate(ApproachConfig, read_toml(src), src), src.parent)
    ac_path = resolve_aircraft(cfg.aircraft, src.parent)
    if not ac_path.is_file():
        raise ConfigError(src, [f"aircraft: {cfg.aircraft!r} -> {ac_path} not found "
                                f"(expected a folder under {aircraft_dir()} or a path to an aircraft.toml)"])
    return Approach(cfg, load_aircraft(ac_path), src, ac_path)


def _relative_to(cfg: ApproachConfig, base: Path) -> ApproachConfig:
    """Data paths the file names, resolved against the file's folder (not the working directory) into
    absolute ones: a relative folder would be joined again by whoever reads them."""
    base = base.resolve()
    g, t = cfg.gnss, cfg.terrain
    update = {}
    gnss = {}
    if g.almanac_path is not None and not g.almanac_path.is_absolute():
        gnss["almanac_path"] = base / g.almanac_path
    for name in CONSTELLATION_SYSTEMS:
        cs = getattr(g, name)
        if cs.orbit_path is not None and not cs.orbit_path.is_absolute():
            gnss[name] = cs.model_copy(update={"orbit_path": base / cs.orbit_path})
    if gnss:
        update["gnss"] = g.model_copy(update=gnss)
    if any(not p.is_absolute() for p in t.dem_paths):
        update["terrain"] = t.model_copy(update={"dem_paths": [p if p.is_absolute() else base / p
                                                              for p in t.dem_paths]})
    return cfg.model_copy(update=update) if update else cfg


def list_approaches() -> list[tuple[str, str]]:
    """(name, one-line description) of every shipped approach."""
    return _list_descriptions(approaches_dir())


def list_campaigns() -> list[tuple[str, str]]:
    """(name, one-line description) of every shipped campaign spec."""
    return _list_descriptions(campaigns_dir())


def _list_descriptions(folder: Path) -> list[tuple[str, str]]:
    out = []
    for p in sorted(folder.glob("*.toml")):
        try:
            d = read_toml(p)
            out.append((p.stem, (str(d.get("description", "")).strip().splitlines() or [""])[0]))
        except ConfigError as exc:
            out.append((p.stem, f"(invalid: {exc.problems[0]})"))
    return out


def fault_from_option(text: str) -> dict:
    """A ``[[faults]]`` table from its one-line form ``KIND:key=value,key=value`` (the keys and values of
    an approach file's fault table, values written as in TOML; a bare word is a string), e.g.
    ``gps_step:prn=random,bias_m=60,onset_s=100`` or ``landmark_moved:landmark=A,delta_enu_m=[5,0,0]``.
    Checked like a file: every problem names ``--fault``, the key and the value."""
    where = f"--fault {text!r}"
    kind, sep, rest = text.partition(":")
    if not kind.strip():
        raise ConfigError("command line", [f"{where}: expected KIND:key=value,... (e.g. "
                                           "gps_step:prn=random,bias_m=60,onset_s=100)"])
    table: dict[str, Any] = {"kind": kind.strip()}
    problems = []
    for item in _split_top_level(rest) if sep else []:
        key, eq, value = item.partition("=")
        if not eq or not key.strip() or not value.strip():
            problems.append(f"{where}: {item!r}: expected key=value")
            continue
        try:
            table[key.strip()] = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            table[key.strip()] = value.strip()  # a bare word: a string (prn=random, landmark=A)
    if problems:
        raise ConfigError("command line", problems)
    from pydantic import TypeAdapter

    try:
        TypeAdapter(Fault).validate_python(table)
    except ValidationError as err:
        raise ConfigError("command line", [f"{where}: {p}" for p in format_validation_error(err, table)]) from None
    return table


def _split_top_level(text: str) -> list[str]:
    """Split at the commas that are not inside brackets."""
    parts, depth, cur = [], 0, ""
    for ch in text:
        depth += ch == "["
        depth -= ch == "]"
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    return [p for p in (*parts, cur) if p.strip()]


def with_overrides(ap: Approach, *, monitors: list[str] | None = None, faults: list[dict] | None = None) -> Approach:
    """``ap`` with its monitors replaced and faults appended (the command line's ``--monitors`` and
    ``--fault``), validated as the file would be."""
    if monitors is None and not faults:
        return ap
    from dataclasses import replace

    data = ap.config.model_dump(exclude_unset=True)
    if monitors is not None:
        data["monitors"] = monitors
    if faults:
        data["faults"] = [*data.get("faults", []), *faults]
    return replace(ap, config=validate(ApproachConfig, data, ap.source))

"""The monitors a run can name: each with its builder, the observations it reads and its options table.

The shipped monitors are listed here explicitly; :func:`register` adds any other (a user's, or a
test's) at run time. An approach file configures a monitor in its own typed table
``[monitor.<name>]``, validated by the model the monitor declares (:attr:`MonitorEntry.options`);
the approach schema is composed from these models (:func:`options_tables`), so a registered monitor's
table is checked like a shipped one's.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Annotated, Any, Callable, Mapping

from pydantic import AfterValidator, ConfigDict, create_model

from testbed.integrity import pixel, raim, va_raim
from testbed.integrity.araim import monitor as araim
from testbed.integrity.araim.settings import AraimMonitorSettings
from testbed.integrity.dpe import monitor as dpe
from testbed.integrity.monitor import INPUT_KINDS, Monitor, MonitorContext, MonitorCost, NoOptions, contract_problems
from testbed.integrity.settings import PixelOptions
from testbed.navigation import monitor as ekf
from testbed.schema import StrictModel

Builder = Callable[[MonitorContext, Any], Monitor]


#: the observation kinds a monitor reads: fixed, or a function of its validated options (ARAIM reads the camera
#: when its vision fault modes are on)
Inputs = frozenset[str] | Callable[[Any], frozenset[str]]


@dataclass(frozen=True)
class MonitorEntry:
    """build(context, options) -> Monitor, the observation kinds it reads (given its options), its options model,
    and what it costs with given options (None: not measured; the resource estimate then assumes the costliest)."""

    build: Builder
    inputs: Inputs
    options: type[StrictModel] = NoOptions
    cost: Callable[[Any], MonitorCost] | None = None


_SHIPPED: dict[str, MonitorEntry] = {
    "gps_raim": MonitorEntry(raim.build_monitor, frozenset({"gnss"}), NoOptions, raim.cost),
    "va_raim": MonitorEntry(va_raim.build_monitor, frozenset({"gnss", "vision"}), va_raim.VaRaimOptions, va_raim.cost),
    "pixel": MonitorEntry(pixel.build_monitor, frozenset({"gnss", "vision"}), PixelOptions, pixel.cost),
    "ekf": MonitorEntry(ekf.build_monitor, frozenset({"gnss", "vision", "imu", "features"}), ekf.EkfSettings,
                        ekf.cost),
    "dpe": MonitorEntry(dpe.build_monitor, frozenset({"gnss", "correlators"}), dpe.DpeSettings, dpe.cost),
    # cost not measured for the resource estimate yet: the costliest shipped figures are assumed
    "araim": MonitorEntry(araim.build_monitor, araim.inputs, AraimMonitorSettings),
}
_ADDED: dict[str, MonitorEntry] = {}


def register(name: str, builder: Builder, inputs: Inputs | set[str],
             options: type[StrictModel] = NoOptions, cost: Callable[[Any], MonitorCost] | None = None) -> None:
    """Make ``name`` a monitor an approach file, a campaign spec or ``--monitors`` can name.

    inputs : the observation kinds it reads (the run synthesises only what some monitor reads), or a function
        of its validated options returning them.
    options : the pydantic model of its ``[monitor.<name>]`` table (the builder receives it validated);
        by default it takes none.
    cost : ``cost(options) -> MonitorCost``, its measured cost for the resource estimate (None: the costliest
        shipped monitor's figures are assumed).
    """
    if not name.isidentifier():
        raise ValueError(f"monitor name: expected an identifier, got {name!r}")
    if name in _SHIPPED:
        raise ValueError(f"monitor {name!r} is a shipped monitor")
    if not (isinstance(options, type) and issubclass(options, StrictModel)):
        raise ValueError(f"monitor {name!r}: options must be a testbed.schema.StrictModel subclass, got {options!r}")
    fixed = None if callable(inputs) else frozenset(inputs)
    bad = set(fixed if fixed is not None else inputs(options())) - INPUT_KINDS  # a function: at its defaults
    if bad:
        raise ValueError(f"monitor {name!r}: unknown inputs {sorted(bad)}; expected some of {sorted(INPUT_KINDS)}")
    _ADDED[name] = MonitorEntry(builder, inputs if fixed is None else fixed, options, cost)


def unregister(name: str) -> None:
    _ADDED.pop(name, None)


def monitor_names() -> tuple[str, ...]:
    """Every monitor that can be named, shipped ones first."""
    return tuple(_SHIPPED) + tuple(_ADDED)


def known_monitor(name: str) -> str:
    """``name`` if it is a registered monitor (a pydantic validator: the error names the list item)."""
    if name not in monitor_names():
        raise ValueError(f"unknown monitor {name!r}; expected one of {list(monitor_names())}")
    return name


#: a validated monitor name for config models
MonitorName = Annotated[str, AfterValidator(known_monitor)]


def entry(name: str) -> MonitorEntry:
    if name in _ADDED:
        return _ADDED[name]
    if name not in _SHIPPED:
        raise KeyError(f"unknown monitor {name!r}; expected one of {list(monitor_names())}")
    return _SHIPPED[name]


def monitor_inputs(name: str, options: Mapping[str, Any] | None = None) -> frozenset[str]:
    """The observation kinds monitor ``name`` reads (without building it), with its options from ``options``
    (tables by monitor name, as :func:`monitor_options` reads them; None or absent: its defaults)."""
    e = entry(name)
    return e.inputs(monitor_options(name, options or {})) if callable(e.inputs) else e.inputs


def reads(kind: str, names, options: Mapping[str, Any] | None = None) -> bool:
    """Whether any of the monitors ``names`` (with their options from ``options``) reads observations of ``kind``
    (one of INPUT_KINDS)."""
    return any(kind in monitor_inputs(n, options) for n in names)


def options_tables() -> type[StrictModel]:
    """The model of an approach file's ``[monitor]`` table: one optional sub-table per registered monitor,
    each validated by that monitor's options model (an unknown name is an error naming the known ones)."""
    return _tables_model(tuple((n, entry(n).options) for n in monitor_names()))


@functools.lru_cache(maxsize=16)
def _tables_model(options: tuple[tuple[str, type[StrictModel]], ...]) -> type[StrictModel]:
    """Built once per registry state (a campaign validates every cell's approach with it)."""
    fields = {n: (model | None, None) for n, model in options}
    return create_model("MonitorTables", __config__=ConfigDict(extra="forbid"), **fields)


def monitor_options(name: str, options: Mapping[str, Any]) -> StrictModel:
    """Monitor ``name``'s validated options from ``options`` (its table by monitor name; absent: the defaults)."""
    given = options.get(name)
    model = entry(name).options
    return given if isinstance(given, model) else model.model_validate(dict(given or {}))


def monitor_cost(name: str, options: Mapping[str, Any]) -> MonitorCost | None:
    """What monitor ``name`` costs per trial-epoch with its options from ``options`` (None: not measured)."""
    e = entry(name)
    return None if e.cost is None else e.cost(monitor_options(name, options))


def build_monitor(name: str, context: MonitorContext) -> Monitor:
    """The monitor ``name`` built for a run (its options from ``context.options``)."""
    e = entry(name)
    mon = e.build(context, monitor_options(name, context.options))
    missing = contract_problems(mon)
    if missing:
        raise TypeError(f"monitor {name!r} lacks {', '.join(missing)} of the monitor contract; derive its class from "
                        "testbed.integrity.monitor.MonitorDefaults for the optional members' defaults")
    registered = monitor_inputs(name, context.options)
    if frozenset(mon.inputs) != registered:
        raise TypeError(f"monitor {name!r} reads {sorted(mon.inputs)} but was registered with {sorted(registered)}")
    return mon

"""Monitor names -> builders. The loop, campaigns, sinks and the API look monitors up here.

The shipped monitors are registered lazily (by module path), so validating an
approach file imports no numerical code; :func:`register` adds any other
(a user's, or a test's) at run time.
"""

from __future__ import annotations

import importlib
from typing import Annotated, Any, Callable, Mapping

from pydantic import AfterValidator

from testbed.integrity.monitor import INPUT_KINDS, Monitor, MonitorContext, contract_problems

Builder = Callable[[MonitorContext, Mapping[str, Any]], Monitor]

#: shipped monitors: name -> ("module:builder", inputs); a builder takes (context, options)
_SHIPPED = {
    "gps_raim": ("testbed.integrity.raim:build_monitor", frozenset({"gnss"})),
    "va_raim": ("testbed.integrity.va_raim:build_monitor", frozenset({"gnss", "vision"})),
    "pixel": ("testbed.integrity.pixel:build_monitor", frozenset({"gnss", "vision"})),
    "ekf": ("testbed.navigation.monitor:build_monitor", frozenset({"gnss", "vision", "imu", "features"})),
    "dpe": ("testbed.integrity.dpe.monitor:build_monitor", frozenset({"gnss", "correlators"})),
    "araim": ("testbed.integrity.araim.monitor:build_monitor", frozenset({"gnss"})),
}
_ADDED: dict[str, tuple[Builder, frozenset[str]]] = {}


def register(name: str, builder: Builder, inputs: frozenset[str] | set[str]) -> None:
    """Make ``name`` a monitor an approach file, a campaign spec or ``--monitors`` can name.

    inputs : the observation kinds it reads (the run synthesises only what some monitor reads).
    """
    if not name.isidentifier():
        raise ValueError(f"monitor name: expected an identifier, got {name!r}")
    if name in _SHIPPED:
        raise ValueError(f"monitor {name!r} is a shipped monitor")
    bad = set(inputs) - INPUT_KINDS
    if bad:
        raise ValueError(f"monitor {name!r}: unknown inputs {sorted(bad)}; expected some of {sorted(INPUT_KINDS)}")
    _ADDED[name] = (builder, frozenset(inputs))


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


def _entry(name: str) -> tuple[Builder | str, frozenset[str]]:
    if name in _ADDED:
        return _ADDED[name]
    if name not in _SHIPPED:
        raise KeyError(f"unknown monitor {name!r}; expected one of {list(monitor_names())}")
    return _SHIPPED[name]


def monitor_inputs(name: str) -> frozenset[str]:
    """The observation kinds monitor ``name`` reads (without building it)."""
    return _entry(name)[1]


def reads_vision(names) -> bool:
    return any("vision" in monitor_inputs(n) for n in names)


def reads_imu(names) -> bool:
    return any("imu" in monitor_inputs(n) for n in names)


def reads_features(names) -> bool:
    return any("features" in monitor_inputs(n) for n in names)


def reads_correlators(names) -> bool:
    return any("correlators" in monitor_inputs(n) for n in names)


def build_monitor(name: str, context: MonitorContext) -> Monitor:
    """The monitor ``name`` built for a run (its options from ``context.options``)."""
    builder, inputs = _entry(name)
    if isinstance(builder, str):
        module, attr = builder.split(":")
        builder = getattr(importlib.import_module(module), attr)
    mon = builder(context, context.options.get(name, {}))
    missing = contract_problems(mon)
    if missing:
        raise TypeError(f"monitor {name!r} lacks {', '.join(missing)} of the monitor contract; derive its class from "
                        "testbed.integrity.monitor.MonitorDefaults for the optional members' defaults")
    if frozenset(mon.inputs) != inputs:
        raise TypeError(f"monitor {name!r} reads {sorted(mon.inputs)} but was registered with {sorted(inputs)}")
    return mon

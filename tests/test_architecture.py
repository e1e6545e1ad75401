"""The house: imports flow one way between the rooms, and generic code names no monitor
(docs/design/architecture.md §the-import-rule).

Every ``import`` of every module of the package, function-level ones included, is read from the
source (ast) and checked against the layers: a module may import its own room and the rooms of
lower layers, never a room of its own layer or above.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "testbed"

#: the rooms (packages) and base modules, bottom to top; rooms of one layer do not import each other
LAYERS = (
    ("schema", "frames", "heap", "threads", "pool", "memo", "kernel_cache", "records", "markdown"),
    ("correlation", "inertial", "resources", "outputs"),
    ("world", "flight"),
    ("sensors",),
    ("integrity",),
    ("navigation", "rinex"),
    ("monitors",),
    ("config",),
    ("sim",),
    ("viz",),
    ("campaign", "replay"),
    ("studies",),
    ("api", "docs_reference", "campaign_cli"),
    ("cli",),
)
LAYER = {room: i for i, rooms in enumerate(LAYERS) for room in rooms}

#: the monitors' names, which only their own modules and the registry may spell
MONITOR_NAMES = ("gps_raim", "va_raim", "pixel", "ekf", "dpe", "araim")
#: modules that name monitors on purpose: the registry and the monitors themselves, the experiments that
#: reproduce a paper's monitor (they are about it), and what still configures a monitor in generic code (each
#: with its reason; the list shrinks as monitors declare their own option tables)
NAMES_ALLOWED = {
    "monitors.py": "the registry lists the shipped monitors",
    "sensors/vision/settings.py": "the [vision.features] description says which monitor reads them",
    "config.py": "the approach file's default monitor list",
    "sim/setup.py": "the DPE's K record named by [monitor.dpe] k_factor and its correlator-statistic check",
    "campaign/spec.py": "the sweep axes va_raim_variant, calibration and dpe_variant set those monitors' options",
    "campaign_cli.py": "testbed calibrate-dpe",
    "cli.py": "testbed calibrate-dpe and its help",
    "campaign/report.py": "the VA-RAIM reproduction's GPS baseline column",
    "replay/run.py": "testbed monitor runs GPS RAIM by default",
    "campaign/sampling.py": "the separation proposal aims at ARAIM's tests (araim alone has them); a refusal names the camera monitors",
}
#: the rooms whose modules are the monitors and their mathematics (they name what they are), and the studies:
#: experiments about particular monitors (a paper's reproduction, where vision pays, the DPE's K calibration)
MONITOR_ROOMS = ("integrity", "navigation", "studies")


def _module_files() -> list[Path]:
    return sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts)


def _room(path: Path) -> str:
    return path.relative_to(PKG).parts[0].removesuffix(".py")


def _imports(path: Path) -> set[str]:
    """Every testbed room or base module a file imports (``from testbed import x`` names ``x``)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            mods = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            mods = [f"testbed.{a.name}" for a in node.names] if node.module == "testbed" else [node.module]
        else:
            continue
        names |= {m.split(".")[1] for m in mods if m.startswith("testbed.")}
    return names


def test_every_room_and_module_has_a_layer():
    rooms = {_room(p) for p in _module_files()} - {"__init__", "__main__"}
    assert sorted(rooms - set(LAYER)) == []
    assert sorted(set(LAYER) - rooms) == []


@pytest.mark.parametrize("room", sorted(LAYER))
def test_a_room_imports_only_rooms_below_it(room):
    bad = []
    for f in _module_files():
        if _room(f) != room or f.name == "__main__.py":  # a package's __main__ is a process's entry point: the top
            continue
        for other in _imports(f) - {room}:
            if other in LAYER and LAYER[other] >= LAYER[room]:
                bad.append(f"{f.relative_to(PKG)} imports testbed.{other} (layer {LAYER[other]} >= {LAYER[room]})")
    assert bad == []


def _names_monitors(path: Path) -> list[str]:
    """The monitor names a module spells: string constants and attribute names."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if (isinstance(node, ast.Constant) and isinstance(node.value, str) and len(node.value) < 60
                and not node.value.endswith(".py")):  # a module's path is no monitor's name
            found |= {n for n in MONITOR_NAMES if re.search(rf"(^|[^a-z_]){n}([^a-z_]|$)", node.value)}
        elif isinstance(node, ast.Attribute) and node.attr in MONITOR_NAMES:
            found.add(node.attr)
    return sorted(found)


def test_generic_code_names_no_monitor():
    """The loop, the pipeline, the campaign engine, the sinks, the API: monitors are looked up in the registry,
    never named. The modules allowed to name one are listed with their reason."""
    bad = []
    for f in _module_files():
        rel = f.relative_to(PKG).as_posix()
        if _room(f) in MONITOR_ROOMS and rel != "monitors.py" or rel in NAMES_ALLOWED:
            continue
        names = _names_monitors(f)
        if names:
            bad.append(f"{rel} names {', '.join(names)}")
    assert bad == []
    stale = [m for m in NAMES_ALLOWED if (PKG / m).exists() and not _names_monitors(PKG / m)]
    assert stale == [], "allowed to name a monitor but names none: take it off the list"

"""The house: imports flow one way between the rooms (docs/design/architecture.md §the-import-rule).

Every ``import`` in a room's modules, function-level ones included, is read from the
source (ast) and checked against the rooms above it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "testbed"

#: room -> rooms it must never import (the ones above it)
ABOVE = {
    "flight": ["config", "sensors", "integrity", "navigation", "sim", "viz", "campaign", "api", "cli"],
    "world": ["config", "flight", "sensors", "integrity", "navigation", "sim", "viz", "campaign", "api", "cli"],
    "sensors": ["config", "integrity", "navigation", "sim", "viz", "campaign", "api", "cli"],
    "integrity": ["config", "navigation", "sim", "viz", "campaign", "api", "cli"],
    "sim": ["viz", "campaign", "api", "cli"],
    "viz": ["campaign", "api", "cli"],
    "campaign": ["api", "cli"],
}


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


@pytest.mark.parametrize("room", sorted(ABOVE))
def test_a_room_imports_nothing_above_it(room):
    base = PKG / room
    files = sorted(base.rglob("*.py")) if base.is_dir() else [base.with_suffix(".py")]
    bad = []
    for f in files:
        for name in _imports(f):
            parts = name.split(".")
            if parts[0] == "testbed" and len(parts) > 1 and parts[1] in ABOVE[room]:
                bad.append(f"{f.relative_to(PKG)} imports {name}")
    assert bad == []

"""Where the shipped aircraft, approaches and campaign specs are read from.

The repository keeps them at its top level (``aircraft/``, ``approaches/``);
the wheel carries the same files inside the package (``testbed/_shipped/``,
mapped there at build time by ``setup.py``). An editable install has no
``_shipped`` folder and reads the checkout beside the package.
``TESTBED_HOME`` (a folder holding ``aircraft/`` and ``approaches/``)
overrides both.
"""

from __future__ import annotations

import importlib.resources
import os
from pathlib import Path

SHIPPED = "_shipped"  # the package folder the wheel carries the top-level data in


def shipped_root() -> Path:
    """The folder that holds the shipped ``aircraft/`` and ``approaches/``."""
    env = os.environ.get("TESTBED_HOME")
    if env:
        return Path(env)
    package = Path(str(importlib.resources.files("testbed")))
    inside = package / SHIPPED
    if (inside / "approaches").is_dir():
        return inside  # an installed wheel
    return package.parent  # an editable checkout: the repository's top level


def shipped_from() -> str:
    """How the shipped files were found (for ``testbed approaches``)."""
    if os.environ.get("TESTBED_HOME"):
        return "TESTBED_HOME"
    return "installed package" if shipped_root().name == SHIPPED else "source checkout"


def approaches_dir() -> Path:
    return shipped_root() / "approaches"


def aircraft_dir() -> Path:
    return shipped_root() / "aircraft"


def campaigns_dir() -> Path:
    return approaches_dir() / "campaigns"


def shipped_or_path(name_or_path, folder: Path, what: str) -> Path:
    """A shipped name (a ``.toml`` in ``folder``) or a path to a file; a ConfigError listing the
    shipped names otherwise."""
    from testbed.schema import ConfigError

    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    cand = folder / f"{name_or_path}.toml"
    if cand.is_file():
        return cand
    known = ", ".join(sorted(q.stem for q in folder.glob("*.toml")))
    raise ConfigError(p, [f"no such {what} file or shipped {what} name (shipped: {known})"])

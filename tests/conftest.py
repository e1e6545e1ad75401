"""Suite-wide settings: the Rerun SDK and viewer send no usage analytics from the tests.

Rerun reads its analytics switch from ``$XDG_CONFIG_HOME/rerun/analytics.json``; the suite
points XDG_CONFIG_HOME at a private folder holding a disabled config (the user's own config
is neither read nor touched). Users turn it off for themselves with ``rerun analytics disable``.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

_HOME: Path | None = None


def pytest_configure(config) -> None:
    global _HOME
    home = _HOME = Path(tempfile.mkdtemp(prefix="testbed-tests-config-"))
    (home / "rerun").mkdir()
    (home / "rerun" / "analytics.json").write_text(json.dumps(
        {"analytics_enabled": False, "analytics_id": "0" * 32, "metadata": {}}))
    os.environ["XDG_CONFIG_HOME"] = str(home)  # subprocesses (viewer, CLI) inherit it


def pytest_unconfigure(config) -> None:
    if _HOME is not None:
        shutil.rmtree(_HOME, ignore_errors=True)

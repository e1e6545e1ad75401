"""Suite-wide settings: the Rerun SDK and viewer send no usage analytics from the tests, and idle OpenMP threads sleep.

Rerun reads its analytics switch from ``$XDG_CONFIG_HOME/rerun/analytics.json``; the suite
points XDG_CONFIG_HOME at a private folder holding a disabled config (the user's own config
is neither read nor touched). Users turn it off for themselves with ``rerun analytics disable``.

Idle OpenMP threads sleep (``OMP_WAIT_POLICY=passive``, what testbed's commands set when they start;
see testbed/threads.py) from the start of the run, whichever test starts numba's thread pool: the
suite used to get it from its first in-process ``main()``, so a file or the slow set run on its own
kept spinning threads, which beside a busy neighbour made the DPE calibration test 10x slower
(230 s against 24 s). A value set in the environment wins.

The heap keeps glibc's own trimming (``TESTBED_SYSTEM_MALLOC=1``, testbed/heap.py): the commands the tests call in
process would otherwise let each test process keep up to 1 GB of freed memory, and two of them side by side
(``-n 2``) came within 0.1 GB of the suite's 4 GB. tests/test_heap.py sets the variable as each case needs.
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
    os.environ.setdefault("OMP_WAIT_POLICY", "passive")  # before any kernel starts the OpenMP threads
    os.environ.setdefault("TESTBED_SYSTEM_MALLOC", "1")  # before any command applies the heap settings
    home = _HOME = Path(tempfile.mkdtemp(prefix="testbed-tests-config-"))
    (home / "rerun").mkdir()
    (home / "rerun" / "analytics.json").write_text(json.dumps(
        {"analytics_enabled": False, "analytics_id": "0" * 32, "metadata": {}}))
    os.environ["XDG_CONFIG_HOME"] = str(home)  # subprocesses (viewer, CLI) inherit it


def pytest_unconfigure(config) -> None:
    if _HOME is not None:
        shutil.rmtree(_HOME, ignore_errors=True)

"""The first run after an install (or an edit of the kernels) says it is compiling; later runs do not."""

from __future__ import annotations

import testbed.kernel_cache as kc
from testbed.api import load_approach
from testbed.sim.preflight import preflight
from testbed.sim.setup import prepare_monitors


def test_the_first_preparation_announces_the_compilation_once(tmp_path, monkeypatch):
    monkeypatch.setattr(kc, "_marker", lambda name: tmp_path / f"prepared-{name}")
    setup = preflight(load_approach("va-raim-2015"))
    said: list[str] = []
    assert prepare_monitors(setup, announce=said.append) == tuple(m.name for m in setup.monitors)
    assert len(said) == 1 and "compiling the integrity kernels" in said[0]
    assert all(m.name in said[0] for m in setup.monitors)
    assert prepare_monitors(setup, announce=said.append) == () and len(said) == 1


def test_the_commands_make_idle_openmp_threads_sleep_and_a_library_import_does_not():
    """OMP_WAIT_POLICY=passive is a process setting: testbed's commands set it when they start (a value
    the user set wins); importing and calling the library leaves the environment alone."""
    import os
    import subprocess
    import sys

    probe = ("import os, sys; from testbed.cli import main; main(['approaches']); "
             "print('policy', os.environ.get('OMP_WAIT_POLICY'), file=sys.stderr)")
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    run = lambda code, **extra: subprocess.run([sys.executable, "-c", code], env={**env, **extra},  # noqa: E731
                                               capture_output=True, text=True, check=True).stderr
    assert "policy passive" in run(probe)
    assert "policy active" in run(probe, OMP_WAIT_POLICY="active")
    lib = ("import os, sys; from testbed.api import load_approach; load_approach('zunz-rwy05-dpe'); "
           "print('policy', os.environ.get('OMP_WAIT_POLICY'), file=sys.stderr)")
    assert "policy None" in run(lib)

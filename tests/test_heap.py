"""testbed.heap: the glibc heap settings are applied once, and never over the user's own."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from testbed import heap


def test_user_malloc_settings_win(monkeypatch):
    monkeypatch.setenv("MALLOC_ARENA_MAX", "2")
    assert heap._apply() is False
    monkeypatch.delenv("MALLOC_ARENA_MAX")
    monkeypatch.setenv("TESTBED_SYSTEM_MALLOC", "1")
    assert heap._apply() is False


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_applied_on_glibc_and_idempotent():
    """In a process of its own: the settings last for the life of a process, and the suite's keep glibc's."""
    env = {k: v for k, v in os.environ.items() if not (k.startswith("MALLOC_") or k == "TESTBED_SYSTEM_MALLOC")}
    code = ("from testbed import heap\n"
            "assert heap._apply() is True\n"
            "first = heap.keep_freed_memory()\n"
            "assert heap.keep_freed_memory() is first\n")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_run_campaign_changes_no_process_setting(monkeypatch, tmp_path):
    """A library call leaves the process as it found it: the commands apply the heap and thread settings where the
    process starts, not run_campaign."""
    from testbed import heap, threads
    from testbed.campaign.runner import run_campaign
    from testbed.resources import campaigns_dir

    def refuse(*a, **k):
        raise AssertionError("a library call changed a process setting")

    monkeypatch.setattr(heap, "_apply", refuse)
    monkeypatch.setattr(heap, "keep_freed_memory", refuse)
    monkeypatch.setattr(threads, "sleep_idle_threads", refuse)
    res = run_campaign(campaigns_dir() / "quick-look.toml", tmp_path / "ql", progress=False, max_chunks=1)
    assert res.chunks_run == 1

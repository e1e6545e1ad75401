"""testbed.heap: the glibc heap settings are applied once, and never over the user's own."""

from __future__ import annotations

import platform

import pytest

from testbed import heap


def test_user_malloc_settings_win(monkeypatch):
    monkeypatch.setenv("MALLOC_ARENA_MAX", "2")
    assert heap._apply() is False
    monkeypatch.delenv("MALLOC_ARENA_MAX")
    monkeypatch.setenv("TESTBED_SYSTEM_MALLOC", "1")
    assert heap._apply() is False


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_applied_on_glibc_and_idempotent(monkeypatch):
    for k in [k for k in __import__("os").environ if k.startswith("MALLOC_") or k == "TESTBED_SYSTEM_MALLOC"]:
        monkeypatch.delenv(k)
    assert heap._apply() is True
    first = heap.keep_freed_memory()
    assert heap.keep_freed_memory() is first

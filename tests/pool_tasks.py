"""Tasks for tests/test_pool.py: importable by name in a spawned worker process."""

from __future__ import annotations

import os
import signal
import time


def square(x: int) -> int:
    return x * x


def pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def fail(message: str) -> None:
    raise ValueError(message)


class TwoArgError(Exception):
    """An exception whose constructor takes other arguments than it keeps: it does not survive pickling."""

    def __init__(self, a: str, b: str):
        super().__init__(f"{a} and {b}")


def fail_unpicklable() -> None:
    raise TwoArgError("one", "two")


def unpicklable_result():
    return lambda: None


def die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def sigint_self_then(value: int) -> int:
    """SIGINT to this worker in the middle of the task (as a terminal's Ctrl-C reaches the whole group)."""
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.2)
    return value

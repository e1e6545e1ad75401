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


def sizes(data: bytes, out_bytes: int) -> tuple[int, bytes]:
    """A task with arguments and a result larger than a pipe's buffer."""
    return len(data), b"y" * out_bytes


class BrokenStr(Exception):
    def __init__(self, a, b):
        super().__init__(a)

    def __str__(self):
        raise RuntimeError("no text")


def fail_broken_str() -> None:
    raise BrokenStr(1, 2)


#: run as a script (tests/test_pool.py): the first pool of a fresh process, a Ctrl-C to the whole process group
#: while its workers are still starting; the caller ignores it here, the workers must survive it too
SIGINT_AT_START = """
import os, signal, sys
sys.path.insert(0, {tests!r})
import pool_tasks
from testbed.pool import WorkerPool

if __name__ == "__main__":
    signal.signal(signal.SIGINT, lambda *a: None)
    with WorkerPool(2) as pool:
        os.killpg(0, signal.SIGINT)
        print(sorted(pool.unordered(pool_tasks.square, [(i, (i,)) for i in range(4)])))
"""

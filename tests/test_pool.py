"""The worker pool (testbed.pool): results, a task's failure, a worker's death and a stop, each without a hang."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

import pool_tasks
from testbed.pool import WorkerDied, WorkerPool


def _gone(pids: list[int], within_s: float) -> bool:
    """Whether every process of ``pids`` has left (zombies count as gone) within ``within_s``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < within_s:
        if all(_gone_now(p) for p in pids):
            return True
        time.sleep(0.01)
    return False


def _gone_now(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except FileNotFoundError:
        return True


def test_every_task_comes_back_once_with_its_tag_whatever_the_worker():
    with WorkerPool(2) as pool:
        got = list(pool.unordered(pool_tasks.square, [(("t", i), (i,)) for i in range(23)]))
        assert sorted(got) == [(("t", i), i * i) for i in range(23)]
        # the pool is reused: a second batch on the same workers
        assert dict(pool.unordered(pool_tasks.square, [(i, (i,)) for i in range(5)])) == {i: i * i for i in range(5)}


def test_tasks_run_side_by_side_on_other_processes():
    with WorkerPool(2) as pool:
        pids = dict(pool.unordered(pool_tasks.pid_after, [(i, (0.3,)) for i in range(2)]))
    assert len(set(pids.values())) == 2 and os.getpid() not in pids.values()


def test_a_task_s_exception_is_raised_here_with_the_worker_s_traceback():
    with pytest.raises(ValueError, match="no such landmark") as info:
        with WorkerPool(2) as pool:
            list(pool.unordered(pool_tasks.fail, [(0, ("no such landmark",))]))
    remote = str(info.value.__cause__)
    assert "in worker process" in remote and "pool_tasks.py" in remote and "def fail" not in remote
    assert 'raise ValueError(message)' in remote


def test_an_exception_that_does_not_survive_pickling_arrives_as_its_type_and_message():
    with pytest.raises(RuntimeError, match="TwoArgError: one and two"):
        with WorkerPool(1) as pool:
            list(pool.unordered(pool_tasks.fail_unpicklable, [(0, ())]))


def test_a_result_that_cannot_be_sent_back_is_an_error_not_a_hang():
    with pytest.raises(Exception, match="pickle") as info:
        with WorkerPool(1) as pool:
            list(pool.unordered(pool_tasks.unpicklable_result, [(0, ())]))
    assert "in worker process" in str(info.value.__cause__)


def test_a_worker_that_dies_is_named_with_its_task_and_the_others_serve_on():
    with WorkerPool(2) as pool:
        pids = [w.process.pid for w in pool._workers]
        with pytest.raises(WorkerDied, match=r"killed by signal 9\) while running task 'the fatal one'"):
            list(pool.unordered(pool_tasks.die, [("the fatal one", ())]))
        # the surviving worker still serves until the block ends
        assert dict(pool.unordered(pool_tasks.square, [(1, (3,))])) == {1: 9}
    assert _gone(pids, 1.0)


def test_an_exception_while_iterating_stops_the_workers_at_once():
    """Ctrl-C in the caller is a KeyboardInterrupt raised while it iterates: the tasks in flight (5 s each)
    are dropped and the workers are gone well before they would have finished."""
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        with WorkerPool(2) as pool:
            pids = [w.process.pid for w in pool._workers]
            for _ in pool.unordered(pool_tasks.pid_after, [(i, (5.0 if i else 0.0,)) for i in range(3)]):
                raise KeyboardInterrupt  # the first result is in, two 5 s tasks are in flight
    assert time.monotonic() - t0 < 4.0
    assert _gone(pids, 1.0)


def test_workers_ignore_sigint_the_caller_decides():
    """A terminal's Ctrl-C reaches the workers too; they go on until the caller stops them."""
    with WorkerPool(1) as pool:
        assert dict(pool.unordered(pool_tasks.sigint_self_then, [(0, (7,))])) == {0: 7}


def test_leaving_normally_lets_the_workers_leave():
    with WorkerPool(2) as pool:
        pids = [w.process.pid for w in pool._workers]
        list(pool.unordered(pool_tasks.square, [(0, (1,))]))
    assert _gone(pids, 1.0)


@pytest.mark.parametrize("n", [0, -1])
def test_a_pool_of_no_workers_is_refused(n):
    with pytest.raises(ValueError, match="expected 1 or more"):
        WorkerPool(n)


def test_stopping_early_drops_the_workers_with_a_task_in_flight_and_keeps_the_rest():
    """A task in flight would answer the next call: its worker is terminated; an idle one serves on."""
    with WorkerPool(2) as pool:
        busy_pids = []
        for tag, pid in pool.unordered(pool_tasks.pid_after, [(0, (0.0,)), (1, (5.0,))]):
            busy_pids = [w.process.pid for w in pool._workers if w.process.pid != pid]
            break  # task 1 (5 s) is still running
        assert len(pool._workers) == 1 and _gone(busy_pids, 1.0)
        assert dict(pool.unordered(pool_tasks.square, [(i, (i,)) for i in range(4)])) == {i: i * i for i in range(4)}


def test_a_ctrl_c_while_the_first_pool_of_a_process_starts_kills_no_worker(tmp_path):
    """The workers start with SIGINT blocked (so a Ctrl-C to the group then is held, and dropped once they ignore
    it), also in a fresh process, where starting multiprocessing's resource tracker unblocks it in the caller."""
    script = tmp_path / "start.py"
    script.write_text(pool_tasks.SIGINT_AT_START.format(tests=str(Path(__file__).parent)))
    root = str(Path(__file__).resolve().parents[1])
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                         start_new_session=True, env=dict(os.environ, PYTHONPATH=root))
    assert out.returncode == 0 and "Traceback" not in out.stderr, out.stderr
    assert out.stdout.strip() == "[(0, 0), (1, 1), (2, 4), (3, 9)]"


def test_arguments_and_results_larger_than_a_pipe_s_buffer_go_through():
    with WorkerPool(2) as pool:
        got = dict(pool.unordered(pool_tasks.sizes, [(i, (b"x" * (3 << 20), 5 << 20)) for i in range(4)]))
    assert {k: (n, len(b)) for k, (n, b) in got.items()} == {i: (3 << 20, 5 << 20) for i in range(4)}


def test_an_exception_whose_text_fails_still_comes_back_as_an_error():
    with pytest.raises(RuntimeError, match="BrokenStr"):
        with WorkerPool(1) as pool:
            list(pool.unordered(pool_tasks.fail_broken_str, [(0, ())]))


def test_arguments_that_cannot_be_sent_fail_here_and_cost_no_worker():
    with WorkerPool(1) as pool:
        with pytest.raises(Exception, match="pickle"):
            list(pool.unordered(pool_tasks.square, [(0, (lambda: 1,))]))
        assert dict(pool.unordered(pool_tasks.square, [(0, (2,))])) == {0: 4}


def test_a_second_iteration_while_one_is_open_is_refused():
    """Its tasks in flight would answer the other's: refused, not mixed up."""
    with WorkerPool(2) as pool:
        first = pool.unordered(pool_tasks.pid_after, [(0, (0.0,)), (1, (2.0,))])
        next(first)
        with pytest.raises(RuntimeError, match="another iteration"):
            next(pool.unordered(pool_tasks.square, [(0, (1,))]))
        first.close()
        assert dict(pool.unordered(pool_tasks.square, [(0, (3,))])) == {0: 9}

"""Worker processes for the commands that spread work over this machine's cores.

A campaign's chunk rows (``testbed campaign --workers N``) and the DPE calibration's chunks (``testbed
calibrate-dpe --workers N``) run on a :class:`WorkerPool`: N worker processes, each fed one task at a time
over a pipe of its own. The pool has no thread of its own: the caller's thread hands a task to each idle
worker and waits on the workers' pipes and process sentinels together
(:func:`multiprocessing.connection.wait`), so there is no lock or queue another thread could leave held
when the work stops. What it guarantees:

- results come back as the tasks finish, each with the tag its task was given; the results do not depend
  on which worker ran what;
- an exception in a task is raised in the caller, the worker's traceback attached as its cause, and the
  other workers are stopped;
- a worker that dies (killed, out of memory) is a :class:`WorkerDied` naming the task it was running,
  never a hang;
- Ctrl-C, or any exception while the caller iterates, stops the workers at once: terminated (SIGTERM),
  then killed if still there after :data:`STOP_GRACE_S`. The tasks in flight are lost; a caller stores
  what finished (a campaign's chunks) and says so;
- the workers are spawned, not forked (a fresh interpreter: no copy of a parent's threads or locks), and
  ignore SIGINT from their first instruction on: a terminal's Ctrl-C goes to the whole process group, and
  the caller is the one to stop them.

It replaced :class:`concurrent.futures.ProcessPoolExecutor` here, which has no public way to stop its
workers before Python 3.14, and whose manager thread, feeder thread and locks must all come to an end
after its workers are terminated mid-task: an interrupted campaign on it once did not stop within its
test's 30 s (the cause was not captured; docs/design/architecture.md, "Worker processes").
"""

from __future__ import annotations

import multiprocessing
import pickle
import signal
import time
import traceback
from collections import deque
from dataclasses import dataclass
from multiprocessing import resource_tracker
from multiprocessing.connection import Connection, wait
from multiprocessing.reduction import ForkingPickler
from typing import Any, Callable, Hashable, Iterable, Iterator

#: how long a terminated worker may take to leave before it is killed (s)
STOP_GRACE_S = 2.0
#: how long a worker told to finish may take to leave before it is terminated (s)
CLOSE_GRACE_S = 10.0


class WorkerDied(RuntimeError):
    """A worker process ended while it ran a task (killed, out of memory, or the interpreter aborted)."""


class RemoteTraceback(Exception):
    """The traceback of an exception raised in a worker (the cause of the exception re-raised here)."""

    def __str__(self) -> str:
        return self.args[0]


@dataclass(eq=False)  # a worker is itself, whatever its fields
class _Worker:
    process: multiprocessing.process.BaseProcess
    conn: Connection


def _serve(conn: Connection) -> None:
    """A worker's loop: ``(fn, args)`` in, ``("ok", result)`` or ``("error", exception, traceback)`` out,
    until ``None`` or the caller's end of the pipe closes."""

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # started with SIGINT blocked (WorkerPool.__enter__)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):  # the caller is gone
            return
        if task is None:
            return
        fn, args = task
        try:
            reply = _pickled(("ok", fn(*args)))
        except BaseException as exc:  # noqa: BLE001 - every failure goes back to the caller
            reply = _pickled_error(exc)
        try:
            conn.send_bytes(reply)
        except OSError:  # the caller is gone
            return


def _pickled(reply: tuple) -> bytes:
    return ForkingPickler.dumps(reply)


def _pickled_error(exc: BaseException) -> bytes:
    """``("error", exc, traceback)`` pickled; an exception that does not survive the trip (one whose
    constructor takes other arguments than it keeps) goes as a RuntimeError with its type and message."""
    remote = "".join(traceback.format_exception(exc))
    try:
        data = _pickled(("error", exc, remote))
        pickle.loads(data)
        return data
    except Exception:  # noqa: BLE001 - any failure to pickle or rebuild it
        said = "".join(traceback.format_exception_only(exc)).strip()  # safe even if its str() raises
        return _pickled(("error", RuntimeError(said), remote))


class WorkerPool:
    """``workers`` spawned processes, as a context manager; :meth:`unordered` runs tasks on them.

    Leaving the block normally lets the workers finish and leave; leaving it with an exception (Ctrl-C
    included) stops them at once (:meth:`stop`). Ctrl-C is the main thread's KeyboardInterrupt: the pool stops
    at once on it when the main thread iterates it (as every caller here does). A script using it needs the
    usual ``if __name__ == "__main__":`` guard (spawned workers import the script's main module).
    """

    def __init__(self, workers: int):
        if int(workers) < 1:
            raise ValueError(f"workers = {workers!r}: expected 1 or more")
        self.n = int(workers)
        self._workers: list[_Worker] = []
        self._dropped: list[_Worker] = []  # found dead or left mid-task: released with the others
        self._iterating = False

    def __enter__(self) -> "WorkerPool":
        ctx = multiprocessing.get_context("spawn")
        # the resource tracker first: starting it unblocks SIGINT in this thread (Python 3.11), which would undo
        # the block below for the first pool of a process
        resource_tracker.ensure_running()
        try:
            # SIGINT blocked while they start, so a Ctrl-C then cannot kill a worker before it ignores SIGINT
            # (the mask is inherited across exec); here a Ctrl-C meanwhile is held and raised on unblocking
            before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            try:
                for _ in range(self.n):
                    mine, theirs = ctx.Pipe(duplex=True)
                    p = ctx.Process(target=_serve, args=(theirs,), daemon=True)
                    p.start()
                    theirs.close()
                    self._workers.append(_Worker(p, mine))
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, before)
        except BaseException:  # a Ctrl-C held while they started is raised here: no worker is left behind
            self.stop()
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.stop()
            return
        try:
            self.close()
        except BaseException:
            self.stop()
            raise

    def unordered(self, fn: Callable, tasks: Iterable[tuple[Hashable, tuple]]) -> Iterator[tuple[Hashable, Any]]:
        """``(tag, fn(*args))`` for each ``(tag, args)`` of ``tasks``, in the order they finish.

        ``fn`` must be importable by name (a module-level function). A task that raises, or a worker that
        dies, raises here. Left before the end (an exception, or the caller stopped iterating), the workers
        with a task in flight are terminated and leave the pool; the others serve on until the block ends.
        One iteration at a time: a second one started while another is still open is refused."""
        if self._iterating:
            raise RuntimeError("WorkerPool.unordered: another iteration of this pool is still open (finish or "
                               "close it first: its tasks in flight would answer this one's)")
        self._iterating = True
        queue = deque(tasks)
        busy: dict[int, tuple[_Worker, Hashable]] = {}  # by the worker's pipe's file descriptor
        try:
            if queue and not self._workers:
                raise WorkerDied("no worker process is left in the pool")
            idle = list(self._workers)
            while queue or busy:
                while queue and idle:
                    tag, args = queue.popleft()
                    payload = ForkingPickler.dumps((fn, args))  # arguments that cannot be sent fail here
                    w = idle.pop()
                    try:
                        w.conn.send_bytes(payload)
                    except (BrokenPipeError, ConnectionResetError):
                        raise self._died(w, tag, "before it could take") from None
                    busy[w.conn.fileno()] = (w, tag)
                ready = wait([w.conn for w, _ in busy.values()] + [w.process.sentinel for w, _ in busy.values()])
                for fd, (w, tag) in list(busy.items()):
                    if w.conn in ready or w.conn.poll():  # a result sent just before its worker ended is still read
                        try:
                            reply = w.conn.recv()
                        except (EOFError, ConnectionResetError):
                            del busy[fd]
                            raise self._died(w, tag, "while running") from None
                        del busy[fd]
                        idle.append(w)
                        if reply[0] == "error":
                            _, exc, remote = reply
                            if remote:
                                exc.__cause__ = RemoteTraceback(f"\nin worker process {w.process.pid}:\n{remote}")
                            raise exc
                        yield tag, reply[1]
                    elif w.process.sentinel in ready:
                        del busy[fd]
                        raise self._died(w, tag, "while running")
        finally:  # left early (an error, or the caller stopped iterating): a task in flight would answer the next
            self._iterating = False
            for w, _ in busy.values():
                w.process.terminate()
                self._drop(w)

    def _drop(self, w: _Worker) -> None:
        if w in self._workers:
            self._workers.remove(w)
            self._dropped.append(w)

    def _died(self, w: _Worker, tag: Hashable, when: str) -> WorkerDied:
        """The error for worker ``w`` found dead ``when`` task ``tag``; the worker leaves the pool."""
        w.process.join(STOP_GRACE_S)
        self._drop(w)
        code = w.process.exitcode
        how = (f"killed by signal {-code}" if code is not None and code < 0 else f"exit code {code}")
        return WorkerDied(f"worker process {w.process.pid} ended ({how}) {when} task {tag!r}")

    def close(self) -> None:
        """Tell the workers to finish and wait for them (terminated after :data:`CLOSE_GRACE_S` in all)."""
        for w in self._workers:
            try:
                w.conn.send(None)
            except OSError:
                pass
        _join_all(self._workers, CLOSE_GRACE_S)
        self.stop()

    def stop(self) -> None:
        """Stop every worker now (SIGTERM, then SIGKILL after :data:`STOP_GRACE_S` in all) and release the pipes."""
        everyone = self._workers + self._dropped
        for w in everyone:
            if w.process.is_alive():
                w.process.terminate()
        _join_all(everyone, STOP_GRACE_S)
        for w in everyone:
            if w.process.is_alive():
                w.process.kill()
                w.process.join()
            w.conn.close()
            w.process.close()
        self._workers, self._dropped = [], []


def _join_all(workers: list[_Worker], within_s: float) -> None:
    """Wait up to ``within_s`` in all for the workers' processes to end."""
    deadline = time.monotonic() + within_s
    for w in workers:
        w.process.join(max(0.0, deadline - time.monotonic()))

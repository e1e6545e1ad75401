"""A command's outputs: tried before any work, written under temporary names, moved into place together.

A command declares every output first (:meth:`OutputSet.file`, :meth:`OutputSet.folder`). Each is
checked by trying it, not by asking about permissions: the folders it would create are created, a
probe file is created in its folder and removed, and what was created is removed again
(:func:`output_problem`). Two outputs that would write the same file are refused too. Both are a
:class:`~testbed.schema.ConfigError` naming the option, the path and why, before any work.

The command then writes each file under a temporary name beside its destination (:meth:`OutputSet.staged`,
:meth:`OutputSet.staged_folder`: the same folder, so the final rename stays on one file system) and
:meth:`OutputSet.commit` moves them all into place at the end. A failure or a Ctrl-C before that
removes the temporary files and leaves every destination as it was; the exception carries a note
saying what was and was not written (the command line prints it).

What the commit guarantees (POSIX renames one file atomically, never several):

- each destination is at every instant its previous version or its new one, never a partial file
  (``rename(2)``; the new data is flushed to disk first);
- the previous versions are kept (as hard links) until every file is in place: a rename that fails
  puts back the ones already moved, so a failed commit leaves every destination as it was;
- a Ctrl-C during the commit (the main thread's SIGINT) is held until the commit has ended, then
  reported.

What it cannot guarantee: another process looking during the commit (milliseconds) can see some files
new and others old; a kill -9 or a power cut inside that window leaves them so, the previous versions
kept beside them as hidden ``.NAME.XXXXXXXX.prev`` files. A kill during the work leaves hidden
``.NAME.XXXXXXXX.part*`` files or ``.testbed-staging-XXXXXXXX`` folders, never a destination's name.
What a command stores as it goes by design (a campaign's chunks, ``calibrate-dpe --work``) is not
staged: :meth:`OutputSet.folder`'s ``kept`` says what stays there when it stops early.
"""

from __future__ import annotations

import errno
import os
import shutil
import signal
import tempfile
import uuid
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from testbed.schema import ConfigError

STAGING_PREFIX = ".testbed-staging-"
PROBE_PREFIX = ".testbed-probe-"
#: errors that only a write raises: a staged write failing with one is said as the output's problem
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS}


def _absolute(path: str | Path) -> Path:
    """``path`` made absolute without following symbolic links (``..`` folded lexically)."""
    return Path(os.path.abspath(path))


def _missing_folders(folder: Path) -> list[Path]:
    """The folders above and including ``folder`` that do not exist, outermost first."""
    missing = []
    while not os.path.lexists(folder) and folder.parent != folder:
        missing.append(folder)
        folder = folder.parent
    return missing[::-1]


def output_problem(path: str | Path, option: str, *, folder: bool) -> str | None:
    """Why ``path`` cannot be written as an output (a file, or with ``folder`` a folder); None when it can.

    Tried: the missing folders are created, a probe file is created and removed in the folder the
    output goes to, and the created folders are removed again (a read-only folder or file system, a
    full quota on inodes, a file where a folder is expected, a folder root may not write into:
    all refused here, whatever ``os.access`` says).
    """
    p = _absolute(path)
    if folder and p.exists() and not p.is_dir():
        return f"{option} {path}: is a file; expected a folder"
    if not folder and p.is_dir():
        return f"{option} {path}: is a folder; expected a file path"
    target = p if folder else p.parent
    missing = _missing_folders(target)
    top = missing[0].parent if missing else target
    if not top.is_dir():
        return f"{option} {path}: {top} is {'a file' if top.exists() else 'a broken link'}, not a folder"
    created = []
    stamp = os.stat(top)  # the probe leaves no trace, not even in the folder's modification time
    try:
        for d in missing:
            os.mkdir(d)
            created.append(d)
        fd, probe = tempfile.mkstemp(prefix=PROBE_PREFIX, dir=target)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        what = f"the folder {exc.filename}" if len(created) < len(missing) else f"a file in {target}"
        return f"{option} {path}: cannot create {what} ({exc.strerror or exc}); expected a place this user can write"
    finally:
        for d in reversed(created):
            try:
                os.rmdir(d)
            except OSError:
                pass  # something else appeared in it meanwhile: not ours to remove
        try:
            os.utime(top, ns=(stamp.st_atime_ns, stamp.st_mtime_ns))
        except OSError:
            pass  # nothing was made, so nothing changed
    return None


def check_output(path: str | Path | None, option: str, *, folder: bool, suffixes: tuple[str, ...] = ()) -> None:
    """A ConfigError before any work unless ``path`` can be written (None: no output, nothing to check)."""
    if path is None:
        return
    p = Path(path)
    problem = None
    if not folder and suffixes and not p.is_dir() and p.suffix.lower() not in suffixes:
        problem = f"{option} {p}: unsupported suffix {p.suffix or '(none)'!r}; expected {' or '.join(suffixes)}"
    problem = problem or output_problem(p, option, folder=folder)
    if problem:
        raise ConfigError(p, [problem])


@dataclass(frozen=True)
class _Output:
    path: Path  # absolute (what is written)
    real: Path  # symbolic links resolved (what is compared)
    given: str  # as the user spelled it (what is said)
    option: str
    folder: bool
    entries: tuple[str, ...]  # a folder's entries known up front ("name" a file, "name/" a folder)
    complete: bool  # a folder receives nothing but its entries
    kept: str | None  # a folder: what the command stores there as it goes
    existed: bool

    def said(self) -> str:
        return f"{self.option} {self.given}"


def _inside(a: Path, b: Path) -> bool:
    """``a`` is ``b`` or lies under it."""
    return a == b or b in a.parents


def _clash(a: _Output, b: _Output) -> str | None:
    """Why outputs ``a`` and ``b`` would write the same file (None: they cannot)."""
    if a.real == b.real or (a.real.exists() and b.real.exists() and os.path.samefile(a.real, b.real)):
        return "name the same path"
    for outer, inner in ((a, b), (b, a)):
        if not _inside(inner.real, outer.real):
            continue
        if not outer.folder:
            return f"{inner.given} lies under the file {outer.given}"
        rel = inner.real.relative_to(outer.real).as_posix()
        if not outer.complete:
            return f"{inner.given} is inside the folder {outer.option} writes"
        for e in outer.entries:
            name = e.rstrip("/")
            if rel == name or rel.startswith(name + "/") or (inner.folder and name.startswith(rel + "/")):
                return f"{outer.option} writes {Path(outer.given) / name} there"
    return None


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - a file system that cannot: the rename is still atomic
        pass
    finally:
        os.close(fd)


@contextmanager
def _sigint_held() -> Iterator[None]:
    """Hold a Ctrl-C (SIGINT) for the block; raise it when the block has ended (main thread only)."""
    got: list[int] = []
    try:
        before = signal.signal(signal.SIGINT, lambda signum, frame: got.append(signum))
    except ValueError:  # not the main thread: signals cannot be caught here
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)
    if got and callable(before):
        before(signal.SIGINT, None)  # Python's own handler raises KeyboardInterrupt here
    elif got and before == signal.SIG_DFL:
        raise KeyboardInterrupt


class OutputSet:
    """Every output of one command, checked up front and committed together (see the module doc).

    >>> with OutputSet() as outs:                      # doctest: +SKIP
    ...     rrd = outs.file(args.rrd, "--rrd", (".rrd",))
    ...     table = outs.folder(args.out, "--out", entries=("summary.json",))
    ...     work()                                       # a failure here writes nothing
    ...     write_summary(outs.staged(table / "summary.json"))
    ...     write_recording(outs.staged(rrd))
    ...     outs.commit()                                # all in place, or none (also on leaving the block)

    A library call that takes ``outputs`` uses the caller's set (:meth:`using`): the caller commits.
    """

    def __init__(self) -> None:
        self._token = uuid.uuid4().hex[:8]
        self._outputs: list[_Output] = []
        self._files: dict[Path, Path] = {}  # declared file -> its temporary path
        self._staging: dict[Path, Path] = {}  # declared folder -> its staging folder (inside it)
        self._created: list[Path] = []  # folders made for the outputs (removed again when nothing is written)
        self.state = "open"  # then "committed" or "abandoned"
        self.written: list[Path] = []
        self._explained = False  # the exception leaving the set already says what was written

    # -- declaring -------------------------------------------------------------------------------------------
    @classmethod
    @contextmanager
    def using(cls, outputs: "OutputSet | None") -> Iterator["OutputSet"]:
        """The caller's set as it is (the caller commits), or a new one committed when the block ends."""
        if outputs is not None:
            yield outputs
            return
        with cls() as own:
            yield own

    def file(self, path: str | Path, option: str, suffixes: tuple[str, ...] = ()) -> Path:
        """Declare an output file (checked now: its suffix, that it can be written, that no other output
        writes it); returns its absolute path."""
        check_output(path, option, folder=False, suffixes=suffixes)
        return self._declare(path, option, folder=False)

    def folder(self, path: str | Path, option: str, *, entries: tuple[str, ...] = (), complete: bool = False,
               kept: str | None = None) -> Path:
        """Declare an output folder; returns its absolute path.

        entries : what the command writes there, when known up front (``"name/"`` for a folder): each is
            checked to be of that kind already. With ``complete`` the folder receives nothing else, so
            another output may name another file in it; without, nothing inside it may be another output.
        kept : what the command stores there as it goes (resumable work), said when it stops early.
        """
        check_output(path, option, folder=True)
        p = _absolute(path)
        problems = []
        for e in entries:
            q = p / e.rstrip("/")
            if e.endswith("/") and q.exists() and not q.is_dir():
                problems.append(f"{option} {path}: {q} is a file; the command writes a folder there")
            elif not e.endswith("/") and q.is_dir():
                problems.append(f"{option} {path}: {q} is a folder; the command writes a file there")
        if problems:
            raise ConfigError(Path(path), problems)
        return self._declare(path, option, folder=True, entries=tuple(entries), complete=complete, kept=kept)

    def _declare(self, path, option: str, **kind) -> Path:
        p = _absolute(path)
        new = _Output(p, Path(os.path.realpath(p)), str(path), option, existed=os.path.lexists(p), **{
            "entries": (), "complete": False, "kept": None, **kind})
        for old in self._outputs:
            why = _clash(old, new)
            if why:
                raise ConfigError(Path(path), [f"{old.said()} and {new.said()}: {why}; expected outputs that "
                                               "do not overwrite each other"])
        self._outputs.append(new)
        return p

    def declares(self, path: str | Path) -> bool:
        """``path`` is a declared output or lies in a declared folder."""
        try:
            self._owner(_absolute(path))
        except KeyError:
            return False
        return True

    def _owner(self, p: Path) -> _Output:
        for o in self._outputs:
            if p == o.path:
                return o
        folders = [o for o in self._outputs if o.folder and o.path in p.parents]
        if folders:
            return max(folders, key=lambda o: len(o.path.parts))
        raise KeyError(f"{p}: not a declared output (declare it with OutputSet.file or OutputSet.folder)")

    # -- staging ---------------------------------------------------------------------------------------------
    def staged(self, path: str | Path) -> Path:
        """Where to write the output file ``path`` (declared, or inside a declared folder) until the commit."""
        p = _absolute(path)
        owner = self._owner(p)
        if owner.folder:
            tmp = self.staged_folder(p.parent) / p.name
        elif p in self._files:
            tmp = self._files[p]
        else:
            self._make_folders(p.parent)
            tmp = self._files[p] = p.with_name(f".{p.name}.{self._token}.part{p.suffix}")
        return tmp

    def staged_folder(self, path: str | Path) -> Path:
        """The temporary counterpart of a declared folder (or of a folder inside one): whatever is
        written there goes to the same place in the folder at the commit."""
        p = _absolute(path)
        owner = self._owner(p)
        if not owner.folder:
            raise KeyError(f"{p}: declared as a file, not a folder")
        root = self._staging.get(owner.path)
        if root is None:
            self._make_folders(owner.path)
            root = owner.path / f"{STAGING_PREFIX}{self._token}"
            root.mkdir()
            self._staging[owner.path] = root
        sub = root / p.relative_to(owner.path)
        sub.mkdir(parents=True, exist_ok=True)
        return sub

    def final(self, staged: str | Path) -> Path:
        """The destination of a temporary path :meth:`staged` or :meth:`staged_folder` gave."""
        s = _absolute(staged)
        for dest, tmp in self._files.items():
            if s == tmp:
                return dest
        for folder, root in self._staging.items():
            if _inside(s, root):
                return folder / s.relative_to(root)
        return s

    def _make_folders(self, folder: Path) -> None:
        for d in _missing_folders(folder):
            d.mkdir()
            self._created.append(d)

    # -- committing ------------------------------------------------------------------------------------------
    def _moves(self) -> list[tuple[Path, Path]]:
        moves = [(tmp, dest) for dest, tmp in self._files.items() if os.path.lexists(tmp)]
        for folder, root in self._staging.items():
            for base, _, names in sorted(os.walk(root)):
                for n in sorted(names):
                    tmp = Path(base) / n
                    moves.append((tmp, folder / tmp.relative_to(root)))
        return moves

    def commit(self) -> list[Path]:
        """Move every staged file into place, all or none (module doc); returns the destinations."""
        if self.state != "open":
            return self.written
        moves = self._moves()
        for tmp, _ in moves:
            _fsync(tmp)
        done: list[tuple[Path, Path | None]] = []  # (destination, its previous version)
        with _sigint_held():
            try:
                for tmp, dest in moves:
                    self._make_folders(dest.parent)
                    previous = self._keep_previous(dest)
                    try:
                        os.replace(tmp, dest)
                    except BaseException:
                        if previous is not None:
                            previous.unlink(missing_ok=True)
                        raise
                    done.append((dest, previous))
            except BaseException as exc:
                stuck = self._put_back(done)
                self.abandon()
                self._explained = True
                message = self._failed_commit(dest, exc, stuck)
                if not isinstance(exc, Exception):  # SystemExit and the like: as they are, said
                    exc.add_note(message)
                    raise
                raise ConfigError(dest, [message]) from None
            for _, previous in done:
                if previous is not None:
                    previous.unlink(missing_ok=True)
            for folder in {dest.parent for _, dest in moves}:
                _fsync(folder)
            for root in self._staging.values():
                shutil.rmtree(root, ignore_errors=True)
            self.state = "committed"
            self.written = [dest for _, dest in moves]
        return self.written

    def _keep_previous(self, dest: Path) -> Path | None:
        """A second name for ``dest``'s current version (None: there is none), to put back on a failure."""
        if not os.path.lexists(dest):
            return None
        if dest.is_dir() and not dest.is_symlink():
            raise IsADirectoryError(errno.EISDIR, "a folder is there", str(dest))
        previous = dest.with_name(f".{dest.name}.{self._token}.prev")
        if dest.is_symlink():
            os.symlink(os.readlink(dest), previous)
        else:
            try:
                os.link(dest, previous)
            except OSError:  # a file system without hard links: a copy keeps it as well
                shutil.copy2(dest, previous)
        return previous

    @staticmethod
    def _put_back(done: list[tuple[Path, Path | None]]) -> list[Path]:
        """Undo the renames made so far; the destinations that could not be put back."""
        stuck = []
        for dest, previous in reversed(done):
            try:
                if previous is None:
                    dest.unlink()
                else:
                    os.replace(previous, dest)
            except OSError:
                stuck.append(dest)
        return stuck

    def _failed_commit(self, dest: Path, exc: Exception, stuck: list[Path]) -> str:
        why = getattr(exc, "strerror", None) or exc
        if not stuck:
            return f"{self._owner(dest).said()}: could not move {dest} into place ({why}); " + self.unwritten()
        return (f"{self._owner(dest).said()}: could not move {dest} into place ({why}), and {len(stuck)} file(s) "
                f"moved before it could not be put back: {', '.join(map(str, stuck))} hold the new version; their "
                f"previous versions are beside them as .NAME.{self._token}.prev")

    def abandon(self) -> None:
        """Remove every temporary file and the folders made for them: the destinations stay as they were."""
        if self.state != "open":
            return
        for dest, tmp in self._files.items():
            for leftover in tmp.parent.glob(f".{dest.name}.{self._token}.part*"):  # a writer's own .part too
                leftover.unlink(missing_ok=True)
        for root in self._staging.values():
            shutil.rmtree(root, ignore_errors=True)
        for d in reversed(self._created):
            try:
                d.rmdir()
            except OSError:
                pass  # not empty (something else was put there) or already gone
        self.state = "abandoned"

    # -- saying what happened -----------------------------------------------------------------------------------
    def unwritten(self) -> str:
        """What a command that stops before its commit leaves: one clause per output."""
        parts = []
        for o in self._outputs:
            if o.kept is not None:
                parts.append(f"{o.said()}: {o.kept}")
            elif o.folder:
                parts.append(f"{o.said()}: {'the files there are as they were' if o.existed else 'not created'}")
            else:
                parts.append(f"{o.said()}: {'as it was' if o.existed else 'not created'}")
        return "the outputs were not written (a command moves them into place together, at its end): " + "; ".join(
            parts)

    def __enter__(self) -> "OutputSet":
        return self

    def __exit__(self, kind, exc, tb) -> bool:
        if exc is None:
            self.commit()
            return False
        if self.state == "committed":
            exc.add_note(f"the outputs had been written: {', '.join(map(str, self.written))}")
            return False
        self.abandon()
        if self._explained:
            return False
        if isinstance(exc, OSError) and self._a_staged_write(exc):
            where = exc.filename and self.final(exc.filename)
            raise ConfigError(where or "outputs", [f"writing {where or 'an output'} failed ({exc.strerror or exc}); "
                                                   + self.unwritten()]) from None
        # bad input refused before anything was staged says its problem alone; anything else says what it left
        if self._outputs and (self._files or self._staging or not isinstance(exc, ConfigError)):
            exc.add_note(self.unwritten())
        return False

    def _a_staged_write(self, exc: OSError) -> bool:
        if exc.errno in _WRITE_ERRNOS:
            return True
        if not exc.filename:
            return False
        f = _absolute(os.fsdecode(exc.filename))
        return any(f.name.startswith(f".{d.name}.{self._token}.part") for d in self._files) or any(
            _inside(f, root) for root in self._staging.values())

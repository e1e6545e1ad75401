"""The resumable result store of a campaign (a folder of Parquet files).

Layout of ``out_dir``::

    manifest.json         spec (JSON), spec hash, cell count, chunk plan size
    cells.parquet         one row per cell: its sweep parameters
    parts/c00003-k00002/  one folder per finished chunk: trials/epochs/hist .parquet
    trials.parquet        consolidated (sorted by cell, trial, monitor) when all chunks are done
    epochs.parquet        per-epoch records of the first ``per_epoch_trials`` trials of each cell
    stanford_hist.parquet Stanford-diagram counts (cell, monitor, dim, err_bin, pl_bin, count)
    runs.json             each run (the first, every resume, a killed one too): start, wall time, chunks, epochs

A chunk folder is written under a temporary name and renamed into place in one
``os.rename`` (atomic on POSIX), so after a kill a chunk is either complete or
absent; ``resume`` skips complete chunks and deletes leftovers. The manifest
(the whole spec and a fingerprint of the inputs) stops a resume with a different
spec or inputs from mixing results, naming what changed. What the store wrote is
read back like an input (:class:`Manifest`, :class:`RunRecord`): a damaged file is
a message naming its key, never a traceback.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
import warnings
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from testbed.campaign.spec import ReportSettings, fingerprint_changes, input_fingerprint, spec_changes
from testbed.schema import ConfigError, read_json

NAMES = {"trials": "trials.parquet", "epochs": "epochs.parquet", "hist": "stanford_hist.parquet"}
#: one entry per run that worked on the folder (wall time, chunks and epochs computed)
RUNS = "runs.json"
#: what to do with a stored run that cannot go on, for every command that meets one (campaign and reproduce
#: take these options; report names them)
AGAIN = "start over in this folder with --restart (testbed campaign or reproduce), or choose another --out folder"


class StoredRecord(BaseModel):
    """A stored record's table: kinds as written (no coercion), every key the readers use."""

    model_config = ConfigDict(strict=True, frozen=True)


class StoredSpec(StoredRecord):
    """The spec in a manifest: the keys the report and a resume read, checked; the others (this version's
    or an earlier one's) are compared on resume, not checked."""

    model_config = ConfigDict(extra="allow")
    name: str
    trials: int = Field(ge=1)
    monitors: list[str] = Field(min_length=1)
    base_seed: int = Field(ge=0)
    block_trials: int = Field(ge=1)
    per_epoch_trials: int = Field(ge=0)
    description: str = ""
    report: ReportSettings = ReportSettings()


class StoredInputs(StoredRecord):
    """The fingerprint of what the cells read (:func:`~testbed.campaign.spec.input_fingerprint`)."""

    model_config = ConfigDict(extra="forbid")
    cells: str = Field(pattern=r"^[0-9a-f]{16}$")
    files: dict[str, Annotated[str, Field(pattern=r"^[0-9a-f]{16}$")]]
    testbed: str


class Manifest(StoredRecord):
    """``manifest.json``: what the stored run is of (format 2)."""

    model_config = ConfigDict(extra="forbid")
    name: str
    spec_hash: str = Field(pattern=r"^[0-9a-f]{16}$")
    cells: int = Field(ge=1)
    spec: StoredSpec
    source: str
    inputs: StoredInputs
    format: Literal[2]


class RunRecord(StoredRecord):
    """One entry of ``runs.json``."""

    model_config = ConfigDict(extra="forbid")
    started_utc: str
    finished: bool
    wall_s: float = Field(ge=0)
    chunks_run: int = Field(ge=0)
    epochs_run: int = Field(ge=0)


_RUNS = TypeAdapter(list[RunRecord])


class ResultStore:
    def __init__(self, out_dir: str | Path) -> None:
        self.dir = Path(out_dir)
        self.parts = self.dir / "parts"

    # -- lifecycle -------------------------------------------------------------
    def open(self, loaded, cells, *, resume: bool, restart: bool = False) -> None:
        """Create the folder (or check it for a resume) before any work starts.

        A resume is refused unless the spec, every cell's resolved configuration and every
        input file are what the stored run used; ``restart`` discards the stored run first.
        """
        man = self.dir / "manifest.json"
        inputs = input_fingerprint(cells)
        if restart:
            self.discard()
        elif man.exists():
            old = self.manifest()
            changed = spec_changes(old["spec"], loaded.spec.model_dump(mode="json"))
            if old["spec_hash"] != loaded.hash and not changed:  # a change this version's keys do not show
                changed = [f"the spec's hash: {old['spec_hash']} → {loaded.hash}"]
            changed += fingerprint_changes(old["inputs"], inputs)
            if changed:
                raise ConfigError(loaded.source, [f"{c} (the run stored in {self.dir} → now)" for c in changed]
                                  + [f"{self.dir} holds a run of another spec or other inputs: {AGAIN}"])
            if not resume:
                raise ConfigError(loaded.source, [f"{self.dir} already holds this campaign: pass --resume to "
                                                  f"complete it, or {AGAIN}"])
        elif resume and self.parts.exists():
            raise ConfigError(loaded.source, [f"{self.dir}: no manifest.json to resume from "
                                              "(start over with --restart)"])
        self.parts.mkdir(parents=True, exist_ok=True)
        for p in self.parts.glob("*.tmp-*"):  # leftovers of a killed run
            shutil.rmtree(p, ignore_errors=True)
        self._write_cells(cells)
        if not man.exists():
            manifest = {"name": loaded.spec.name, "spec_hash": loaded.hash, "cells": len(cells),
                        "spec": loaded.spec.model_dump(mode="json"), "source": str(loaded.source),
                        "inputs": inputs, "format": 2}
            _atomic_bytes(man, json.dumps(manifest, indent=1).encode())

    def _write_cells(self, cells) -> None:
        rows = [c.params for c in cells]
        keys = list(rows[0])
        t = pa.table({k: [r[k] for r in rows] for k in keys})
        _atomic_table(self.dir / "cells.parquet", t)

    def manifest(self) -> dict:
        """``manifest.json`` as stored, checked like an input (:class:`Manifest`): a ConfigError naming the
        file, the key and the value when it is damaged or not one."""
        return read_json(self.dir / "manifest.json", Manifest, what="a campaign manifest",
                         remedy=AGAIN).model_dump(mode="json")

    def discard(self) -> None:
        """Remove a stored run's files (only the ones the store writes; anything else is left alone)."""
        for name in ("manifest.json", "cells.parquet", "report.md", RUNS, *NAMES.values()):
            (self.dir / name).unlink(missing_ok=True)
        for sub in ("parts", "figures"):
            shutil.rmtree(self.dir / sub, ignore_errors=True)

    # -- chunks ----------------------------------------------------------------
    @staticmethod
    def chunk_name(cell: int, chunk: int) -> str:
        return f"c{cell:05d}-k{chunk:05d}"

    def done_chunks(self) -> set[tuple[int, int]]:
        out = set()
        if not self.parts.exists():
            return out
        for p in self.parts.iterdir():
            if p.is_dir() and ".tmp-" not in p.name and p.name.startswith("c"):
                try:
                    c, k = (int(x) for x in p.name[1:].split("-k"))
                except ValueError:
                    continue  # not a chunk folder of ours
                if _readable(p):
                    out.add((c, k))
                else:  # damaged after it was written (truncated, edited): recompute it
                    warnings.warn(f"{p}: unreadable chunk removed; it will be computed again", stacklevel=2)
                    shutil.rmtree(p, ignore_errors=True)
        return out

    def write_chunk(self, cell: int, chunk: int, tables: dict) -> None:
        final = self.parts / self.chunk_name(cell, chunk)
        if final.exists():
            return
        tmp = self.parts / f"{final.name}.tmp-{uuid.uuid4().hex[:8]}"
        tmp.mkdir(parents=True)
        for key, t in tables.items():
            if t is not None and t.num_rows:
                pq.write_table(t, tmp / f"{key}.parquet")
                _fsync(tmp / f"{key}.parquet")
        os.rename(tmp, final)
        _fsync_dir(self.parts)

    # -- consolidation -----------------------------------------------------------
    def finalize(self) -> None:
        """Merge the chunk parts into the sorted top-level tables (atomically, each).

        Cell by cell: every sort key starts with the cell, so the cells' sorted tables written
        one after another are the whole table sorted, and memory holds one cell's rows, not the
        campaign's (10⁵ sorties × 90 cells × 2 monitors is ~10⁷ rows)."""
        for key, name in NAMES.items():
            files = sorted(self.parts.glob(f"c*-k*/{key}.parquet"))
            files = [f for f in files if ".tmp-" not in f.parent.name]
            if not files:
                continue
            by_cell: dict[int, list[Path]] = {}
            for f in files:
                by_cell.setdefault(int(f.parent.name[1:].split("-k")[0]), []).append(f)
            schema = pa.unify_schemas([pq.read_schema(f) for f in files])  # as concatenation promotes
            if (self.dir / name).exists() and not _readable(self.dir / name):
                _keep_aside(self.dir / name, "not a readable Parquet table", "consolidated again from parts/")
            with _AtomicWriter(self.dir / name) as w:
                for _, cell_files in sorted(by_cell.items()):
                    t = pa.concat_tables([pq.read_table(f) for f in cell_files], promote_options="default")
                    t = _sorted_part(key, _conform(t, schema))
                    w.write(t)

    # -- the runs that computed it ----------------------------------------------
    def start_run(self) -> int:
        """Add a run (an invocation: the first or a resume) to ``runs.json``; returns its index for
        :meth:`update_run`. A campaign finished over several runs still knows how long it took."""
        runs = self.runs() + [{"started_utc": _utc_now(), "finished": False, "wall_s": 0.0, "chunks_run": 0,
                               "epochs_run": 0}]
        _atomic_bytes(self.dir / RUNS, json.dumps(runs, indent=1).encode())
        return len(runs) - 1

    def update_run(self, index: int, wall_s: float, chunks_run: int, epochs_run: int, finished: bool = False) -> None:
        """What run ``index`` has done so far (written after every chunk row: a killed run keeps its time)."""
        runs = self.runs()
        if not 0 <= index < len(runs):
            return
        runs[index] |= {"wall_s": round(float(wall_s), 3), "chunks_run": int(chunks_run),
                        "epochs_run": int(epochs_run), "finished": bool(finished)}
        _atomic_bytes(self.dir / RUNS, json.dumps(runs, indent=1).encode())

    def runs(self) -> list[dict]:
        """The recorded runs, oldest first (none for a folder written before they were recorded). A damaged
        ``runs.json`` is moved aside (``runs.json.damaged-*``, with a warning), not written over."""
        path = self.dir / RUNS
        if not path.exists():
            return []
        try:
            return [r.model_dump() for r in read_json(path, _RUNS, what="a list of runs", remedy="")]
        except ConfigError as exc:
            _keep_aside(path, "; ".join(exc.problems), "the run times start again")
            return []

    def wall_s(self) -> float:
        """Wall time of every recorded run added up (0 when none was recorded)."""
        return float(sum(r.get("wall_s", 0.0) for r in self.runs()))

    def complete(self) -> bool:
        """The consolidated tables are there and every one of them opens (a truncated or edited one does
        not: the next run consolidates the stored chunks again, :meth:`finalize`)."""
        tables = [self.dir / n for n in NAMES.values()]
        return tables[0].exists() and all(_readable(t) for t in tables if t.exists())

    def table(self, key: str) -> pa.Table | None:
        p = self.dir / NAMES.get(key, f"{key}.parquet")
        return pq.read_table(p) if p.exists() else None


def tables_equal(a: pa.Table, b: pa.Table) -> bool:
    """Tables equal bit for bit: same schema and row order, NaN equal to NaN."""
    if a.schema != b.schema or a.num_rows != b.num_rows:
        return False
    for n in a.column_names:
        x, y = a.column(n).to_numpy(zero_copy_only=False), b.column(n).to_numpy(zero_copy_only=False)
        if not (np.array_equal(x, y, equal_nan=True) if x.dtype.kind == "f" else list(x) == list(y)):
            return False
    return True


def _readable(path: Path) -> bool:
    """A Parquet file, or every one of a chunk folder, opens (its footer is intact)."""
    try:
        for f in (path.glob("*.parquet") if path.is_dir() else [path]):
            pq.read_metadata(f)
    except (OSError, pa.ArrowException):
        return False
    return True


def _keep_aside(path: Path, what: str, then: str) -> None:
    """Move a damaged file of the store aside (``<name>.damaged-<tag>``, with a warning): a file the
    store wrote is never written over, even one it cannot read."""
    aside = path.with_name(f"{path.name}.damaged-{uuid.uuid4().hex[:8]}")
    path.replace(aside)
    warnings.warn(f"{path}: {what}; kept as {aside.name}, {then}", stacklevel=3)


#: the consolidated tables' row order
SORT_KEYS = {"trials": ("cell", "trial", "monitor"), "epochs": ("cell", "trial", "monitor", "t"),
             "hist": ("cell", "monitor", "dim", "err_bin", "pl_bin")}


def _sorted_part(key: str, t: pa.Table) -> pa.Table:
    """Rows of one cell in the table's order (histogram chunks of the cell added up first)."""
    if key == "hist":
        t = t.group_by(list(SORT_KEYS["hist"])).aggregate([("count", "sum")])
        t = t.rename_columns([c if c != "count_sum" else "count" for c in t.column_names])
    return t.sort_by([(k, "ascending") for k in SORT_KEYS[key]])


def _conform(t: pa.Table, schema: pa.Schema) -> pa.Table:
    """``t`` in ``schema``'s column order, a column it lacks as nulls (as concatenating with promotion gives)."""
    cols = [(t.column(f.name) if t.column(f.name).type == f.type else t.column(f.name).cast(f.type))
            if f.name in t.column_names else pa.nulls(t.num_rows, f.type) for f in schema]
    return pa.Table.from_arrays(cols, schema=schema)


class _AtomicWriter:
    """A Parquet file written in pieces (one schema) beside its name, renamed into place when all went well."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.tmp = _beside(path)
        self.writer: pq.ParquetWriter | None = None

    def __enter__(self) -> "_AtomicWriter":
        return self

    def write(self, t: pa.Table) -> None:
        if self.writer is None:  # the first piece's schema is the file's
            self.writer = pq.ParquetWriter(self.tmp, t.schema)
        self.writer.write_table(t)

    def __exit__(self, exc_type, exc, tb) -> None:
        if self.writer is not None:
            self.writer.close()
        if exc_type is not None or self.writer is None:
            self.tmp.unlink(missing_ok=True)
            return
        _fsync(self.tmp)
        os.replace(self.tmp, self.path)


def read_columns(path: Path, names: list[str] | None = None) -> dict[str, np.ndarray]:
    """Columns of a Parquet table as numpy arrays, read one at a time (memory: the arrays, not also a table).

    Values as ``pyarrow``'s ``to_numpy`` gives them (nulls as NaN in numeric columns); a string column
    becomes an object array whose equal values share one ``str`` (a column of 10⁷ monitor names is
    80 MB of references, not 10⁷ strings). Names absent from the table are skipped.
    """
    pf = pq.ParquetFile(path)
    have = pf.schema_arrow.names
    out = {}
    for n in (have if names is None else [n for n in names if n in have]):
        col = pf.read(columns=[n]).column(0).combine_chunks()
        if pa.types.is_string(col.type) and col.null_count == 0:
            enc = col.dictionary_encode()
            out[n] = np.asarray(enc.dictionary.to_pylist(), dtype=object)[enc.indices.to_numpy(zero_copy_only=False)]
        else:
            out[n] = col.to_numpy(zero_copy_only=False)
    return out


def _beside(path: Path) -> Path:
    """A temporary name beside ``path`` (same folder: the rename into place is atomic)."""
    return path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:8]}")


def _atomic_table(path: Path, t: pa.Table) -> None:
    with _AtomicWriter(path) as w:
        w.write(t)


def _atomic_bytes(path: Path, data: bytes) -> None:
    tmp = _beside(path)
    tmp.write_bytes(data)
    _fsync(tmp)
    os.replace(tmp, path)


def _utc_now() -> str:
    import datetime as dt

    return dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(path: Path) -> None:
    try:
        _fsync(path)
    except OSError:  # pragma: no cover - some filesystems refuse directory fsync
        pass

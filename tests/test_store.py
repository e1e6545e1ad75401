"""The result store's consolidation and column reader against brute force: one global concatenate-and-sort
(what ``finalize`` did before it went cell by cell) and pyarrow's own conversion."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from testbed.campaign.store import SORT_KEYS, ResultStore, read_columns

from test_campaign import same


def _part(rng, cell: int, chunk: int, schema_variant: str) -> dict[str, pa.Table]:
    """A chunk's tables with its rows shuffled (as the runner writes them: monitor-major, not sorted)."""
    trials = np.arange(chunk * 5, chunk * 5 + 5)
    rows = [(int(t), m) for m in ("va_raim", "gps_raim") for t in trials]
    rng.shuffle(rows)
    cols = {"cell": pa.array([cell] * len(rows), pa.int32()), "trial": pa.array([t for t, _ in rows], pa.int64()),
            "monitor": pa.array([m for _, m in rows]), "max_hpl": pa.array(rng.normal(size=len(rows)))}
    if schema_variant == "extra":  # a column the other cells' parts lack
        cols["extra"] = pa.array(rng.normal(size=len(rows)))
    if schema_variant == "null":  # all-null here, int64 elsewhere
        cols["vre_n"] = pa.nulls(len(rows))
    else:
        cols["vre_n"] = pa.array(np.where([m == "va_raim" for _, m in rows], rng.integers(0, 9, len(rows)), 0))
    epochs = pa.table({"cell": pa.array([cell] * 6, pa.int32()), "trial": pa.array([chunk * 5] * 6, pa.int64()),
                       "monitor": pa.array(["va_raim"] * 3 + ["gps_raim"] * 3), "t": pa.array([2.0, 0.0, 1.0] * 2),
                       "hpl": pa.array(rng.normal(size=6))})
    keys = rng.integers(0, 3, size=(8, 2))  # the same bins in both chunks: counts add up
    hist = pa.table({"cell": pa.array([cell] * 8, pa.int32()), "monitor": pa.array(["gps_raim", "va_raim"] * 4),
                     "dim": pa.array(["H", "V"] * 4), "err_bin": pa.array(keys[:, 0]), "pl_bin": pa.array(keys[:, 1]),
                     "count": pa.array(rng.integers(1, 5, 8))})
    return {"trials": pa.table(cols), "epochs": epochs, "hist": hist}


def _global_sort(key: str, tables: list[pa.Table]) -> pa.Table:
    t = pa.concat_tables(tables, promote_options="default")
    if key == "hist":
        t = t.group_by(list(SORT_KEYS["hist"])).aggregate([("count", "sum")])
        t = t.rename_columns([c if c != "count_sum" else "count" for c in t.column_names])
    return t.sort_by([(k, "ascending") for k in SORT_KEYS[key]])


def test_finalize_cell_by_cell_equals_one_global_sort(tmp_path):
    rng = np.random.default_rng(3)
    store = ResultStore(tmp_path)
    variants = {0: "plain", 1: "extra", 2: "null", 11: "plain", 123456: "plain"}  # by number, not by name
    written = {k: [] for k in SORT_KEYS}
    for cell, v in variants.items():
        for chunk in (1, 0):
            tables = _part(rng, cell, chunk, v)
            store.parts.mkdir(parents=True, exist_ok=True)
            store.write_chunk(cell, chunk, tables)
            for k in SORT_KEYS:
                written[k].append((store.chunk_name(cell, chunk), tables[k]))
    store.finalize()
    for key, name in (("trials", "trials.parquet"), ("epochs", "epochs.parquet"), ("hist", "stanford_hist.parquet")):
        reference = _global_sort(key, [t for _, t in sorted(written[key], key=lambda x: x[0])])
        got = pq.read_table(tmp_path / name)
        assert same(reference, got), key
        assert pq.ParquetFile(tmp_path / name).num_row_groups == len(variants)  # written one cell at a time
    assert got.column("count").to_pylist() and sum(got.column("count").to_pylist()) == sum(
        sum(t.column("count").to_pylist()) for _, t in written["hist"])


def test_read_columns_gives_pyarrows_values_and_shares_equal_strings(tmp_path):
    t = pa.table({"f": pa.array([1.5, None, 3.0]), "i": pa.array([1, None, 3]), "b": pa.array([True, False, True]),
                  "s": pa.array(["va_raim", "gps_raim", "va_raim"]), "n": pa.array([4, 5, 6], pa.int32())})
    path = tmp_path / "t.parquet"
    pq.write_table(t, path, row_group_size=2)  # two row groups: chunked columns
    cols = read_columns(path)
    assert list(cols) == t.column_names
    for n in t.column_names:
        want = t.column(n).to_numpy(zero_copy_only=False)
        assert cols[n].dtype == want.dtype, n
        if want.dtype.kind == "f":
            assert np.array_equal(cols[n], want, equal_nan=True)
        else:
            assert list(cols[n]) == list(want)
    assert cols["s"][0] is cols["s"][2]  # one str per distinct value
    assert (cols["s"] == "va_raim").tolist() == [True, False, True]
    assert list(read_columns(path, ["n", "absent", "f"])) == ["n", "f"]


def test_runs_are_recorded_and_added_up(tmp_path):
    store = ResultStore(tmp_path)
    assert store.runs() == [] and store.wall_s() == 0.0
    i = store.start_run()
    store.update_run(i, 2.5, 3, 300)
    j = store.start_run()
    store.update_run(j, 1.25, 1, 100, finished=True)
    runs = store.runs()
    assert [r["finished"] for r in runs] == [False, True] and [r["chunks_run"] for r in runs] == [3, 1]
    assert store.wall_s() == pytest.approx(3.75)
    store.discard()
    assert store.runs() == []


def test_a_damaged_runs_file_is_kept_aside_not_written_over(tmp_path):
    store = ResultStore(tmp_path)
    (tmp_path / "runs.json").write_text("{not json")
    with pytest.warns(UserWarning, match="runs.json"):
        i = store.start_run()
    assert i == 0 and len(store.runs()) == 1
    kept = list(tmp_path.glob("runs.json.damaged-*"))
    assert len(kept) == 1 and kept[0].read_text() == "{not json"

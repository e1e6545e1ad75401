"""Shared draws across a sweep's cells (testbed.memo): the same tables bit for bit, and the memo's rules."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from testbed import memo
from testbed.campaign.runner import run_campaign

from test_campaign import same, table

# common random numbers over a GPS-step sweep x two cameras: each camera's frames are drawn once for both
# magnitudes, each magnitude's pseudoranges (and VA-RAIM's step 1) once for both cameras
SWEEP = """
name = "shared"
approaches = ["va-raim-2015"]
monitors = ["gps_raim", "va_raim"]
trials = 40
block_trials = 10
chunk_trials = 20
base_seed = 11
per_epoch_trials = 4
duration_s = 30.0
common_random_numbers = true

[sorties]
start = "consecutive"
sortie_s = 60.0

[[faults]]
kind = "gps_step"
magnitudes = [0.0, 40.0]
onset_s = 10.0

[sweep]
camera_focal_px = [992.0, 1e4]
"""


@pytest.fixture(autouse=True)
def _fresh_memo():
    memo.clear()
    yield
    memo.clear()


def test_a_sweep_gives_the_same_tables_with_and_without_shared_draws(tmp_path):
    spec = tmp_path / "shared.toml"
    spec.write_text(SWEEP)
    run_campaign(spec, tmp_path / "on", progress=False)
    shared = memo.counts()
    # per block, cells in order (0 m, f1) (0 m, f2) (40 m, f1) (40 m, f2): the pseudoranges and step 1 are new
    # for each magnitude and reused by its second camera (2 + 2 hits), the frames new for each camera and
    # reused at 40 m (2 hits), the dithering drawn with the first frames and reused by the second camera's
    # (1 hit; the block's landmark survey is drawn with the frames), VA-RAIM's vision step new in every cell
    # (4 misses; it reads both records), the fault-free GNSS errors drawn for 0 m and reused at 40 m (1 miss,
    # 1 hit), GPS RAIM's own table columns (its output is step 1's) new for each magnitude and reused by its
    # second camera (2 misses, 2 hits): 10 hits and 14 misses a block, 4 blocks a cell
    assert shared["hits"] == 4 * 10 and shared["misses"] == 4 * 14
    _same_tables_without_sharing(spec, tmp_path)


def test_a_camera_sweep_tabulates_gps_raim_once_per_magnitude_and_holds_no_unshared_output(tmp_path, monkeypatch):
    """GPS RAIM's output is VA-RAIM's shared step 1, so its table columns are made once per magnitude and
    block; VA-RAIM's own output differs per cell and is tabulated every time without being held."""
    from collections import Counter

    from testbed.campaign import tables

    made, tabulate = Counter(), tables._trial_columns

    def counted(ctx, d, out, he, ve):
        made[out.name] += 1
        return tabulate(ctx, d, out, he, ve)

    monkeypatch.setattr(tables, "_trial_columns", counted)
    spec = tmp_path / "shared.toml"
    spec.write_text(SWEEP)
    run_campaign(spec, tmp_path / "on", progress=False)
    assert made == {"gps_raim": 4 * 2, "va_raim": 4 * 4}  # 4 blocks: 2 magnitudes, 4 cells
    assert {k[1] for k in memo._store if k[0] == "monitor_tables"} == {"gps_raim"}


def test_va_raim_settings_after_the_vision_step_share_it(tmp_path):
    """Cells differing in the VA-RAIM variant or the calibration share the vision step (the cosine-rule solve)."""
    spec = tmp_path / "variants.toml"
    spec.write_text(SWEEP.replace('magnitudes = [0.0, 40.0]', 'magnitudes = [0.0]').replace(
        "camera_focal_px = [992.0, 1e4]", 'va_raim_variant = ["seed", "gated"]\ncalibration = ["gps", "none"]'))
    run_campaign(spec, tmp_path / "on", progress=False)
    # per block, 4 cells on one pseudorange draw and one camera draw; misses: the GNSS errors, pseudoranges,
    # frames (with the block's survey), dithering, step 1, the vision step, GPS RAIM's table columns; the other
    # 3 cells reuse the pseudoranges, frames, step 1, vision step and GPS RAIM's table columns
    shared = memo.counts()
    assert shared["misses"] == 4 * 7 and shared["hits"] == 4 * 3 * 5
    _same_tables_without_sharing(spec, tmp_path)


def test_a_gps_fault_sweep_shares_the_fault_free_errors_and_draws_each_faults_target_alike(tmp_path):
    """Three GPS-step magnitudes, two of them faulted: the noise and clock are drawn once a block, and each
    faulted cell draws its random satellite from the same fresh fault stream (a reused, already spawned-from
    stream gave the third magnitude other satellites)."""
    spec = tmp_path / "steps.toml"
    spec.write_text(SWEEP.replace('["gps_raim", "va_raim"]', '["gps_raim"]')
                    .replace("magnitudes = [0.0, 40.0]", "magnitudes = [0.0, 20.0, 40.0]")
                    .replace("camera_focal_px = [992.0, 1e4]", "camera_dpi = [720.0]"))
    run_campaign(spec, tmp_path / "on", progress=False)
    # per block: the errors once (1 miss, 2 hits), each magnitude's observations (3 misses)
    assert memo.counts()["misses"] == 4 * 4 and memo.counts()["hits"] == 4 * 2
    _same_tables_without_sharing(spec, tmp_path)
    t = table(tmp_path / "on").to_pandas()
    by_cell = t.pivot(index="trial", columns="cell", values="fault_target")
    assert (by_cell[0] == -1).all() and (by_cell[1] == by_cell[2]).all() and (by_cell[1] >= 0).all()


def _same_tables_without_sharing(spec: Path, tmp_path: Path) -> None:
    memo.clear()
    with memo.limit(0):
        run_campaign(spec, tmp_path / "off", progress=False)
    assert memo.counts()["hits"] == 0
    for name in ("trials.parquet", "epochs.parquet", "stanford_hist.parquet"):
        assert same(table(tmp_path / "on", name), table(tmp_path / "off", name)), name


def test_without_common_random_numbers_nothing_is_shared(tmp_path):
    spec = tmp_path / "own.toml"
    spec.write_text(SWEEP.replace("common_random_numbers = true", "common_random_numbers = false"))
    run_campaign(spec, tmp_path / "out", progress=False)
    assert memo.counts() == {"hits": 0, "misses": 0, "entries": 0, "bytes": 0}


def test_off_by_default_and_in_other_threads_the_memo_computes_every_time():
    import threading

    calls = []
    for _ in range(2):
        memo.shared(("k",), lambda: calls.append(1) or np.zeros(3))
    assert len(calls) == 2 and memo.counts()["entries"] == 0
    with memo.sharing():  # on in this thread only: a flight in another thread of the process keeps its own arrays
        t = threading.Thread(target=lambda: memo.shared(("k",), lambda: calls.append(2) or np.zeros(3)))
        t.start()
        t.join()
        assert calls[-1] == 2 and memo.counts()["entries"] == 0


def test_a_shared_value_is_frozen_and_served_again():
    with memo.sharing():
        a = memo.shared(("k", 1), lambda: (np.arange(4.0), {"b": np.ones(2)}))
        b = memo.shared(("k", 1), lambda: pytest.fail("recomputed"))
    assert b is a
    with pytest.raises(ValueError, match="read-only"):
        a[0][0] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        a[1]["b"][0] = 1.0


def test_is_shared_names_the_stores_arrays_not_any_read_only_one():
    import gc

    with memo.sharing():
        a = memo.shared(("k", 2), lambda: (np.arange(4.0), {"b": np.ones(2)}))
    assert memo.is_shared(a[0]) and memo.is_shared(a[1]["b"])
    view = np.broadcast_to(np.ones(3), (2, 3))  # read-only, not the store's
    assert not view.flags.writeable and not memo.is_shared(view) and not memo.is_shared(np.ones(2))
    key = id(a[0])
    ref = memo._held[key]
    memo.clear()
    del a
    gc.collect()
    assert ref() is None and memo._held.get(key) is not ref  # the entry left with its array


def test_a_guarded_entry_serves_only_the_very_object_it_was_made_for():
    x, y = np.zeros(2), np.zeros(2)
    with memo.sharing():
        memo.shared(("id", 1), lambda: np.ones(1), guard=x)
        assert memo.shared(("id", 1), lambda: np.full(1, 2.0), guard=y)[0] == 2.0  # same key, another object
        assert memo.shared(("id", 1), lambda: np.full(1, 3.0), guard=y)[0] == 2.0  # now y's
        assert memo.counts()["entries"] == 1
        z = np.zeros(2)
        memo.shared(("ids", 1), lambda: np.ones(1), guard=(x, y))
        assert memo.shared(("ids", 1), lambda: np.full(1, 2.0), guard=(x, y))[0] == 1.0  # the same two objects
        assert memo.shared(("ids", 1), lambda: np.full(1, 3.0), guard=(x, z))[0] == 3.0  # one of them another
        assert memo.shared(("ids", 1), lambda: np.full(1, 4.0), guard=(x,))[0] == 4.0


def test_the_store_is_bounded_in_bytes_least_recently_used_first():
    with memo.sharing(), memo.limit(3 * 800):
        for k in range(5):
            memo.shared(("lru", k), lambda: np.zeros(100))  # 800 bytes each
        memo.shared(("lru", 2), lambda: pytest.fail("2 was evicted"))  # touch 2: 3 becomes the oldest
        memo.shared(("lru", 5), lambda: np.zeros(100))
        assert memo.counts()["entries"] == 3 and memo.counts()["bytes"] == 2400
        again = []
        memo.shared(("lru", 3), lambda: again.append(1) or np.zeros(100))
        assert again == [1]
        memo.shared(("big",), lambda: np.zeros(1000))  # larger than the budget: computed, not kept
        assert memo.counts()["bytes"] <= 2400


def test_seed_keys_name_a_fresh_stream_and_refuse_unseeded_generators():
    a = np.random.default_rng(np.random.SeedSequence(5, spawn_key=(1, 2)))
    b = np.random.default_rng(np.random.SeedSequence(5, spawn_key=(1, 3)))
    assert memo.seed_key(a) != memo.seed_key(b)
    assert memo.seed_key(a) == memo.seed_key(np.random.SeedSequence(5, spawn_key=(1, 2)))
    with pytest.raises(TypeError, match="SeedSequence"):
        memo.seed_key(5)


def test_digests_see_dtype_shape_and_content():
    a = np.arange(6.0)
    assert memo.digest(a) == memo.digest(a.copy())
    assert memo.digest(a) != memo.digest(a.reshape(2, 3))
    assert memo.digest(a) != memo.digest(a.astype(np.float32))
    assert memo.digest(a[::2]) == memo.digest(np.array([0.0, 2.0, 4.0]))


@pytest.mark.parametrize("module, name, shares", [
    ("test_dpe_loop", "SPEC", True),  # no camera; each magnitude its own pseudoranges on the shared errors
    ("test_ekf_loop", "EKF_SPEC", True),  # the step's cells share the camera frames
])
def test_the_filter_and_the_dpe_give_the_same_tables_with_shared_draws(module, name, shares, tmp_path):
    import importlib

    text = getattr(importlib.import_module(module), name).format(chunk=6)
    spec = tmp_path / "crn.toml"
    spec.write_text(text.replace("per_epoch_trials", "common_random_numbers = true\nper_epoch_trials"))
    run_campaign(spec, tmp_path / "on", progress=False)
    assert (memo.counts()["hits"] > 0) == shares and memo.counts()["misses"] > 0
    memo.clear()
    with memo.limit(0):
        run_campaign(spec, tmp_path / "off", progress=False)
    for t in ("trials.parquet", "epochs.parquet", "stanford_hist.parquet"):
        assert same(table(tmp_path / "on", t), table(tmp_path / "off", t)), t

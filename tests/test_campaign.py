"""Campaigns: spec validation, determinism across chunkings/workers, kill-and-resume, Dask, figures."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from testbed.campaign.report import binomial_interval, minimal_detectable_bias, write_report
from record_checks import markdown_table_problems
from testbed.campaign.runner import run_campaign
from testbed.campaign.spec import expand_cells, load_spec
from testbed.campaign.store import ResultStore, tables_equal
from testbed.schema import ConfigError
from testbed.sim.evaluate import REGIONS

ROOT = Path(__file__).resolve().parents[1]

TINY = """
name = "tiny"
approaches = ["va-raim-2015"]
monitors = {monitors}
trials = 40
block_trials = 10
chunk_trials = {chunk}
base_seed = 7
per_epoch_trials = 4
duration_s = 40.0

[[faults]]
kind = "gps_step"
magnitudes = [0.0, 60.0]
onset_s = 15.0

[sweep]
camera_dpi = [720.0]
"""


def write_spec(tmp_path: Path, name: str = "tiny.toml", chunk: int = 20,
               monitors: str = '["gps_raim", "va_raim"]', text: str | None = None) -> Path:
    p = tmp_path / name
    p.write_text(text if text is not None else TINY.format(chunk=chunk, monitors=monitors))
    return p


def table(out: Path, name: str = "trials.parquet"):
    return pq.read_table(out / name)


def same(a, b) -> bool:
    """Tables equal bit for bit (NaN == NaN, same schema and row order)."""
    return tables_equal(a, b)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted run of the tiny spec (chunks of 20 trials)."""
    d = tmp_path_factory.mktemp("ref")
    spec = write_spec(d)
    res = run_campaign(spec, d / "out", progress=False)
    assert res.chunks_run == 4 and res.trials == 80
    return d / "out"


# ----------------------------------------------------------------------------- spec validation

@pytest.mark.parametrize("text, where, expected", [
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["gps_raim"]\ntrials = 10\ntrails = 3\n',
     "trails", "unknown key"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["raim"]\ntrials = 10\n',
     "monitors.0", "gps_raim"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["gps_raim"]\ntrials = 10\n'
     'block_trials = 4\nchunk_trials = 10\n', "<top level>", "multiple of block_trials"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["gps_raim"]\ntrials = 10\n'
     '[[faults]]\nkind = "gps_step"\nmagnitudes = ["big"]\n', "faults.0.magnitudes.0", "valid number"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["gps_raim"]\ntrials = 10\n'
     '[sweep]\nstart_time_utc = [2026-03-01T04:00:00]\n', "sweep.start_time_utc", "UTC"),
    ('name = "x"\napproaches = ["no-such-approach"]\nmonitors = ["gps_raim"]\ntrials = 10\n',
     "approaches.0", "no such approach"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["va_raim"]\ntrials = 10\n'
     '[sweep]\ncamera_focal_px = [992.0, 0.0]\n', "sweep.camera_focal_px", "focal lengths > 0 px"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["va_raim"]\ntrials = 10\n'
     '[sweep]\ncamera_focal_px = [992.0]\ncamera_dpi = [720.0]\n', "sweep", "at most one camera axis"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["va_raim"]\ntrials = 10\n'
     '[sweep]\nlandmark_sets = [[{kind = "triangle", radius_m = -100.0}]]\n', "sweep.landmark_sets.0.0", "radius_m"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["gps_raim"]\ntrials = 10\n'
     '[[faults]]\nkind = "constellation_bias"\nmagnitudes = [10.0]\n', "faults.0", "expected system = 'gps'"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["gps_raim"]\ntrials = 10\n'
     '[[faults]]\nkind = "gps_step"\nsystem = "gps"\nmagnitudes = [10.0]\n', "faults.0",
     "read by kinds 'constellation_bias', 'constellation_orbit' only"),
    ('name = "x"\napproaches = ["va-raim-2015"]\nmonitors = ["gps_raim"]\ntrials = 10\n'
     '[[faults]]\nkind = "constellation_bias"\nsystem = "galileo"\nmagnitudes = [10.0]\n', "cell 0",
     "not tracked"),
])
def test_spec_errors_name_file_key_and_expectation(tmp_path, text, where, expected):
    p = write_spec(tmp_path, "bad.toml", text=text)
    with pytest.raises(ConfigError) as ei:
        load_spec(p)
    msg = str(ei.value)
    assert str(p) in msg and where in msg and expected in msg, msg


def test_bad_cell_combination_is_reported_before_any_work(tmp_path):
    # the zunz approach's 1080p camera preset takes no dpi: caught at load time, per cell
    text = ('name = "x"\napproaches = ["zunz-rwy05-final"]\nmonitors = ["va_raim"]\ntrials = 10\n'
            '[sweep]\ncamera_dpi = [300.0]\n')
    p = write_spec(tmp_path, "bad.toml", text=text)
    with pytest.raises(ConfigError) as ei:
        run_campaign(p, tmp_path / "out", progress=False)
    assert "cell 0" in str(ei.value) and "dpi" in str(ei.value)
    assert not (tmp_path / "out").exists()


def test_a_constellation_bias_family_sweeps_the_bias_on_its_system(tmp_path):
    """``constellation_bias`` is a sweepable family: each magnitude is the bias (m) on every satellite of the
    family's system, the cells say so, and a spec without the family hashes as before it existed."""
    from testbed.sensors.faults import ConstellationBias

    text = ('name = "x"\napproaches = ["zunz-rwy05-dfmc"]\nmonitors = ["gps_raim", "araim"]\ntrials = 10\n'
            '[[faults]]\nkind = "constellation_bias"\nsystem = "beidou"\nmagnitudes = [0.0, 7.5]\n'
            'onset_s = 12.0\nend_s = 30.0\n')
    cells = expand_cells(load_spec(write_spec(tmp_path, text=text)))
    assert [c.params["fault_kind"] for c in cells] == ["none", "constellation_bias"]
    assert cells[1].params["fault_unit"] == "m" and cells[1].params["fault_size"] == 7.5
    (fault,) = cells[1].config.faults
    assert isinstance(fault, ConstellationBias)
    assert (fault.system, fault.bias_m, fault.rate_m_s, fault.onset_s, fault.end_s) == ("beidou", 7.5, 0.0, 12.0, 30.0)
    assert cells[0].config.faults == []
    # stored campaigns resume: the new key, unset, leaves the hash of a spec as it was (value before the key)
    assert load_spec(ROOT / "approaches" / "campaigns" / "gps-step-sweep.toml").hash == "5270645a44aa341a"


def test_a_monitors_own_column_that_one_block_lacks_is_nan_on_its_rows():
    """ARAIM's clock column of a system is written only where a block used that system: the blocks' columns
    join, NaN where a block had none, in the order they first appear."""
    from testbed.campaign.tables import _cat_cols

    t = _cat_cols([{"monitor": "araim", "x": np.array([1.0, 2.0])},
                   {"monitor": "araim", "x": np.array([5.0]), "clock_gal_m": np.array([3.0])}])
    assert t.column_names == ["monitor", "x", "clock_gal_m"]
    assert t.column("monitor").to_pylist() == ["araim"] * 3 and t.column("x").to_pylist() == [1.0, 2.0, 5.0]
    np.testing.assert_array_equal(t.column("clock_gal_m").to_numpy(), [np.nan, np.nan, 3.0])


def test_cells_are_the_product_of_the_axes(tmp_path):
    text = TINY.format(chunk=20, monitors='["gps_raim", "va_raim"]').replace(
        "camera_dpi = [720.0]", "camera_dpi = [120.0, 720.0]\ndetection_sigma_px = [1.0, 2.0, 4.0]")
    cells = expand_cells(load_spec(write_spec(tmp_path, text=text)))
    assert len(cells) == 2 * 2 * 3
    assert {(c.params["dpi"], c.params["sigma_px"]) for c in cells} == {(d, s) for d in (120, 720) for s in (1, 2, 4)}
    assert all(c.config.vision.rate_hz == c.config.gnss.rate_hz for c in cells)
    assert [c.params["fault_size"] for c in cells[:6]] == [0.0] * 6


# ----------------------------------------------------------------------------- determinism

def test_results_do_not_depend_on_chunk_size(reference, tmp_path):
    spec = write_spec(tmp_path, chunk=10)
    run_campaign(spec, tmp_path / "out", progress=False)
    a, b = table(reference), table(tmp_path / "out")
    assert a.num_rows == 2 * 40 * 2
    assert same(a, b)
    assert same(table(reference, "stanford_hist.parquet"), table(tmp_path / "out", "stanford_hist.parquet"))
    assert same(table(reference, "epochs.parquet"), table(tmp_path / "out", "epochs.parquet"))


def test_dask_local_cluster_gives_the_same_tables(reference, tmp_path):
    from distributed import Client, LocalCluster

    spec = write_spec(tmp_path, chunk=10)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        res = run_campaign(spec, tmp_path / "out", scheduler=client, progress=False)
    assert res.chunks_run == 8
    assert same(table(reference), table(tmp_path / "out"))


@pytest.mark.slow  # 15 s: spawns two worker processes (the Ctrl-C test below spawns them in the default set too)
def test_local_worker_processes_give_the_same_tables(reference, tmp_path):
    spec = write_spec(tmp_path, chunk=10)  # 4 chunk rows of 2 cells
    res = run_campaign(spec, tmp_path / "out", progress=False, workers=2)
    assert res.chunks_run == 8
    assert same(table(reference), table(tmp_path / "out"))
    assert same(table(reference, "stanford_hist.parquet"), table(tmp_path / "out", "stanford_hist.parquet"))
    assert same(table(reference, "epochs.parquet"), table(tmp_path / "out", "epochs.parquet"))
    assert {p.name for p in tmp_path.iterdir()} == {"tiny.toml", "out"}  # the workers wrote nothing beside it


def test_local_workers_auto_only_for_a_run_that_repays_their_start():
    from testbed.campaign.plan import POOL_MIN_CELL_SORTIES, local_workers

    big = POOL_MIN_CELL_SORTIES // 4
    two_rows = [(c, k, big) for c in range(2) for k in range(2)]  # 4 x big cell-sorties over 2 chunk rows
    assert local_workers("auto", two_rows, 2) == 2
    assert local_workers("auto", two_rows, 1) == 1  # one core: this process
    assert local_workers("auto", two_rows[:3], 2) == 1  # below the threshold
    assert local_workers("auto", [(c, 0, big) for c in range(8)], 2) == 1  # one chunk row: its blocks on threads
    gib = 2**30
    assert local_workers("auto", two_rows, 64, memory_bytes=8 * gib) == 2  # no more than the memory holds (3 GiB)
    assert local_workers("auto", two_rows, 2, memory_bytes=2 * gib) == 1
    assert local_workers("auto", two_rows, 2, memory_bytes=24 * gib) == 2
    assert local_workers(3, two_rows, 2) == 3  # as asked, whatever the cores
    assert local_workers(8, [(0, 0, 10)], 2) == 1  # at most one per task
    assert local_workers(2, [], 2) == 1


@pytest.mark.parametrize("workers", [0, -1, 1.5, "two", True])
def test_bad_workers_are_refused_before_any_work(tmp_path, workers):
    with pytest.raises(ConfigError, match="--workers"):
        run_campaign(write_spec(tmp_path), tmp_path / "out", progress=False, workers=workers)
    assert not (tmp_path / "out").exists()


def test_workers_and_a_scheduler_are_refused_together(tmp_path):
    with pytest.raises(ConfigError, match="--scheduler"):
        run_campaign(write_spec(tmp_path), tmp_path / "out", progress=False, workers=2, scheduler="tcp://127.0.0.1:1")
    assert not (tmp_path / "out").exists()


def test_worker_tasks_are_chunk_rows_cut_only_to_keep_every_worker_busy():
    from testbed.campaign.plan import chunk_rows, worker_tasks

    todo = [(c, k, 10) for c in range(5) for k in range(3) if (c, k) != (2, 1)]  # one chunk already stored
    assert worker_tasks(todo, 1) == chunk_rows(todo)  # 3 rows >= 2 tasks per worker: whole rows
    assert worker_tasks([], 4) == []
    tasks = worker_tasks(todo, 4)  # 3 rows < 8 wanted: each row cut into runs of consecutive cells
    assert len(tasks) >= 8
    assert sorted((c, k, n) for k, row in tasks for c, n in row) == sorted(todo)  # every chunk exactly once
    for k, row in tasks:
        cells = [c for c, _ in row]
        row_cells = [c for c, kk, _ in todo if kk == k]
        i = row_cells.index(cells[0])
        assert cells == row_cells[i:i + len(cells)]  # consecutive cells of one row: they share draws


def test_faults_are_detected_and_fault_free_trials_carry_no_fault(reference):
    t = table(reference).to_pylist()
    cells = pq.read_table(reference / "cells.parquet").to_pylist()
    size = {c["cell"]: c["fault_size"] for c in cells}
    free = [r for r in t if size[r["cell"]] == 0]
    faulty = [r for r in t if size[r["cell"]] > 0]
    assert all(r["fault_target"] == -1 for r in free)
    assert all(r["fault_target"] > 0 for r in faulty)  # a PRN
    assert all(r["fault_satellite"] == "" for r in free)
    assert all(r["fault_satellite"] == f"G{r['fault_target']:02d}" for r in faulty)  # its RINEX name
    # a 60 m step on one of 7 satellites: GPS RAIM sees most of them
    det = np.mean([r["detected"] for r in faulty if r["monitor"] == "gps_raim"])
    assert det > 0.5
    assert all(np.isnan(r["time_to_alert_s"]) or r["time_to_alert_s"] >= 0 for r in faulty)


# ----------------------------------------------------------------------------- resume

def test_a_damaged_consolidated_table_is_kept_aside_and_consolidated_again(reference, tmp_path, capsys):
    import shutil

    from testbed.campaign.store import ResultStore
    from testbed.cli import main

    out = tmp_path / "out"
    shutil.copytree(reference, out)
    spec = write_spec(tmp_path)
    trials = out / "trials.parquet"
    damaged = trials.read_bytes()[:-200]  # the footer cut off, as a full disk or a killed copy leaves it
    trials.write_bytes(damaged)
    assert not ResultStore(out).complete()
    assert main(["report", str(out)]) == 2  # a clear error, not a traceback
    said = capsys.readouterr()
    assert "trials.parquet" in said.out + said.err and "--resume" in said.out + said.err
    with pytest.warns(UserWarning, match="consolidated again"):
        res = run_campaign(spec, out, resume=True, progress=False)
    assert res.chunks_run == 0 and ResultStore(out).complete()
    assert same(table(reference), table(out))  # rebuilt from the stored chunks
    kept = list(out.glob("trials.parquet.damaged-*"))
    assert len(kept) == 1 and kept[0].read_bytes() == damaged  # not written over



@pytest.mark.slow  # 8.5 s: a worker process killed mid-run and the campaign resumed
def test_kill_and_resume_equals_an_uninterrupted_run(reference, tmp_path):
    spec = write_spec(tmp_path)
    out = tmp_path / "out"
    env = dict(os.environ, TESTBED_CAMPAIGN_THROTTLE_S="0.6", PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "testbed.campaign", "campaign", str(spec), "--out", str(out),
                             "--quiet", "--no-report"], cwd=tmp_path, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    parts = out / "parts"
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < 60:
            done = [p for p in parts.glob("c*-k*") if ".tmp-" not in p.name] if parts.exists() else []
            if done:
                break
            assert proc.poll() is None, proc.stderr.read().decode()
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    stored = [p for p in parts.glob("c*-k*") if ".tmp-" not in p.name]
    assert 1 <= len(stored) < 4, "the run was not interrupted mid-way"
    assert not (out / "trials.parquet").exists()
    # without --resume the folder is refused, with it the run completes
    with pytest.raises(ConfigError, match="--resume"):
        run_campaign(spec, out, progress=False)
    killed = ResultStore(out).runs()
    assert len(killed) == 1 and not killed[0]["finished"]  # the killed run is on record
    res = run_campaign(spec, out, resume=True, progress=False)
    assert res.chunks_skipped == len(stored) and res.chunks_run == 4 - len(stored)
    runs = ResultStore(out).runs()
    assert len(runs) == 2 and runs[1]["finished"] and runs[1]["chunks_run"] == 4 - len(stored)
    assert runs[1]["wall_s"] == pytest.approx(res.wall_s, abs=1e-3)
    assert ResultStore(out).wall_s() == pytest.approx(runs[0]["wall_s"] + runs[1]["wall_s"])
    a, b = table(reference), table(out)
    assert same(a, b)
    assert len({(r["cell"], r["trial"], r["monitor"]) for r in b.to_pylist()}) == b.num_rows  # no duplicates
    assert same(table(reference, "stanford_hist.parquet"), table(out, "stanford_hist.parquet"))


@pytest.mark.slow  # 18 s a variant: two throttled worker processes interrupted
@pytest.mark.parametrize("to", ["group", "driver"])
def test_ctrl_c_on_worker_processes_stops_them_keeps_the_stored_chunks_and_resumes(reference, tmp_path, to):
    """SIGINT as a terminal's Ctrl-C sends it (to the whole foreground group: driver and workers) and as
    ``kill -INT`` does (to the driver alone, whose workers must still stop at once)."""
    spec = write_spec(tmp_path)
    out = tmp_path / "out"
    # each task 5 s: one in flight; a driver that does not stop is made to print its threads' stacks (SIGABRT)
    env = dict(os.environ, TESTBED_CAMPAIGN_THROTTLE_S="5.0", PYTHONPATH=str(ROOT), PYTHONFAULTHANDLER="1")
    # SIGINT restored to its default in case this suite runs where it is ignored (a background job)
    proc = subprocess.Popen([sys.executable, "-m", "testbed.campaign", "campaign", str(spec), "--out", str(out),
                             "--quiet", "--no-report", "--workers", "2"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    parts = out / "parts"
    try:
        t0 = time.monotonic()  # a loaded machine may take minutes to spawn the workers and store a chunk
        while not (parts.exists() and [p for p in parts.glob("c*-k*") if ".tmp-" not in p.name]):
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() - t0 < 600, "no chunk stored in 10 min"
            time.sleep(0.02)
        (os.killpg if to == "group" else os.kill)(proc.pid, signal.SIGINT)
        t_int = time.monotonic()
        try:
            said, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGABRT)
            said, err = proc.communicate(timeout=30)
            pytest.fail(f"not stopped 30 s after SIGINT; its processes: {_live_in_group(proc.pid)}; "
                        f"its stderr, with the stacks at SIGABRT:\n{err.decode()}")
        stopped_s = time.monotonic() - t_int
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, (said, err)
    told = err.decode()  # what is kept and how to go on (testbed.outputs' note), on stderr
    assert told.startswith("interrupted: ") and f"--out {out}: the chunks finished so far are stored" in told, told
    assert "the same command with --resume completes the run" in told, told
    assert b"Traceback" not in err, err.decode()
    assert stopped_s < 3.0  # at once, not after the 5 s rows in flight (0.2-0.3 s measured)
    t0 = time.monotonic()  # a terminated worker takes a few ms to leave; a running one would stay seconds
    while _live_in_group(proc.pid) and time.monotonic() - t0 < 1.0:
        time.sleep(0.01)
    assert _live_in_group(proc.pid) == []
    stored = [p for p in parts.glob("c*-k*") if ".tmp-" not in p.name]
    assert 1 <= len(stored) < 4, "the run was not interrupted mid-way"
    res = run_campaign(spec, out, resume=True, progress=False)
    assert res.chunks_skipped == len(stored) and res.chunks_run == 4 - len(stored)
    assert same(table(reference), table(out))


def _live_in_group(pgid: int) -> list[str]:
    """Processes of group ``pgid`` that are not zombies (Linux /proc): ``pid state command`` each."""
    live = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:  # gone meanwhile
            continue
        name_end = text.rindex(")")
        state, _, group = text[name_end + 2:].split()[:3]
        if int(group) == pgid and state != "Z":
            live.append(f"{stat.parent.name} {state} {text[:name_end + 1]}")
    return live


def test_resume_with_another_spec_is_refused(reference, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(reference, out)
    spec = write_spec(tmp_path, text=TINY.format(chunk=20, monitors='["gps_raim"]'))
    with pytest.raises(ConfigError, match="another spec"):
        run_campaign(spec, out, resume=True, progress=False)


# ----------------------------------------------------------------------------- report

def test_report_figures_and_region_counts(reference):
    idx = write_report(reference)
    figs = {p.name for p in (reference / "figures").glob("*.png")}
    assert {"pl_time.png", "stanford_gps_raim.png", "stanford_va_raim.png",
            "vision_range_error.png", "detection_0_gps_step.png"} <= figs
    text = idx.read_text()
    for f in figs:
        assert f"figures/{f}" in text
    # availability and PL statistics: one compact table, a row per setting and monitor
    assert "| setting | monitor | sorties | max HPL: median / p95 / max (m)" in text
    assert text.count("| dpi 720") + text.count("| all cells") >= 2
    t = table(reference).to_pydict()
    # the vision-range table: each mean with its standard error over the landmark surveys (4 blocks of 10)
    from testbed.campaign.report import clustered_mean_se

    va = (np.asarray(t["monitor"]) == "va_raim") & (np.asarray(t["cell"]) == 0)
    se, surveys = clustered_mean_se(np.asarray(t["trial"])[va] // 10, np.asarray(t["vre_raw_n"], float)[va],
                                    np.asarray(t["vre_raw_sum"], float)[va])
    mean = np.asarray(t["vre_raw_sum"], float)[va].sum() / np.asarray(t["vre_raw_n"], float)[va].sum()
    row = next(r for r in text.splitlines() if r.startswith("| 0 | 720 |"))
    assert f"{mean:.3f} ± {se:.3f}" in row and row.rstrip(" |").endswith(str(surveys)) and surveys == 4
    epochs = np.asarray(t["epochs"])
    for dim in "hv":
        total = sum(np.asarray(t[f"{dim}_{r}"]) for r in REGIONS)
        assert np.array_equal(total, epochs)  # every epoch in exactly one region
    h = table(reference, "stanford_hist.parquet").to_pydict()
    for m in ("gps_raim", "va_raim"):
        for dim in "HV":
            n_hist = sum(c for c, mm, d in zip(h["count"], h["monitor"], h["dim"]) if mm == m and d == dim)
            sel = np.asarray(t["monitor"]) == m
            rest = sum(np.asarray(t[f"{dim.lower()}_{r}"])[sel].sum() for r in ("no_solution", "alerted"))
            assert n_hist + rest == epochs[sel].sum()


def test_binomial_intervals_and_mdb():
    lo, hi = binomial_interval(np.array([0, 5, 10]), np.array([10, 10, 10]), 0.95)
    # Clopper-Pearson, n = 10: k = 0 -> [0, 0.3085]; k = 5 -> [0.1871, 0.8129]
    assert lo[0] == 0 and hi[0] == pytest.approx(0.30850, abs=1e-4)
    assert lo[1] == pytest.approx(0.18709, abs=1e-4) and hi[1] == pytest.approx(0.81291, abs=1e-4)
    assert hi[2] == 1
    wl, wh = binomial_interval(np.array([5]), np.array([10]), 0.95, "wilson")
    assert wl[0] == pytest.approx(0.2366, abs=1e-3) and wh[0] == pytest.approx(0.7634, abs=1e-3)
    assert minimal_detectable_bias(np.array([0, 10, 20]), np.array([0.0, 0.5, 1.0]), 0.99).value == pytest.approx(19.8)
    assert not minimal_detectable_bias(np.array([0, 10]), np.array([0.0, 0.5]), 0.99).reached


# ----------------------------------------------------------------------------- shipped specs, CLI

@pytest.mark.parametrize("spec", sorted((ROOT / "approaches" / "campaigns").glob("*.toml")), ids=lambda p: p.stem)
def test_shipped_specs_are_valid(spec):
    assert len(expand_cells(load_spec(spec))) >= 2


def test_reproduction_specs_are_valid():
    from testbed.studies.reproduce import loaded_experiments

    exps = loaded_experiments(200)
    assert set(exps) == {"vision-calibration", "vision-calibration-precise", "resolution", "gps-faults",
                         "vision-faults", "where-vision-pays", "baseline-matched", "blur-floor"}
    assert len(expand_cells(exps["resolution"])) == 32  # 4 resolutions x 4 detection errors x 2 VA-RAIM variants
    pays = expand_cells(exps["where-vision-pays"])
    assert len(pays) == 6 * 5 * 3  # GPS steps (0 included) x focal lengths x baselines
    cam = pays[-1].config.vision.camera.build()  # f = 1e5 px at the 720-dpi camera's field of view
    assert cam.fx == 1e5 and abs(cam.width_px / cam.fx - 1020 / 992.1) < 1e-3
    assert all(e.spec.sorties.start == "consecutive" for e in exps.values())


def test_cli_parsers_register_three_subcommands(tmp_path, capsys):
    import argparse

    from testbed.campaign_cli import add_campaign_parsers

    parser = argparse.ArgumentParser()
    add_campaign_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["campaign", "x.toml", "--out", "d", "--resume", "--scheduler", "tcp://h:8786"])
    assert args.resume and args.scheduler == "tcp://h:8786" and callable(args.func)
    assert parser.parse_args(["report", "d"]).func is not None
    assert parser.parse_args(["reproduce", "va-raim-2015", "--full"]).full
    bad = write_spec(tmp_path, "bad.toml", text='name = "x"\n')
    from testbed.campaign_cli import main

    assert main(["campaign", str(bad), "--out", str(tmp_path / "o")]) == 2  # python -m testbed.campaign
    said = capsys.readouterr()
    assert said.err.startswith("error: ") and "approaches" in said.err and said.out == ""
    assert not (tmp_path / "o").exists()


def test_gps_raim_is_one_estimator_alone_or_beside_va_raim(reference, tmp_path):
    """With VA-RAIM in the campaign, GPS RAIM is provided by VA-RAIM's step 1 instead of a second
    solve; that is an optimisation, not another definition: every column of GPS RAIM's trial rows
    equals a GPS-only campaign's, bit for bit."""
    spec = write_spec(tmp_path, monitors='["gps_raim"]')
    run_campaign(spec, tmp_path / "out", progress=False)
    alone = table(tmp_path / "out").to_pandas().set_index(["cell", "trial"]).sort_index()
    both = table(reference).to_pandas()
    both = both[both.monitor == "gps_raim"].set_index(["cell", "trial"]).loc[alone.index]
    cols = [c for c in alone.columns if alone[c].notna().any()]
    assert len(cols) > 20
    for col in cols:
        np.testing.assert_array_equal(alone[col].to_numpy(), both[col].to_numpy(), err_msg=col)


@pytest.mark.slow  # moved out of the default set: its run time (the default set stays within 8 min)
def test_report_leaves_the_callers_matplotlib_state_alone(reference):
    """No pyplot, no backend switch, no rcParams change from drawing a report."""
    import subprocess
    import sys

    code = ("import matplotlib; matplotlib.use('svg'); rc = dict(matplotlib.rcParams); import sys; "
            "from testbed.campaign.report import write_report; write_report(sys.argv[1]); "
            "assert matplotlib.get_backend() == 'svg', matplotlib.get_backend(); "
            "assert 'matplotlib.pyplot' not in sys.modules; "
            "assert dict(matplotlib.rcParams) == rc")
    res = subprocess.run([sys.executable, "-c", code, str(reference)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


def test_pixel_monitor_campaign_runs_and_detects_the_gps_step(tmp_path):
    """The patent's pixel-domain monitor in a campaign: tables written, every epoch placed in one
    Stanford region, and the 60 m GPS step detected far more often than fault-free trials alarm."""
    spec = write_spec(tmp_path, monitors='["pixel"]')
    res = run_campaign(spec, tmp_path / "out", progress=False)
    t = table(tmp_path / "out").to_pandas()
    assert res.trials == 80 and set(t.monitor) == {"pixel"}
    regions = [c for c in t.columns if c.startswith("h_") and c[2:] in REGIONS]
    assert (t[regions].sum(axis=1) == t["epochs"]).all()
    cells = table(tmp_path / "out", "cells.parquet").to_pandas()
    faulted = t.cell.isin(cells.loc[cells.fault_size > 0, "cell"])
    assert t.loc[faulted, "detected"].mean() > 0.9
    assert t.loc[~faulted, "detected"].mean() < 0.3


def test_campaign_caches_are_bounded():
    from testbed.campaign import context

    context.clear_caches()
    for k in range(context._CACHE_MAX + 10):
        context.cached(("probe", k), lambda: k)
        context.cached(("probe", 0), lambda: "made again")  # used on every round: never the oldest
    assert len(context._CACHE) == context._CACHE_MAX
    assert context._CACHE[("probe", 0)] == 0 and ("probe", 1) not in context._CACHE
    context.clear_caches()


def test_the_campaign_cache_makes_each_key_once_under_threads():
    """A Dask worker's threads build contexts side by side: each key made once, eviction never raising."""
    import threading
    import time as _time

    from testbed.campaign import context

    context.clear_caches()
    made: list[int] = []
    errors: list[BaseException] = []

    def slow(k: int) -> int:
        made.append(k)
        _time.sleep(0.001)
        return k

    def hammer(seed: int) -> None:
        rng = np.random.default_rng(seed)
        try:
            for _ in range(300):
                k = int(rng.integers(0, 8)) if rng.random() < 0.7 else int(rng.integers(100, 100 + 4 * context._CACHE_MAX))
                assert context.cached(("thread probe", k), lambda: slow(k)) == k
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=hammer, args=(i,)) for i in range(4)]
    [t.start() for t in threads]
    [t.join() for t in threads]
    try:
        assert not errors
        assert sorted(k for k in made if k < 8) == list(range(8))  # the hot keys: made once each, never evicted
        assert len(context._CACHE) <= context._CACHE_MAX
    finally:
        context.clear_caches()


def test_a_gps_fault_sweep_wider_than_the_cache_computes_its_geometry_once(tmp_path, monkeypatch):
    """70 GPS-step cells, each context built twice (two chunk rows): one GNSS geometry, one camera geometry
    (a GPS fault does not change what the camera sees; before, every row recomputed both)."""
    from testbed.campaign import context
    from testbed.sensors.vision import detect

    made = {"gnss": 0, "vision": 0}

    def counted(fn, what):
        def wrapper(*a, **k):
            made[what] += 1
            return fn(*a, **k)
        return wrapper

    monkeypatch.setattr(context, "gnss_geometry", counted(context.gnss_geometry, "gnss"))  # the name it calls
    monkeypatch.setattr(detect, "vision_geometry", counted(detect.vision_geometry, "vision"))
    text = TINY.format(chunk=20, monitors='["gps_raim", "va_raim"]').replace(
        "magnitudes = [0.0, 60.0]", f"magnitudes = {[float(m) for m in range(70)]}")
    loaded = load_spec(write_spec(tmp_path, text=text))
    cells = expand_cells(loaded)
    assert len(cells) == 70 > context._CACHE_MAX
    context.clear_caches()
    try:
        for _ in range(2):
            ctxs = [context.cell_context(c, loaded.spec) for c in cells]
        assert made == {"gnss": 1, "vision": 1}
        assert all(c.g_geom is ctxs[0].g_geom and c.v_geom is ctxs[0].v_geom for c in ctxs)
    finally:
        context.clear_caches()


def test_per_epoch_and_per_sortie_detection_match_a_hand_count(reference):
    """From the stored per-epoch records of the first trials: per sortie = any alert from the onset
    on; per epoch = alerted epochs / faulty epochs from the onset with a solution (finite PL, the
    faulty satellite in view). The trial table's counts and detection_table's rates are those hand
    counts."""
    from testbed.campaign.report import detection_table

    ep = table(reference, "epochs.parquet").to_pandas()
    tr = table(reference).to_pandas().set_index(["cell", "trial", "monitor"])
    cells = table(reference, "cells.parquet").to_pylist()
    onset = {c["cell"]: c["onset_s"] for c in cells}
    n_checked = 0
    for (cell, trial, mon), g in ep.groupby(["cell", "trial", "monitor"]):
        t0 = onset[cell] if onset[cell] == onset[cell] else -np.inf
        after = g[g.t >= t0 - 1e-9]
        solved = after[np.isfinite(after.hpl) & after.fault_present]
        row = tr.loc[(cell, trial, mon)]
        assert row.onset_epochs == len(solved) and row.onset_alerts == int(solved.alert.sum())
        assert row.detected == bool(after.alert.any())
        n_checked += 1
    assert n_checked >= 16
    rows = detection_table(cells, table(reference))
    for r in rows:
        g = tr.xs(r["monitor"], level="monitor").loc[r["cell"]]
        exercised = (g.onset_epochs > 0) | (r["fault_kind"] == "none")
        assert r["k"] == int((g.detected & exercised).sum()) and r["n"] == len(g) and r["n_ex"] == exercised.sum()
        assert r["k_ep"] == g.onset_alerts.sum() and r["n_ep"] == g.onset_epochs.sum()
        assert r["lo_ep"] <= r["rate_ep"] <= r["hi_ep"]
    faulted = [r for r in rows if r["fault_size"] > 0]
    assert all(r["rate_ep"] <= r["rate"] for r in faulted)  # the per-epoch rate is never the looser


def test_accuracy_quantile_from_the_histogram_matches_the_sample_quantile():
    """hist_quantile on the runner's 0.05-dex bins against numpy's quantile of the raw errors."""
    from testbed.campaign.report import hist_quantile
    from testbed.viz.stanford import HIST_BINS, HIST_LOG10_MAX, HIST_LOG10_MIN

    rng = np.random.default_rng(5)
    for scale in (0.7, 3.0, 25.0):
        e = scale * np.abs(rng.standard_normal(200_000))
        le = np.clip(np.log10(e), HIST_LOG10_MIN, HIST_LOG10_MAX - 1e-9)
        counts, _ = np.histogram(le, bins=np.linspace(HIST_LOG10_MIN, HIST_LOG10_MAX, HIST_BINS + 1))
        b = np.flatnonzero(counts)
        hc = {"err_bin": b, "count": counts[b]}
        got, ref = hist_quantile(hc, None, 0.95), np.quantile(e, 0.95)
        assert abs(got / ref - 1) < 10 ** 0.05 - 1, (scale, got, ref)  # within one bin (12 %)
        assert abs(got / (1.95996 * scale) - 1) < 0.13  # and the half-normal's closed form
    assert np.isnan(hist_quantile({"err_bin": np.zeros(0, int), "count": np.zeros(0)}, None, 0.95))


def test_a_chunk_row_gives_each_cell_what_its_chunk_alone_gives(reference, tmp_path):
    """The driver runs chunk k of every cell block-major (run_chunk_row); each cell's tables are its run_chunk's."""
    from testbed.campaign.runner import run_chunk, run_chunk_row

    loaded = load_spec(write_spec(tmp_path))
    row = run_chunk_row(loaded, 1, [1, 0], threads=2)
    assert sorted(row) == [0, 1]
    for c in (0, 1):
        alone = run_chunk(loaded, c, 1, threads=1)
        for name in ("trials", "epochs", "hist"):
            assert (row[c][name] is None) == (alone[name] is None)
            if alone[name] is not None:
                assert same(row[c][name], alone[name]), (c, name)


def test_clustered_standard_error_against_closed_form_and_monte_carlo():
    from testbed.campaign.report import clustered_mean_se

    rng = np.random.default_rng(11)
    # one observation per cluster: the textbook standard error s/sqrt(G) (s with G - 1)
    x = rng.normal(size=50)
    se, g = clustered_mean_se(np.arange(50), np.ones(50), x)
    assert g == 50 and se == pytest.approx(np.std(x, ddof=1) / np.sqrt(50), rel=1e-12)
    # 40 surveys of 500 epochs, each survey with its own bias (sd 1) under white noise (sd 3): over 400
    # replications the estimate follows the pooled mean's real spread, which sd/sqrt(N) understates ~7x
    G, n, reps = 40, 500, 400
    cluster = np.repeat(np.arange(G), n)
    means, ses, naive = [], [], []
    for _ in range(reps):
        e = np.repeat(rng.normal(size=G), n) + 3.0 * rng.normal(size=G * n)
        means.append(e.mean())
        ses.append(clustered_mean_se(cluster, np.ones(G * n), e)[0])
        naive.append(e.std() / np.sqrt(G * n))
    true_sd = np.std(means, ddof=1)  # its own sampling error is ~3.5 % at 400 replications
    assert np.sqrt(np.mean(np.square(ses))) == pytest.approx(true_sd, rel=0.12)
    assert true_sd > 5 * np.mean(naive)
    # per-trial sums give the same answer as the epochs they sum (the campaign tables store sums)
    e = rng.normal(size=(G, n)) + rng.normal(size=(G, 1))
    per_trial = e.reshape(G, 10, n // 10).sum(-1).ravel()
    a = clustered_mean_se(cluster, np.ones(G * n), e.ravel())[0]
    b = clustered_mean_se(np.repeat(np.arange(G), 10), np.full(G * 10, n // 10), per_trial)[0]
    assert a == pytest.approx(b, rel=1e-12)
    assert np.isnan(clustered_mean_se(np.zeros(5), np.ones(5), x[:5])[0])  # one survey: no standard error


def test_stanford_counts_are_numpys_histogram2d():
    """The sparse Stanford counts against np.histogram2d on the same clipped logs, points on bin edges,
    beyond both ends, NaN and alerted epochs included."""
    from types import SimpleNamespace

    from testbed.campaign import tables
    from testbed.viz import stanford

    edges = np.linspace(stanford.HIST_LOG10_MIN, stanford.HIST_LOG10_MAX, stanford.HIST_BINS + 1)
    rng = np.random.default_rng(3)
    e = 10.0 ** np.concatenate([rng.uniform(-4, 6, 4000), edges, [np.nan, -np.inf]])
    p = 10.0 ** rng.permutation(np.concatenate([rng.uniform(-4, 6, 4000), edges, [1.0, 2.0]]))
    alert = rng.random(e.size) < 0.1
    out = SimpleNamespace(alert=alert[None], hpl=p[None], vpl=p[::-1][None])
    got = tables._stanford_counts("m", out, e[None], e[None])
    for dim, pl in (("H", p), ("V", p[::-1])):
        ok = np.isfinite(e) & np.isfinite(pl) & ~alert
        clip = lambda v: np.clip(np.log10(np.maximum(v[ok], 1e-12)), edges[0], edges[-1] - 1e-9)  # noqa: E731
        H, _, _ = np.histogram2d(clip(e), clip(pl), bins=[edges, edges])
        ei, pi, c = got[f"m/{dim}"]
        want = np.zeros_like(H)
        want[ei, pi] = c
        assert np.array_equal(H, want) and (c > 0).all()


@pytest.mark.slow  # 10 s
def test_every_table_of_a_report_is_well_formed(reference, tmp_path, capsys, monkeypatch):
    """The report's Markdown tables render: the same number of cells in the header, the separator and every
    row, with swept axes (the tiny spec) and with none (quick-look: its cells differ by the fault only)."""
    from testbed.cli import main

    assert markdown_table_problems(write_report(reference).read_text()) == []
    from testbed.campaign import report

    calls = [0]

    def counted(*a, **kw):
        calls[0] += 1
        return detection_table(*a, **kw)

    detection_table = report.detection_table
    monkeypatch.setattr(report, "detection_table", counted)
    out = tmp_path / "ql"
    assert main(["campaign", "quick-look", "--out", str(out), "--trials", "10", "--quiet", "--workers", "1"]) == 0
    assert markdown_table_problems((out / "report.md").read_text()) == []
    assert calls == [1]  # the console's headlines and the report share one detection table
    said = capsys.readouterr().out  # the console's headline: each cell and monitor's result, not only paths
    assert "gps_raim, fault-free: false alarm in" in said and "va_raim, gps_step 20 m: detected in" in said
    from testbed.campaign.report import headlines

    lines = headlines(reference)
    assert len(lines) == 4 and all(" of 40 sorties (" in x for x in lines)
    lines = headlines(reference, limit=3)
    assert len(lines) == 4 and lines[-1] == "... and 1 more cell-monitor rows in report.md"


def test_markdown_tables_have_one_maker_and_escape_what_would_split_a_cell():
    """Every Markdown table of the testbed comes from testbed.markdown.table (no separator row written by hand
    anywhere else), and a cell holding a pipe or a line break stays one cell: the claims table's calibration
    assumption ("|mean| > 3 standard errors") split its row into more cells than the header."""
    import re

    from record_checks import markdown_table_problems
    from testbed.studies.reproduce import claims_section
    from testbed.markdown import table

    by_hand = [f"{p.relative_to(ROOT)}:{k}" for p in sorted((ROOT / "testbed").rglob("*.py"))
               if p.name != "markdown.py"
               for k, line in enumerate(p.read_text().splitlines(), 1) if re.search(r"\|-{3,}\|", line)]
    assert by_hand == []
    assert markdown_table_problems("\n".join(claims_section({}, {}))) == []
    lines = table(["a", "b"], [["x | y", "`p|q` or r\nor s"], ["already \\| escaped", 1]])
    assert lines[2] == "| x \\| y | `p|q` or r or s |" and lines[3] == "| already \\| escaped | 1 |"
    assert markdown_table_problems("\n".join(lines)) == []
    with pytest.raises(ValueError, match="rows \\[0\\]"):
        table(["a", "b"], [["only one"]])


# ----------------------------------------------------------------------------- faults that never happen

NEVER = """
name = "never"
approaches = ["va-raim-2015"]
monitors = {monitors}
trials = 20
block_trials = 10
chunk_trials = 20
per_epoch_trials = 20
duration_s = 40.0
{sorties}
[[faults]]
onset_s = 15.0
{fault}
"""


@pytest.mark.parametrize("monitors, fault, said", [
    ('["gps_raim"]', 'kind = "gps_step"\nmagnitudes = [0.0, 30.0]\nprn = 1',
     "faults.0 (gps_step, prn = 1): in every cell that carries it (cell 1), PRN 1 is never in view"),
    ('["va_raim"]', 'kind = "landmark_moved"\nmagnitudes = [0.0, 5000.0]\ndirection_enu = [0.0, 0.0, 1.0]',
     "faults.0 (landmark_moved, landmark = 'random'): in every cell that carries it (cell 1), every landmark in "
     "view at the onset, moved by (0.0, 0.0, 5000.0) m ENU, is never in the camera's image"),
])
def test_a_fault_no_trial_can_exercise_is_refused_before_any_work(tmp_path, capsys, monitors, fault, said):
    """A step on a satellite that never rises over the sortie, a landmark moved out of the image for the
    whole flight: exit 2 naming the fault table and its target, nothing written. The geometric verdict is
    the sensors': a block drawn for the cell carries the fault in no observation (its satellite in view, its
    landmark detected) and the trials' fault_target is -1 where no slot took it, which the report reads as
    not exercised."""
    from testbed.campaign_cli import main
    from testbed.campaign.blocks import draw_block
    from testbed.campaign.context import cell_context

    spec = write_spec(tmp_path, "never.toml", text=NEVER.format(monitors=monitors, fault=fault, sorties=""))
    assert main(["campaign", str(spec), "--out", str(tmp_path / "o"), "--quiet", "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and said in err and "no trial could exercise the fault" in err
    assert not (tmp_path / "o").exists()
    loaded = load_spec(spec)
    cell = expand_cells(loaded)[1]
    ctx = cell_context(cell, loaded.spec)
    d = draw_block(ctx, loaded.spec, 0)
    observed = np.asarray(d.gnss_truth.faulty, bool) & np.asarray(d.obs.gnss.visible, bool)
    if d.vision_truth is not None:
        observed = np.concatenate([observed, np.asarray(d.vision_truth.faulty, bool)], axis=-1)
        assert (d.fault_target == -1).all()
    assert not observed.any()


def test_sorties_that_do_not_exercise_the_fault_are_counted_apart_in_the_report(tmp_path, capsys):
    """PRN 5 in view for only some of 20 sorties spread over 10 h: the campaign runs, and the sorties in which
    no epoch carried the fault with a solution — counted by hand from the stored epochs — are reported as
    not exercised, out of the detection rate, in the tables and the console's headline."""
    from record_checks import markdown_table_problems
    from testbed.campaign_cli import main

    text = NEVER.format(monitors='["gps_raim"]', fault='kind = "gps_step"\nmagnitudes = [0.0, 30.0]\nprn = 5',
                        sorties='[sorties]\nstart = "consecutive"\nsortie_s = 1800.0\n')
    out = tmp_path / "o"
    assert main(["campaign", str(write_spec(tmp_path, "part.toml", text=text)), "--out", str(out), "--quiet",
                 "--workers", "1"]) == 0
    ep = table(out, "epochs.parquet").to_pandas()
    ep = ep[(ep.cell == 1) & (ep.t >= 15.0)]
    solved = ep[ep.fault_present & np.isfinite(ep.hpl)].groupby("trial").size()
    exercised = set(solved.index)
    assert 0 < len(exercised) < 20
    tr = table(out).to_pandas()
    tr = tr[tr.cell == 1]
    detected = int(tr[tr.trial.isin(exercised)].detected.sum())
    said = capsys.readouterr().out
    assert (f"gps_step 30 m: detected in {detected} of the {len(exercised)} sorties that exercised the fault" in said
            and f"{20 - len(exercised)} of 20 not exercised" in said)
    report = (out / "report.md").read_text()
    assert markdown_table_problems(report) == []
    assert f"| 1 | gps_raim | gps_step | 30 m | 20 | {20 - len(exercised)} | {detected} |" in report
    assert f"**Faults not exercised**: in {20 - len(exercised)} of 20 faulty sortie-monitor pairs" in report


def test_a_landmark_move_whose_direction_overflows_still_moves_it():
    """direction_enu is normalised with hypot: a direction of 1e200 (whose sum of squares overflows) gave a
    move of 0 m, a fault that never happened; one of 1e-200 (whose sum of squares underflows) was refused as
    a zero vector."""
    from testbed.campaign.spec import FaultSweep

    big = FaultSweep(kind="landmark_moved", magnitudes=[0.0, 10.0], direction_enu=(1e200, 0.0, -1e200))
    assert big.fault(10.0)["delta_enu_m"] == pytest.approx((10 / np.sqrt(2), 0.0, -10 / np.sqrt(2)), rel=1e-15)
    tiny = FaultSweep(kind="landmark_moved", magnitudes=[10.0], direction_enu=(1e-200, 1e-200, 0.0))
    assert tiny.fault(10.0)["delta_enu_m"] == pytest.approx((10 / np.sqrt(2), 10 / np.sqrt(2), 0.0), rel=1e-15)
    assert any(FaultSweep(kind="landmark_moved", magnitudes=[5e-324], direction_enu=(1.0, 1.0, 1.0)).fault(5e-324)
               ["delta_enu_m"])  # the smallest magnitude still moves it


def test_every_text_of_every_report_figure_lies_inside_it(reference, monkeypatch):
    """Titles, labels and legends inside their figure once drawn (pl_time.png's title, wider than its one
    panel, was clipped at both ends)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from testbed.campaign import report

    seen = {}
    save = report._save
    monkeypatch.setattr(report, "_save", lambda fig, path: (save(fig, path), seen.__setitem__(path.name, fig)))
    write_report(reference)
    assert {"pl_time.png", "vision_range_error.png", "detection_0_gps_step.png"} <= set(seen)
    for name, fig in seen.items():
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        box = fig.bbox
        texts = list(fig.texts)
        for ax in fig.axes:
            texts += [ax.title, ax.xaxis.label, ax.yaxis.label]
            if ax.get_legend() is not None:
                texts += ax.get_legend().get_texts()
        outside = [t.get_text() for t in texts if t.get_text() and (
            (e := t.get_window_extent(canvas.get_renderer())).x0 < box.x0 - 0.5 or e.x1 > box.x1 + 0.5
            or e.y0 < box.y0 - 0.5 or e.y1 > box.y1 + 0.5)]
        assert outside == [], name

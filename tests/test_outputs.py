"""A command's outputs: tried before any work, committed together or not at all (``testbed.outputs``).

Two classes of defect, one test each through the real command line (``testbed.cli.main``):

- several outputs of one command are all written or none: a failure or a Ctrl-C while writing the
  last one leaves the earlier files as they were, the message says what was and was not written, and
  two outputs that would write the same file are refused before any work;
- every output option of every command is tried before any work: a destination that cannot take the
  file (a regular file where a folder is expected, a folder where a file is expected, a read-only
  folder, a place nothing can be created) is exit 2 naming the option, the path and why.

The "work" of each command is replaced by a function that fails the test if it is ever reached.
"""

from __future__ import annotations

import errno
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main
from testbed.outputs import OutputSet, _sigint_held
from testbed.schema import ConfigError

SPEC = ('name = "s"\napproaches = ["va-raim-2015"]\nmonitors = ["gps_raim"]\ntrials = 10\nblock_trials = 10\n'
        'chunk_trials = 10\nduration_s = 10.0\n')


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    said = capsys.readouterr()
    return code, said.out, said.err


def contents(*folders: Path) -> dict[str, bytes]:
    """Every file under ``folders`` (hidden ones too) and its bytes."""
    return {str(p): p.read_bytes() for f in folders for p in sorted(f.rglob("*")) if p.is_file()}


def rinex_pair(folder: Path, seed: int) -> tuple[Path, Path]:
    """A 20 s synthetic approach as RINEX observation and navigation files (our own export)."""
    from testbed.flight.kinematic import straight_truth
    from testbed.records import Mount
    from testbed.sensors.gnss.rinex import write_rinex
    from testbed.sensors.gnss.settings import GnssSettings
    from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss
    from testbed.world.airport import runway_frame

    truth = straight_truth(runway_frame(), [-6300.0, -4450.0, 410.0], [-1600.0, -1130.0, 80.0], 20.0, rate_hz=1.0)
    s = GnssSettings(terrain_masking=False)
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc="2024-03-15T06:00:00Z")
    ep, tr = sample_gnss(g, s, rng=np.random.default_rng(seed))
    folder.mkdir(parents=True, exist_ok=True)
    return write_rinex(ep, g, folder, name="synthetic", clock_bias_m=tr.clock_bias)


@pytest.fixture(scope="module")
def rinex(tmp_path_factory):
    """Two different observation files of the same approach (seeds 1 and 2)."""
    root = tmp_path_factory.mktemp("rinex")
    return rinex_pair(root / "one", 1), rinex_pair(root / "two", 2)


def no_work(monkeypatch) -> None:
    """Every command's work fails the test when reached (a refusal must come before it)."""
    import testbed.api
    import testbed.studies.dpe_calibration
    import testbed.campaign.report
    import testbed.studies.reproduce
    import testbed.studies.reproduce_dpe
    import testbed.studies.reproduce_won
    import testbed.campaign.runner
    import testbed.replay.run
    import testbed.sim.loop

    def work(*a, **k):
        raise AssertionError("the work started before the outputs were refused")

    for module, name in ((testbed.api, "fly"), (testbed.sim.loop, "run_loop"), (testbed.replay.run, "form_epochs"),
                         (testbed.campaign.runner, "chunk_plan"), (testbed.studies.dpe_calibration, "calibrate_dpe"),
                         (testbed.campaign.report, "detection_table"),
                         (testbed.studies.reproduce, "loaded_experiments"),
                         (testbed.studies.reproduce_won, "won_scene"), (testbed.studies.reproduce_dpe, "epoch_cases")):
        monkeypatch.setattr(module, name, work)


# ------------------------------------------------------------------------------- A: all outputs or none

def test_a_command_with_several_outputs_writes_all_or_none(rinex, tmp_path, monkeypatch, capsys):
    import testbed.replay.recording
    import testbed.sensors.gnss.rinex

    (obs1, nav1), (obs2, nav2) = rinex
    monkeypatch.chdir(tmp_path)
    out, rrd = tmp_path / "results", tmp_path / "flight.rrd"
    argv = ["--out", out, "--rrd", rrd, "--format", "csv"]
    assert run(capsys, "monitor", obs1, nav1, *argv)[0] == 0
    before = contents(tmp_path)
    assert sorted(p.name for p in out.iterdir()) == ["epochs-gps_raim.csv", "summary.json"]

    # another file's run, stopped while the recording (written last) is being written: nothing replaced
    def stopped(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(testbed.replay.recording, "write_recording", stopped)
    code, _, err = run(capsys, "monitor", obs2, nav2, *argv)
    assert contents(tmp_path) == before  # no temporary file left either
    assert code == 130 and err.startswith("interrupted: the outputs were not written"), err
    assert f"--out {out}: the files there are as they were" in err and f"--rrd {rrd}: as it was" in err, err

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(testbed.replay.recording, "write_recording", full)
    code, _, err = run(capsys, "monitor", obs2, nav2, *argv)
    assert code == 2 and "No space left on device" in err and "the outputs were not written" in err, err
    assert "Traceback" not in err and contents(tmp_path) == before

    # the same path twice, refused before any work
    no_work(monkeypatch)
    code, _, err = run(capsys, "monitor", obs2, nav2, "--out", tmp_path / "same.rrd", "--rrd", tmp_path / "same.rrd")
    assert code == 2 and f"--out {tmp_path / 'same.rrd'} and --rrd {tmp_path / 'same.rrd'}: name the same path" in err
    work = tmp_path / "work"
    work.mkdir()
    code, _, err = run(capsys, "calibrate-dpe", "--work", work, "--out", work / "k.json")
    assert code == 2 and f"{work / 'k.json'} is inside the folder --work writes" in err, err
    assert contents(tmp_path) == before and not (tmp_path / "same.rrd").exists() and os.listdir(work) == []
    monkeypatch.undo()

    # export-rinex: the navigation file (written after the observations) fails: the earlier export stays whole
    monkeypatch.chdir(tmp_path)
    rx = tmp_path / "rx"
    assert run(capsys, "export-rinex", "va-raim-2015", rx, "--seed", "1")[0] == 0
    before = contents(tmp_path)
    monkeypatch.setattr(testbed.sensors.gnss.rinex, "write_nav", full)
    code, _, err = run(capsys, "export-rinex", "va-raim-2015", rx, "--seed", "2")
    assert contents(tmp_path) == before
    assert code == 2 and "No space left on device" in err and f"DIR {rx}: the files there are as they were" in err


def test_a_failed_commit_puts_back_the_files_it_had_moved(rinex, tmp_path, monkeypatch, capsys):
    """The commit renames the recording, then the table, then the summary; the summary's rename fails: the
    recording and the table moved before it are put back (their earlier versions), nothing is left over."""
    import testbed.outputs

    (obs1, nav1), (obs2, nav2) = rinex
    monkeypatch.chdir(tmp_path)
    argv = ["--out", tmp_path / "results", "--rrd", tmp_path / "flight.rrd", "--format", "csv"]
    assert run(capsys, "monitor", obs1, nav1, *argv)[0] == 0
    before = contents(tmp_path)
    replace, moved = os.replace, []

    def refused_at_the_summary(src, dst):
        if Path(dst).name == "summary.json":
            raise PermissionError(errno.EACCES, "Permission denied", str(dst))
        if not Path(dst).name.startswith("."):  # into a destination (not a writer's own temporary rename)
            moved.append(Path(dst).name)
        return replace(src, dst)

    monkeypatch.setattr(testbed.outputs.os, "replace", refused_at_the_summary)
    code, _, err = run(capsys, "monitor", obs2, nav2, *argv)
    assert moved == ["flight.rrd", "epochs-gps_raim.csv", "epochs-gps_raim.csv", "flight.rrd"]  # moved, put back
    assert code == 2 and "could not move" in err and "summary.json into place (Permission denied)" in err, err
    assert "the outputs were not written" in err and contents(tmp_path) == before


def test_a_ctrl_c_during_the_commit_is_held_until_it_ends():
    # Python's own handler, as a terminal's session has it: a suite run as a background job starts with SIGINT
    # ignored, and then (rightly) nothing is raised
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    done = []
    try:
        with pytest.raises(KeyboardInterrupt):
            with _sigint_held():
                os.kill(os.getpid(), signal.SIGINT)
                done.append("the block ran to its end")
    finally:
        signal.signal(signal.SIGINT, before)
    assert done == ["the block ran to its end"]


def test_an_interruption_after_the_commit_says_the_outputs_were_written(tmp_path):
    with pytest.raises(KeyboardInterrupt) as caught:
        with OutputSet() as outs:
            outs.file(tmp_path / "a.json", "--out")
            outs.staged(tmp_path / "a.json").write_text("{}")
            outs.commit()
            raise KeyboardInterrupt
    assert caught.value.__notes__ == [f"the outputs had been written: {tmp_path / 'a.json'}"]
    assert os.listdir(tmp_path) == ["a.json"]


# ------------------------------------------------------------------ B: every output tried before any work

def _chmod_bites() -> bool:
    """A read-only folder refuses this process a new file (not so for root, who overrides permissions)."""
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        os.chmod(d, 0o555)
        try:
            Path(d, "x").touch()
        except PermissionError:
            return True
        finally:
            os.chmod(d, 0o755)
    return False


def _cases():
    """(id, argv from the fixture's paths, the option, the path said, why)."""
    proc = Path("/proc")
    cases = [
        ("fly --rrd under a file", lambda p: ["fly", "va-raim-2015", "--rrd", p["file"] / "r.rrd"], "--rrd",
         lambda p: p["file"] / "r.rrd", "is a file, not a folder"),
        ("fly --truth under a file", lambda p: ["fly", "va-raim-2015", "--flight-only", "--truth",
                                                p["file"] / "t.csv"], "--truth", lambda p: p["file"] / "t.csv",
         "is a file, not a folder"),
        ("monitor --out: a folder where summary.json goes", lambda p: ["monitor", *p["rinex"], "--out", p["taken"]],
         "--out", lambda p: p["taken"] / "summary.json", "is a folder; the command writes a file there"),
        ("campaign --out: a file where figures/ goes", lambda p: ["campaign", p["spec"], "--out", p["figures"],
                                                                  "--quiet"],
         "--out", lambda p: p["figures"] / "figures", "is a file; the command writes a folder there"),
        ("report: a file where figures/ goes", lambda p: ["report", p["report"]], "DIR",
         lambda p: p["report"] / "figures", "is a file; the command writes a folder there"),
        ("calibrate-dpe --work under a file", lambda p: ["calibrate-dpe", "--out", p["cwd"] / "k.json", "--work",
                                                         p["file"] / "w"], "--work", lambda p: p["file"] / "w",
         "is a file, not a folder"),
        ("reproduce --out under a file", lambda p: ["reproduce", "won-2013", "--out", p["file"] / "r"], "--out",
         lambda p: p["file"] / "r", "is a file, not a folder"),
    ]
    if proc.is_dir():  # a folder nobody, root included, can create a file in
        cases += [
            ("monitor --rrd in /proc", lambda p: ["monitor", *p["rinex"], "--rrd", proc / "x.rrd"], "--rrd",
             lambda p: proc / "x.rrd", "cannot create a file in /proc"),
            ("fly --rrd in /proc", lambda p: ["fly", "va-raim-2015", "--rrd", proc / "x.rrd"], "--rrd",
             lambda p: proc / "x.rrd", "cannot create a file in /proc"),
            ("calibrate-dpe --out in /proc", lambda p: ["calibrate-dpe", "--out", proc / "k.json"], "--out",
             lambda p: proc / "k.json", "cannot create a file in /proc"),
            ("reproduce dpe-vertical --out in /proc", lambda p: ["reproduce", "dpe-vertical", "--out", proc / "r"],
             "--out", lambda p: proc / "r", "cannot create the folder /proc/r"),
        ]
    chmod = pytest.mark.skipif(not _chmod_bites(), reason="chmod does not bite root (the /proc cases stand in)")
    cases += [
        ("calibrate-dpe --out in a read-only folder", lambda p: ["calibrate-dpe", "--out", p["ro"] / "k.json"],
         "--out", lambda p: p["ro"] / "k.json", "Permission denied", chmod),
        ("monitor --out: a read-only folder", lambda p: ["monitor", *p["rinex"], "--out", p["ro"]], "--out",
         lambda p: p["ro"], "Permission denied", chmod),
        ("fly --truth in a read-only folder", lambda p: ["fly", "va-raim-2015", "--truth", p["ro"] / "t.npz"],
         "--truth", lambda p: p["ro"] / "t.npz", "Permission denied", chmod),
    ]
    return cases


@pytest.mark.parametrize("argv, option, said, why", [pytest.param(*c[1:5], id=c[0], marks=c[5:]) for c in _cases()])
def test_every_output_that_cannot_be_written_is_refused_before_any_work(argv, option, said, why, rinex, tmp_path,
                                                                        monkeypatch, capsys):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    paths = {"cwd": cwd, "file": tmp_path / "a-file", "taken": tmp_path / "taken", "figures": tmp_path / "campaign",
             "report": tmp_path / "report", "ro": tmp_path / "read-only", "spec": tmp_path / "s.toml",
             "rinex": rinex[0]}
    paths["file"].write_text("mine")
    (paths["taken"] / "summary.json").mkdir(parents=True)
    for folder in (paths["figures"], paths["report"]):
        folder.mkdir()
        (folder / "figures").write_text("mine")
    (paths["report"] / "manifest.json").write_text('{"spec_hash": "x", "spec": {}}')
    paths["ro"].mkdir()
    paths["spec"].write_text(SPEC)
    os.chmod(paths["ro"], 0o555)
    try:
        before, entries = contents(tmp_path), sorted(tmp_path.rglob("*"))
        no_work(monkeypatch)
        code, out, err = run(capsys, *argv(paths))
        assert code == 2 and "Traceback" not in err, (code, out, err)
        assert f"{option} " in err and str(said(paths)) in err and why in err, err
        assert contents(tmp_path) == before and sorted(tmp_path.rglob("*")) == entries  # nothing made, nothing left
    finally:
        os.chmod(paths["ro"], 0o755)


def test_fly_writes_the_recording_and_the_truth_together(tmp_path, monkeypatch, capsys):
    """The truth is written before the recording is complete; the recording's last step fails: the earlier
    truth file stays as it was (it was replaced before)."""
    import testbed.viz.rerun_sink

    monkeypatch.chdir(tmp_path)
    rrd, truth = tmp_path / "r.rrd", tmp_path / "t.csv"
    rrd.write_bytes(b"an earlier recording")
    truth.write_bytes(b"an earlier truth")

    def full(self, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(testbed.viz.rerun_sink.RerunSink, "commit", full)
    code, _, err = run(capsys, "fly", "va-raim-2015", "--monitors", "gps_raim", "--rrd", rrd, "--truth", truth)
    assert truth.read_bytes() == b"an earlier truth" and rrd.read_bytes() == b"an earlier recording"
    assert sorted(os.listdir(tmp_path)) == ["r.rrd", "t.csv"]
    assert code == 2 and "No space left on device" in err and f"--truth {truth}: as it was" in err, err


def test_run_approach_from_python_writes_the_recording_and_the_truth_together(tmp_path, monkeypatch):
    """The library call, not only the command: a failure while committing the recording leaves both earlier
    files as they were; a run that succeeds has both in place when ``on_landed`` is called."""
    import testbed.viz.rerun_sink
    from testbed.api import run_approach

    monkeypatch.chdir(tmp_path)
    rrd, truth = tmp_path / "r.rrd", tmp_path / "t.csv"
    rrd.write_bytes(b"an earlier recording")
    truth.write_bytes(b"an earlier truth")
    commit = testbed.viz.rerun_sink.RerunSink.commit

    def full(self, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(testbed.viz.rerun_sink.RerunSink, "commit", full)
    with pytest.raises(ConfigError, match="No space left") as said:
        run_approach("va-raim-2015", monitors=["gps_raim"], rrd_path=rrd, truth_path=truth)
    assert f"--truth {truth}: as it was" in str(said.value)
    assert truth.read_bytes() == b"an earlier truth" and rrd.read_bytes() == b"an earlier recording"
    assert sorted(os.listdir(tmp_path)) == ["r.rrd", "t.csv"]

    monkeypatch.setattr(testbed.viz.rerun_sink.RerunSink, "commit", commit)
    seen = []
    run_approach("va-raim-2015", monitors=["gps_raim"], rrd_path=rrd, truth_path=truth,
                 on_landed=lambda result: seen.append((rrd.read_bytes()[:4], truth.read_bytes()[:4])))
    assert seen and seen[0][0] != b"an e" and seen[0][1] != b"an e"  # both new, both in place at landing
    assert sorted(os.listdir(tmp_path)) == ["r.rrd", "t.csv"]

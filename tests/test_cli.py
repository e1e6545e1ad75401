"""The `testbed` command: every subcommand end to end; nothing written to the working directory unasked."""

import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from testbed.cli import main


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    d = tmp_path / "cwd"
    d.mkdir()
    monkeypatch.chdir(d)
    return d


def test_approaches_lists_the_shipped_ones(cwd, capsys):
    assert main(["approaches"]) == 0
    out = capsys.readouterr().out
    for name in ("zunz-rwy05-final", "zunz-rwy05-rnp", "va-raim-2015"):
        assert name in out
    assert "docs/design/dpe.md" in out  # the DPE campaigns cite the documentation page
    assert os.listdir(cwd) == []


def test_fly_flight_only_writes_only_the_truth_asked_for(cwd, tmp_path, capsys):
    truth = tmp_path / "t.csv"
    assert main(["fly", "va-raim-2015", "--flight-only", "--truth", str(truth)]) == 0
    data = np.genfromtxt(truth, delimiter=",", names=True)
    assert data["t"][-1] == pytest.approx(60.7, abs=0.5) and len(data) > 7000
    assert os.listdir(cwd) == []


def test_fly_with_monitors_no_record_writes_nothing(cwd, capsys):
    assert main(["fly", "va-raim-2015", "--no-record", "--monitors", "gps_raim"]) == 0
    out = capsys.readouterr().out
    assert "integrity monitors" in out and "gps_raim" in out
    assert os.listdir(cwd) == []


def test_the_summary_names_the_injected_fault_and_why_a_monitor_never_served(cwd, capsys):
    """The shipped faulted final: the fault's kind, size, onset and the satellite the draw picked, with the
    epochs it was in the observations; the DPE without a K says why it is never available; one real-time
    factor (the loop's)."""
    assert main(["fly", "zunz-rwy05-gps-step", "--no-record", "--monitors", "gps_raim", "dpe"]) == 0
    out = " ".join(capsys.readouterr().out.split())  # rich wraps at the terminal width
    assert "fault: gps_step +60 m on a random visible satellite from 100 s" in out
    seen = re.search(r"in the observations: PRN (\d+) at (\d+) of 150 epochs \((\d+)-(\d+) s\)", out)
    assert seen is not None, out  # the draw picks the satellite; it is in view from the onset, once a second
    prn, n, first, last = map(int, seen.groups())
    assert 1 <= prn <= 32 and first == 100 and n == last - first + 1
    assert "dpe: unavailable at every epoch: K not calibrated" in out
    assert "0 % (V only)" in out  # the DPE bounds the vertical alone: its availability says so
    assert out.count("x real time") == 1


def test_a_fault_from_the_command_line_is_flown_and_named(cwd, capsys):
    assert main(["fly", "va-raim-2015", "--no-record", "--monitors", "gps_raim",
                 "--fault", "gps_step:prn=random,bias_m=80,onset_s=20"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "fault: gps_step +80 m on a random visible satellite from 20 s" in out
    assert "in the observations: PRN" in out and os.listdir(cwd) == []


def test_bad_faults_on_the_command_line_are_all_named_before_any_work(cwd, capsys):
    argv = ["fly", "--fault", "gps_step:prn=random,bias=40", "--fault", "pixel_bias:magnitude_px=-3",
            "--fault", "gps_step:prn=[3,5],bias_m=1e9"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--fault 'gps_step:prn=random,bias=40': bias_m: Field required" in err
    assert "bias: unknown key" in err and "magnitude_px: Input should be greater than or equal to 0" in err
    assert "'gps_step:prn=[3,5],bias_m=1e9': bias_m:" in err and "Traceback" not in err
    assert os.listdir(cwd) == []
    assert main(["fly", "--fault", "gps_step:prn=99,bias_m=10"]) == 2  # not a satellite of the constellation
    assert "99" in capsys.readouterr().err and os.listdir(cwd) == []


def test_fly_default_recording_goes_under_runs(cwd, capsys):
    assert main(["fly", "va-raim-2015", "--monitors", "gps_raim", "--seed", "2"]) == 0
    assert os.listdir(cwd) == ["runs"] and os.listdir(cwd / "runs") == ["va-raim-2015-seed2.rrd"]


def test_bad_file_exit_code_2_with_message(cwd, tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n')
    assert main(["fly", str(bad)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "description" in err and "Field required" in err


def test_export_rinex_is_read_by_rtklib(cwd, tmp_path):
    out = tmp_path / "rnx"
    assert main(["export-rinex", "va-raim-2015", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["va-raim-2015.nav", "va-raim-2015.obs",
                                                     "va-raim-2015.truth.csv"]
    rnx2rtkp = shutil.which("rnx2rtkp")
    if rnx2rtkp is None:
        pytest.skip("RTKLIB rnx2rtkp not installed (.ci/run installs it)")
    pos = tmp_path / "out.pos"
    subprocess.run([rnx2rtkp, "-p", "0", "-sys", "G", "-o", str(pos), str(out / "va-raim-2015.obs"),
                    str(out / "va-raim-2015.nav")], check=True, capture_output=True, timeout=60)
    rows = [line.split() for line in pos.read_text().splitlines() if line and not line.startswith("%")]
    assert len(rows) == 61  # one single-point solution per 1 Hz epoch of the 60 s sortie
    truth = np.genfromtxt(out / "va-raim-2015.truth.csv", delimiter=",", names=True)
    dlat = (np.array([float(r[2]) for r in rows]) - truth["lat_deg"]) * 111_000.0
    assert np.sqrt(np.mean(dlat**2)) < 10.0  # metres: SPP with ~1 m ranging noise
    assert os.listdir(cwd) == []

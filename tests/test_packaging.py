"""The wheel carries everything the package reads, and nothing else.

Builds the wheel from this checkout, checks its file list, then imports the
installed copy (not the editable checkout) from an empty folder and flies the
default approach from the files inside it. ``.ci/run`` does the same in a
brand-new virtual environment with a full ``testbed fly`` and a campaign.
"""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(ROOT)],
                   check=True, capture_output=True, cwd=out)
    (whl,) = out.glob("testbed-*.whl")
    return whl


@pytest.mark.slow
def test_wheel_holds_the_shipped_files_and_no_tests_recordings_or_build_products(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    shipped = {n.split("testbed/_shipped/", 1)[1] for n in names if n.startswith("testbed/_shipped/")}
    repo = {str(p.relative_to(ROOT)) for d in ("aircraft", "approaches") for p in (ROOT / d).rglob("*.toml")}
    repo |= {str(p.relative_to(ROOT)) for p in (ROOT / "approaches" / "calibration").glob("*.json")}
    assert shipped == repo  # every shipped aircraft, approach, campaign spec and calibration record, nothing more
    assert "testbed/data/do229_gps_almanac_24sat.tsv" in names
    bad = [n for n in names if n.startswith("tests/") or "/tests/" in n or "__pycache__" in n
           or n.endswith((".rrd", ".part", ".pyc", ".nbi", ".nbc", ".png", ".parquet"))]
    assert bad == []


@pytest.mark.slow
def test_installed_wheel_flies_the_default_approach_from_an_empty_folder(wheel, tmp_path):
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site), str(wheel)],
                   check=True, capture_output=True)
    empty = tmp_path / "empty"
    empty.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "TESTBED_HOME"}
    env["PYTHONPATH"] = str(site)  # ahead of the editable checkout's finder

    def testbed(*args: str) -> str:
        res = subprocess.run([sys.executable, "-m", "testbed.cli", *args], cwd=empty, env=env,
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stdout + res.stderr
        return res.stdout

    listing = testbed("approaches")
    assert f"{site / 'testbed' / '_shipped' / 'approaches'}" in listing and "(installed package)" in listing
    assert "zunz-rwy05-final" in listing and "quick-look" in listing
    flown = testbed("fly", "--flight-only")
    assert "reached threshold" in flown and "yes" in flown
    assert list(empty.iterdir()) == []  # nothing written to the working directory


def test_a_shipped_campaign_is_found_by_name_and_trials_can_be_overridden():
    from testbed.campaign.spec import load_spec
    from testbed.resources import campaigns_dir
    from testbed.schema import ConfigError

    loaded = load_spec("quick-look", trials=150)
    assert loaded.source == campaigns_dir() / "quick-look.toml"
    assert (loaded.spec.trials, loaded.spec.block_trials, loaded.spec.chunk_trials) == (150, 100, 200)
    with pytest.raises(ConfigError, match="quick-look"):  # the message lists what is shipped
        load_spec("no-such-campaign")


def test_testbed_home_replaces_the_shipped_folders(tmp_path, monkeypatch, capsys):
    import shutil

    from testbed.cli import main
    from testbed.config import load_approach

    (tmp_path / "approaches").mkdir()
    shutil.copytree(ROOT / "aircraft", tmp_path / "aircraft")
    mine = (ROOT / "approaches" / "zunz-rwy05-final.toml").read_text().replace(
        'name = "zunz-rwy05-final"', 'name = "my-final"', 1)
    assert 'name = "my-final"' in mine
    (tmp_path / "approaches" / "my-final.toml").write_text(mine)
    monkeypatch.setenv("TESTBED_HOME", str(tmp_path))
    assert main(["approaches"]) == 0
    listing = capsys.readouterr().out
    assert f"{tmp_path / 'approaches'} (TESTBED_HOME)" in listing
    assert "my-final" in listing and "zunz-rwy05-final" not in listing
    loaded = load_approach("my-final")
    assert loaded.source == tmp_path / "approaches" / "my-final.toml"
    assert loaded.aircraft_source.is_relative_to(tmp_path / "aircraft")


def test_the_readme_states_the_python_the_package_requires():
    import re
    import tomllib

    need = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    assert need == ">=3.11"  # tomllib (testbed.config)
    assert re.search(r"Python ≥ 3\.11\b", (ROOT / "README.md").read_text())

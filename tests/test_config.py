"""Bad input gets a clear error naming the file, the key path and what was expected (one test per class)."""

import re
from pathlib import Path

import pytest

from testbed.api import check_file
from testbed.cli import main
from testbed.config import approaches_dir, load_approach
from testbed.schema import ConfigError

SHIPPED = sorted(approaches_dir().glob("*.toml"))
BASE = (approaches_dir() / "zunz-rwy05-final.toml").read_text()


def write(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def edit(old: str, new: str) -> str:
    assert old in BASE, old
    return BASE.replace(old, new, 1)


def problems_of(path: Path) -> list[str]:
    with pytest.raises(ConfigError) as exc:
        load_approach(path)
    assert str(path) in str(exc.value)
    return exc.value.problems


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_approaches_are_valid(path):
    assert check_file(path) == []


def test_unknown_key_names_its_path(tmp_path):
    probs = problems_of(write(tmp_path, edit("glide_path_deg = 3.0", "glide_path_deg = 3.0\nglidepath = 3.0")))
    assert any(p.startswith("vertical.glidepath: unknown key") for p in probs)


def test_wrong_type_says_what_was_expected(tmp_path):
    probs = problems_of(write(tmp_path, edit("speed_kt = 0.0", 'speed_kt = "fast"')))
    assert any(p.startswith("wind.speed_kt:") and "number" in p and "'fast'" in p for p in probs)


def test_negative_sigma_rejected(tmp_path):
    text = BASE.replace('intensity = "none"', 'intensity = "none"\nw20_kt = -3.0')
    probs = problems_of(write(tmp_path, text))
    assert any(p.startswith("gusts.w20_kt:") and "greater than or equal to 0" in p for p in probs)


@pytest.mark.parametrize("gpa", [0.0, 20.0])
def test_impossible_glide_path_rejected(tmp_path, gpa):
    probs = problems_of(write(tmp_path, edit("glide_path_deg = 3.0", f"glide_path_deg = {gpa}")))
    assert any(p.startswith("vertical.glide_path_deg:") and "between 1 and 8 degrees" in p for p in probs)


def test_start_inside_terrain_rejected(tmp_path):
    text = BASE.replace('kind = "linzhi_synthetic"', 'kind = "flat"\nflat_height_m = 4000.0')
    probs = check_file(write(tmp_path, text))
    assert len(probs) == 1 and "start inside the terrain" in probs[0] and "4000 m" in probs[0]


def test_toml_syntax_error_names_line(tmp_path):
    probs = problems_of(write(tmp_path, BASE.replace("[wind]", "[wind")))
    assert re.search(r"not valid TOML: .*line \d+", probs[0])


def test_aircraft_path_is_relative_to_the_file(tmp_path):
    (tmp_path / "planes" / "mine").mkdir(parents=True)
    src = (approaches_dir().parent / "aircraft" / "c172x" / "aircraft.toml").read_text()
    (tmp_path / "planes" / "mine" / "aircraft.toml").write_text(src.replace('name = "c172x"', 'name = "mine"'))
    ap = load_approach(write(tmp_path, edit('aircraft = "b737"', 'aircraft = "planes/mine"')))
    assert ap.aircraft.name == "mine"
    probs = problems_of(write(tmp_path, edit('aircraft = "b737"', 'aircraft = "planes/nothere"'), "b.toml"))
    assert "aircraft: 'planes/nothere'" in probs[0] and "not found" in probs[0]


def test_all_problems_reported_at_once_and_cli_exit_code(tmp_path, capsys):
    text = edit("glide_path_deg = 3.0", "glide_path_deg = 0.5").replace("[wind]", "[wind]\ngust = 1")
    p = write(tmp_path, text)
    assert main(["check", str(p)]) == 1
    out = capsys.readouterr().out
    assert "2 problem(s)" in out and "vertical.glide_path_deg" in out and "wind.gust: unknown key" in out


CAMPAIGNS = sorted((approaches_dir() / "campaigns").glob("*.toml"))


@pytest.mark.parametrize("path", CAMPAIGNS, ids=[p.stem for p in CAMPAIGNS])
def test_shipped_campaign_specs_are_valid(path):
    assert check_file(path) == []


def test_bad_campaign_spec_lists_every_problem(tmp_path):
    p = write(tmp_path, 'name = "x"\ndescription = "y"\napproaches = ["va-raim-2015"]\ntrials = -3\nbogus = 1\n')
    probs = check_file(p)
    assert any(q.startswith("trials:") and "greater than or equal to 1" in q for q in probs)
    assert any(q.startswith("bogus: unknown key") for q in probs)


def _guide_config_block() -> str:
    text = (Path(__file__).resolve().parents[1] / "docs" / "guide" / "configuration.md").read_text()
    return text.split("```toml\n", 1)[1].split("\n```", 1)[0]


@pytest.mark.parametrize("monitors", [None, '["gps_raim", "va_raim", "pixel", "ekf", "dpe"]'])
def test_the_guides_configuration_example_is_a_valid_approach(tmp_path, monitors):
    """The configuration guide's annotated approach file checks clean as written, and with every monitor it names on."""
    import shutil

    block = _guide_config_block()
    assert "[gnss.correlators]" in block and "[monitor.pixel]" in block  # the whole example, not a fragment
    if monitors is not None:
        block, n = re.subn(r'^monitors = \[[^\]]*\]', f"monitors = {monitors}", block, count=1, flags=re.M)
        assert n == 1
    shutil.copytree(approaches_dir() / "calibration", tmp_path / "calibration")  # [monitor.dpe] k_factor's file
    p = tmp_path / "example.toml"
    p.write_text(block)
    assert check_file(p) == []


def test_the_guides_campaign_example_is_a_valid_spec(tmp_path):
    text = (Path(__file__).resolve().parents[1] / "docs" / "guide" / "campaigns.md").read_text()
    block = text.split("An example (the shipped specs", 1)[1].split("```toml\n", 1)[1].split("\n```", 1)[0]
    assert "[[faults]]" in block and "[sweep]" in block
    p = tmp_path / "example.toml"
    p.write_text(block)
    assert check_file(p) == []

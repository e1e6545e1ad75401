"""The resource estimate (testbed.sim.budget, testbed.campaign.budget) and what `testbed check` computes.

The estimate is checked against what the machine measures (a campaign's peak resident memory in a fresh
process), the refusal against a spec far above the limits (exit 2, the estimate and how to shrink it in the
message, nothing flown or written), and the override.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from testbed.campaign.budget import campaign_estimate
from testbed.campaign.spec import load_spec
from testbed.cli import main
from testbed.resources import approaches_dir
from testbed.sim.budget import Limits, check_budget

ROOT = Path(__file__).resolve().parents[1]

BIG = """
name = "too-big"
approaches = ["{approach}"]
monitors = ["gps_raim", "va_raim"]
trials = 10000000
block_trials = 100000
chunk_trials = 100000
[[faults]]
kind = "gps_step"
magnitudes = [0.0, 10.0, 20.0, 40.0, 80.0]
"""


def run(capsys, *argv) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out + out.err


@pytest.fixture
def big_spec(tmp_path) -> Path:
    p = tmp_path / "big.toml"
    p.write_text(BIG.format(approach=approaches_dir() / "va-raim-2015.toml"))
    return p


def test_a_spec_above_the_limits_is_refused_before_any_work(big_spec, tmp_path, capsys, monkeypatch):
    """10^7 trials x 5 cells in blocks of 10^5: ~100 GB of blocks and days of work. Refused at once with the
    estimate, what dominates and how to shrink or override it; nothing flown, nothing written."""
    import testbed.campaign.context as context
    import testbed.campaign.runner as runner

    monkeypatch.setattr(runner, "run_campaign", lambda *a, **k: pytest.fail("the campaign started"))
    monkeypatch.setattr(context, "flown_truth", lambda *a, **k: pytest.fail("a flight started"))
    out = tmp_path / "out"
    t0 = time.perf_counter()
    code, text = run(capsys, "campaign", big_spec, "--out", out)
    took = time.perf_counter() - t0
    assert code == 2, text
    assert "estimate for campaign too-big" in text and "above the limit" in text, text
    assert "draw blocks" in text and "block_trials" in text and "--trials" in text, text  # what dominates, how to shrink
    assert "--allow-large" in text, text
    assert not out.exists()
    assert took < 30, took  # the spec's checks and the estimate, no flight


def test_the_override_lets_it_start(big_spec, tmp_path, capsys, monkeypatch):
    import testbed.campaign.runner as runner

    started = []

    def fake_run(loaded, out, **kw):
        started.append(loaded.spec.trials)
        raise KeyboardInterrupt  # stop at once: what matters is that it started

    monkeypatch.setattr(runner, "run_campaign", fake_run)
    code, text = run(capsys, "campaign", big_spec, "--out", tmp_path / "out", "--allow-large")
    assert started == [10_000_000] and code == 130, text
    assert "estimate for campaign too-big" in text and "--allow-large given" in text, text


def test_the_limits_are_the_ones_given():
    """Memory and time each refuse on their own, and the message says which."""
    from testbed.schema import ConfigError
    from testbed.sim.budget import Estimate

    est = Estimate("x", {"blocks": 5e9}, {"sorties": 7200.0}, ("fewer trials",), cores=2)
    check_budget(est, limits=Limits(6e9, 7300.0))  # inside both
    with pytest.raises(ConfigError) as err:
        check_budget(est, limits=Limits(4e9, 7300.0))
    assert any("peak memory 5.0 GB" in p and "blocks" in p for p in err.value.problems)
    assert not any("wall time" in p for p in err.value.problems[1:])
    with pytest.raises(ConfigError) as err:
        check_budget(est, limits=Limits(6e9, 3600.0))
    assert any("wall time 2.0 h" in p for p in err.value.problems)
    said = []
    check_budget(est, limits=Limits(1e9, 1.0), allow_large=True, say=said.append)
    assert said and "--allow-large given" in said[0]


def test_the_estimate_grows_as_the_block_arrays_do():
    """Doubling block_trials doubles the blocks' part; trials scale the time, not the memory."""
    base = load_spec("quick-look")
    est = {b: campaign_estimate(load_spec("quick-look", trials=400).__class__(
        base.spec.model_copy(update={"block_trials": b, "chunk_trials": 2 * b, "trials": 2 * b}), base.source,
        base.approaches), workers=1, cores=2) for b in (100, 200)}
    blocks = {b: next(v for k, v in e.memory.items() if k.startswith("draw blocks")) for b, e in est.items()}
    assert blocks[200] == pytest.approx(2 * blocks[100])
    assert est[200].wall_s > est[100].wall_s


@pytest.mark.slow
def test_the_estimate_is_within_a_factor_2_of_a_measured_campaign(tmp_path):
    """quick-look with blocks of 1000 trials, in a fresh process: the estimate against its peak resident set."""
    spec = tmp_path / "s.toml"
    spec.write_text((approaches_dir() / "campaigns" / "quick-look.toml").read_text()
                    .replace('approaches = ["va-raim-2015"]',
                             f'approaches = ["{approaches_dir() / "va-raim-2015.toml"}"]')
                    .replace("block_trials = 100", "block_trials = 1000").replace("chunk_trials = 200",
                                                                                  "chunk_trials = 2000")
                    .replace("trials = 200", "trials = 2000"))
    est = campaign_estimate(load_spec(spec), workers=1, report=False)
    proc = subprocess.Popen([sys.executable, "-m", "testbed.cli", "campaign", str(spec), "--out", str(tmp_path / "o"),
                             "--workers", "1", "--no-report", "--quiet"], cwd=ROOT, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    measured = usage.ru_maxrss * 1024.0
    assert 0.5 < est.peak_bytes / measured < 2.0, (est.memory, measured)


# ----------------------------------------------------------------------------- what `testbed check` computes

DENSE = """
[vision.features]
enabled = true
density_per_km2 = 10000.0
half_width_m = 20000.0
beyond_m = 50000.0
"""


def test_check_does_not_build_the_ground_feature_scene(tmp_path, monkeypatch):
    """A dense corridor (25 million points) is what a run draws, not what a check needs: `testbed check` built
    it (5.7 GB resident, 48 s). The scene is made when a run first reads it."""
    import testbed.sensors.vision.features as features
    import testbed.sim.setup as setup
    from testbed.api import check_file
    from testbed.config import load_approach

    text = (approaches_dir() / "zunz-rwy05-slam.toml").read_text().replace("[vision.features]\nenabled = true", DENSE)
    p = tmp_path / "dense.toml"
    p.write_text(text)
    built = []

    def record(*a, **k):
        built.append(1)
        return np.zeros((1, 3))

    monkeypatch.setattr(features, "corridor_features", record)
    monkeypatch.setattr(setup, "corridor_features", record, raising=False)
    assert check_file(p) == []
    assert built == []
    s = setup.build_setup(load_approach(p), None)
    assert built == [] and s.features.shape == (1, 3) and built == [1]  # made on first read, once
    assert s.features is s.features and built == [1]


def test_the_landmark_id_check_is_linear():
    """80 000 ids: the duplicate search counted each id in the list (quadratic: 100 s)."""
    from testbed.sensors.vision.landmarks import Landmarks

    n = 80_000
    t0 = time.perf_counter()
    Landmarks(id=np.array([f"P{i}" for i in range(n)]), pos_ecef=np.zeros((n, 3)), size_m=np.ones(n))
    assert time.perf_counter() - t0 < 5.0
    with pytest.raises(ValueError, match=r"duplicates \['P1'\]"):
        Landmarks(id=np.array(["P0", "P1", "P1"]), pos_ecef=np.zeros((3, 3)), size_m=np.ones(3))


def test_common_random_numbers_speed_up_only_what_the_cells_share():
    """A DPE fault sweep shares its draws but not its correlograms nor the DPE (they follow each cell's faulted
    pseudoranges): its estimate with common random numbers is within a few per cent of the one without, where
    dividing all of it by the sharing factor made it a third of the measured time."""
    from dataclasses import replace

    from testbed.campaign.budget import SHARED_SPEEDUP

    shared = load_spec("dpe-vs-raim", trials=20)
    alone = replace(shared, spec=shared.spec.model_copy(update={"common_random_numbers": False}))
    assert shared.spec.common_random_numbers
    with_crn, without = (campaign_estimate(x, workers=1, report=False).wall_s for x in (shared, alone))
    assert 0.95 * without < with_crn <= without
    assert with_crn > 2 * without / SHARED_SPEEDUP

"""``python -m testbed.studies.stanford_pair``: a campaign's monitors' Stanford diagrams side by side, over the
cells chosen. Its panels against the stored tables read here: every epoch the histogram holds is one the trials
table places in a region (not alerted, with a solution), per monitor, dimension and cell selection."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest

from testbed.campaign.report import report_inputs
from testbed.campaign.runner import run_campaign
from testbed.campaign.spec import load_spec
from testbed.studies import stanford_pair

SPEC = """name = "orbit-small"
approaches = ["zunz-rwy05-dfmc"]
monitors = ["gps_raim", "araim"]
trials = 4
base_seed = 7
block_trials = 4
chunk_trials = 4
common_random_numbers = true

[sorties]
start = "uniform"
span_s = 86400.0
window_s = 900.0
sortie_s = 40.0

[[faults]]
kind = "constellation_orbit"
system = "galileo"
direction_ecef = [-0.0657, 0.8696, 0.4893]
magnitudes = [0.0, 150.0]
onset_s = 10.0
"""


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("orbit")
    spec = tmp / "orbit-small.toml"
    spec.write_text(SPEC)
    out = tmp / "out"
    run_campaign(load_spec(spec), out, progress=False, workers=1)
    return out


@pytest.mark.slow
def test_the_panels_hold_what_the_tables_place(result):
    inp = report_inputs(result)
    trials = pq.read_table(result / "trials.parquet").to_pydict()
    monitor, cell = np.array(trials["monitor"]), np.array(trials["cell"])
    for cells in ([0, 1], [1]):
        for m in ("gps_raim", "araim"):
            sel = (monitor == m) & np.isin(cell, cells)
            for dim, H, counts, total, al in stanford_pair.monitor_panels(inp, m, cells):
                d = dim.lower()
                assert counts == {r: int(np.sum(np.array(trials[f"{d}_{r}"])[sel])) for r in counts}
                assert total == int(np.sum(np.array(trials["epochs"])[sel])) > 0
                assert H.sum() == total - counts["alerted"] - counts["no_solution"]
                assert al == (40.0 if dim == "H" else 20.0)
    # the 150 m Galileo displacement: ARAIM alerts on it, so its faulty cell plots fewer epochs than it flew
    (_, _, c_araim, _, _), = [p for p in stanford_pair.monitor_panels(inp, "araim", [1]) if p[0] == "V"]
    assert c_araim["alerted"] > 0


@pytest.mark.slow
def test_the_command_draws_and_refuses_what_the_campaign_lacks(result, tmp_path, capsys):
    png = tmp_path / "pair.png"
    assert stanford_pair.main([str(result), str(png), "--monitors", "gps_raim", "araim", "--cells", "1"]) == 0
    assert png.stat().st_size > 10_000
    bad = tmp_path / "bad.png"
    assert stanford_pair.main([str(result), str(bad), "--monitors", "va_raim"]) == 2
    assert stanford_pair.main([str(result), str(bad), "--cells", "9"]) == 2
    err = capsys.readouterr().err
    assert "'va_raim': not in the campaign" in err and "--cells 9: not a cell" in err
    assert not bad.exists()

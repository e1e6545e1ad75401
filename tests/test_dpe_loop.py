"""The DPE monitor in the loop: testbed fly with correlators, live blocks = one flight, its recording tab,
and a campaign with it."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from testbed.api import load_approach, run_approach
from testbed.resources import approaches_dir
from testbed.viz import readback


def _short():
    ap = load_approach("zunz-rwy05-dpe")
    cfg = ap.config.model_copy(update={"flight": ap.config.flight.model_copy(update={"start_distance_m": 3000.0})})
    return dataclasses.replace(ap, config=cfg)


def test_block_by_block_equals_one_flight_and_the_recording_has_the_dpe_tab(tmp_path):
    """Correlators drawn per epoch and the DPE's carried fix: 2 s and 7 s blocks give bit-identical
    outputs; every epoch is available with its vertical error inside the VPL; the recording holds
    the VPL, the overbound and the error density the VPL bounds."""
    a = run_approach(_short(), seed=3, rrd_path=tmp_path / "a.rrd", block_s=2.0)
    b = run_approach(_short(), seed=3, rrd_path=None, block_s=7.0)
    oa, ob = a.outputs["dpe"], b.outputs["dpe"]
    for f in ("pos_enu", "vpl", "test_stat", "clock"):
        np.testing.assert_array_equal(getattr(oa, f), getattr(ob, f), err_msg=f)
    np.testing.assert_array_equal(oa.diagnostics.marginal, ob.diagnostics.marginal)
    shipped = json.loads((approaches_dir() / "calibration" / "dpe-k.json").read_text())
    assert oa.diagnostics.k_factor == shipped["k"] and shipped["validation"]["passed"]  # the calibrated K, read
    s = a.summaries["dpe"]
    assert (oa.reason == 0).all() and s.mi_epochs == 0 and s.hmi_epochs == 0
    assert np.all(np.isnan(oa.hpl)) and np.isnan(s.hpl_max)
    t, v = readback.scalar_series(a.rrd_path, "integrity/dpe/vertical/vpl")
    np.testing.assert_allclose(v, oa.vpl, rtol=1e-6)
    t, v = readback.scalar_series(a.rrd_path, "integrity/dpe/overbound/sigma_ob")
    np.testing.assert_allclose(v, oa.diagnostics.sigma_ob, rtol=1e-6)
    assert "/integrity/dpe/vertical_error_density" in readback.entity_paths(a.rrd_path)
    views = {(v["class"], v["origin"]) for v in readback.views(a.rrd_path)}
    assert ("BarChart", "/integrity/dpe/vertical_error_density") in views
    assert ("TimeSeries", "/integrity/dpe/overbound") in views
    assert ("TimeSeries", "/integrity/dpe/horizontal") not in views  # vertical only: no HPL plot


SPEC = """
name = "dpe-tiny"
approaches = ["zunz-rwy05-dpe"]
monitors = ["gps_raim", "dpe"]
trials = 4
block_trials = 2
chunk_trials = {chunk}
base_seed = 11
per_epoch_trials = 2
duration_s = 25.0

[[faults]]
kind = "gps_step"
magnitudes = [0.0, 60.0]
onset_s = 10.0
prn = "random"
"""


@pytest.mark.slow  # moved out of the default set: its run time (the default set stays within 8 min)
def test_a_campaign_runs_the_dpe_beside_gps_raim_on_the_same_fault(tmp_path):
    """Correlograms synthesised per trial inside the block: chunking does not change a bit; fault-free, the
    DPE has no misleading epoch; under a 60 m step GPS RAIM alerts while the DPE, which detects nothing,
    is misled (its VPL is not fault tolerant: the report's per-cell MI/HMI table shows it)."""
    import pyarrow.parquet as pq

    from testbed.campaign.runner import run_campaign

    outs = []
    for chunk in (2, 4):
        spec = tmp_path / f"s{chunk}.toml"
        spec.write_text(SPEC.format(chunk=chunk))
        run_campaign(spec, tmp_path / f"out{chunk}", progress=False)
        outs.append(pq.read_table(tmp_path / f"out{chunk}" / "trials.parquet").to_pandas())
    a, b = outs
    assert a.equals(b)
    dpe, raim = a[a.monitor == "dpe"], a[a.monitor == "gps_raim"]
    assert (dpe[dpe.cell == 0].mi_epochs == 0).all() and dpe["avail_APV-I"].min() > 0.9
    assert raim[raim.cell == 1].detected.all() and not dpe.detected.any()
    assert dpe[dpe.cell == 1].mi_epochs.sum() > 0
    from testbed.campaign.report import write_report

    report = write_report(tmp_path / "out2").read_text()
    assert "## Misleading information per cell" in report and "| dpe |" in report
    # paired on the same epochs: A only − B only = A's available epochs − B's, sortie by sortie
    d_s, r_s = dpe.sort_values(["cell", "trial"]), raim.sort_values(["cell", "trial"])
    T = int(a.epochs.iloc[0])
    for lv in ("APV-I", "APV-II"):
        diff = d_s[f"only_available_vs_gps_raim_{lv}"].to_numpy() - r_s[f"only_available_vs_dpe_{lv}"].to_numpy()
        np.testing.assert_array_equal(diff, np.round(d_s[f"avail_{lv}"].to_numpy() * T)
                                      - np.round(r_s[f"avail_{lv}"].to_numpy() * T))
    assert (a.four_sat_epochs >= 0).all()
    assert "## The monitors paired on the same epochs" in report and "McNemar" in report
    pl_table = report.split("## Protection levels")[1].split("\n## ")[0]
    assert "only_available" not in pl_table and "APV-II |" in pl_table  # levels only, not the pairing counts


def test_mcnemar_exact_p_against_closed_forms():
    from testbed.campaign.report import mcnemar_p

    assert mcnemar_p(0, 5) == 2 * 0.5**5  # all 5 discordant one way
    assert mcnemar_p(3, 3) == 1.0 and mcnemar_p(0, 0) == 1.0
    assert abs(mcnemar_p(2, 10) - 2 * sum(__import__("math").comb(12, k) for k in range(3)) / 2**12) < 1e-15


def test_the_multipath_strength_axis_sets_the_correlators_echo(tmp_path):
    """``sweep.multipath_echo_db``: one cell per value, the correlators' ground echo on at that amplitude
    ('off': none), recorded in the cells table; a bad value is refused naming the key."""
    from testbed.campaign.spec import expand_cells, load_spec
    from testbed.schema import ConfigError

    spec = tmp_path / "mp.toml"
    spec.write_text(SPEC.format(chunk=2).replace("magnitudes = [0.0, 60.0]", "magnitudes = [0.0]")
                    + '\n[sweep]\nmultipath_echo_db = ["off", -20.0, -6.0]\n')
    cells = expand_cells(load_spec(spec))
    assert [c.params["multipath_echo_db"] for c in cells][1:] == [-20.0, -6.0]
    assert np.isnan(cells[0].params["multipath_echo_db"])
    got = [(c.approach.config.gnss.correlators.multipath, c.approach.config.gnss.correlators.ground_echo_db)
           for c in cells]
    assert got[0][0] == "off" and got[1] == ("ground", -20.0) and got[2] == ("ground", -6.0)
    bad = tmp_path / "bad.toml"
    bad.write_text(SPEC.format(chunk=2) + '\n[sweep]\nmultipath_echo_db = [3.0]\n')
    with pytest.raises(ConfigError, match="multipath_echo_db"):
        load_spec(bad)


def test_a_campaign_can_fly_the_last_segment_of_the_final(tmp_path):
    """``segment = "last"``: the sorties fly the last duration_s down to the threshold, their time from 0 (the
    height above ground falls to the threshold's ~15 m; the first segment starts ~700 m up)."""
    from testbed.campaign.context import cell_context
    from testbed.campaign.spec import expand_cells, load_spec

    spec = tmp_path / "last.toml"
    text = SPEC.format(chunk=2).replace("duration_s = 25.0", 'duration_s = 25.0\nsegment = "last"')
    spec.write_text(text)
    loaded = load_spec(spec)
    ctx = cell_context(expand_cells(loaded)[0], loaded.spec)
    t, agl = ctx.truth_g.t, ctx.truth_g.agl
    assert t[0] == 0.0 and abs(t[-1] - 25.0) < 1.0 and agl[-1] < 30.0 and agl[0] < 150.0
    first = tmp_path / "first.toml"
    first.write_text(SPEC.format(chunk=2))
    lf = load_spec(first)
    assert cell_context(expand_cells(lf)[0], lf.spec).truth_g.agl[0] > 500.0


def test_the_dpe_variant_axis_runs_the_seed_over_sorties_beside_the_likelihood(tmp_path):
    """``sweep.dpe_variant``: a 'seed' cell's receiver reports the seed's magnitude statistic (exact
    synthesis; the monitor refuses any other) and its K is Q⁻¹(P/2) = 5.33 at P = 1e-7; a 'likelihood' cell
    keeps the approach's calibrated K. In the loop the seed's VPL is set by its ±110 m grid
    (docs/design/dpe.md F2: ~6× the likelihood's here, measured 322 m against 12.7 m over 10 sorties); a bad variant is refused naming the key."""
    import pyarrow.parquet as pq

    from testbed.campaign.runner import run_campaign
    from testbed.campaign.spec import expand_cells, load_spec
    from testbed.integrity.dpe.calibration import gaussian_k
    from testbed.schema import ConfigError

    assert gaussian_k(1e-7) == pytest.approx(5.3267, abs=1e-4)
    text = (SPEC.format(chunk=2).replace("magnitudes = [0.0, 60.0]", "magnitudes = [0.0]")
            .replace("trials = 4", "trials = 2").replace("duration_s = 25.0", "duration_s = 4.0")
            + '\n[sweep]\ndpe_variant = ["likelihood", "seed"]\n')
    spec = tmp_path / "v.toml"
    spec.write_text(text)
    cells = expand_cells(load_spec(spec))
    assert [c.params["dpe_variant"] for c in cells] == ["likelihood", "seed"]
    lik, seed = (c.approach.config for c in cells)
    assert (seed.gnss.correlators.statistic, seed.gnss.correlators.synthesis) == ("mag", "exact")
    assert seed.monitor["dpe"].variant == "seed" and seed.monitor["dpe"].k_factor == gaussian_k(1e-7)
    assert lik.gnss.correlators.statistic == "pow" and isinstance(lik.monitor["dpe"].k_factor, str)  # the record
    run_campaign(spec, tmp_path / "out", progress=False)
    t = pq.read_table(tmp_path / "out" / "trials.parquet").to_pandas()
    vpl = t[t.monitor == "dpe"].groupby("cell").max_vpl.median()
    assert np.isfinite(vpl).all() and vpl[1] > 4 * vpl[0], vpl
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('"seed"]', '"paper"]'))
    with pytest.raises(ConfigError, match="dpe_variant"):
        load_spec(bad)

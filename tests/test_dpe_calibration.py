"""K calibration of the DPE's VPL (docs/design/dpe.md §6, §10 C1-C3): known σ recovered, the seed's estimator's
refusal, held-out validation catching an under-calibrated K, and the record the monitor reads."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from testbed.integrity.dpe.calibration import (fit_k_quantile, fit_k_tail, read_k_file, settings_fingerprint,
                                               validate)
from testbed.integrity.dpe.monitor import DpeSettings
from testbed.sensors.gnss.settings import CorrelatorSettings


@pytest.mark.parametrize("s", [1.0, 2.5])
def test_a_known_sigma_is_recovered_from_a_million_samples(s):
    """C1: z ~ N(0, s²), N = 1e6: σ_z/s in [1.00, 1.05] (the Clopper-Pearson margin makes it conservative)."""
    z = np.random.default_rng(int(10 * s)).normal(0.0, s, 1_000_000)
    f = fit_k_tail(z, 1e-7)
    assert 1.0 <= f.sigma_z / s <= 1.05
    assert abs(f.k - f.sigma_z * 5.3267 - abs(f.b_z)) < 1e-3  # Q⁻¹(5e-8) = 5.3267


def test_an_offset_core_and_heavy_tails():
    """C2: N(0.3, 1.5²) -> b_z 0.30, σ_z 1.53, K 8.46 (the Gaussian K 8.29); t₅ needs σ_z ≈ 2× its sd."""
    rng = np.random.default_rng(2)
    f = fit_k_tail(rng.normal(0.3, 1.5, 1_000_000), 1e-7)
    assert abs(f.b_z - 0.3) < 0.01 and 1.50 <= f.sigma_z <= 1.56 and 8.2 < f.k < 8.7
    t5 = rng.standard_t(5, 1_000_000)
    ft = fit_k_tail(t5, 1e-7)
    assert ft.sigma_z > 1.9 * t5.std()


def test_the_seed_estimator_refuses_too_few_samples_and_matches_the_quantile():
    """C3: the empirical K needs N·P ≥ 10; with enough, it is the (1 − P) quantile of |z|."""
    z = np.random.default_rng(3).normal(size=200_000)
    with pytest.raises(ValueError, match="N·P"):
        fit_k_quantile(z, 1e-7)
    f = fit_k_quantile(z, 1e-4)
    assert abs(f.k - 3.89) < 0.15 and np.mean(np.abs(z) > f.k) <= 1e-4


def test_held_out_validation_passes_a_good_k_and_fails_an_under_calibrated_one():
    rng = np.random.default_rng(4)
    fit = fit_k_tail(rng.normal(size=50_000), 1e-7)
    good = rng.normal(size=50_000)
    assert validate(fit, good, np.zeros(good.size, bool)).passed
    wide = rng.normal(0.0, 1.4, 50_000)  # the truth is wider than the calibration said
    v = validate(fit, wide, np.abs(wide) > fit.k)
    assert not v.tails_hold and not v.passed and v.worst_ratio > 1.0


def test_the_record_is_read_only_for_the_settings_it_was_made_for(tmp_path):
    s, c = DpeSettings(k_factor=1.0), CorrelatorSettings()
    fp, cover = settings_fingerprint(s, c)
    p = tmp_path / "k.json"
    p.write_text(json.dumps({"k": 5.9, "settings": cover, "fingerprint": fp, "p_hmi": 1e-7, "n": 5000}))
    assert read_k_file(p, cover) == 5.9
    other = settings_fingerprint(DpeSettings(k_factor=1.0, sis="none"), CorrelatorSettings(n_noncoherent=20))[1]
    with pytest.raises(ValueError, match=r"dpe.sis = 'add' there, 'none' here.*n_noncoherent = 50 there, 20 here"):
        read_k_file(p, other)
    p.write_text("not json")
    with pytest.raises(ValueError, match="cannot be read"):
        read_k_file(p, cover)


@pytest.mark.parametrize("change, message", [
    ({"k": True}, "k = True: expected a number from 0.5 to 100"),
    ({"k": "5.9"}, "k = '5.9'"), ({"k": -1.0}, "k = -1.0"), ({"k": float("nan")}, "k = nan"),
    ({"settings": {}}, "expected the tables 'dpe' and 'correlators'"),
    ({"settings": {"dpe": {}, "correlators": {}}}, "expected the tables"),
    ({"fingerprint": "0000000000000000"}, "does not match its settings"),
    ({"p_hmi": 2.0}, "p_hmi = 2.0"), ({"n": 1.5}, "n = 1.5"), ({"n": False}, "n = False"),
])
def test_a_stored_k_record_is_validated_like_an_input(tmp_path, change, message):
    """A record whose K is a boolean and whose settings table is empty used to pass (K = 1, a VPL of 2 m
    and misleading epochs with no alert): kinds, ranges, the whole settings and its fingerprint are checked."""
    s, c = DpeSettings(k_factor=1.0), CorrelatorSettings()
    fp, cover = settings_fingerprint(s, c)
    rec = {"k": 5.9, "settings": cover, "fingerprint": fp, "p_hmi": 1e-7, "n": 5000, **change}
    p = tmp_path / "k.json"
    p.write_text(json.dumps(rec))
    with pytest.raises(ValueError, match=re.escape(message)):
        read_k_file(p, cover)


def test_a_record_that_does_not_say_a_setting_it_was_fitted_for_is_refused(tmp_path):
    s, c = DpeSettings(k_factor=1.0), CorrelatorSettings()
    fp, cover = settings_fingerprint(s, c)
    older = json.loads(json.dumps(cover))
    del older["dpe"]["sis"]  # a record written before the option existed
    import hashlib

    fp_old = hashlib.sha256(json.dumps(older, sort_keys=True).encode()).hexdigest()[:16]
    p = tmp_path / "k.json"
    p.write_text(json.dumps({"k": 5.9, "settings": older, "fingerprint": fp_old, "p_hmi": 1e-7, "n": 5000}))
    with pytest.raises(ValueError, match="dpe.sis missing there, 'add' here"):
        read_k_file(p, cover)


def test_the_shipped_k_records_are_valid():
    from testbed.integrity.dpe.calibration import record_problems
    from testbed.resources import approaches_dir

    for path in sorted((approaches_dir() / "calibration").glob("*.json")):
        assert record_problems(json.loads(path.read_text())) == [], path.name
    assert fit_k_tail(np.random.default_rng(0).normal(size=5000), 1e-7).n_eff == 5000
    with pytest.raises(ValueError, match="N_eff"):
        fit_k_tail(np.random.default_rng(0).normal(size=900), 1e-7)


@pytest.mark.slow
def test_calibrate_dpe_end_to_end_even_when_the_approach_names_a_stale_record(tmp_path):
    """7 + 7 sorties of the shipped DPE approach, whose k_factor names a record made for other settings
    (the usual state right after a settings change): the calibration ignores it, fits, validates, and
    its record is readable for the settings it was made for."""
    from testbed.studies.dpe_calibration import calibrate_dpe, write_record
    from testbed.resources import approaches_dir

    text = (approaches_dir() / "zunz-rwy05-dpe.toml").read_text()
    (tmp_path / "stale.json").write_text(json.dumps({"k": 5.0, "settings": {"dpe": {"sis": "none"}}}))
    ap = tmp_path / "dpe.toml"
    ap.write_text(text.replace('k_factor = "calibration/dpe-k.json"', 'k_factor = "stale.json"'))
    rec = calibrate_dpe(ap, sorties=7)
    assert rec["n_calibration"] > 1000 and rec["validation"]["epochs"] > 1000
    assert 4.5 < rec["k"] < 9.0 and 0.8 < rec["sigma_z"] < 1.6
    write_record(rec, tmp_path / "k.json")
    s = DpeSettings.model_validate({"k_factor": 1.0, "sis": "add"})
    assert read_k_file(tmp_path / "k.json", settings_fingerprint(s, CorrelatorSettings())[1]) == rec["k"]


def test_the_sortie_plan_keeps_one_trajectorys_order_and_balances_three():
    from testbed.studies.dpe_calibration import CN0_OFFSETS_DB, MULTIPATH, sortie_plan

    for j in range(40):  # one trajectory: the plan the shipped record was made with
        assert sortie_plan(j, 40, 1) == (0, j * 2160.0, CN0_OFFSETS_DB[j % 3], MULTIPATH[(j // 3) % 2],
                                         j % 3 + 3 * ((j // 3) % 2))
    plan = [sortie_plan(j, 180, 3, 240.0) for j in range(180)]
    pairs = {(t, s) for t, _, _, _, s in plan}
    assert len(pairs) == 18  # every trajectory meets every C/N0 x multipath stratum, 10 times each
    assert all(sum(1 for t, _, _, _, s in plan if (t, s) == p) == 10 for p in pairs)
    assert plan[1][1] - plan[0][1] == 480.0 and plan[0][1] == 240.0


def test_vdop_of_a_zenith_satellite_and_three_on_the_horizon():
    """Closed form: zenith + three at 0 deg elevation 120 deg apart: VDOP = 2/sqrt(3)."""
    from testbed.studies.dpe_calibration import vdop
    from testbed.frames import LocalFrame

    f = LocalFrame(29.3, 94.3, 2939.0)
    az = np.radians([0.0, 120.0, 240.0])
    enu = np.r_[[[0.0, 0.0, 2e7]], np.c_[2e7 * np.sin(az), 2e7 * np.cos(az), np.zeros(3)]]
    sats = f.enu_to_ecef(enu)[None]
    ant = f.enu_to_ecef(np.zeros(3))[None]
    assert vdop(f, sats, np.ones((1, 4), bool), ant) == pytest.approx(2 / np.sqrt(3), rel=1e-9)
    assert np.isnan(vdop(f, sats, np.array([[True, True, True, False]]), ant)[0])


def test_strata_cover_the_set_and_name_what_they_hold():
    from testbed.studies.dpe_calibration import strata

    rng = np.random.default_rng(1)
    n = 3000
    c = {"stratum": rng.integers(0, 6, n), "trajectory": rng.integers(0, 3, n), "n_sat": rng.integers(4, 11, n),
         "vdop": rng.uniform(0.8, 3.0, n)}
    st = strata(c, ("a.toml", "b.toml", "c.toml"))
    groups = [[k for k in st if k.startswith(p)] for p in ("cn0", "trajectory", "satellites", "VDOP")]
    assert [len(g) for g in groups] == [6, 3, 3, 3] and "trajectory b" in st
    for g in groups:  # each family partitions the set
        assert (sum(st[k].astype(int) for k in g) >= 1).all()
        assert sum(int(st[k].sum()) for k in g) <= n + 2  # VDOP tercile bounds are shared by two strata
    assert abs(int(st[groups[3][0]].sum()) - n / 3) <= 1
    assert len(strata(c, ("a.toml",))) == 12  # one trajectory: no trajectory strata


@pytest.mark.slow  # moved out of the default set: its run time (the default set stays within 8 min)
def test_a_chunked_killed_and_resumed_calibration_equals_one_run(tmp_path):
    """6 + 6 sorties of the DPE's settings on the VA-RAIM paper's sortie (61 epochs each): chunks of 2 stopped after
    3 chunks and resumed from the work folder give the sets one chunk of 6 gives, bit for bit."""
    from testbed.studies.dpe_calibration import CalibrationRun, run_chunks
    from testbed.config import resolve_approach

    src, traj = str(resolve_approach("zunz-rwy05-dpe")), str(resolve_approach("va-raim-2015"))
    whole = run_chunks(CalibrationRun(src, (traj,), 6, 3, 6))
    run = CalibrationRun(src, (traj,), 6, 3, 2)
    assert run_chunks(run, work=tmp_path / "w", max_chunks=3) is None
    assert len(list((tmp_path / "w").glob("c*.npz"))) == 3
    (tmp_path / "w" / "c0-00001.npz").write_bytes(b"damaged")  # computed again
    again = run_chunks(run, work=tmp_path / "w", resume=True)
    for name in ("calibration", "validation"):
        assert whole[name].keys() == again[name].keys()
        for k in whole[name]:
            assert np.array_equal(whole[name][k], again[name][k], equal_nan=True), (name, k)
    assert whole["calibration"]["z"].size > 300 and set(np.unique(whole["calibration"]["stratum"])) == set(range(6))

"""Sorties spread over a span: start offsets, sky windows, their error bounds, and determinism.

References: the geometry computed exactly at each sortie's own start time (no window),
and the campaign run at other chunk sizes and thread counts.
"""

from __future__ import annotations

import numpy as np
import pytest

from test_campaign import TINY

from testbed.campaign import context
from testbed.campaign.sorties import n_windows, sky_windows, sortie_offsets, window_offsets
from testbed.campaign.spec import SKY_REPEAT_S, expand_cells, load_spec
from testbed.schema import ConfigError
from testbed.sensors.gnss.synth import gnss_geometry

def spec_text(trials: int, chunk: int, sorties: str) -> str:
    """test_campaign's tiny spec (GPS RAIM + VA-RAIM, a 60 m step), with these trials and sorties."""
    return (TINY.format(chunk=chunk, monitors='["gps_raim", "va_raim"]').replace("trials = 40", f"trials = {trials}")
            + f"\n[sorties]\n{sorties}\n")


def write(tmp_path, sorties='start = "consecutive"\nsortie_s = 60.0', trials=40, chunk=20, name="span.toml"):
    p = tmp_path / name
    p.write_text(spec_text(trials, chunk, sorties))
    return p


def test_consecutive_and_uniform_offsets_are_pure_functions_of_the_trial(tmp_path):
    spec = load_spec(write(tmp_path)).spec
    np.testing.assert_array_equal(sortie_offsets(spec, [0, 1, 39]), [0.0, 60.0, 2340.0])
    uni = load_spec(write(tmp_path, 'start = "uniform"\nsortie_s = 60.0\nspan_s = 864000.0', name="u.toml")).spec
    all_ = sortie_offsets(uni, np.arange(40))
    np.testing.assert_array_equal(sortie_offsets(uni, [17, 3]), all_[[17, 3]])  # any subset, any order
    assert (all_ >= 0).all() and (all_ <= 864000.0 - 60.0).all() and np.unique(all_).size == 40
    fixed = load_spec(write(tmp_path, 'start = "fixed"', name="f.toml")).spec
    assert (sortie_offsets(fixed, np.arange(5)) == 0).all()


def test_window_phase_error_is_at_most_half_a_window():
    """Every offset's phase (mod the repeat period) is within window_s / 2 (+ the grid's
    rounding at the period's end) of the phase its window's geometry is computed at."""
    off = np.linspace(0.0, 6e6, 100_001)
    for window in (60.0, 7.0):
        w = sky_windows(off, window)
        assert w.min() >= 0 and w.max() < n_windows(window)
        phase = np.mod(off, SKY_REPEAT_S)
        err = np.abs(phase - window_offsets(w, window))
        err = np.minimum(err, SKY_REPEAT_S - err)  # window 0 also serves the period's end
        slack = abs(SKY_REPEAT_S - n_windows(window) * window)
        assert err.max() <= window / 2 + slack + 1e-6
    assert n_windows(60.0) == 1436


@pytest.fixture(scope="module")
def span_context(tmp_path_factory):
    d = tmp_path_factory.mktemp("span")
    loaded = load_spec(write(d, trials=1500, chunk=10))
    cell = expand_cells(loaded)[0]
    return loaded.spec, context.cell_context(cell, loaded.spec), cell


def test_sorties_of_different_windows_fly_different_skies(span_context):
    spec, ctx, _ = span_context
    assert ctx.sky is not None and ctx.sky.size == 1436  # 1500 sorties of 60 s wrap the repeat period once
    w = sky_windows(sortie_offsets(spec, [0, 360]), 60.0)  # six hours apart
    g = ctx.gnss_geometry_of(w)
    assert (g.visible[0] != g.visible[1]).any()
    assert np.abs(g.sat_pos_ecef[0] - g.sat_pos_ecef[1]).max() > 1e6


def test_sorties_one_repeat_apart_share_a_sky_that_matches_their_own_to_the_bound(span_context):
    """Trials 0 and 1436 fall in one window: the same geometry (to the bit); the geometry
    computed exactly at the later sortie's own start differs by less than the stated
    0.044° per period plus the 30 s phase error (0.22°)."""
    spec, ctx, cell = span_context
    w = sky_windows(sortie_offsets(spec, [0, 1436]), 60.0)
    assert w[0] == w[1]
    g = ctx.gnss_geometry_of(w)
    np.testing.assert_array_equal(g.sat_pos_ecef[0], g.sat_pos_ecef[1])
    s = ctx.setup
    truth = context.cached(("truth_g", context._flight_key(cell), s.gnss.rate_hz, spec.duration_s, spec.segment),
                           lambda: None)
    own = gnss_geometry(truth, s.antenna, s.gnss, start_utc=cell.config.start_time_utc, terrain=context.cell_terrain(cell),
                        constellation=ctx.g_geom.eph, offsets_s=sortie_offsets(spec, [1436]))  # one almanac, propagated
    up = g.visible[1] & own.visible[0]
    assert up.sum() > 100
    assert np.degrees(np.abs(g.elevation[1] - own.elevation[0]))[up].max() < 0.044 + 0.22


def test_span_results_do_not_depend_on_chunks_or_threads(tmp_path):
    from test_campaign import same, table

    from testbed.campaign.runner import run_campaign

    run_campaign(write(tmp_path, chunk=20), tmp_path / "a", progress=False)
    run_campaign(write(tmp_path, chunk=10, name="b.toml"), tmp_path / "b", progress=False)
    a, b = table(tmp_path / "a"), table(tmp_path / "b")
    assert same(a, b)
    t = a.to_pydict()
    assert sorted(set(t["start_offset_s"]))[:3] == [0.0, 60.0, 120.0] and len(set(t["sky_window"])) == 40
    # detection still works under the moving sky: the 60 m step is caught in most sorties
    det = np.asarray(t["detected"])[(np.asarray(t["cell"]) == 1) & (np.asarray(t["monitor"]) == "gps_raim")]
    assert det.mean() > 0.8


@pytest.mark.parametrize("sorties, where, expected", [
    ('start = "uniform"\nsortie_s = 60.0', "sorties", "span_s"),
    ('start = "uniform"\nsortie_s = 60.0\nspan_s = 30.0', "sorties", "shorter than one sortie"),
    ('start = "consecutive"\nsortie_s = -1.0', "sorties.sortie_s", "greater than 0"),
    ('start = "sometimes"', "sorties.start", "consecutive"),
    ('start = "fixed"\nspan_s = 600.0', "sorties.span_s", "read only with start = 'uniform', not with start = 'fixed'"),
    # a key the mode does not read is refused, as span_s always was, never silently ignored
    ('start = "fixed"\nsortie_s = 60.0', "sorties.sortie_s",
     "read only with start = 'consecutive' or 'uniform', not with start = 'fixed'"),
    ('start = "fixed"\nwindow_s = 600.0', "sorties.window_s",
     "read only with start = 'consecutive' or 'uniform', not with start = 'fixed'"),
    ('start = "consecutive"\nsortie_s = 60.0\nspan_s = 600.0', "sorties.span_s",
     "read only with start = 'uniform', not with start = 'consecutive'"),
    ('start = "consecutive"\nsortie_s = 60.0\nwindow_s = nan', "sorties.window_s", "finite number"),
    ('start = "consecutive"\nsortie_s = "60"', "sorties.sortie_s", "not a string"),
])
def test_bad_sortie_settings_name_the_key(tmp_path, sorties, where, expected):
    p = write(tmp_path, sorties)
    with pytest.raises(ConfigError) as ei:
        load_spec(p)
    msg = str(ei.value)
    assert str(p) in msg and where in msg and expected in msg, msg


def test_a_span_shorter_than_the_flight_is_refused(tmp_path):
    text = spec_text(10, 10, 'start = "uniform"\nspan_s = 20.0')  # duration_s = 40
    p = tmp_path / "short.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match="shorter than one sortie"):
        load_spec(p)

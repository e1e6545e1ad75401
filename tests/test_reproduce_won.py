"""``testbed reproduce won-2013``: the signal-in-space error its cases draw (time-correlated by default, white on
request) and the argument check."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.schema import ConfigError
from testbed.studies.reproduce_won import PRNS, SIS_TAU_S, _gnss_settings, reproduce_won_2013, won_scene


def _lag1(tau):
    from testbed.sensors.gnss.synth import sample_gnss

    scene = won_scene(duration_s=40.0)
    _, truth = sample_gnss(scene.gnss_geom, _gnss_settings(True, tau), rng=np.random.default_rng(3), n_trials=400)
    i = [int(np.flatnonzero(np.asarray(scene.gnss_geom.prn) == p)[0]) for p in PRNS]
    e = np.asarray(truth.noise)[:, :, i]  # (B, T, 3)
    x = (e - e.mean(0)).reshape(e.shape[0], e.shape[1], -1)
    return float(np.sum(x[:, 1:] * x[:, :-1]) / np.sqrt(np.sum(x[:, 1:] ** 2) * np.sum(x[:, :-1] ** 2)))


def test_the_cases_draw_the_sis_error_correlated_by_default_and_white_on_request():
    """Lag-1 correlation of the drawn pseudorange errors of the three satellites: the URA + troposphere share
    (σ_URA 1.5 m against the ~0.5 m white receiver terms at these elevations) carries exp(−1/τ) ≈ 1, so the
    correlation is that share of the variance, far from the white draw's 0."""
    corr, white = _lag1(SIS_TAU_S), _lag1(None)
    assert abs(white) < 0.05
    assert corr > 0.7


def test_a_bad_correlation_time_is_refused_before_any_work(tmp_path):
    with pytest.raises(ConfigError, match="sis_tau_s"):
        reproduce_won_2013(tmp_path / "x", trials=1, sis_tau_s=-5.0)
    assert not (tmp_path / "x").exists()

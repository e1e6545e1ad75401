"""Pseudoranges from the correlograms (``pseudorange_source = "correlator"``): the peak estimator against the
closed-form correlation and the Cramér-Rao bound, and GPS RAIM reading the DPE's own signal in the loop."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from testbed.api import load_approach, run_approach
from testbed.correlation import amplitude_sq, correlation, crb_delay_sigma
from testbed.sensors.gnss.code_tracking import peak_delays
from testbed.sensors.gnss.correlators import delay_grid, epoch_statistic
from testbed.sensors.gnss.settings import CorrelatorSettings


def _corr(stat, grid):
    return SimpleNamespace(stat=stat[None], delay0_m=grid.delay0_m, delay_step_m=grid.step_m,
                           visible=np.ones((1, stat.shape[0]), bool))


def test_peak_of_the_noise_free_correlogram_is_the_delay():
    """R_B² sampled on the 2 m grid, true delays across a grid cell: the parabola's bias (measured 0.04 mm at
    the shipped b = 1, 0.11 mm at b = 2, 1.4 mm at b = 8 where the peak nears the triangle's cusp) stays
    two orders below the code noise (0.3-2 m at b = 1, 0.1-0.7 m at b = 8)."""
    grid = delay_grid(CorrelatorSettings())
    true = np.linspace(-1.5, 1.5, 61)
    for b, bound in ((1.0, 1e-4), (2.0, 3e-4), (8.0, 2e-3)):
        stat = correlation(grid.offsets[None, :] - true[:, None], b) ** 2
        assert np.abs(peak_delays(_corr(stat, grid))[0] - true).max() < bound


@pytest.mark.parametrize("synthesis, cn0, n, statistic", [
    ("fast", 35.0, 4000, "pow"), ("fast", 45.0, 4000, "pow"), ("fast", 50.0, 4000, "pow"),
    pytest.param("exact", 45.0, 2000, "pow", marks=pytest.mark.slow),
    pytest.param("exact", 35.0, 2000, "mag", marks=pytest.mark.slow)])
def test_peak_delay_spread_is_the_cramer_rao_bound(synthesis, cn0, n, statistic):
    """n channels: the peak's sd against √J (chi-square 99 % band of the ratio: ±2.58/√(2n), 2.9 % for
    n = 4000), plus 1 % for the non-coherent estimator's excess at 35 dB-Hz; its mean within 3 standard
    errors of zero. Measured ratios 1.002-1.028. The seed's magnitude statistic (1/N_b)Σ|y_b| (a DPE
    'seed' cell's receiver) peaks as tightly: measured 1.022 at 35 dB-Hz."""
    cs = CorrelatorSettings(synthesis=synthesis, statistic=statistic)
    grid = delay_grid(cs)
    A = float(np.sqrt(amplitude_sq(cn0, cs.coherent_s)))
    rng = np.random.default_rng(int(cn0) + (0 if synthesis == "fast" else 100))
    true = rng.uniform(-3.0, 3.0, n)
    stat = epoch_statistic(rng, cs, grid, np.full(n, A), true, np.zeros(n), np.zeros(n),
                           np.zeros((n, cs.n_noncoherent)))
    e = peak_delays(_corr(stat, grid))[0] - true
    crb = float(crb_delay_sigma(A**2, cs.n_noncoherent, cs.bandwidth_chips))
    ratio = e.std(ddof=1) / crb
    print(f"\n{synthesis} {cn0:g} dB-Hz: sd/CRB {ratio:.3f}, mean {e.mean():+.3f} m (se {e.std() / np.sqrt(n):.3f})")
    assert abs(ratio - 1.0) < 2.58 / np.sqrt(2 * n) + 0.01
    assert abs(e.mean()) < 3 * e.std() / np.sqrt(n)


def _short(source: str, multipath: str = "off", start_m: float = 3000.0):
    ap = load_approach("zunz-rwy05-dpe")
    g = ap.config.gnss
    corr = g.correlators.model_copy(update={"pseudorange_source": source, "multipath": multipath})
    cfg = ap.config.model_copy(update={"flight": ap.config.flight.model_copy(update={"start_distance_m": start_m}),
                                       "gnss": g.model_copy(update={"correlators": corr}),
                                       "monitors": ["gps_raim", "dpe"]})
    return dataclasses.replace(ap, config=cfg)


def test_gps_raim_reads_the_signal_the_dpe_sees():
    """With correlator pseudoranges every GPS RAIM range error is the correlators' SIS draw plus a code error
    whose spread is the Cramér-Rao bound at the channel's C/N0; the σ it is told bounds the error; blocks of
    2 s and 7 s give bit-identical runs."""
    a = run_approach(_short("correlator", start_m=8000.0), seed=5, rrd_path=None, block_s=2.0)
    b = run_approach(_short("correlator", start_m=8000.0), seed=5, rrd_path=None, block_s=7.0)
    for f in ("pos_enu", "hpl", "vpl", "test_stat"):
        np.testing.assert_array_equal(getattr(a.outputs["gps_raim"], f), getattr(b.outputs["gps_raim"], f))
    np.testing.assert_array_equal(a.outputs["dpe"].vpl, b.outputs["dpe"].vpl)
    g, gt = a.loop.gnss, a.loop.gnss_truth
    vis = np.asarray(g.visible)
    err = (np.asarray(g.pseudorange) - gt.geometric_range - gt.clock_bias[:, None] - gt.fault_bias)[vis]
    np.testing.assert_allclose(err, np.asarray(gt.noise)[vis], atol=1e-6)
    # the correlators' own truth: the same SIS; what is left is the code loop's error
    from testbed.sensors.gnss.correlators import synthesize_correlators
    from testbed.sim.pipeline import correlator_words
    from testbed.sim.streams import StreamTree

    model = run_approach(_short("model", start_m=8000.0), seed=5, rrd_path=None)
    corr, ctruth = synthesize_correlators(model.loop.gnss, model.loop.gnss_truth, model.loop.truth_at_gnss,
                                          _short("model").config.gnss,
                                          correlator_words(StreamTree.of_run(5)))
    sis = np.asarray(ctruth.sis_m)[vis]
    a2 = amplitude_sq(np.asarray(ctruth.cn0_dbhz)[vis], corr.coherent_s)
    z_code = (err - sis) / crb_delay_sigma(a2, corr.n_noncoherent, corr.bandwidth_chips)
    z_all = err / np.asarray(g.sigma)[vis]
    print(f"\n{vis.sum()} ranges: code error / CRB sd {z_code.std():.3f}, mean {z_code.mean():+.3f}; error / σ told "
          f"sd {z_all.std():.3f}")
    n = z_code.size
    assert abs(z_code.std() - 1.0) < 2.58 / np.sqrt(2 * n) + 0.02 and abs(z_code.mean()) < 3 / np.sqrt(n)
    # σ also holds σ_MP, which no echo fills here: the spread may not exceed 1 beyond its 99 % band
    assert 0.5 < z_all.std() < 1.0 + 2.58 / np.sqrt(2 * n)
    s = a.summaries["gps_raim"]
    assert s.mi_epochs == 0 and s.alert_epochs <= 1


def test_a_ground_echo_biases_the_code_loop():
    """The specular ground echo (−6 dB to make it visible, delay 2·h·sin el) pulls the code peak late while the
    echo sits inside the correlation peak: the low-altitude errors become positive on average."""
    ap = _short("correlator", multipath="ground")
    cfg = ap.config.model_copy(update={"gnss": ap.config.gnss.model_copy(update={"correlators": ap.config.gnss.correlators.model_copy(
        update={"ground_echo_db": -6.0})})})
    run = run_approach(dataclasses.replace(ap, config=cfg), seed=2, rrd_path=None)
    g, gt, tr = run.loop.gnss, run.loop.gnss_truth, run.loop.truth_at_gnss
    vis = np.asarray(g.visible)
    echo = 2.0 * np.maximum(tr.agl, 0.0)[:, None] * np.sin(np.maximum(gt.elevation, 0.0))
    inside = vis & (echo > 5.0) & (echo < 150.0)
    err = np.asarray(gt.noise)
    print(f"\n{inside.sum()} ranges with the echo 5-150 m late: mean error {err[inside].mean():+.2f} m "
          f"(se {err[inside].std() / np.sqrt(inside.sum()):.2f})")
    assert inside.sum() > 50
    assert err[inside].mean() > 4 * err[inside].std() / np.sqrt(inside.sum())

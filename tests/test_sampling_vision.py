"""Importance sampling in the camera's draws (testbed.campaign.sampling_vision): the vision columns' tilt and
weight against a linear-Gaussian pixel model's closed form, the proposal aimed from a pseudorange-only model
flagged on it, the sensor hook as drawn without a shift, and a pixel-aimed campaign bit for bit across chunking."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy import stats

from testbed.campaign.runner import run_campaign
from testbed.campaign.sampling import Components, LinearModel, components, draw_proposal, log_weights, weighted_rate
from testbed.campaign.sampling_vision import TiltRecorder, VisionColumns
from testbed.campaign.spec import SamplingPlan
from testbed.campaign.store import tables_equal
from testbed.sensors.gnss.synth import GnssErrors
from testbed.sensors.vision.detect import VisionDraws
from testbed.sim import pipeline

PLAN = SamplingPlan(method="importance", event="hazardous")


# ----------------------------------------------------------------------------- a linear-Gaussian pixel monitor

def pixel_problem(T: int, S: int, L: int, seed: int = 5):
    """A snapshot fix on S pseudoranges and L landmarks' pixels per epoch, its vertical error linear in the
    errors: ``e_v = g·ε_gnss + h·ε_pix`` with the pixel errors ``ε_pix = σ_px z_pix + J (σ_b z_b + σ_n z_n)``
    (z_b the attitude bias, one per sortie: the full pixel covariance ``σ_px² I + J diag(σ_b² + σ_n²) Jᵀ`` per
    epoch, correlated across landmarks and, through the bias, across epochs). Returns the gains and σ's."""
    rng = np.random.default_rng(seed)
    g = rng.normal(size=(T, S)) * 0.5  # m per m of pseudorange error
    h = rng.normal(size=(T, 2 * L)) * 0.3  # m per px
    J = rng.normal(size=(T, 2 * L, 3)) * 1000.0  # px per rad (f ~ 1000 px)
    sig_g = rng.uniform(0.5, 1.5, size=(T, S))
    sig_px, sig_b, sig_n = 1.0, np.radians([0.05, 0.05, 0.2]), np.radians([0.01, 0.01, 0.02])
    return g, h, J, sig_g, sig_px, sig_b, sig_n


def vertical_sigma(problem) -> np.ndarray:
    """σ of e_v per epoch from the covariances (no draws, no proposal code)."""
    g, h, J, sig_g, sig_px, sig_b, sig_n = problem
    cov_pix = sig_px**2 * np.eye(h.shape[1]) + np.einsum("tia,a,tja->tij", J, sig_b**2 + sig_n**2, J)
    return np.sqrt(np.einsum("ts,ts->t", g, g * sig_g**2) + np.einsum("ti,tij,tj->t", h, cov_pix, h))


def linear_model_of(problem, vision: bool = True) -> LinearModel:
    """The problem's :class:`LinearModel` over the joint columns (the slots, then the vision columns of
    :class:`VisionColumns`), as the probe measures it; ``vision`` False keeps the slots only (the old proposal)."""
    g, h, J, sig_g, sig_px, sig_b, sig_n = problem
    T, S = g.shape
    cols = VisionColumns(h.shape[1] // 2)
    A = np.zeros((T, 3, S + cols.size))
    A[:, 2, :S] = g * sig_g
    if vision:
        A[:, 2, S + cols.detection.start:S + cols.detection.stop] = h * sig_px
        hJ = np.einsum("ti,tia->ta", h, J)
        A[:, 2, S + cols.attitude_noise.start:S + cols.attitude_noise.stop] = hJ * sig_n
        A[:, 2, S + cols.attitude_bias.start:S + cols.attitude_bias.stop] = hJ * sig_b
    return LinearModel(e0=np.zeros((T, 3)), A=A, design=np.zeros((T, S, 4)), used=np.ones((T, S), bool),
                       hpl=np.full(T, np.nan), vpl=np.full(T, np.nan), dimensions=("V",))


def sorties(problem, comps: Components, n: int, seed: int):
    """``n`` sorties drawn through the campaign's path: the pseudorange draws tilted by the pipeline, the camera's
    through a :class:`TiltRecorder` (the bias shared by the epochs), the mixture's weights over both. Returns the
    vertical errors (n, T) built from the moved draws and the log-weights."""
    g, h, J, sig_g, sig_px, sig_b, sig_n = problem
    T, S = g.shape
    L = h.shape[1] // 2
    cols = VisionColumns(L)
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((n, T, S))
    drawn = VisionDraws(detection=rng.standard_normal((n, T, L, 2)), blur=rng.standard_normal((n, T)),
                        attitude_bias=rng.standard_normal((n, 1, 3)), attitude_noise=rng.standard_normal((n, T, 3)),
                        dither_noise=rng.standard_normal((n, T, 3)), dither_tone_angle=np.zeros((n, T, 3)),
                        dither_tone_rate=np.zeros((n, T, 3)))
    errors = GnssErrors(batch=(n,), sigma=sig_g, noise=z * sig_g, clock_bias=np.zeros((n, T)),
                        clock_drift=np.zeros((n, T)), rr_noise=np.zeros((n, T, S)), fault_seed=(0, (), 4, 0),
                        fault_bit_generator=np.random.PCG64)
    which = np.zeros(n, np.int64)
    draw = draw_proposal([comps], which, PLAN, np.zeros((n, T, S + cols.size)), rng)
    tilted, zg = pipeline.tilt_gnss_errors(errors, draw.shift[..., :S])
    rec = TiltRecorder(cols, draw.shift[..., S:])
    moved = rec(drawn)
    lw = log_weights([comps], which, PLAN, np.concatenate([zg, rec.z], -1))
    eps_pix = sig_px * moved.detection.reshape(n, T, 2 * L) + np.einsum(
        "tia,nta->nti", J, sig_b * moved.attitude_bias + sig_n * moved.attitude_noise)
    e_v = np.einsum("ts,nts->nt", g, tilted.noise) + np.einsum("ti,nti->nt", h, eps_pix)
    return e_v, lw


@pytest.mark.parametrize("p", [1e-5, 1e-7])
def test_pixel_model_tail_against_the_closed_form(p):
    """Four epochs, eight satellites, six landmarks, the attitude bias shared by the epochs: the rate of
    ``|e_v| > L`` per epoch, L at the epoch's two-sided ``p`` point of σ_v from the covariances, is p; the
    joint proposal's 99 % interval over 4000 sorties holds it to a few per cent. Tilting the bias per epoch
    instead of once per sortie, or leaving the camera's draws out of the weight, would not."""
    problem = pixel_problem(4, 8, 6)
    sigma_v = vertical_sigma(problem)
    limit = stats.norm.isf(p / 2) * sigma_v
    comps = _at_limits(linear_model_of(problem), limit)
    e_v, lw = sorties(problem, comps, 4000, seed=1)
    r = weighted_rate((np.abs(e_v) > limit).sum(-1), e_v.shape[1], lw, 0.99)
    assert r.settled, r.problems
    assert r.lo <= p <= r.hi, (r, p)
    assert r.se / r.estimate < 0.1


def _at_limits(model: LinearModel, limit: np.ndarray) -> Components:
    """The dominating-point components of ``|e_v| > limit[t]`` on ``model`` (vertical, both signs)."""
    m = LinearModel(model.e0, model.A, model.design, model.used, model.hpl, vpl=np.asarray(limit, float),
                    dimensions=("V",))
    return components(m, SamplingPlan(method="importance"), np.inf, np.inf)


def test_a_proposal_in_the_pseudoranges_alone_is_flagged_where_the_camera_carries_the_error():
    """The same closed form where the pixels carry most of the vertical error: the proposal aimed from the
    pseudorange columns alone (what a monitor reading the pseudoranges alone aims) gives no settled rate; the
    joint proposal does, and holds the closed form."""
    problem = pixel_problem(2, 8, 6, seed=9)
    g = problem[0] * 0.05  # the pseudoranges' part small beside the pixels'
    problem = (g,) + problem[1:]
    sigma_v = vertical_sigma(problem)
    p = 1e-7
    limit = stats.norm.isf(p / 2) * sigma_v
    old = _at_limits(linear_model_of(problem, vision=False), limit)
    e_v, lw = sorties(problem, old, 4000, seed=4)
    r_old = weighted_rate((np.abs(e_v) > limit).sum(-1), e_v.shape[1], lw, 0.99)
    assert not r_old.settled, r_old
    new = _at_limits(linear_model_of(problem), limit)
    e_v, lw = sorties(problem, new, 4000, seed=4)
    r = weighted_rate((np.abs(e_v) > limit).sum(-1), e_v.shape[1], lw, 0.99)
    assert r.settled and r.lo <= p <= r.hi, (r, p)


# ----------------------------------------------------------------------------- the sensor hook

def test_the_vision_hook_draws_as_before_and_moves_the_draws_it_is_given():
    """``sample_vision`` with a tilt that returns the draws unchanged gives the output without one, bit for bit
    (the streams read alike); a shift of one pixel column by 3 standard units moves that landmark's detection
    error by 3 σ at that epoch and nothing else."""
    from testbed.campaign.context import cell_context
    from testbed.campaign.spec import expand_cells, load_spec
    from testbed.sensors.vision.detect import sample_vision
    from testbed.sim.streams import StreamTree

    loaded = load_spec("vision-hmi-fault-free")
    ctx = cell_context(expand_cells(loaded)[0], loaded.spec)
    v_geom = ctx.v_geom[0:3]
    s = ctx.setup

    def draw(tilt=None):
        return sample_vision(v_geom, s.vision, landmarks=s.landmarks, rng=StreamTree(3).generator("vision"),
                             n_trials=4, survey_ecef=s.landmarks.pos_ecef, tilt=tilt)

    ve, vt = draw()
    ve2, vt2 = draw(lambda d: d)
    assert np.array_equal(ve.pixel_uv, ve2.pixel_uv, equal_nan=True)
    assert np.array_equal(ve.q_body_to_enu_ref, ve2.q_body_to_enu_ref)
    cols = VisionColumns(len(s.landmarks))
    k = int(np.flatnonzero(vt.visible[0, 1])[0])
    shift = np.zeros((4, 3, cols.size))
    shift[0, 1, 2 * k] = 3.0
    _, vt3 = draw(TiltRecorder(cols, shift))
    sigma = np.sqrt(s.vision.detection.sigma_px**2 + (s.vision.detection.blur_independent * vt.blur_sigma_px)**2)
    moved = vt3.noise_px - vt.noise_px
    assert moved[0, 1, k, 0] == pytest.approx(3.0 * sigma[0, 1], rel=1e-9)
    moved[0, 1, k, 0] = 0.0
    assert np.allclose(moved, 0.0, atol=1e-12)


# ----------------------------------------------------------------------------- on the campaign path

PIXEL_SPEC = """
name = "{name}"
approaches = ["zunz-rwy05-final"]
monitors = ["gps_raim", "pixel"]
trials = {trials}
base_seed = 11
block_trials = 50
chunk_trials = {chunk}
per_epoch_trials = 0
duration_s = 2.0
segment = "last"

[sampling]
method = "importance"
monitor = "pixel"
"""


def test_pixel_aimed_campaign_is_deterministic_across_chunking(tmp_path: Path):
    """A campaign aimed from the pixel monitor (the pseudoranges and the camera moved): the same weights and
    tables bit for bit with chunks of 100 and of 50 trials; the weights are not all 1 (the camera's columns are
    in them), and the pixel monitor's coverage says aimed."""
    from testbed.campaign.report import write_report

    outs = []
    for name, chunk in (("a", 100), ("b", 50)):
        spec = tmp_path / f"{name}.toml"
        spec.write_text(PIXEL_SPEC.format(name=name, trials=100, chunk=chunk))
        outs.append(run_campaign(spec, tmp_path / name, progress=False).out_dir)
    ta, tb = (pq.read_table(o / "trials.parquet") for o in outs)
    assert tables_equal(ta, tb)
    lw = ta.column("log_weight").to_numpy()
    assert np.isfinite(lw).all() and np.ptp(lw) > 0
    text = write_report(outs[0]).read_text()
    row = next(line for line in text.splitlines() if line.startswith("| pixel |"))
    assert "P_MI: aimed" in row


def test_a_move_of_the_dithering_noise_is_made_through_its_white_grid():
    """The dithering's band-limited noise moved by δ at one epoch (through the filter's white grid): its standard
    value there moves by δ, at the other epochs (1 s apart, 5 Hz bandwidth) by their correlation with it, below
    1e-6; the tones are as drawn; with no move the parts are the angles of ``dithering_angles``, bit for bit."""
    from testbed.sensors.vision import DitheringSettings, dithering_angles
    from testbed.sensors.vision.dithering import dithering_parts

    t = np.arange(0.0, 20.0, 1.0)
    s = DitheringSettings()
    base = dithering_parts(t, s, np.random.default_rng(8), 3, sample_rate_hz=1.0)
    angle, rate = dithering_angles(t, s, np.random.default_rng(8), 3, sample_rate_hz=1.0)
    assert np.array_equal(base.angle, angle) and np.array_equal(base.rate, rate)
    shift = np.zeros((3, t.size, 3))
    shift[1, 7, 0] = 2.5
    moved = dithering_parts(t, s, np.random.default_rng(8), 3, sample_rate_hz=1.0, noise_shift=shift)
    dz = moved.noise_z - base.noise_z
    assert dz[1, 7, 0] == pytest.approx(2.5, abs=1e-9)
    dz[1, 7, 0] = 0.0
    assert np.abs(dz).max() < 1e-6
    assert np.array_equal(moved.tone_angle, base.tone_angle)
    assert np.std(base.noise_z) == pytest.approx(1.0, abs=0.15)  # standard values under the error model


def loose_pixel_spec(tmp_path: Path, name: str, trials: int, sampling: str) -> Path:
    """The last 20 s of the runway-05 final, the pixel monitor alone with its PLs loosened (P_FA 1e-2, P_MD 0.1,
    p_ff 1e-2, no two-fault hypothesis), so that fault-free misleading epochs come at ~1e-3 (brute force)."""
    from testbed.resources import approaches_dir

    ap = (approaches_dir() / "zunz-rwy05-final.toml").read_text().replace('name = "zunz-rwy05-final"',
                                                                           'name = "loosepx"')
    (tmp_path / "loosepx.toml").write_text(ap + "\n[integrity]\np_fa = 0.01\np_md = 0.1\n\n"
                                                "[monitor.pixel]\np_ff = 0.01\ntwo_faults = false\n")
    spec = tmp_path / f"{name}.toml"
    spec.write_text(f'name = "{name}"\napproaches = ["loosepx.toml"]\nmonitors = ["pixel"]\ntrials = {trials}\n'
                    'base_seed = 7\nblock_trials = 100\nchunk_trials = 1000\nper_epoch_trials = 0\n'
                    'duration_s = 20.0\nsegment = "last"\n' + sampling)
    return spec


@pytest.mark.slow
def test_pixel_importance_agrees_with_brute_force(tmp_path: Path):
    """The pixel monitor's misleading epochs (~1e-3) at loosened PLs on the last 20 s of the runway-05 final:
    4000 plain sorties and 1000 importance-sampled ones aimed from the pixel monitor (pseudoranges and camera
    moved) estimate the same per-epoch and per-sortie rates, within 99 % of their combined standard error."""
    plain = run_campaign(loose_pixel_spec(tmp_path, "plain", 4000, ""), tmp_path / "plain", progress=False).out_dir
    imp = run_campaign(loose_pixel_spec(tmp_path, "imp", 1000, '[sampling]\nmethod = "importance"\nmonitor = "pixel"\n'),
                       tmp_path / "imp", progress=False).out_dir
    got = {}
    for name, out in (("plain", plain), ("imp", imp)):
        t = pq.read_table(out / "trials.parquet").to_pydict()
        lw = np.asarray(t["log_weight"]) if "log_weight" in t else np.zeros(len(t["trial"]))
        mi = np.asarray(t["mi_epochs"], float)
        got[name] = {"epoch": weighted_rate(mi, np.asarray(t["epochs"], float), lw),
                     "sortie": weighted_rate((mi > 0).astype(float), 1.0, lw)}
    for per in ("epoch", "sortie"):
        x, y = got["plain"][per], got["imp"][per]
        print(per, x.text(), x.ess_events, y.text(), y.ess_events)
        assert x.settled and y.settled, (x, y)
        assert abs(x.estimate - y.estimate) <= 2.576 * np.hypot(x.se, y.se), (per, x, y)


def test_the_scale_proposal_aimed_from_a_camera_monitor_is_refused_before_any_work(tmp_path: Path):
    """The scale proposal scales the pseudorange residual space only: aimed from the pixel monitor it is refused,
    naming the key, and nothing is written."""
    from testbed.schema import ConfigError

    spec = tmp_path / "bad.toml"
    spec.write_text(PIXEL_SPEC.format(name="bad", trials=100, chunk=100).replace(
        'monitor = "pixel"', 'monitor = "pixel"\nproposal = "scale"'))
    with pytest.raises(ConfigError) as ei:
        run_campaign(spec, tmp_path / "out", progress=False)
    assert "[sampling.proposal]" in str(ei.value) and "pixel" in str(ei.value)
    assert not (tmp_path / "out").exists()

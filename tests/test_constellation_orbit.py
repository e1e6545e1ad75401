"""The ``constellation_orbit`` fault: every satellite of one system displaced (a common ECEF translation and a
rotation of the constellation's frame), so the range error differs from satellite to satellite.

Checked against closed forms written here: the line-of-sight projection u·(d + θ × s) of the displacement,
the user-seen translation θ × x of a rotation, and the weighted least-squares shift of a fix with one clock
per system (what the system's clock cannot absorb moves the position); ARAIM alerts on it where a
``constellation_bias`` of the same size (tests/test_araim_monitor.py) moves nothing.
"""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from testbed.campaign.spec import FaultSweep
from testbed.config import load_approach
from testbed.flight.kinematic import straight_truth
from testbed.integrity.araim.fault_modes import fault_modes
from testbed.integrity.araim.monitor import araim_gnss
from testbed.integrity.araim.settings import AraimMonitorSettings, ConstellationIsm
from testbed.integrity.raim import gps_raim
from testbed.integrity.settings import IntegritySettings
from testbed.records import Mount
from testbed.sensors.faults import MAS_RAD, ConstellationBias, ConstellationOrbit
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.synth import apply_gnss_errors, draw_gnss_errors, gnss_geometry
from testbed.sim.evaluate import describe_faults
from testbed.world.airport import runway_frame

START = "2024-03-15T06:00:00Z"
ONSET = 20.0


@pytest.fixture(scope="module")
def sky():
    frame = runway_frame()
    truth = straight_truth(frame, [-9000.0, -6400.0, 650.0], [-3000.0, -2100.0, 200.0], 60.0, rate_hz=1.0)
    s = GnssSettings(terrain_masking=False, constellations=["gps", "galileo", "beidou"])
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc=START)
    err = draw_gnss_errors(g, s, rng=np.random.default_rng(11))
    return frame, g, err


def _injected(sky, fault):
    frame, g, err = sky
    clean, _ = apply_gnss_errors(g, err)
    hit, truth = apply_gnss_errors(g, err, [fault])
    return clean, hit, truth, hit.pseudorange - clean.pseudorange


def _los(g):
    d = g.sat_pos_ecef - g.ant_pos_ecef[:, None, :]
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def test_range_errors_are_the_line_of_sight_projection_of_the_displacement(sky):
    """Translation d and rotation θ of the Galileo frame: each Galileo range grows by u·(d + θ × s) (first order:
    the exact injected |R·s + d − x| − |s − x| differs by |δ|²/ρ < 1 mm), from the onset on, and differs from
    satellite to satellite; no other system's range moves."""
    frame, g, _ = sky
    d = np.array([30.0, -20.0, 50.0])
    rot = np.array([2.0, -3.0, 8.0])
    fault = ConstellationOrbit(kind="constellation_orbit", system="galileo", translation_m=tuple(d),
                               rotation_mas=tuple(rot), onset_s=ONSET)
    clean, hit, truth, dz = _injected(sky, fault)
    E = g.system == "E"
    vis = g.visible
    delta = d + np.cross(rot * MAS_RAD, g.sat_pos_ecef)  # (T, S, 3) each satellite's displacement
    expected = np.where((g.t >= ONSET)[:, None], np.einsum("tsk,tsk->ts", _los(g), delta), 0.0)
    np.testing.assert_allclose(np.where(vis[:, E], dz[:, E], 0.0), np.where(vis[:, E], expected[:, E], 0.0),
                               rtol=0, atol=1e-3)
    assert np.nanmax(np.abs(dz[:, ~E])) == 0.0 and not truth.faulty[:, ~E].any()
    after = g.t >= ONSET
    seen = np.where(vis[:, E], dz[:, E], np.nan)[after]
    spread = np.nanmax(seen, -1) - np.nanmin(seen, -1)  # not one common value: a clock cannot absorb it
    assert (spread > 20.0).all()
    assert (truth.faulty[after][:, E] | ~vis[after][:, E]).all() and not truth.faulty[~after].any()


def test_a_rotation_is_a_translation_by_theta_cross_the_user(sky):
    """To a user at x, the frame turned by θ about the Earth's centre is the satellites moved by θ × x:
    u·(θ × (s − x)) = 0 along the line of sight, whatever the satellite (100 mas: 13 m at the orbits)."""
    frame, g, _ = sky
    rot = np.array([0.0, 40.0, 100.0])
    fault = ConstellationOrbit(kind="constellation_orbit", system="beidou", rotation_mas=tuple(rot), onset_s=0.0)
    *_, dz = _injected(sky, fault)
    C = (g.system == "C") & g.visible.all(0)
    user = np.cross(rot * MAS_RAD, g.ant_pos_ecef)  # (T, 3)
    expected = np.einsum("tsk,tk->ts", _los(g)[:, C], user)
    np.testing.assert_allclose(dz[:, C], expected, rtol=0, atol=1e-3)
    assert np.abs(expected).max() > 0.5  # 100 mas at the user's 6370 km: ~3 m displacement


def test_what_the_system_clock_cannot_absorb_moves_the_fix(sky):
    """A common translation of every Galileo satellite: GPS RAIM's fix (one clock per system, no exclusion) moves by
    the weighted least-squares shift (GᵀWG)⁻¹GᵀW·e of the range errors e, computed here from the true geometry;
    the Galileo clock takes their common part. A constellation_bias of the same errors' mean moves nothing
    (its clock takes it all)."""
    frame, g, _ = sky
    fault = ConstellationOrbit(kind="constellation_orbit", system="galileo", translation_m=(0.0, 0.0, 60.0),
                               onset_s=0.0)
    clean, hit, _, dz = _injected(sky, fault)
    st = IntegritySettings(fde=False)
    a, b = gps_raim(clean, frame, st), gps_raim(hit, frame, st)
    k = 30  # one epoch
    vis = clean.visible[k]
    u = _los(g)[k, vis] @ frame.R.T  # ENU
    systems = g.system[vis]
    G = np.column_stack([-u] + [(systems == x).astype(float) for x in "GEC"])
    w = 1.0 / np.asarray(clean.sigma)[k, vis] ** 2
    e = dz[k, vis]
    shift = np.linalg.solve(G.T @ (w[:, None] * G), G.T @ (w * e))
    np.testing.assert_allclose(b.pos_enu[k] - a.pos_enu[k], shift[:3], atol=5e-3)
    assert np.linalg.norm(shift[:3]) > 1.0  # the part a clock cannot take: metres of position error
    # the errors' common part alone, as a constellation bias: absorbed whole
    mean = float(np.average(e[systems == "E"], weights=w[systems == "E"]))
    biased, _ = apply_gnss_errors(g, sky[2], [ConstellationBias(kind="constellation_bias", system="galileo",
                                                                  bias_m=mean)])
    np.testing.assert_allclose(gps_raim(biased, frame, st).pos_enu[k], a.pos_enu[k], atol=1e-6)


def test_araim_alerts_on_a_galileo_orbit_fault(sky):
    """A 100 m translation of Galileo along the local vertical: ARAIM's solution separation (its Galileo
    constellation mode among them) alerts at every epoch after the onset and none before."""
    frame, g, _ = sky
    up = frame.R[2]  # the local vertical in ECEF (the ENU rotation's third row)
    fault = ConstellationOrbit(kind="constellation_orbit", system="galileo", translation_m=tuple(100.0 * up),
                               onset_s=ONSET)
    clean, hit, *_ = _injected(sky, fault)
    base, out = araim_gnss(clean, frame), araim_gnss(hit, frame)
    after = g.t >= ONSET
    assert not base.alert.any() and not out.alert[~after].any()
    assert out.alert[after].all()


def test_the_campaign_fault_family(tmp_path):
    """A spec's ``constellation_orbit`` family: each magnitude (m) moves the system's satellites that far along
    ``direction_ecef`` (normalised); ``system`` and ``direction_ecef`` are required there and refused elsewhere."""
    f = FaultSweep(kind="constellation_orbit", system="galileo", direction_ecef=(0.0, 3.0, 4.0), magnitudes=[10.0])
    t = f.fault(10.0)
    assert t["kind"] == "constellation_orbit" and t["system"] == "galileo"
    np.testing.assert_allclose(t["translation_m"], (0.0, 6.0, 8.0))
    ConstellationOrbit(**t)  # an approach file's fault table
    assert f.fault(0.0) is None
    with pytest.raises(ValidationError, match="direction_ecef"):
        FaultSweep(kind="constellation_orbit", system="galileo", magnitudes=[10.0])
    with pytest.raises(ValidationError, match="finite non-zero"):
        FaultSweep(kind="constellation_orbit", system="galileo", direction_ecef=(0.0, 0.0, 0.0), magnitudes=[1.0])
    with pytest.raises(ValidationError, match="read by kind 'constellation_orbit' only"):
        FaultSweep(kind="gps_step", direction_ecef=(1.0, 0.0, 0.0), magnitudes=[1.0])
    with pytest.raises(ValidationError, match="expected system"):
        FaultSweep(kind="constellation_orbit", direction_ecef=(1.0, 0.0, 0.0), magnitudes=[1.0])


def test_the_run_summary_names_the_displacement():
    f = ConstellationOrbit(kind="constellation_orbit", system="galileo", translation_m=(0.0, 60.5, 35.0),
                           rotation_mas=(0.0, 0.0, 20.0), onset_s=3.0)
    line = describe_faults([f], np.array([11]), np.ones((2, 1), bool), np.ones((2, 1), bool), np.arange(2.0),
                           np.array(["E"]))[0]
    assert "translation [0, 60.5, 35] m, rotation [0, 0, 20] mas (ECEF X, Y, Z) on every galileo satellite" in line


def test_araims_galileo_constellation_mode_is_what_catches_a_small_one():
    """A 10 m Galileo displacement along the local vertical (DFMC errors, 40 sorties of 61 s on one sky): ARAIM
    with its Galileo constellation mode (P_const 1e-4) alerts at more than 10x the epochs it does when Galileo's
    P_const is 1e-9 (the mode then not monitored, nor most two-satellite modes: the fault order falls with the
    prior), and in every sortie (measured: 0.57 of the epochs against 0.019; docs/design/araim.md)."""
    s = load_approach("zunz-rwy05-dfmc").config.gnss.model_copy(update={"terrain_masking": False})
    frame = runway_frame()
    truth = straight_truth(frame, [-9000.0, -6400.0, 650.0], [-3000.0, -2100.0, 200.0], 60.0, rate_hz=1.0)
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc="2026-03-01T10:00:00Z")
    err = draw_gnss_errors(g, s, rng=np.random.default_rng(1), n_trials=40)
    fault = ConstellationOrbit(kind="constellation_orbit", system="galileo", translation_m=tuple(10.0 * frame.R[2]))
    hit, _ = apply_gnss_errors(g, err, [fault])
    with_mode = araim_gnss(hit, frame, AraimMonitorSettings())
    without = araim_gnss(hit, frame, AraimMonitorSettings(ism={"Galileo": ConstellationIsm(p_const=1e-9)}))
    print(f"\n10 m Galileo orbit fault: ARAIM alerts at {with_mode.alert.mean():.3f} of the epochs with the Galileo "
          f"constellation mode, {without.alert.mean():.3f} without")
    galileo = np.asarray(g.system)[g.visible[0]] == "E"
    system = np.where(galileo, 1, np.where(np.asarray(g.system)[g.visible[0]] == "G", 0, 2))
    for settings, monitored in ((AraimMonitorSettings(), True),
                                (AraimMonitorSettings(ism={"Galileo": ConstellationIsm(p_const=1e-9)}), False)):
        modes = fault_modes(system, settings.allocation(("LPV-200",))).removed
        assert any((m == galileo).all() for m in modes) == monitored  # the mode that drops every Galileo row
    assert with_mode.alert.mean() > 10.0 * without.alert.mean()
    assert with_mode.alert.any(-1).all() and not without.alert.any(-1).all()

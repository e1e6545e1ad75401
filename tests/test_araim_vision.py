"""ARAIM with landmark pixels as rows and the landmarks and the camera as fault events (docs/design/araim.md §11).

The oracles are written here from scratch: every subset solved by generalised least squares on the pseudoranges
and the landmark pixels with the FULL marginal pixel covariance of the pixel model (no rotation states), the
protection level equation solved by scipy's brentq, closed forms for the marginal covariance and for a biased
landmark.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import optimize, stats

from test_pixel import CAMERA, FRAME, LANDMARKS, K, scene
from testbed.config import load_approach, with_overrides
from testbed.inertial import body_to_world
from testbed.integrity.araim import AraimRows, AraimSettings, araim
from testbed.integrity.araim.core import _risk_terms, AraimReason, araim_modes
from testbed.integrity.araim.fault_modes import AID_CAMERA, AID_LANDMARK
from testbed.integrity.araim.inertia_rows import with_inertial_prediction
from testbed.integrity.araim.vision_rows import camera_epochs, camera_rows
from testbed.integrity.pixel_model import attitude_pixel_jacobians, pixel_covariance, project_landmarks
from testbed.schema import ConfigError

LEVER_ANT = np.array([0.0, 0.0, -2.0])
DITHER = np.radians([0.02, 0.03, 0.01])


def _sky(n: int, systems, seed: int = 3):
    rng = np.random.default_rng(seed)
    az = rng.uniform(0, 2 * np.pi, n)
    el = np.radians(rng.uniform(10, 85, n))
    return np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1), np.resize(systems, n)


def _case(n_sat=9, systems=(0, 1), n_landmarks=4, seed=3, settings=None, residual_seed=None, pixel_bias=None,
          nan_pixel=False):
    """GNSS rows of a random sky plus the camera rows of the test_pixel scene at the true antenna position."""
    settings = settings or AraimSettings()
    los, system = _sky(n_sat, systems, seed)
    rng = np.random.default_rng(residual_seed)
    _, vision, pos, _ = scene(T=1, rng=rng if residual_seed is not None else None)
    det = np.zeros_like(vision.detected)
    det[..., :n_landmarks] = True
    uv = vision.pixel_uv.copy()
    if pixel_bias is not None:
        uv[0, pixel_bias[0]] += pixel_bias[1]
    if nan_pixel:
        uv[0, 0] = np.nan
    vision = replace(vision, detected=det, pixel_uv=uv, dither_sigma=DITHER)
    cam = camera_epochs(vision, FRAME, LEVER_ANT, (1,))
    q_ref = vision.q_body_to_enu_ref[0]
    p_ant = pos[0] + body_to_world(FRAME, pos[0], q_ref) @ LEVER_ANT
    Rb = body_to_world(FRAME, p_ant, q_ref)  # as the rows take it: at the antenna
    res = None if residual_seed is None else rng.standard_normal(n_sat) * 0.5
    gnss = AraimRows.from_elevation(los, system, np.ones(n_sat, bool), settings, res)
    aid = camera_rows(cam, p_ant[None], max_landmarks=8)
    aid = {k: (v[0] if k not in ("aid_state", "aid_label") else v) for k, v in aid.items()}
    if res is None:
        aid["aid_residual"] = None
    rows = replace(gnss, **aid)
    p_ref = p_ant - Rb @ LEVER_ANT
    _, H_all, _ = project_landmarks(p_ref, Rb @ CAMERA.R_sensor_to_body, Rb @ CAMERA.lever_arm_body, LANDMARKS, K)
    pix = rows.aid_g[rows.aid_used & (rows.aid_label[:, 0] == AID_LANDMARK), :3].reshape(-1, 2, 3)
    order = [int(np.argmin(np.abs(H_all - h).sum((-1, -2)))) for h in pix]  # the rows' landmarks, in row order
    return gnss, rows, dict(pos=p_ref, Rb=Rb, vision=vision, order=order)


def _pixel_model(geo):
    """H and the full marginal pixel covariance of the rows' landmarks (in row order), from the pixel model."""
    Rb, v = geo["Rb"], geo["vision"]
    lm = LANDMARKS[geo["order"]]
    n_landmarks = len(lm)
    _, H, _ = project_landmarks(geo["pos"], Rb @ CAMERA.R_sensor_to_body, Rb @ CAMERA.lever_arm_body, lm, K)
    J_att, J_dith = attitude_pixel_jacobians(geo["pos"], Rb, CAMERA, lm, K)
    Sig = pixel_covariance(np.ones(n_landmarks), [(J_att, v.attitude_sigma), (J_dith, DITHER)])
    return H.reshape(-1, 3), Sig


def _brute(gnss: AraimRows, H, Sig, removed_sats, removed_landmarks, camera_out, n_pixel=None, keep_extra=True):
    """Position rows S (3, N + len(H)) of the GLS on the kept pseudoranges and pixels, full pixel covariance.
    Rows of H past the first ``n_pixel`` (a position prediction) are kept iff ``keep_extra``."""
    N, L2 = gnss.los_enu.shape[0], H.shape[0]
    n_pixel = L2 if n_pixel is None else n_pixel
    keep_g = np.setdiff1d(np.arange(N), list(removed_sats))
    keep_p = ([] if camera_out else [i for i in range(n_pixel) if i // 2 not in removed_landmarks]) + (
        list(range(n_pixel, L2)) if keep_extra else [])
    systems = sorted(set(gnss.system[keep_g]))
    X = np.concatenate([np.concatenate([-gnss.los_enu[keep_g],
                                        (gnss.system[keep_g, None] == np.array(systems)).astype(float)], 1),
                        np.concatenate([H[keep_p], np.zeros((len(keep_p), len(systems)))], 1)], 0)
    C = np.zeros((X.shape[0],) * 2)
    C[:keep_g.size, :keep_g.size] = np.diag(gnss.c_int[keep_g])
    C[keep_g.size:, keep_g.size:] = Sig[np.ix_(keep_p, keep_p)]
    Ci = np.linalg.inv(C)
    S_k = np.linalg.solve(X.T @ Ci @ X, X.T @ Ci)[:3]
    S = np.zeros((3, N + L2))
    S[:, keep_g] = S_k[:, :keep_g.size]
    S[:, N + np.array(keep_p, int)] = S_k[:, keep_g.size:]
    return S


def _mode_parts(removed, N, n_landmarks):
    sats = [i for i in removed if i < N]
    aid = [i - N for i in removed if i >= N]
    return sats, {a // 2 for a in aid if a < 2 * n_landmarks}, any(a >= 2 * n_landmarks for a in aid)


def test_gnss_only_rows_are_unchanged_by_an_unused_camera_block():
    """The regression oracle: an epoch whose camera has no landmark is solved exactly as GNSS alone."""
    gnss, with_cam, _ = _case(n_landmarks=0, residual_seed=1)
    assert not np.any(with_cam.aid_used)
    a, b = araim(gnss), araim(with_cam)
    for name in ("hpl", "vpl", "emt", "sigma_acc_enu", "test_ratio", "n_modes", "p_unmonitored"):
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=0, atol=1e-9, err_msg=name)
    assert np.all(b.n_modes_aid == 0) and np.all(b.risk_aid_enu == 0.0)


def test_epochs_of_different_structures_in_one_call_equal_each_alone():
    """Two epochs whose camera rows differ (4 landmarks, then the first one's pixels unused: two row structures)
    solved in one call give each epoch's own results (the vision group's reported risk was computed with a name the
    next structure's loop reused: the second structure ended in an IndexError)."""
    _, a, _ = _case(n_landmarks=4, residual_seed=2)
    used = a.aid_used.copy()
    used[np.flatnonzero(a.aid_label[:, 0] == AID_LANDMARK)[:2]] = False
    b = replace(a, aid_used=used)
    batch = {f: np.stack([getattr(a, f), getattr(b, f)]) for f in ("los_enu", "used", "c_int", "c_acc", "b_nom",
                                                                     "b_cont", "residual", "aid_g", "aid_used",
                                                                     "aid_c", "aid_residual")}
    both = araim(replace(a, **batch))
    for k, one in enumerate((araim(a), araim(b))):
        for name in ("hpl", "vpl", "emt", "test_ratio", "n_modes", "n_modes_aid", "risk_aid_enu"):
            np.testing.assert_allclose(getattr(both, name)[k], getattr(one, name), rtol=1e-12, err_msg=name)


def test_rotation_states_with_prior_rows_give_the_pixel_models_full_covariance():
    """Marginalising the rotation states: σ_px² I + J_rot diag(σ²) J_rotᵀ is pixel_covariance exactly."""
    _, rows, geo = _case(n_landmarks=5)
    H, Sig = _pixel_model(geo)
    pix = rows.aid_label[:, 0] == AID_LANDMARK
    prior = rows.aid_label[:, 0] == AID_CAMERA
    J = rows.aid_g[pix][:, 3:]
    Sig_rows = np.diag(rows.aid_c[pix]) + J @ np.diag(rows.aid_c[prior]) @ J.T
    assert prior.sum() == 6
    np.testing.assert_allclose(Sig_rows, Sig, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(rows.aid_g[pix][:, :3], H, rtol=1e-9, atol=1e-12)
    assert np.abs(Sig - np.diag(np.diag(Sig))).max() > 1.0  # the landmarks' pixels really are correlated


@pytest.mark.parametrize("systems", [(0,), (0, 1)])
def test_every_subset_matches_a_gls_with_the_full_pixel_covariance(systems):
    """Each mode's σ, bias, σ_ss and separation from the rotation-state form equal a from-scratch GLS on the kept
    pseudoranges and pixels weighted by the full marginal covariance; the camera mode's is the GNSS-only one."""
    L = 4
    _, rows, geo = _case(n_sat=8, systems=systems, n_landmarks=L, residual_seed=5)
    H, Sig = _pixel_model(geo)
    table = araim_modes(rows)
    N = rows.los_enu.shape[0]
    C = np.zeros((N + 2 * L,) * 2)
    C[:N, :N] = np.diag(rows.c_int)
    C[N:, N:] = Sig
    C_acc = C.copy()
    C_acc[:N, :N] = np.diag(rows.c_acc)  # the separations' sigmas: σ_URE for the GNSS rows, the pixels alike
    pix = rows.aid_label[:, 0] == AID_LANDMARK
    y = np.concatenate([rows.residual, rows.aid_residual[pix]])
    S0 = _brute(rows, H, Sig, [], set(), False)
    kinds = set()
    for k, removed in enumerate(table.removed):
        if not table.observable[k]:
            continue
        sats, lms, cam = _mode_parts(removed, N, L)
        kinds.add(("sat" if sats else "") + ("lm" if lms else "") + ("cam" if cam else ""))
        S = _brute(rows, H, Sig, sats, lms, cam)
        np.testing.assert_allclose(table.sigma[k], np.sqrt(np.diag(S @ C @ S.T)), rtol=1e-7, err_msg=str(removed))
        np.testing.assert_allclose(table.bias[k], np.abs(S[:, :N]) @ rows.b_nom, rtol=1e-7, atol=1e-9)
        if k:
            D = S - S0
            np.testing.assert_allclose(table.sigma_ss[k], np.sqrt(np.diag(D @ C_acc @ D.T)), rtol=1e-6, atol=1e-9)
            np.testing.assert_allclose(table.separation[k], D @ y, rtol=1e-6, atol=1e-7)
    assert {"sat", "lm", "lmcam"} <= kinds  # satellites, landmarks, the camera (all its rows)


def test_vpl_solves_the_protection_level_equation():
    """VPL against brentq on eq. 16 rebuilt from the brute-force sigmas and the monitor's priors."""
    L = 4
    st = AraimSettings()
    _, rows, geo = _case(n_sat=8, systems=(0, 1), n_landmarks=L)
    H, Sig = _pixel_model(geo)
    ep, table = araim(rows, st), araim_modes(rows, st)
    assert ep.reason == AraimReason.OK and ep.n_modes_aid[0] > 0
    N = rows.los_enu.shape[0]
    C = np.zeros((N + 2 * L,) * 2)
    C[:N, :N] = np.diag(rows.c_int)
    C[N:, N:] = Sig
    C_acc = C.copy()
    C_acc[:N, :N] = np.diag(rows.c_acc)
    S0 = _brute(rows, H, Sig, [], set(), False)
    terms, aid_modes = [], []
    for k, removed in enumerate(table.removed):
        S = _brute(rows, H, Sig, *_mode_parts(removed, N, L)) if table.observable[k] else None
        if k == 0:
            s0, b0 = np.sqrt(S[2] @ C @ S[2]), np.abs(S[2, :N]) @ rows.b_nom
        elif S is not None:
            D = S[2] - S0[2]
            T = float(ep.k_fa[2]) * np.sqrt(D @ C_acc @ D)
            terms.append((table.p[k], T + np.abs(S[2, :N]) @ rows.b_nom, np.sqrt(S[2] @ C @ S[2]), table.alpha[k]))
            aid_modes.append(any(i >= N for i in removed))
    target = st.p_hmi_vert * (1 - float(ep.p_unmonitored) / (st.p_hmi_vert + st.p_hmi_hor)) / st.n_es_int

    def q_tilde(z):  # eq. 16's Q̃: a mode's error may sit anywhere up to its threshold
        return 1.0 if z <= 0.0 else stats.norm.sf(z)

    def risk(pl):
        return (2 * stats.norm.sf((pl - b0) / s0)
                + sum(p * min(q_tilde((pl - off) / s), a) for p, off, s, a in terms) - target)

    vpl = optimize.brentq(risk, 0.0, 1e3, xtol=1e-6)
    assert float(ep.vpl) - st.tol_pl - 1e-6 <= vpl <= float(ep.vpl) + 1e-6
    # the risk the vision modes take at the VPL, over the exposure (× N_ES)
    at = float(ep.vpl)
    vision = sum(p * min(q_tilde((at - off) / s), a) for (p, off, s, a), v in zip(terms, aid_modes) if v)
    assert sum(aid_modes) == int(ep.n_modes_aid[0]) > 0
    np.testing.assert_allclose(ep.risk_aid_enu[0, 2], vision * st.n_es_int, rtol=1e-6)
    # a mode whose threshold and bias reach past the PL counts in full (Q̃ = 1): the reported risk is the PL
    # equation's own term, not Q's, there
    t = _risk_terms(np.full((1, 3), 5.0), np.zeros((1, 1, 3)), np.ones((1, 1, 3)), np.array([1e-5]),
                    np.array([[True]]), np.array([True]), np.full((1, 1, 3), 8.0), np.array([1.0]))
    np.testing.assert_allclose(t[0, 0], 1e-5)  # Q would give 1e-5 · Q(−3) ≈ 0.9987e-5


def test_a_biased_landmark_leaves_its_own_subset_unmoved():
    """50 px on landmark 1: the all-in-view fix moves, the 'landmark 1 faulty' subset x̂⁽⁰⁾ + separation does not
    move at all (its rows are out), and the test sees the fault."""
    _, clean, geo_c = _case(n_landmarks=4, residual_seed=7)
    _, biased, geo_b = _case(n_landmarks=4, residual_seed=7, pixel_bias=(1, np.array([50.0, -30.0])))
    t_clean, t_bias = araim_modes(clean), araim_modes(biased)
    N = clean.los_enu.shape[0]
    j_c, j_b = geo_c["order"].index(1), geo_b["order"].index(1)
    k_c = t_clean.removed.index((N + 2 * j_c, N + 2 * j_c + 1))  # landmark 1's two pixel rows
    k_b = t_bias.removed.index((N + 2 * j_b, N + 2 * j_b + 1))
    dx_c, dx_b = araim(clean).dx_enu, araim(biased).dx_enu
    np.testing.assert_allclose(dx_b + t_bias.separation[k_b], dx_c + t_clean.separation[k_c], atol=1e-9)
    assert np.linalg.norm(dx_b - dx_c) > 0.1
    assert araim(biased).test_ratio > 1.0 > araim(clean).test_ratio


def test_degenerate_cameras_give_reasons_not_exceptions():
    one = araim(_case(n_landmarks=1)[1])
    assert one.reason == AraimReason.OK and one.n_modes_aid[0] >= 2  # the landmark and the camera
    nan = araim(_case(n_landmarks=3, nan_pixel=True)[1])
    assert nan.reason == AraimReason.NAN_INPUT and np.isinf(nan.vpl)


def test_vision_makes_the_constellation_mode_of_a_gps_only_sky_observable():
    """GPS alone: its constellation mode (P_const 1e-4) removes every row, so ARAIM is unavailable; with the camera
    the mode's subset is the vision fix and the epoch is protected."""
    gnss, rows, _ = _case(n_sat=8, systems=(0,), n_landmarks=4)
    assert araim(gnss).reason == AraimReason.UNMONITORED
    ep = araim(rows)
    assert ep.reason == AraimReason.OK and np.isfinite(ep.vpl)
    assert 0.0 <= ep.risk_aid_enu[0, 2] < AraimSettings().p_hmi_vert


def test_vision_modes_make_araim_read_the_camera_by_itself():
    """The registry's inputs follow the options: with vision = true ARAIM reads the camera, so a run listing no
    other vision monitor still synthesises the detections (and sets the vision rate), and a RINEX replay, which has
    no camera, refuses it by the same rule that refuses va_raim."""
    from testbed.monitors import monitor_inputs
    from testbed.replay.run import check_monitors

    assert monitor_inputs("araim") == {"gnss"}
    assert monitor_inputs("araim", {"araim": {"vision": True}}) == {"gnss", "vision"}
    ap = with_overrides(load_approach("zunz-rwy05-dfmc-vision"), monitors=["gps_raim", "araim"])
    assert ap.config.monitor["araim"].vision and ap.config.reads("vision")
    assert not with_overrides(load_approach("zunz-rwy05-dfmc"), monitors=["gps_raim", "araim"]).config.reads("vision")
    check_monitors(("araim",), {"araim": {"vision": False}})
    with pytest.raises(ConfigError, match=r"'araim' reads \['gnss', 'vision'\]"):
        check_monitors(("araim",), {"araim": {"vision": True}})


# ----------------------------------------------------------------------------- an inertial prediction

P_PRED = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, -0.4], [0.5, -0.4, 9.0]])  # m², correlated axes


def _with_prediction(rows, offset=np.zeros(3)):
    """``rows`` plus a prediction at the linearisation point + ``offset`` (the rows' residuals are taken there)."""
    return with_inertial_prediction(rows, np.zeros(3) + offset, P_PRED, p_lin=np.zeros(3))


def test_an_inertial_prediction_is_a_fault_event_whose_subsets_match_a_gls():
    """Vision and an inertial prediction in one budget: every mode's σ, σ_ss and separation against the GLS on the
    kept pseudoranges, pixels (full covariance) and the prediction (its full P⁻)."""
    L = 3
    _, rows, geo = _case(n_sat=8, systems=(0, 1), n_landmarks=L, residual_seed=11)
    rows = _with_prediction(rows, np.array([0.7, -1.2, 2.0]))
    H, Sig = _pixel_model(geo)
    table = araim_modes(rows)
    N = rows.los_enu.shape[0]
    n_aid = rows.aid_g.shape[0]
    inertia_rows = set(range(N + n_aid - 3, N + n_aid))

    def gls(removed):
        sats, lms, cam = _mode_parts([i for i in removed if i not in inertia_rows], N, L)
        return _brute(rows, np.concatenate([H, np.eye(3)]), _blockdiag(Sig, P_PRED), sats, lms, cam, n_pixel=2 * L,
                      keep_extra=not inertia_rows & set(removed))

    C = _blockdiag(np.diag(rows.c_acc), _blockdiag(Sig, P_PRED))
    C_int = _blockdiag(np.diag(rows.c_int), _blockdiag(Sig, P_PRED))
    y = np.concatenate([rows.residual, rows.aid_residual[:2 * L], np.array([0.7, -1.2, 2.0])])
    S0 = gls(())
    seen = 0
    for k, removed in enumerate(table.removed):
        if not table.observable[k] or k == 0:
            continue
        S = gls(removed)
        D = S - S0
        np.testing.assert_allclose(table.sigma[k], np.sqrt(np.diag(S @ C_int @ S.T)), rtol=1e-7)
        np.testing.assert_allclose(table.sigma_ss[k], np.sqrt(np.diag(D @ C @ D.T)), rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(table.separation[k], D @ y, rtol=1e-6, atol=1e-7)
        seen += bool(inertia_rows & set(removed))
    assert seen >= 1
    ep = araim(rows)
    assert ep.reason == AraimReason.OK and ep.n_modes_aid[1] >= 1 and ep.risk_aid_enu[1, 2] >= 0.0


def test_a_biased_prediction_leaves_the_inertia_subset_unmoved():
    _, rows, _ = _case(n_landmarks=3, residual_seed=13)
    clean, biased = _with_prediction(rows), _with_prediction(rows, np.array([30.0, -20.0, 40.0]))
    t_c, t_b = araim_modes(clean), araim_modes(biased)
    N, n_aid = rows.los_enu.shape[0], clean.aid_g.shape[0]
    k = t_c.removed.index(tuple(range(N + n_aid - 3, N + n_aid)))
    np.testing.assert_allclose(araim(biased).dx_enu + t_b.separation[k], araim(clean).dx_enu + t_c.separation[k],
                               atol=1e-9)
    assert araim(biased).test_ratio > 1.0


def test_a_prediction_without_a_positive_covariance_is_a_nan_row():
    _, rows, _ = _case(n_landmarks=2)
    bad = with_inertial_prediction(rows, np.zeros(3), -np.eye(3))
    assert araim(bad).reason == AraimReason.NAN_INPUT
    none = with_inertial_prediction(rows, np.full(3, np.nan), np.eye(3))
    np.testing.assert_allclose(araim(none).vpl, araim(rows).vpl, atol=1e-9)  # no prediction: no rows


def _blockdiag(A, B):
    out = np.zeros((A.shape[0] + B.shape[0],) * 2)
    out[:A.shape[0], :A.shape[0]] = A
    out[A.shape[0]:, A.shape[0]:] = B
    return out


def test_a_rinex_replay_refuses_vision_modes_before_any_work(tmp_path, capsys):
    """testbed monitor reads RINEX, which has no camera: ARAIM with vision = true is refused, exit 2, before any
    file is read (the observation files named here do not even exist)."""
    from testbed.cli import main

    cfg = tmp_path / "m.toml"
    cfg.write_text("[monitor.araim]\nvision = true\n")
    code = main(["monitor", str(tmp_path / "none.obs"), str(tmp_path / "none.nav"), "--config", str(cfg),
                 "--monitors", "araim", "--out", str(tmp_path / "o")])
    text = capsys.readouterr()
    text = text.out + text.err
    assert code == 2 and "--monitors" in text and "vision" in text and "Traceback" not in text, text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.toml"]


def test_the_araim_monitor_without_vision_observations_is_a_clear_error():
    from testbed.integrity.araim.monitor import araim_gnss
    from testbed.integrity.araim.settings import AraimMonitorSettings
    from test_integrity_core_helpers import make_gnss

    gnss, _, _ = make_gnss(FRAME, np.array([[0.0, -3000.0, 160.0]]), np.array([344063.0]), None)
    with pytest.raises(ValueError, match="no vision observations"):
        araim_gnss(gnss, FRAME, AraimMonitorSettings(vision=True))


def test_the_monitor_reads_the_camera_per_trial_and_reports_the_vision_modes():
    """araim_gnss with vision on trials × epochs: each trial's output equals that trial run alone (the camera's
    epochs follow the trial chunks), the landmarks and vision modes are reported, and the summary shows them."""
    from testbed.integrity.araim.monitor import araim_gnss
    from testbed.integrity.araim.settings import AraimMonitorSettings

    rng = np.random.default_rng(21)
    gnss, vision, _, _ = scene(T=3, batch=(4,), rng=rng)
    ms = AraimMonitorSettings(vision=True, ism={"GPS": {"p_const": 1e-8}})
    out = araim_gnss(gnss, FRAME, ms, vision=vision, threads=2)
    d = out.diagnostics
    assert (out.reason == 0).all() and (d.n_landmarks >= 2).all() and (d.n_modes_vision >= 3).all()
    assert np.isfinite(d.risk_vision_v).all()
    rows = d.summary_rows()
    assert "vision fault modes (min-max)" in rows and "landmarks in ARAIM (min-max)" in rows
    one = lambda a, b: replace(a, **{f: getattr(a, f)[b] for f in ("pseudorange", "sat_pos_ecef", "visible")})  # noqa: E731
    for b in (0, 3):
        alone = araim_gnss(one(gnss, b), FRAME, ms, threads=1,
                           vision=replace(vision, pixel_uv=vision.pixel_uv[b], detected=vision.detected[b],
                                          reason=vision.reason[b], sigma_px=vision.sigma_px[b],
                                          q_body_to_enu_ref=vision.q_body_to_enu_ref[b]))
        np.testing.assert_allclose(out.vpl[b], alone.vpl, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(d.n_modes_vision[b], alone.diagnostics.n_modes_vision)
    plain = araim_gnss(gnss, FRAME, ms.model_copy(update={"vision": False}), threads=2)
    assert not plain.diagnostics.vision and "vision fault modes (min-max)" not in plain.diagnostics.summary_rows()


# ----------------------------------------------------------------------------- in campaigns

def _spec(tmp_path, approach: str, tail: str) -> str:
    p = tmp_path / "s.toml"
    p.write_text(f'name = "s"\napproaches = ["{approach}"]\nmonitors = ["araim"]\ntrials = 4\nduration_s = 2.0\n'
                 + tail)
    return str(p)


def test_a_camera_fault_is_judged_per_cell_with_the_monitors_options(tmp_path, capsys):
    """ARAIM alone reads the camera when its options say so: a pixel fault is accepted on the vision approach and
    refused, naming the cell, where ARAIM's vision modes are off (the spec alone cannot tell)."""
    from testbed.cli import main

    fault = '[[faults]]\nkind = "pixel_bias"\nmagnitudes = [10.0]\nonset_s = 0.0\n'
    assert main(["check", _spec(tmp_path, "zunz-rwy05-dfmc-vision", fault)]) == 0
    capsys.readouterr()
    assert main(["check", _spec(tmp_path, "zunz-rwy05-dfmc", fault)]) == 1
    text = capsys.readouterr().out
    assert "cell 0" in text and "pixel_bias fault needs a monitor that reads vision" in text, text


def test_importance_sampling_refuses_a_monitor_whose_options_change_what_it_reads(tmp_path, capsys):
    """The proposal is aimed and its coverage reported from a monitor's registered inputs: ARAIM with its vision
    modes on is refused before any work, by `check` and by `campaign` alike (it ended in a traceback)."""
    from testbed.cli import main

    spec = _spec(tmp_path, "zunz-rwy05-dfmc-vision", '[sampling]\nmethod = "importance"\n')
    assert main(["check", spec]) == 1
    said = capsys.readouterr().out
    assert "araim read ['gnss', 'vision'] with their options" in said and "not supported yet" in said, said
    assert main(["campaign", spec, "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("table, said", [("max_landmarks = 3", "max_landmarks read only with vision = true"),
                                         ("camera = { p = 1e-3 }", "camera read only with vision = true"),
                                         ("inertia = { p = 1e-4 }", "feeds no inertial prediction")])
def test_araim_options_the_monitor_would_not_read_are_refused(tmp_path, capsys, table, said):
    from testbed.cli import main
    from testbed.resources import approaches_dir

    p = tmp_path / "a.toml"
    p.write_text((approaches_dir() / "zunz-rwy05-dfmc.toml").read_text() + f"\n[monitor.araim]\n{table}\n")
    code = main(["fly", str(p), "--no-record"])
    text = capsys.readouterr()
    text = text.out + text.err
    assert code == 2 and "monitor.araim" in text and said in text and "Traceback" not in text, text

"""``testbed monitor --monitors araim``: ARAIM's own per-epoch outputs (EMT, σ_acc, fault modes, one clock per
system) in the replay's table and summary, equal to the same monitor's in the loop on the same signals."""

import json

import numpy as np
import pytest

from testbed.api import export_rinex, run_approach
from testbed.cli import main
from testbed.config import load_approach, with_overrides

SEED = 5
#: a 60 m step on a random satellite from 60 s: alerts and separations beside the fault-free first minute
FAULT = {"kind": "gps_step", "prn": "random", "bias_m": 60.0, "onset_s": 60.0}


@pytest.fixture(scope="module")
def dfmc(tmp_path_factory):
    """The DFMC approach exported to RINEX, the in-loop ARAIM output of the same flight and seed, and the
    replay's CSV output folder (``--monitors gps_raim araim``)."""
    tmp = tmp_path_factory.mktemp("dfmc")
    ap = with_overrides(load_approach("zunz-rwy05-dfmc"), faults=[FAULT])
    obs, nav = export_rinex(ap, tmp, seed=SEED)
    loop = run_approach(ap, seed=SEED, rrd_path=None, monitors=["araim"])
    fr = ap.config.frame
    cfg = tmp / "monitor.toml"
    cfg.write_text(f"[rinex]\norigin = [{fr.lat_deg}, {fr.lon_deg}, {fr.h}]\n")
    out = tmp / "out"
    rc = main(["monitor", str(obs), str(nav), "--config", str(cfg), "--out", str(out), "--format", "csv",
               "--monitors", "gps_raim", "araim", "--rrd", str(out / "r.rrd")])
    assert rc == 0
    return loop.outputs["araim"], out, (obs, nav)


def _read_csv(path):
    return np.genfromtxt(path, delimiter=",", names=True, dtype=None, encoding="utf-8", deletechars="")


def test_araims_own_columns_equal_the_in_loop_values(dfmc):
    """Every epoch: EMT, σ_acc,v, σ_acc,h, the fault modes, N_fault,max, the unmonitored prior, K_fa,v and the
    per-system clocks of the replay's table are the loop's (RINEX's 1 mm ranges: the clocks within 5 mm, as GPS
    RAIM's in tests/test_rinex.py, the rest 1e-6 relative), the availability per service level, the alerts and the
    reason code are the loop's exactly."""
    own, out, _ = dfmc
    t = _read_csv(out / "epochs-araim.csv")
    d = own.diagnostics
    assert t.size == own.t.size
    pairs = {"emt_m": d.emt, "sigma_acc_v_m": d.sigma_acc_v, "sigma_acc_h_m": d.sigma_acc_h, "fault_modes": d.n_modes,
             "fault_order": d.fault_order, "p_unmonitored": d.p_unmonitored, "k_fa_v": d.k_fa_v}
    for name, loop_values in pairs.items():
        np.testing.assert_allclose(t[name], np.asarray(loop_values, float), rtol=1e-6, atol=1e-9, err_msg=name)
    for k, system in enumerate(("gps", "galileo", "beidou")):
        np.testing.assert_allclose(t[f"clock_{system}_m"], d.clock[:, k], rtol=0, atol=5e-3, err_msg=system)
    assert np.isfinite(t["emt_m"]).all() and (t["fault_modes"] > 3).all()  # every epoch protected, modes counted
    for k, lv in enumerate(own.service_levels):
        np.testing.assert_array_equal(t[f"available_{lv}"].astype(bool), own.available[:, k])
    np.testing.assert_array_equal(t["reason"], own.reason)
    np.testing.assert_array_equal(t["alert"].astype(bool), own.alert)
    assert own.alert.any() and not own.alert[own.t < 60.0].any()  # the step is seen, and only after its onset
    assert "clock_glonass_m" not in t.dtype.names  # a system no epoch used has no column


def test_the_summary_carries_each_monitors_own_rows_and_reason_codes(dfmc):
    own, out, _ = dfmc
    s = json.loads((out / "summary.json").read_text())["monitors"]
    assert set(s["araim"]["own"]) == {"EMT max / p95", "σ_acc,v max / p95", "fault modes (min-max)"}
    assert s["araim"]["own"]["EMT max / p95"] == own.diagnostics.summary_rows()["EMT max / p95"]
    assert s["araim"]["reason_codes"] == list(own.reasons)
    assert "own" not in s["gps_raim"]  # GPS RAIM has no rows of its own
    gps = _read_csv(out / "epochs-gps_raim.csv")
    assert "emt_m" not in gps.dtype.names  # nor columns


def test_the_recording_has_araims_own_curves(dfmc):
    from testbed.viz.readback import entity_paths, scalar_series

    own, out, _ = dfmc
    assert {"/integrity/araim/vertical/emt", "/integrity/araim/vertical/sigma_acc_v",
            "/integrity/gps_raim/vertical/vpl"} <= entity_paths(out / "r.rrd")
    _, emt = scalar_series(out / "r.rrd", "/integrity/araim/vertical/emt")
    np.testing.assert_allclose(emt, own.diagnostics.emt, rtol=1e-6)


@pytest.mark.parametrize("names, fragment", [
    (["va_raim"], "reads ['gnss', 'vision']"),
    (["araim", "araim"], "named more than once"),
    (["nope"], "unknown monitor 'nope'"),
])
def test_monitors_that_cannot_run_on_rinex_exit_2(tmp_path, capsys, names, fragment):
    """Refused before the files are read (so these need not even be RINEX)."""
    obs, nav = tmp_path / "f.obs", tmp_path / "f.nav"
    obs.write_text("not read\n")
    nav.write_text("not read\n")
    out = tmp_path / "out"
    assert main(["monitor", str(obs), str(nav), "--out", str(out), "--monitors", *names]) == 2
    err = capsys.readouterr().err
    assert "--monitors" in err and fragment in err and "Traceback" not in err
    assert not out.exists()

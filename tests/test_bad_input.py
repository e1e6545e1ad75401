"""Every bad input is a clear error before any work: exit code 2 (1 for ``check``), a message that
names the file, the key and the value, never a traceback, and nothing written or replaced.

Each case runs the real command line (``testbed.cli.main``) from an empty working folder; an
exception escaping ``main`` fails the test (a traceback is a bug).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from testbed.cli import main
from testbed.resources import approaches_dir

BASE = (approaches_dir() / "va-raim-2015.toml").read_text()


def approach(tmp: Path, *, top: str = "", tail: str = "", replace: tuple[str, str] | None = None,
             name: str = "bad.toml") -> Path:
    """The seed sortie's approach with top-level keys prepended, tables appended or a line replaced."""
    text = BASE if replace is None else BASE.replace(*replace)
    assert replace is None or replace[0] in BASE
    p = tmp / name
    p.write_text(top + "\n" + text + "\n" + tail + "\n")
    return p


def run(capsys, *argv: str) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out + out.err


def listing(*folders: Path) -> dict:
    return {str(p): p.stat().st_mtime_ns for f in folders if f.exists() for p in sorted(f.rglob("*"))}


@pytest.fixture
def work(tmp_path, monkeypatch):
    """An empty working folder (the command's cwd) and a separate folder for input files."""
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    inputs = tmp_path / "in"
    inputs.mkdir()
    monkeypatch.chdir(cwd)
    return cwd, inputs


def far_away_dem(folder: Path) -> Path:
    p = folder / "elsewhere.npz"
    lat, lon = np.linspace(10.0, 10.5, 11), np.linspace(10.0, 10.5, 11)
    np.savez(p, lat_deg=lat, lon_deg=lon, height_m=np.full((11, 11), 100.0))
    return p


FAULT = "[[faults]]\nkind = \"{kind}\"\n{body}\n"


def _k_record_for(**dpe_options) -> str:
    """A complete K record, as `testbed calibrate-dpe` writes it, for DPE options other than the defaults."""
    import json

    from testbed.integrity.dpe.calibration import settings_fingerprint
    from testbed.integrity.dpe.monitor import DpeSettings
    from testbed.sensors.gnss.settings import CorrelatorSettings

    fp, cover = settings_fingerprint(DpeSettings(k_factor=1.0, **dpe_options), CorrelatorSettings())
    return json.dumps({"k": 5.9, "settings": cover, "fingerprint": fp, "p_hmi": 1e-7, "n": 5000})

# (id, how to build the file from the inputs folder, expected key text, expected value text)
FILE_CASES = [
    ("prn-not-in-constellation", lambda d: approach(d, tail=FAULT.format(kind="gps_step", body="prn = 99\nbias_m = 10.0\nonset_s = 5.0")),
     "faults.0.prn", "99"),
    ("landmark-not-in-scene", lambda d: approach(d, tail=FAULT.format(kind="pixel_bias", body='landmark = "NOPE"\nmagnitude_px = 5.0')),
     "faults.0.landmark", "NOPE"),
    ("start-before-gps-epoch", lambda d: approach(d, replace=("start_time_utc = 2026-03-01T04:00:00Z", "start_time_utc = 1975-01-01T00:00:00Z")),
     "start_time_utc", "1975"),
    ("nan-coordinate", lambda d: approach(d, replace=("lat_deg = 29.3065\nlon_deg = 94.3359", "lat_deg = nan\nlon_deg = 94.3359")),
     "frame.lat_deg", "nan"),
    ("vision-sigma-zero", lambda d: approach(d, replace=("sigma_px = 1.0", "sigma_px = 0.0")),
     "vision.detection.sigma_px", "0"),
    ("dem-of-another-area", lambda d: approach(d, replace=('kind = "two_ridges"', f'kind = "dem"\ndem_paths = ["{far_away_dem(d).name}"]')),
     "terrain", "no height under the planned path"),
    ("speed-cannot-trim", lambda d: approach(d, replace=("speed_kt = 160.0", "speed_kt = 31.0")),
     "flight.speed_kt", "31"),
    ("missing-yuma", lambda d: approach(d, tail='[gnss]\nalmanac_source = "yuma"\nalmanac_path = "missing.alm"'),
     "gnss.almanac_path", "missing.alm"),
    ("empty-yuma", lambda d: ((d / "empty.alm").write_text(""), approach(d, tail='[gnss]\nalmanac_source = "yuma"\nalmanac_path = "empty.alm"'))[1],
     "gnss.almanac_path", "empty.alm"),
    ("truncated-sem", lambda d: ((d / "a.al3").write_text("31 CURRENT.ALM\n 703 344064\n1\n"), approach(d, tail='[gnss]\nalmanac_source = "sem"\nalmanac_path = "a.al3"'))[1],
     "gnss.almanac_path", "announces 31 record(s)"),
    ("binary-yuma", lambda d: ((d / "bin.alm").write_bytes(bytes(range(256)) * 8), approach(d, tail='[gnss]\nalmanac_source = "yuma"\nalmanac_path = "bin.alm"'))[1],
     "gnss.almanac_path", "bin.alm"),
    ("truncated-rinex-nav", lambda d: ((d / "nav.rnx").write_text("     3.04           N: GNSS NAV DATA    G: GPS              RINEX VERSION / TYPE\n"),
                                       approach(d, tail='[gnss]\nalmanac_source = "rinex_nav"\nalmanac_path = "nav.rnx"'))[1],
     "gnss.almanac_path", "nav.rnx"),
    ("binary-approach-file", lambda d: ((d / "bin.toml").write_bytes(b"\xff\xfe\x00\x81" * 50), d / "bin.toml")[1],
     "bin.toml", "not a text"),
    ("name-that-leaves-its-folder", lambda d: approach(d, replace=('name = "va-raim-2015"', 'name = "../../etc/x"')),
     "name", "../../etc/x"),
    ("broadcast-records-of-another-day", lambda d: approach(  # RTKLIB's 2005 sample beside a 2026 flight
        d, tail=f'[gnss]\nalmanac_source = "rinex_nav"\nalmanac_path = '
                f'"{Path(__file__).parent / "references" / "rinex" / "07590920.05n"}"'),
     "gnss.almanac_path", "expected a navigation file with records within 2 h of the flight"),
    ("empty-prn-list", lambda d: approach(d, tail=FAULT.format(kind="gps_step", body="prn = []\nbias_m = 10.0")),
     "faults.0.prn", "at least 1 PRN"),
    ("no-service-level", lambda d: approach(d, tail="[integrity]\nservice_levels = []"),
     "integrity.service_levels", "at least one service level"),
    ("nan-fault-bias", lambda d: approach(d, tail=FAULT.format(kind="gps_step", body="bias_m = nan")),
     "faults.0.bias_m", "nan"),
    ("inf-ramp", lambda d: approach(d, tail=FAULT.format(kind="gps_ramp", body="rate_m_s = inf")),
     "faults.0.rate_m_s", "inf"),
    ("absurd-pixel-bias", lambda d: approach(d, tail=FAULT.format(kind="pixel_bias", body="magnitude_px = 1e9")),
     "faults.0.magnitude_px", "1000000000"),
    ("orbit-fault-that-moves-nothing", lambda d: approach(d, tail=FAULT.format(kind="constellation_orbit", body='system = "gps"')),
     "faults.0", "non-zero translation_m or rotation_mas"),
    ("orbit-fault-of-10000-km", lambda d: approach(d, tail=FAULT.format(
        kind="constellation_orbit", body='system = "gps"\ntranslation_m = [1e7, 0.0, 0.0]')), "faults.0.translation_m.0", "10000000"),
    ("orbit-fault-nan-rotation", lambda d: approach(d, tail=FAULT.format(
        kind="constellation_orbit", body='system = "gps"\nrotation_mas = [0.0, nan, 0.0]')), "faults.0.rotation_mas.1", "nan"),
    ("orbit-fault-on-an-untracked-system", lambda d: approach(d, tail=FAULT.format(
        kind="constellation_orbit", body='system = "galileo"\ntranslation_m = [5.0, 0.0, 0.0]')), "faults.0.system", "galileo"),
    ("onset-after-the-flight", lambda d: approach(d, tail=FAULT.format(kind="gps_step", body="bias_m = 50.0\nonset_s = 5000.0")),
     "faults.0.onset_s", "5000"),
    ("misassociated-with-itself", lambda d: approach(d, tail=FAULT.format(kind="misassociation", body='landmarks = ["T1", "T1"]')),
     "faults.0", "T1"),
    ("megahertz-camera", lambda d: approach(d, replace=("rate_hz = 1.0", "rate_hz = 1e6")),
     "vision.rate_hz", "1000000"),
    ("nano-degree-fov", lambda d: approach(d, replace=('camera = { preset = "va-raim-2015", dpi = 720.0 }',
                                                       'camera = { preset = "custom", width_px = 640, height_px = 480, hfov_deg = 1e-9 }')),
     "vision.camera.hfov_deg", "1e-09"),
    ("lpe-1000-km", lambda d: approach(d, replace=("lpe_sigma_m = 0.05", "lpe_sigma_m = 1e6")),
     "landmarks.lpe_sigma_m", "1000000"),
    ("string-for-number", lambda d: approach(d, replace=("glide_path_deg = 4.86", 'glide_path_deg = "4.86"')),
     "vertical.glide_path_deg", "'4.86'"),
    ("string-for-bool", lambda d: approach(d, tail='[gnss]\nterrain_masking = "yes"'),
     "gnss.terrain_masking", "'yes'"),
    ("unknown-monitor", lambda d: approach(d, top='monitors = ["gps_raim", "raim2"]'),
     "monitors.1", "raim2"),
    ("unknown-va-raim-variant", lambda d: approach(d, tail='[monitor.va_raim]\nvariant = "foo"'), "monitor.va_raim.variant", "foo"),
    ("nan-linearity-inflation", lambda d: approach(d, tail="[monitor.va_raim]\nlinearity_inflation = nan"),
     "monitor.va_raim.linearity_inflation", "nan"),
    ("negative-linearity-inflation", lambda d: approach(d, tail="[monitor.va_raim]\nlinearity_inflation = -1.0"),
     "monitor.va_raim.linearity_inflation", "-1.0"),
    # the options of this change: FDE, the pixel monitor, the IMU, the ekf monitor, the GNSS schedule
    ("fde-three-exclusions", lambda d: approach(d, tail="[integrity]\nfde_max_excluded = 3"),
     "integrity.fde_max_excluded", "3"),
    ("unknown-fde-rule", lambda d: approach(d, tail='[integrity]\nfde_rule = "worst"'), "integrity.fde_rule", "worst"),
    ("unknown-pixel-h1", lambda d: approach(d, tail='[monitor.pixel]\nh1 = "axial"'), "monitor.pixel.h1", "axial"),
    ("zero-landmark-cap", lambda d: approach(d, tail="[monitor.pixel]\nmax_landmarks = 0"),
     "monitor.pixel.max_landmarks", "0"),
    # options that moved to the monitors' own tables name where they are now
    ("old-va-raim-table", lambda d: approach(d, tail='[va_raim]\nvariant = "seed"'), "va_raim",
     "moved to [monitor.va_raim]"),
    ("old-pixel-key", lambda d: approach(d, tail='[integrity]\npixel_h1 = "patent"'), "integrity",
     "pixel_h1 moved to [monitor.pixel] h1"),
    ("old-p-ff", lambda d: approach(d, tail="[integrity]\np_ff = 1e-6"), "integrity", "moved to [monitor.pixel] p_ff"),
    ("table-of-no-monitor", lambda d: approach(d, tail="[monitor.raim2]\nx = 1"), "monitor.raim2", "raim2"),
    ("option-of-an-optionless-monitor", lambda d: approach(d, tail="[monitor.gps_raim]\nx = 1"),
     "monitor.gps_raim", "x"),
    ("imu-rate-not-a-divisor", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]', tail="[imu]\nrate_hz = 50.0"),
     "imu.rate_hz", "50"),
    ("nan-imu-rate", lambda d: approach(d, tail="[imu]\nrate_hz = nan"), "imu.rate_hz", "nan"),
    ("custom-imu-without-figures", lambda d: approach(d, tail='[imu]\ngrade = "custom"\narw_rad_sqrt_s = 1e-4'),
     "imu", "custom"),
    ("negative-scale-factor", lambda d: approach(d, tail="[imu]\nscale_factor_ppm = -5.0"),
     "imu.scale_factor_ppm", "-5"),
    ("unknown-ekf-option", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]', tail="[monitor.ekf]\nfoo = 1"),
     "monitor.ekf", "foo"),
    ("zero-range-rate-sigma", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]',
                                                 tail="[monitor.ekf]\nrange_rate_sigma_m_s = 0.0"),
     "monitor.ekf.range_rate_sigma_m_s", "0"),
    ("nan-range-rate-sigma", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]',
                                                tail="[monitor.ekf]\nrange_rate_sigma_m_s = nan"),
     "monitor.ekf.range_rate_sigma_m_s", "nan"),
    ("string-range-rate-switch", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]',
                                                    tail='[monitor.ekf]\nrange_rate = "yes"'),
     "monitor.ekf.range_rate", "yes"),
    ("zero-feature-density", lambda d: approach(d, tail="[vision.features]\nenabled = true\ndensity_per_km2 = 0.0"),
     "vision.features.density_per_km2", "0"),
    ("nan-feature-noise", lambda d: approach(d, tail="[vision.features]\nsigma_px = nan"),
     "vision.features.sigma_px", "nan"),
    ("no-tracks", lambda d: approach(d, tail="[vision.features]\nmax_tracks = 0"), "vision.features.max_tracks", "0"),
    ("unknown-feature-key", lambda d: approach(d, tail="[vision.features]\ndensity = 3"), "vision.features", "density"),
    ("string-features-switch", lambda d: approach(d, tail='[vision.features]\nenabled = "on"'),
     "vision.features.enabled", "on"),
    ("no-feature-slots", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]', tail="[monitor.ekf]\nfeature_slots = 0"),
     "monitor.ekf.feature_slots", "0"),
    ("right-angle-parallax", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]', tail="[monitor.ekf]\nparallax_deg = 90.0"),
     "monitor.ekf.parallax_deg", "90"),
    ("negative-ekf-dither", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]', tail="[monitor.ekf]\ndither_sigma_px = -1.0"),
     "monitor.ekf.dither_sigma_px", "-1"),
    ("unknown-ekf-pl-variant", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]', tail='[monitor.ekf]\npl_variant = "arai"'),
     "monitor.ekf.pl_variant", "arai"),
    ("unknown-ekf-vision-modes", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]',
                                                    tail='[monitor.ekf]\nss_vision = "pixel"'),
     "monitor.ekf.ss_vision", "pixel"),
    ("negative-ekf-window", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]', tail="[monitor.ekf]\nwindow_s = -1.0"),
     "monitor.ekf.window_s", "-1"),
    ("nan-ekf-window", lambda d: approach(d, top='monitors = ["gps_raim", "ekf"]', tail="[monitor.ekf]\nwindow_s = nan"),
     "monitor.ekf.window_s", "nan"),
    ("schedule-out-of-order", lambda d: approach(d, tail="[gnss]\nschedule = [{ from_s = 5.0, max_satellites = 2 }, "
                                                         "{ from_s = 1.0, max_satellites = 3 }]"),
     "gnss.schedule", "5.0"),
    ("negative-satellite-cap", lambda d: approach(d, tail="[gnss]\nschedule = [{ from_s = 0.0, max_satellites = -1 }]"),
     "gnss.schedule.0.max_satellites", "-1"),
    ("nan-schedule-time", lambda d: approach(d, tail="[gnss]\nschedule = [{ from_s = nan, max_satellites = 2 }]"),
     "gnss.schedule.0.from_s", "nan"),
    # the DPE's options: the correlators and the dpe monitor
    ("negative-dpe-k", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]', tail="[monitor.dpe]\nk_factor = -1.0"),
     "monitor.dpe.k_factor", "-1"),
    ("nan-dpe-k", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]', tail="[monitor.dpe]\nk_factor = nan"),
     "monitor.dpe.k_factor", "nan"),
    ("unknown-dpe-option", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]', tail="[monitor.dpe]\ngrid = 3"),
     "monitor.dpe", "grid"),
    ("unknown-dpe-variant", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]', tail='[monitor.dpe]\nvariant = "ml"'),
     "monitor.dpe.variant", "ml"),
    ("mag-statistic-fast", lambda d: approach(d, tail='[gnss.correlators]\nstatistic = "mag"'),
     "gnss.correlators", "mag"),
    ("zero-bandwidth", lambda d: approach(d, tail="[gnss.correlators]\nbandwidth_chips = 0.0"),
     "gnss.correlators.bandwidth_chips", "0"),
    ("cn0-out-of-range", lambda d: approach(d, tail='[gnss.correlators]\ncn0_by_elevation = { "10" = 400.0 }'),
     "gnss.correlators.cn0_by_elevation", "C/N0 in [10, 70] dB-Hz, got 10.0: 400.0"),
    # the option table of a monitor the file does not list is checked all the same
    ("unlisted-va-raim-typo", lambda d: approach(d, top='monitors = ["gps_raim"]', tail='[monitor.va_raim]\nvarient = "seed"'),
     "monitor.va_raim", "varient"),
    ("unlisted-ekf-bad-value", lambda d: approach(d, top='monitors = ["gps_raim"]', tail="[monitor.ekf]\nwindow_s = -1.0"),
     "monitor.ekf.window_s", "-1"),
    ("unlisted-dpe-typo", lambda d: approach(d, top='monitors = ["gps_raim"]',
                                             tail='[monitor.dpe]\nk_factor = "calibration/dpe-k.json"\ngrid = 3'),
     "monitor.dpe", "grid"),
    ("dpe-k-file-missing", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]', tail='[monitor.dpe]\nk_factor = "missing.json"'),
     "monitor.dpe.k_factor", "missing.json"),
    ("dpe-k-file-for-other-settings", lambda d: ((d / "k.json").write_text(_k_record_for(sis="none")),
        approach(d, top='monitors = ["gps_raim", "dpe"]', tail='[monitor.dpe]\nk_factor = "k.json"'))[1],
     "monitor.dpe.k_factor", "dpe.sis = 'none' there, 'add' here"),
    ("seed-variant-on-the-power-statistic", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]',
                                                                tail='[monitor.dpe]\nvariant = "seed"\nk_factor = 5.0'),
     "gnss.correlators.statistic", "'seed' reads 'mag'"),
    ("fast-synthesis-with-few-blocks", lambda d: approach(d, tail="[gnss.correlators]\nn_noncoherent = 5"),
     "gnss.correlators", "n_noncoherent ≥ 20"),
    ("correlated-sis-for-the-correlators", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]',
                                                                tail="[gnss]\nura_tropo_tau_s = 60.0"),
     "gnss.ura_tropo_tau_s", "white per epoch"),
    ("nan-delay-step", lambda d: approach(d, tail="[gnss.correlators]\ndelay_step_m = nan"),
     "gnss.correlators.delay_step_m", "nan"),
    ("negative-window", lambda d: approach(d, tail="[gnss.correlators]\nhalf_window_m = -5.0"),
     "gnss.correlators.half_window_m", "-5"),
    ("unknown-multipath", lambda d: approach(d, tail='[gnss.correlators]\nmultipath = "sky"'),
     "gnss.correlators.multipath", "sky"),
    ("echo-stronger-than-direct", lambda d: approach(d, tail="[gnss.correlators]\nground_echo_db = 6.0"),
     "gnss.correlators.ground_echo_db", "6"),
    ("nan-doppler", lambda d: approach(d, tail="[gnss.correlators]\nresidual_doppler_hz = nan"),
     "gnss.correlators.residual_doppler_hz", "nan"),
    ("doppler-past-the-first-null", lambda d: approach(d, tail="[gnss.correlators]\nresidual_doppler_hz = 50.0"),
     "gnss.correlators.residual_doppler_hz", "50"),
    ("string-block-count", lambda d: approach(d, tail='[gnss.correlators]\nn_noncoherent = "50"'),
     "gnss.correlators.n_noncoherent", "'50'"),
    ("nan-dpe-grid", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]', tail="[monitor.dpe]\ncoarse_spacing_m = nan"),
     "monitor.dpe.coarse_spacing_m", "nan"),
    ("zero-seed-passes", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]', tail="[monitor.dpe]\nseed_passes = 0"),
     "monitor.dpe.seed_passes", "0"),
    ("binary-dpe-k-file", lambda d: ((d / "k.bin").write_bytes(bytes(range(256))),
                                     approach(d, top='monitors = ["gps_raim", "dpe"]', tail='[monitor.dpe]\nk_factor = "k.bin"'))[1],
     "monitor.dpe.k_factor", "cannot be read"),
    ("blocks-longer-than-an-epoch", lambda d: approach(d, top='monitors = ["gps_raim", "dpe"]',
                                                       tail="[gnss.correlators]\nn_noncoherent = 100"),
     "gnss.correlators", "100 blocks"),
    ("unknown-pseudorange-source", lambda d: approach(d, tail='[gnss.correlators]\npseudorange_source = "dll"'),
     "gnss.correlators.pseudorange_source", "dll"),
    # runway edge points are named by the whole metre: a finer spacing repeated ids (a traceback, after 100 s of a
    # quadratic duplicate search at 0.1 m)
    ("sub-metre-runway-spacing", lambda d: approach(d, replace=('sets = [{ kind = "triangle" }]',
                                                                'sets = [{ kind = "runway", edge_spacing_m = 0.5 }]')),
     "landmarks.sets.0.edge_spacing_m", "0.5"),
    ("one-id-in-two-sets", lambda d: approach(d, replace=('sets = [{ kind = "triangle" }]',
                                                          'sets = [{ kind = "triangle" }, { kind = "triangle" }]')),
     "landmarks.sets", "T1"),
    # a sensor is on the airframe: no lever arm is longer than the largest aircraft (NaN is not a length)
    ("kilometre-camera-lever-arm", lambda d: approach(d, tail="[vision.mount]\nlever_arm_body_m = [1500.0, 0.0, 1.0]"),
     "vision.mount.lever_arm_body_m", "a lever arm of 1500 m: expected at most 100 m"),
    ("kilometre-imu-lever-arm", lambda d: approach(d, tail="[imu]\nlever_arm_body_m = [0.0, 2000.0, 0.0]"),
     "imu.lever_arm_body_m", "a lever arm of 2000 m: expected at most 100 m"),
    ("nan-camera-lever-arm", lambda d: approach(d, tail="[vision.mount]\nlever_arm_body_m = [nan, 0.0, 1.0]"),
     "vision.mount.lever_arm_body_m.0", "nan"),
    ("string-in-imu-lever-arm", lambda d: approach(d, tail='[imu]\nlever_arm_body_m = ["1", 0.0, 0.0]'),
     "imu.lever_arm_body_m.0", "'1'"),
    # correlator pseudoranges need correlograms that fit an epoch, even with no monitor reading them
    ("correlator-pseudoranges-with-long-blocks", lambda d: approach(
        d, tail='[gnss.correlators]\npseudorange_source = "correlator"\nn_noncoherent = 100'),
     "gnss.correlators", "100 blocks"),
]


@pytest.mark.parametrize("case", FILE_CASES, ids=[c[0] for c in FILE_CASES])
def test_a_bad_file_is_refused_by_check_and_by_fly_before_any_work(case, work, capsys):
    cwd, inputs = work
    _, make, key, value = case
    path = make(inputs)
    before = listing(cwd, inputs)
    code, out = run(capsys, "check", path)
    assert code == 1, out
    assert str(path) in out and key in out and value in out, out
    code, out = run(capsys, "fly", path, "--rrd", cwd / "x.rrd")
    assert code == 2, out
    assert str(path) in out and key in out and value in out, out
    assert listing(cwd, inputs) == before  # nothing written or replaced


def test_an_aircraft_file_problem_names_the_aircraft_file(work, capsys):
    cwd, inputs = work
    ac = inputs / "ac"
    ac.mkdir()
    text = (approaches_dir().parent / "aircraft" / "b737" / "aircraft.toml").read_text()
    (ac / "aircraft.toml").write_text(text.replace('jsbsim_model = "737"', 'jsbsim_model = "no-such-model"'))
    path = approach(inputs, replace=('aircraft = "b737"', 'aircraft = "./ac"'))
    code, out = run(capsys, "check", path)
    assert code == 1 and str(ac / "aircraft.toml") in out and "jsbsim_model" in out and "no-such-model" in out, out


@pytest.mark.parametrize("key, value, said", [
    ("antenna_lever_arm_m", "[0.0, 0.0, -2000.0]", "a lever arm of 2000 m: expected at most 100 m"),
    ("camera_lever_arm_m", "[14.0, 0.0, nan]", "camera_lever_arm_m.2"),
])
def test_an_aircraft_lever_arm_off_the_airframe_names_the_aircraft_file(work, capsys, key, value, said):
    """An antenna 2 km above the CG used to fly (the monitors then saw a 2 km lever arm rotate with the
    attitude); it is refused like any bad value, naming the aircraft file, the key and the value."""
    cwd, inputs = work
    ac = inputs / "ac"
    ac.mkdir()
    text = (approaches_dir().parent / "aircraft" / "b737" / "aircraft.toml").read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith(key))
    (ac / "aircraft.toml").write_text(text.replace(line, f"{key} = {value}"))
    path = approach(inputs, replace=('aircraft = "b737"', 'aircraft = "./ac"'))
    code, out = run(capsys, "check", path)
    assert code == 1 and str(ac / "aircraft.toml") in out and key in out and said in out, out


def test_data_paths_are_relative_to_the_file_that_names_them(work, capsys):
    """almanac_path beside the approach file, run from another folder."""
    cwd, inputs = work
    code, out = run(capsys, "check", approach(inputs, tail='[gnss]\nalmanac_source = "yuma"\nalmanac_path = "a.alm"'))
    assert code == 1 and str(inputs / "a.alm") in out, out


ARG_CASES = [
    ("seed-negative", ["--seed", "-1"], "--seed", "-1"),
    ("block-nan", ["--block", "nan"], "--block", "nan"),
    ("block-zero", ["--block", "0"], "--block", "0"),
    ("block-negative", ["--block", "-5"], "--block", "-5"),
    ("port-out-of-range", ["--live", "--port", "99999"], "--port", "99999"),
    ("gust-seed-negative", ["--gust-seed", "-3"], "--gust-seed", "-3"),
    ("linger-nan", ["--live", "--linger", "nan"], "--linger", "nan"),
    ("truth-unknown-suffix", ["--truth", "out.txt"], "--truth", ".txt"),
]


@pytest.mark.parametrize("case", ARG_CASES, ids=[c[0] for c in ARG_CASES])
def test_a_bad_option_is_refused_before_the_flight(case, work, capsys):
    cwd, inputs = work
    _, args, key, value = case
    code, out = run(capsys, "fly", "va-raim-2015", "--rrd", cwd / "keep.rrd", *args)
    assert code == 2 and key in out and value in out, out
    assert listing(cwd) == {}


def test_rrd_at_a_folder_or_under_a_file_is_refused(work, capsys):
    cwd, inputs = work
    code, out = run(capsys, "fly", "va-raim-2015", "--rrd", inputs)
    assert code == 2 and "--rrd" in out and "folder" in out, out
    (inputs / "plain.txt").write_text("x")
    code, out = run(capsys, "fly", "va-raim-2015", "--rrd", inputs / "plain.txt" / "r.rrd")
    assert code == 2 and "is a file" in out, out


def test_a_bad_truth_path_never_replaces_the_recording(work, capsys):
    """``fly --truth out.txt`` used to fail after it had already replaced the recording."""
    cwd, inputs = work
    rrd = inputs / "old.rrd"
    rrd.write_bytes(b"an earlier recording")
    code, out = run(capsys, "fly", "va-raim-2015", "--rrd", rrd, "--truth", inputs / "out.txt")
    assert code == 2 and "--truth" in out
    assert rrd.read_bytes() == b"an earlier recording" and not list(inputs.glob("*.part"))


def test_live_on_a_busy_port_is_refused_before_flying(work, capsys):
    import socket

    cwd, inputs = work
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        rrd = inputs / "old.rrd"
        rrd.write_bytes(b"earlier")
        code, out = run(capsys, "fly", "va-raim-2015", "--live", "--port", port, "--rrd", rrd)
    assert code == 2 and str(port) in out and "not free" in out, out
    assert rrd.read_bytes() == b"earlier" and not list(inputs.glob("*.part"))


def test_a_non_loopback_bind_warns(work):
    import warnings

    from testbed.api import _check_live_address

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        _check_live_address("0.0.0.0", 0)
    assert any("UNAUTHENTICATED" in str(x.message) for x in w)


SPEC = ('name = "s"\napproaches = ["va-raim-2015"]\nmonitors = ["gps_raim"]\ntrials = 10\nblock_trials = 10\n'
        'chunk_trials = 10\nduration_s = 10.0\n')


def test_options_that_cannot_apply_are_refused_not_ignored(work, capsys):
    cwd, inputs = work
    spec = inputs / "s.toml"
    spec.write_text(SPEC)
    with pytest.raises(SystemExit) as exc:  # argparse: usage and the clash, exit code 2
        main(["campaign", str(spec), "--out", str(inputs / "o"), "--resume", "--restart"])
    assert exc.value.code == 2 and "not allowed with argument" in capsys.readouterr().err
    for paper in ("won-2013", "dpe-vertical"):
        for extra in (["--scheduler", "tcp://127.0.0.1:9"], ["--resume"], ["--workers", "2"]):
            code, out = run(capsys, "reproduce", paper, "--out", inputs / "r", *extra)
            assert code == 2 and extra[0] in out and paper in out, out
    code, out = run(capsys, "reproduce", "won-2013", "--out", inputs / "r", "--restart")
    assert code == 2 and "--restart" in out and "won-2013 stores no campaign" in out, out
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "va-raim-2015", "--out", str(inputs / "r"), "--resume", "--restart"])
    assert exc.value.code == 2 and "not allowed with argument" in capsys.readouterr().err
    assert not (inputs / "o").exists() and not (inputs / "r").exists() and not any(cwd.iterdir())


def test_campaign_inputs_are_checked_before_any_work(work, capsys):
    cwd, inputs = work
    empty = inputs / "empty-faults.toml"
    empty.write_text(SPEC + "faults = []\n")
    code, out = run(capsys, "campaign", empty, "--out", inputs / "o1")
    assert code == 2 and "faults" in out and str(empty) in out, out
    spec = inputs / "s.toml"
    spec.write_text(SPEC)
    code, out = run(capsys, "campaign", spec, "--out", inputs / "o2", "--scheduler", "tcp://127.0.0.1:9", "--quiet")
    assert code == 2 and "--scheduler" in out and "tcp://127.0.0.1:9" in out, out
    assert not (inputs / "o1").exists() and not (inputs / "o2").exists()
    for text, key, value in (('segment = "middle"\n', "segment", "middle"),
                             ('segment = "last"\n', "segment", "duration_s"),
                             ('[sweep]\nmultipath_echo_db = [6.0]\n', "sweep.multipath_echo_db", "6"),
                             ('[sweep]\nmultipath_echo_db = ["on"]\n', "sweep.multipath_echo_db", "on"),
                             ('[sweep]\nmax_satellites = [-1]\n', "sweep.max_satellites", "-1"),
                             ('[sweep]\nmax_satellites = [2.5]\n', "sweep.max_satellites", "2.5"),
                             ('[sweep]\nground_features = ["yes"]\n', "sweep.ground_features", "yes"),
                             ('[[faults]]\nkind = "gps_step"\nmagnitudes = [0.0, 20.0]\nonset_s = 20.0\n',
                              "faults.0.onset_s", "no epoch would be faulty: expected an onset at or before 10 s (got 20)")):
        bad = inputs / "bad-axis.toml"
        bad.write_text(SPEC.replace("duration_s", "# duration_s") + text if "duration_s" in value else SPEC + text)
        code, out = run(capsys, "campaign", bad, "--out", inputs / "o3")
        assert code == 2 and key in out and value in out and str(bad) in out, (text, out)
        assert not (inputs / "o3").exists()
    for name in ("../escaped", "/tmp/absolute", ".hidden"):  # the name makes the default output folder
        bad = inputs / "bad-name.toml"
        bad.write_text(SPEC.replace('name = "s"', f'name = "{name}"'))
        code, out = run(capsys, "campaign", bad, "--quiet")
        assert code == 2 and "name" in out and name in out and "without '/'" in out, out
    assert listing(cwd) == {}


def test_report_on_a_bad_folder_is_a_message(work, capsys):
    cwd, inputs = work
    code, out = run(capsys, "report", inputs / "nothing-here")
    assert code == 2 and "nothing-here" in out, out
    d = inputs / "corrupt"
    d.mkdir()
    (d / "manifest.json").write_text("{ not json")
    code, out = run(capsys, "report", d)
    assert code == 2 and "manifest.json" in out, out
    (d / "manifest.json").write_text(json.dumps({"spec_hash": "x", "spec": {}}))  # checked like an input
    code, out = run(capsys, "report", d)
    assert code == 2 and "spec_hash: String should match pattern" in out and "spec.trials: Field required" in out, out


def test_resume_after_an_input_file_changed_is_refused_and_restart_starts_over(work, capsys):
    from testbed.campaign.runner import run_campaign
    from testbed.campaign.store import ResultStore
    from testbed.schema import ConfigError

    cwd, inputs = work
    ap = approach(inputs, name="mine.toml")
    spec = inputs / "s.toml"
    spec.write_text(SPEC.replace('"va-raim-2015"', '"mine.toml"').replace("trials = 10", "trials = 30"))
    out = inputs / "out"
    run_campaign(spec, out, progress=False, max_chunks=1)  # killed after one chunk
    ap.write_text(ap.read_text().replace("speed_kt = 160.0", "speed_kt = 165.0"))
    with pytest.raises(ConfigError) as ei:
        run_campaign(spec, out, resume=True, progress=False)
    assert str(ap) in str(ei.value) and "changed" in str(ei.value) and "--restart" in str(ei.value)
    res = run_campaign(spec, out, restart=True, progress=False)
    assert res.chunks_skipped == 0 and ResultStore(out).complete()


def test_resume_after_the_spec_changed_names_every_key_that_changed(work, capsys):
    """README: a resume is refused naming what changed, not with two hashes: each spec key as stored → now,
    and each input file changed since."""
    from testbed.campaign.runner import run_campaign

    cwd, inputs = work
    ap = approach(inputs, name="mine.toml")
    spec = inputs / "s.toml"
    spec.write_text(SPEC.replace('"va-raim-2015"', '"mine.toml"').replace("trials = 10", "trials = 20"))
    out = inputs / "out"
    run_campaign(spec, out, progress=False, max_chunks=1)
    spec.write_text(SPEC.replace('"va-raim-2015"', '"mine.toml"').replace("trials = 10", "trials = 40")
                    + "base_seed = 3\n[[faults]]\nkind = \"gps_step\"\nmagnitudes = [0.0, 20.0]\nonset_s = 5.0\n")
    ap.write_text(ap.read_text().replace("speed_kt = 160.0", "speed_kt = 165.0"))
    before = listing(out)
    code, text = run(capsys, "campaign", spec, "--out", out, "--resume", "--quiet")
    assert code == 2, text
    for said in ("trials: 20 → 40", "base_seed: 0 → 3", 'faults.0.kind: "none" → "gps_step"',
                 "faults.0.magnitudes: [0.0] → [0.0, 20.0]", f"{ap}: changed since the stored run", "--restart"):
        assert said in text, (said, text)
    assert "hash" not in text, text
    assert listing(out) == before
    # the report settings change no result: not a reason to refuse
    spec.write_text(SPEC.replace('"va-raim-2015"', '"mine.toml"').replace("trials = 10", "trials = 20")
                    + "[report]\nconfidence = 0.9\n")
    ap.write_text(ap.read_text().replace("speed_kt = 165.0", "speed_kt = 160.0"))
    assert run(capsys, "campaign", spec, "--out", out, "--resume", "--quiet", "--no-report")[0] == 0


@pytest.mark.slow  # moved out of the default set: its run time (the default set stays within 8 min)
def test_reproduce_takes_the_restart_its_refusal_advises(work, capsys, monkeypatch):
    """`reproduce va-raim-2015` over a stored run of another size is refused naming what changed and advising
    --restart, which `reproduce` takes (it used to lack it) and which then starts over. The reproduction is cut
    down to one tiny experiment (10 sorties, 20 with --full) so it runs in seconds."""
    import tomllib

    import testbed.studies.reproduce as rp
    from testbed.campaign.spec import CampaignSpec, resolve_spec
    from testbed.campaign.store import ResultStore

    def tiny(n: int) -> dict:
        trials = 10 if n == rp.QUICK_TRIALS else 20
        d = tomllib.loads(SPEC) | {"trials": trials, "block_trials": trials, "chunk_trials": trials}
        return {"gps-faults": resolve_spec(CampaignSpec.model_validate(d), rp.approaches_dir() / "campaigns" / "t")}

    monkeypatch.setattr(rp, "loaded_experiments", tiny)
    monkeypatch.setattr(rp, "write_summary", lambda out, n, walls, outs=None: out / "reproduce.md")
    monkeypatch.setattr("testbed.campaign.report.write_report", lambda d, **k: d / "report.md")  # figures: not the point
    cwd, inputs = work
    out = inputs / "r"
    assert run(capsys, "reproduce", "va-raim-2015", "--out", out, "--quiet")[0] == 0
    code, text = run(capsys, "reproduce", "va-raim-2015", "--out", out, "--full", "--quiet")
    assert code == 2 and "trials: 10 → 20" in text and "--restart" in text, text
    assert run(capsys, "reproduce", "va-raim-2015", "--out", out, "--full", "--restart", "--quiet")[0] == 0
    assert ResultStore(out / "gps-faults").manifest()["spec"]["trials"] == 20


def _edit_json(path: Path, edit) -> None:
    d = json.loads(path.read_text())
    edit(d)
    path.write_text(json.dumps(d))


@pytest.mark.parametrize("edit, said", [
    (lambda m: m.update(cells="3"), ["cells: Input should be a valid integer", "'3'"]),
    (lambda m: m["spec"].pop("monitors"), ["spec.monitors: Field required"]),
    (lambda m: m["spec"].update(trials=-5), ["spec.trials: Input should be greater than or equal to 1", "-5"]),
    (lambda m: m["inputs"]["files"].update(x=7), ["inputs.files.x: Input should be a valid string", "7"]),
    (lambda m: m.update(format=1), ["format: Input should be 2", "1"]),
], ids=["cells-a-string", "no-monitors", "negative-trials", "file-digest-a-number", "another-format"])
def test_an_edited_manifest_is_named_key_by_key_by_every_command_that_reads_it(work, capsys, edit, said):
    """The stored manifest is read like an input by resume, report and reproduce: a key of the wrong kind,
    missing or out of range names the file, the key and the value, exit 2 (a spec without monitors made
    `testbed report` fail with a KeyError traceback; a string cell count passed)."""
    from testbed.campaign.runner import run_campaign

    cwd, inputs = work
    spec = inputs / "s.toml"
    spec.write_text(SPEC)
    out = inputs / "out"
    run_campaign(spec, out, progress=False)
    man = out / "manifest.json"
    _edit_json(man, edit)
    before = listing(out)
    for argv in (["campaign", spec, "--out", out, "--resume", "--quiet"], ["report", out]):
        code, text = run(capsys, *argv)
        assert code == 2 and "Traceback" not in text and str(man) in text and "--restart" in text, (argv, text)
        for s in said:
            assert s in text, (argv, s, text)
    assert listing(out) == before  # nothing written over


def test_a_damaged_run_log_is_kept_aside_not_summed(work):
    """runs.json with a wall time that is not a number: kept aside with a warning (it made the total a
    TypeError), the run times start again."""
    from testbed.campaign.store import ResultStore

    cwd, inputs = work
    (inputs / "runs.json").write_text(json.dumps([{"started_utc": "2026-01-01T00:00:00Z", "finished": True,
                                                   "wall_s": "12", "chunks_run": 1, "epochs_run": 10}]))
    with pytest.warns(UserWarning, match="wall_s"):
        assert ResultStore(inputs).wall_s() == 0.0
    assert not (inputs / "runs.json").exists() and len(list(inputs.glob("runs.json.damaged-*"))) == 1


def test_a_damaged_chunk_is_computed_again_on_resume(work):
    import pyarrow.parquet as pq

    from testbed.campaign.runner import run_campaign

    cwd, inputs = work
    spec = inputs / "s.toml"
    spec.write_text(SPEC.replace("trials = 10", "trials = 20"))
    whole = inputs / "whole"
    run_campaign(spec, whole, progress=False)
    out = inputs / "out"
    run_campaign(spec, out, progress=False, max_chunks=1)
    part = next((out / "parts").glob("c*/trials.parquet"))
    part.write_bytes(part.read_bytes()[:40])  # truncated after it was written
    with pytest.warns(UserWarning, match="unreadable chunk"):
        run_campaign(spec, out, resume=True, progress=False)
    from test_campaign import same

    assert same(pq.read_table(out / "trials.parquet"), pq.read_table(whole / "trials.parquet"))


# --------------------------------------------------------------------------- fuzz

VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12), st.booleans(),
    st.text(max_size=6), st.lists(st.floats(-1e3, 1e3), max_size=3))
KEYS = [("vertical", "glide_path_deg"), ("vertical", "crossing_height_m"), ("flight", "speed_kt"),
        ("flight", "flaps"), ("frame", "h"), ("gnss", "elevation_mask_deg"), ("gnss", "sigma_ura_m"),
        ("vision", "rate_hz"), ("landmarks", "lpe_sigma_m"), ("vision.detection", "sigma_px"),
        ("integrity", "p_fa"), ("wind", "speed_kt")]


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if v != v else ("inf" if v == np.inf else "-inf" if v == -np.inf else repr(v))
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return json.dumps(v) if isinstance(v, str) else str(v)


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # the same 40 cases on every machine
@given(key=st.sampled_from(KEYS), value=VALUES)
def test_fuzzed_approach_values_give_a_clear_error_or_a_valid_run(tmp_path_factory, key, value):
    """Any value at any of these keys: ``check_file`` returns problems that name the key, or none
    (then the set-up builds); it never raises."""
    from testbed.api import check_file, load_approach
    from testbed.sim.setup import build_setup

    d = tmp_path_factory.mktemp("fuzz")
    table, name = key
    text = BASE
    header = f"[{table}]"
    line = f"{name} = {_toml(value)}"
    if header in text:
        lines = text.splitlines()
        lines = [ln for ln in lines if not ln.startswith(f"{name} =") or not _in_table(lines, ln, header)]
        i = lines.index(header)
        lines.insert(i + 1, line)
        text = "\n".join(lines)
    else:
        text += f"\n{header}\n{line}\n"
    p = d / "f.toml"
    p.write_text(text)
    problems = check_file(p)
    if problems:
        assert any(name in q for q in problems) or any("TOML" in q for q in problems), problems
    else:
        build_setup(load_approach(p), None)


def _in_table(lines: list[str], line: str, header: str) -> bool:
    """Whether ``line`` sits in the table ``header`` (between it and the next header)."""
    cur = None
    for ln in lines:
        if ln.startswith("["):
            cur = ln.strip()
        if ln is line:
            return cur == header
    return False


def test_nothing_is_written_to_the_working_folder_by_check(work, capsys):
    cwd, _ = work
    assert run(capsys, "check", approaches_dir() / "va-raim-2015.toml")[0] == 0
    assert listing(cwd) == {}
    assert os.listdir(cwd) == []


def test_an_output_folder_that_is_a_file_is_refused(work, capsys):
    cwd, inputs = work
    f = inputs / "taken"
    f.write_text("mine")
    spec = inputs / "s.toml"
    spec.write_text(SPEC)
    for argv in (["campaign", spec, "--out", f, "--quiet"], ["export-rinex", "va-raim-2015", f],
                 ["calibrate-dpe", "--out", cwd / "k.json", "--work", f]):
        code, out = run(capsys, *argv)
        assert code == 2 and str(f) in out and "is a file" in out, out
        assert f.read_text() == "mine"


@pytest.mark.parametrize("argv", [["--sorties", "3"], ["--sorties", "x"], ["--p-hmi", "0.5"], ["--p-hmi", "nan"], [],
                                  ["--chunk", "0"], ["--chunk", "x"], ["--trajectories"]])
def test_calibrate_dpe_options_are_checked_before_any_work(argv, work, capsys):
    cwd, _ = work
    with pytest.raises(SystemExit) as ei:  # argparse: usage message, exit 2 (no --out: required)
        main(["calibrate-dpe", *argv] + ([] if not argv else ["--out", str(cwd / "k.json")]))
    assert ei.value.code == 2
    assert not list(cwd.iterdir())


def test_calibrate_dpe_names_an_unknown_trajectory_before_any_work(work, capsys):
    cwd, _ = work
    code, out = run(capsys, "calibrate-dpe", "--out", cwd / "k.json", "--trajectories", "zunz-rwy05-final",
                    "no-such-approach", "--work", cwd / "w")
    assert code == 2 and "no-such-approach" in out, out
    assert not list(cwd.iterdir())


@pytest.mark.slow  # 10 s: a calibration chunk stored, then a different run refused
def test_calibrate_dpe_refuses_a_work_folder_of_another_run_and_changes_nothing(work, capsys):
    cwd, _ = work
    w = cwd / "w"
    w.mkdir()
    manifest = w / "manifest.json"
    manifest.write_text('{"approach": "x", "trajectories": [], "sorties": 6, "seed": 0, "chunk": 25}')
    before = listing(cwd)
    code, out = run(capsys, "calibrate-dpe", "--out", cwd / "k.json", "--work", w)
    assert code == 2 and "--resume to continue" in out, out
    code, out = run(capsys, "calibrate-dpe", "--out", cwd / "k.json", "--work", w, "--resume", "--sorties", "7")
    assert code == 2 and "sorties = 6 there, 7 here" in out and "approach = 'x' there" in out, out
    manifest.write_text("{not json")
    code, out = run(capsys, "calibrate-dpe", "--out", cwd / "k.json", "--work", w, "--resume")
    assert code == 2 and "cannot be read" in out and str(manifest) in out, out
    for text, said in (("[1, 2]", "<top level>: Input should be a valid dictionary"),  # was an AttributeError
                       ('{"approach": "x", "trajectories": [], "sorties": "6", "seed": 0, "chunk": 25}',
                        "sorties: Input should be a valid integer")):
        manifest.write_text(text)
        code, out = run(capsys, "calibrate-dpe", "--out", cwd / "k.json", "--work", w, "--resume")
        assert code == 2 and "Traceback" not in out and str(manifest) in out and said in out, out
    assert listing(cwd) == {**before, str(manifest): manifest.stat().st_mtime_ns}
    assert not (cwd / "k.json").exists()


def test_calibrate_dpe_into_a_missing_folder_is_refused(work, capsys):
    cwd, _ = work
    code, out = run(capsys, "calibrate-dpe", "--out", cwd / "no" / "k.json")
    assert code == 2 and "does not exist" in out
    assert not list(cwd.iterdir())


def test_new_campaign_options_are_checked(work, capsys):
    cwd, inputs = work
    for bad in ("-1", "0", "abc", "nan"):
        with pytest.raises(SystemExit) as ei:  # argparse: usage message, exit 2
            main(["campaign", "quick-look", "--trials", bad, "--out", str(inputs / "o")])
        assert ei.value.code == 2 and bad in capsys.readouterr().err
    for cmd in (["campaign", "quick-look"], ["reproduce", "va-raim-2015"]):
        for bad in ("0", "-2", "1.5", "many"):
            with pytest.raises(SystemExit) as ei:
                main([*cmd, "--workers", bad, "--out", str(inputs / "o")])
            err = capsys.readouterr().err
            assert ei.value.code == 2 and "--workers" in err and repr(bad) in err and "auto" in err, err
    code, out = run(capsys, "campaign", "quick-look", "--workers", "2", "--scheduler", "tcp://127.0.0.1:9",
                    "--out", inputs / "o")
    assert code == 2 and "--workers" in out and "--scheduler" in out, out
    spec = inputs / "v.toml"
    spec.write_text(SPEC + '[sweep]\nva_raim_variant = ["nope"]\n')
    code, out = run(capsys, "campaign", spec, "--out", inputs / "o")
    assert code == 2 and "sweep.va_raim_variant.0" in out and "nope" in out, out
    assert not (inputs / "o").exists()
    spec.write_text(SPEC + '[sweep]\ndpe_variant = ["likelihood", "paper"]\n')
    code, out = run(capsys, "campaign", spec, "--out", inputs / "o")
    assert code == 2 and "sweep.dpe_variant.1" in out and "paper" in out and "seed" in out, out
    assert not (inputs / "o").exists()


def test_a_path_too_steep_to_trim_names_the_speed_and_the_path(tmp_path):
    """The fuzz found it on a fresh machine: an 8° glide path at 160 kt does not trim; the message names
    both keys that set the trim condition."""
    from testbed.api import check_file

    import re

    text = re.sub(r"(?m)^glide_path_deg = .*$", "glide_path_deg = 8.0", BASE)
    assert "glide_path_deg = 8.0" in text
    p = tmp_path / "steep.toml"
    p.write_text(text)
    problems = check_file(p)
    assert problems and any("glide_path_deg = 8" in q and "speed_kt" in q for q in problems), problems


@pytest.mark.parametrize("script,args,named", [
    ("bench_campaign.py", ["--repeats", "0"], "--repeats"),
    ("bench_campaign.py", ["--per-experiment", "150"], "--per-experiment"),
    ("bench_campaign_breakdown.py", ["--sorties", "-3"], "--sorties"),
    ("bench_campaign_breakdown.py", ["--experiment", "nope"], "--experiment"),
    ("bench_dask.py", ["--workers", "0"], "--workers"),
    ("bench_dask.py", ["--trials", "nan"], "--trials"),
    ("bench_dask.py", ["--experiment", "nope"], "--experiment"),
])
def test_campaign_benchmarks_refuse_bad_options_before_any_work(tmp_path, script, args, named):
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, str(root / "benchmarks" / script), *args], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert named in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("argv", [["observability", "--seed", "-1"], ["fly", "va-raim-2015", "--flight-only", "--seed", "-1"],
                                  ["calibrate-dpe", "--out", "k.json", "--seed", "-1"]],
                         ids=["observability", "fly-flight-only", "calibrate-dpe"])
def test_every_seed_option_is_checked_before_any_work(argv, work, capsys):
    cwd, _ = work
    code, out = run(capsys, *argv)
    assert code == 2 and "--seed = -1: expected a whole number from 0 to 2^63 - 1" in out, out
    assert listing(cwd) == {}


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_an_output_folder_where_nothing_can_be_created_is_refused(work, capsys):
    """/proc passes os.access for root but refuses a new folder: the check tries one (root or not)."""
    code, out = run(capsys, "export-rinex", "va-raim-2015", "/proc/testbed-out")
    assert code == 2 and "DIR /proc/testbed-out: cannot create the folder /proc/testbed-out" in out, out


def test_campaign_commands_report_bad_input_on_stderr_also_as_a_module(work):
    """`python -m testbed.campaign` is the campaign commands' own entry: the same message and exit code."""
    cwd, _ = work
    for argv in (["report", str(cwd / "nothing")], ["reproduce", "no-such-paper"]):
        res = subprocess.run([sys.executable, "-m", "testbed.campaign", *argv], cwd=cwd, capture_output=True,
                             text=True, timeout=120)
        assert res.returncode == 2 and res.stderr.startswith("error: ") and "Traceback" not in res.stderr, res
        assert res.stdout == ""


def test_calibrate_dpe_with_too_few_sorties_for_the_tail_fit_is_refused_before_they_run(work, capsys):
    """6 sorties pass --sorties' range (one per stratum) but cannot reach the tail fit's 1000 epochs on this
    150-epoch trajectory: said after the one flight, not after the sorties."""
    cwd, _ = work
    code, out = run(capsys, "calibrate-dpe", "--out", cwd / "k.json", "--sorties", "6")
    assert code == 2 and "--sorties = 6: at most 900 calibration epochs" in out and "at least 7 sorties" in out, out
    assert "chunks of" not in out  # no sortie ran
    assert listing(cwd) == {}


def test_a_dem_beside_an_approach_named_by_a_relative_path_is_found(work, capsys):
    """`testbed check sub/a.toml` with dem_paths = ["dem.npz"] in sub/: the DEM is sub/dem.npz (it was joined
    to sub/ twice, sub/sub/dem.npz, and a good file was refused)."""
    cwd, _ = work
    sub = cwd / "sub"
    sub.mkdir()
    lat, lon = np.linspace(29.0, 29.6, 61), np.linspace(93.9, 94.7, 81)
    np.savez(sub / "dem.npz", lat_deg=lat, lon_deg=lon, height_m=np.full((lat.size, lon.size), 2900.0))
    approach(sub, replace=('[terrain]\nkind = "two_ridges"', '[terrain]\nkind = "dem"\ndem_paths = ["dem.npz"]'),
             name="a.toml")
    code, out = run(capsys, "check", "sub/a.toml")
    assert code == 0 and "sub/a.toml: ok" in out, out


def test_a_navigation_file_of_the_flights_own_day_is_accepted(work, capsys):
    """The other side of 'broadcast-records-of-another-day': the flight's own exported navigation file checks clean."""
    cwd, inputs = work
    assert run(capsys, "export-rinex", "va-raim-2015", inputs / "rx")[0] == 0
    p = approach(inputs, tail=f'[gnss]\nalmanac_source = "rinex_nav"\nalmanac_path = "{inputs / "rx" / "va-raim-2015.nav"}"')
    code, out = run(capsys, "check", p)
    assert code == 0 and f"{p}: ok" in out, out


def test_more_bad_paths_and_options_are_named_before_any_work(work, capsys):
    cwd, inputs = work
    a_file = inputs / "taken"
    a_file.write_text("mine")
    cases = [
        (["reproduce", "won-2013", "--out", a_file], "is a file"),
        (["reproduce", "dpe-vertical", "--out", a_file / "x"], "is a file"),
        (["calibrate-dpe", "--out", a_file / "k.json"], f"--out: {a_file} is a file, not a folder"),
        (["calibrate-dpe", "--out", cwd / "k.json", "--resume"], "--resume: expected --work DIR too"),
        (["fly", inputs], "is a folder: expected a TOML file"),
        (["campaign", inputs, "--out", cwd / "o"], "is a folder: expected a TOML file"),
    ]
    for argv, said in cases:
        code, out = run(capsys, *argv)
        assert code == 2 and said in out, (argv, out)
    assert a_file.read_text() == "mine" and listing(cwd) == {}
    spec = inputs / "no-trials.toml"
    spec.write_text(SPEC.replace("trials = 10\n", "", 1))  # a spec missing one key is still a spec
    code, out = run(capsys, "check", spec)
    assert code == 1 and "1 problem(s)" in out and "trials: Field required" in out, out


def test_ctrl_c_in_any_command_is_exit_130_without_a_traceback(work):
    """README: exit code 130 when interrupted, never a traceback (campaign and reproduce have their own
    message and test in test_campaign.py); observability works for 15-20 s, interrupted after 4."""
    import signal
    import time

    cwd, _ = work
    proc = subprocess.Popen([sys.executable, "-m", "testbed.cli", "observability"], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        time.sleep(4.0)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err, (out, err)
    assert listing(cwd) == {}


@pytest.mark.parametrize("delay_s", [0.3, 0.8, 1.5])
def test_ctrl_c_while_the_packages_load_is_exit_130_without_a_traceback(work, delay_s):
    """The first seconds of a command import numba, scipy, pydantic...: a Ctrl-C there gave a
    KeyboardInterrupt traceback; the imports now run inside the command's handler."""
    import ast
    import signal
    import time

    top = [n for n in ast.parse((Path(__file__).resolve().parents[1] / "testbed" / "cli.py").read_text()).body
           if isinstance(n, (ast.Import, ast.ImportFrom))]
    assert all(not (getattr(n, "module", None) or "").startswith("testbed") and
               not any(a.name.startswith("testbed") for a in n.names) for n in top)  # the stdlib only
    cwd, _ = work
    proc = subprocess.Popen([sys.executable, "-m", "testbed.cli", "fly", "--no-record"], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        time.sleep(delay_s)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    # -SIGINT: stopped before Python installed its own handler (the shell reports 130 as well)
    assert proc.returncode in (130, -signal.SIGINT) and "Traceback" not in err, (proc.returncode, err)
    assert listing(cwd) == {}


def test_a_command_that_succeeds_replaces_its_own_outputs(work, capsys):
    """README: `export-rinex` into the same folder twice replaces its files (the second seed's observations)."""
    cwd, _ = work
    assert run(capsys, "export-rinex", "va-raim-2015", cwd / "rx", "--seed", "1")[0] == 0
    first = (cwd / "rx" / "va-raim-2015.obs").read_text()
    assert run(capsys, "export-rinex", "va-raim-2015", cwd / "rx", "--seed", "2")[0] == 0
    second = (cwd / "rx" / "va-raim-2015.obs").read_text()
    assert second != first and sorted(p.name for p in (cwd / "rx").iterdir()) == [
        "va-raim-2015.nav", "va-raim-2015.obs", "va-raim-2015.truth.csv"]

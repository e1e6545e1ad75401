"""The monitor contract: a monitor registered here runs in the loop, the recording and a
campaign without any change to their code, and every shipped monitor stepped block by block
equals one call on all epochs (its typed state carries exactly what later epochs need)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pyarrow.parquet as pq
import pytest
from record_checks import assert_records_equal

from pydantic import Field

from testbed import monitors as registry
from testbed.integrity import lsq
from testbed.integrity.monitor import ANTENNA, Monitor, MonitorContext, MonitorDefaults, Observations
from testbed.records import Diagnostics, MonitorOutput, epoch_array
from testbed.schema import ConfigError, StrictModel


@dataclass(frozen=True)
class PlainLsqDiagnostics(Diagnostics):
    n_iter: np.ndarray = epoch_array()


class PlainLsqOptions(StrictModel):
    """The test monitor's own options table, ``[monitor.plain_lsq]``."""

    up_offset_m: float = Field(0.0, ge=-1000.0, le=1000.0, description="added to the fix's up coordinate")


@dataclass(frozen=True)
class PlainLsq(MonitorDefaults):
    """Weighted least squares on the visible pseudoranges, no integrity (a test's monitor)."""

    name: str
    context: MonitorContext
    options: PlainLsqOptions = PlainLsqOptions()
    inputs: ClassVar[frozenset[str]] = frozenset({"gnss"})
    reference: ClassVar[str] = ANTENNA

    def initial_state(self):
        return None

    def step(self, obs: Observations, state):
        g, frame = obs.gnss, self.context.frame
        vis = np.asarray(g.visible)
        anchor = frame.ecef_to_enu(np.asarray(g.sat_pos_ecef))
        z = np.where(vis, g.pseudorange, 0.0)
        w = np.where(vis, 1.0 / np.where(vis, g.sigma, 1.0) ** 2, 0.0)
        sol = lsq.solve_ranges(anchor, z, w, vis, np.ones(vis.shape[-1]))
        nan = np.full(vis.shape[:-1], np.nan)
        levels = tuple(self.context.integrity.service_levels)
        out = MonitorOutput(
            name=self.name, t=np.asarray(g.t), pos_enu=sol.x[..., :3] + [0.0, 0.0, self.options.up_offset_m], clock=sol.x[..., 3], hpl=nan, vpl=nan,
            test_stat=nan, threshold=nan, alert=np.zeros(nan.shape, bool),
            available=np.zeros(nan.shape + (len(levels),), bool), service_levels=levels,
            n_used=vis.sum(-1).astype(np.int16), excluded=np.full(nan.shape, -1, np.int16),
            reason=sol.reason.astype(np.int8), reasons=lsq.REASONS, diagnostics=PlainLsqDiagnostics(sol.n_iter))
        return out, state


@pytest.fixture
def plain_lsq():
    registry.register("plain_lsq", lambda ctx, options: PlainLsq("plain_lsq", ctx, options), {"gnss"},
                      PlainLsqOptions)
    yield "plain_lsq"
    registry.unregister("plain_lsq")


def test_the_shipped_monitors_follow_the_protocol():
    from testbed.api import load_approach
    from testbed.sim.setup import build_setup

    setup = build_setup(load_approach("va-raim-2015"), None)
    assert setup.monitor_names == ("gps_raim", "va_raim", "pixel")
    for mon in setup.monitors:
        assert isinstance(mon, Monitor)
        assert mon.inputs == registry.monitor_inputs(mon.name)


def test_a_registered_monitor_runs_in_the_loop_the_recording_a_campaign_and_rinex_replay(plain_lsq, tmp_path):
    """...with its own options table read from the approach file (the campaign) or the monitor file (replay)."""
    from testbed.api import load_approach, run_approach
    from testbed.campaign.runner import run_campaign
    from testbed.resources import approaches_dir
    from testbed.viz.readback import entity_paths, scalar_series

    path = tmp_path / "plain-approach.toml"
    text = (approaches_dir() / "va-raim-2015.toml").read_text()
    path.write_text(text.replace("\n[", f'\nmonitors = ["gps_raim", "{plain_lsq}"]\n\n[', 1)
                    + f"\n[monitor.{plain_lsq}]\nup_offset_m = 5.0\n")
    ap = load_approach(path)
    assert ap.config.monitor[plain_lsq].up_offset_m == 5.0
    rrd = tmp_path / "plain.rrd"
    run = run_approach(ap, seed=2, rrd_path=rrd, block_s=7.0)
    out, ref = run.outputs[plain_lsq], run.outputs["gps_raim"]
    # the same weighted fix as GPS RAIM's, solved by other code, moved up by its option
    ok = ref.reason == 0
    assert ok.mean() > 0.9
    np.testing.assert_allclose(out.pos_enu[ok], ref.pos_enu[ok] + [0.0, 0.0, 5.0], atol=0.01)
    assert run.summaries[plain_lsq].reference == ANTENNA
    assert run.summaries[plain_lsq].hpe95 == pytest.approx(run.summaries["gps_raim"].hpe95, abs=0.01)
    assert run.summaries[plain_lsq].vpe95 > 4.0
    assert f"/integrity/{plain_lsq}/horizontal/hpl" in entity_paths(rrd)
    t, n_used = scalar_series(rrd, f"/sensors/satellites_used/{plain_lsq}")
    np.testing.assert_array_equal(n_used, out.n_used)

    spec = tmp_path / "plain.toml"
    spec.write_text(f'name = "plain"\napproaches = ["{path}"]\nmonitors = ["{plain_lsq}"]\ntrials = 20\n'
                    'block_trials = 10\nchunk_trials = 20\nduration_s = 20.0\n')
    run_campaign(spec, tmp_path / "camp", progress=False)
    trials = pq.read_table(tmp_path / "camp" / "trials.parquet").to_pydict()
    assert set(trials["monitor"]) == {plain_lsq} and len(trials["trial"]) == 20
    assert all(np.isfinite(trials["max_he"])) and not any(trials["detected"])
    assert min(trials["max_ve"]) > 4.0  # the option reached the campaign's monitor

    # RINEX replay: the flight's observations written as RINEX and read back, both monitors stepped over them
    from testbed.api import export_rinex
    from testbed.replay import monitor_rinex

    obs, nav = export_rinex(ap, tmp_path / "rnx", seed=2)
    cfg = tmp_path / "monitor.toml"
    cfg.write_text(f"[monitor.{plain_lsq}]\nup_offset_m = -3.0\n")
    replay = monitor_rinex(obs, nav, config=cfg, monitors=("gps_raim", plain_lsq), out_dir=tmp_path / "replay")
    got, want = replay.outputs[plain_lsq], replay.outputs["gps_raim"]
    fixed = want.reason == 0
    assert fixed.mean() > 0.9
    np.testing.assert_allclose(got.pos_enu[fixed], want.pos_enu[fixed] + [0.0, 0.0, -3.0], atol=0.01)
    cfg.write_text(f"[monitor.{plain_lsq}]\nup_offset_m = 1e6\n")  # checked by the monitor's own model
    with pytest.raises(ConfigError, match=f"monitor.{plain_lsq}.up_offset_m"):
        monitor_rinex(obs, nav, config=cfg, monitors=(plain_lsq,), out_dir=tmp_path / "replay2")
    assert any(plain_lsq in p.name for p in replay.written)


def test_an_unregistered_name_is_a_config_error_naming_the_list_item(tmp_path):
    from testbed.api import check_file
    from testbed.resources import approaches_dir

    text = 'monitors = ["gps_raim", "plain_lsq"]\n' + (approaches_dir() / "zunz-rwy05-final.toml").read_text()
    p = tmp_path / "x.toml"
    p.write_text(text)
    problems = check_file(p)
    assert any("monitors.1" in q and "plain_lsq" in q and "gps_raim" in q for q in problems), problems


@pytest.mark.parametrize("blocks", [[5, 9, 47], [1] * 8 + [53]])
def test_every_shipped_monitor_stepped_in_blocks_equals_one_call(blocks):
    """Typed state across blocks, with trials (a batch of 3) and a GPS step: block by block is
    the one-call output, every field of it (VA-RAIM carries only its context epochs)."""
    from test_va_raim_scenario import make_scenario

    from testbed.integrity.settings import IntegritySettings
    from testbed.records import take_epochs

    sc = make_scenario(np.random.default_rng(5), (3,), t0=0.0, t1=60.0, rate_hz=1.0)
    pr = sc.gnss.pseudorange.copy()
    pr[1, 25:, np.flatnonzero(sc.gnss.visible[1, 25])[0]] += 50.0
    gnss = dataclasses.replace(sc.gnss, pseudorange=pr)
    # VA-RAIM's seed variant: its vision rows and calibration state are exercised
    ctx = MonitorContext(frame=sc.frame, integrity=IntegritySettings(), options={"va_raim": {"variant": "seed"}},
                         threads=1)
    assert sum(blocks) == len(gnss.t)
    for name in ("gps_raim", "va_raim", "pixel"):
        mon = registry.build_monitor(name, ctx)
        whole, _ = mon.step(Observations(gnss, sc.vision), mon.initial_state())
        state, parts, k = mon.initial_state(), [], 0
        for n in blocks:
            sl = slice(k, k + n)
            part, state = mon.step(Observations(take_epochs(gnss, sl), take_epochs(sc.vision, sl)), state)
            parts.append(part)
            k += n
        from testbed.records import concat_epochs

        assert_records_equal(concat_epochs(parts), whole, f"{name}.", rtol=1e-9, atol=1e-6)
        if name == "va_raim":
            assert len(state.context.t) <= 4  # calibration epoch(s) and the last fix, not the flight


def test_joining_blocks_pads_a_ragged_field_instead_of_dropping_it():
    from testbed.records import concat_epochs

    @dataclass(frozen=True)
    class Rows(Diagnostics):
        rows: np.ndarray = epoch_array(1, ragged=True)
        flag: np.ndarray = epoch_array(1, ragged=True)

    a = Rows(np.ones((2, 3)), np.ones((2, 3), bool))
    b = Rows(np.full((1, 5), 2.0), np.ones((1, 5), bool))
    j = concat_epochs([a, b])
    assert j.rows.shape == (3, 5) and np.isnan(j.rows[:2, 3:]).all() and (j.rows[2] == 2).all()
    assert not j.flag[:2, 3:].any() and j.flag[2].all()
    with pytest.raises(TypeError, match="epoch_array"):
        @dataclass(frozen=True)
        class Undeclared(Diagnostics):
            x: np.ndarray

        concat_epochs([Undeclared(np.ones(2)), Undeclared(np.ones(2))])


def test_check_compiles_nothing_and_library_calls_leave_the_heap_alone():
    """``testbed check`` (check_file) calls no compiled kernel, and a monitor call from the library
    does not apply the process-wide heap setting (only the CLI and the campaign driver do)."""
    import subprocess
    import sys

    code = (
        "import numba\n"
        "from testbed.api import check_file\n"
        "assert check_file('va-raim-2015') == []\n"
        "from testbed.integrity import kernels\n"
        "used = [n for n in dir(kernels) if isinstance(getattr(kernels, n), numba.core.registry.CPUDispatcher)"
        " and getattr(kernels, n).signatures]\n"
        "assert used == [], used\n"
        "from testbed import heap\n"
        "from test_integrity_core_helpers import make_gnss\n"
        "from testbed.integrity.raim import gps_raim\n"
        "import numpy as np\n"
        "from testbed.frames import LocalFrame\n"
        "frame = LocalFrame(29.3, 94.3, 2950.0)\n"
        "g, _, _ = make_gnss(frame, np.zeros((3, 3)), 1e5 + np.arange(3.0), np.random.default_rng(0))\n"
        "assert (gps_raim(g, frame).reason == 0).all()\n"
        "assert heap.keep_freed_memory.cache_info().currsize == 0  # never applied by the library\n"
    )
    from pathlib import Path

    import os

    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=Path(__file__).parent,
                         env={**os.environ, "PYTHONPATH": str(Path(__file__).parent)})
    assert res.returncode == 0, res.stderr[-2000:]


def test_a_monitor_lacking_a_member_of_the_contract_is_refused_by_name():
    """Every member callers use is declared (no probing with getattr): a monitor class that neither defines the
    optional members nor derives from MonitorDefaults is refused when built, naming what it lacks."""
    from testbed.integrity.monitor import CONTRACT, MonitorDefaults, contract_problems
    from testbed.integrity.settings import IntegritySettings
    from testbed.frames import LocalFrame

    @dataclass(frozen=True)
    class Bare:
        name: str
        inputs: ClassVar[frozenset[str]] = frozenset({"gnss"})
        reference: ClassVar[str] = ANTENNA

        def initial_state(self):
            return None

        def step(self, obs, state):
            raise AssertionError("never stepped")

    assert contract_problems(Bare("bare")) == ["dimensions", "several_tests", "compiles_kernels", "provides_others",
                                               "prepare", "provides"]
    assert contract_problems(type("Full", (Bare, MonitorDefaults), {})("full")) == []
    declared = set(Monitor.__annotations__) | {k for k, v in vars(Monitor).items() if callable(v) and k[0] != "_"}
    assert declared == set(CONTRACT)
    registry.register("bare", lambda ctx, options: Bare("bare"), {"gnss"})
    try:
        ctx = MonitorContext(LocalFrame(29.3, 94.3, 2939.0), IntegritySettings())
        with pytest.raises(TypeError, match="lacks dimensions, several_tests.*MonitorDefaults"):
            registry.build_monitor("bare", ctx)
    finally:
        registry.unregister("bare")

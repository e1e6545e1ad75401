"""The public Python API: everything the ``testbed`` command does, as plain calls.

>>> from testbed.api import fly_approach
>>> result = fly_approach("zunz-rwy05-final")
>>> result.summary.xtk_rms_m
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from testbed.config import Approach, list_approaches, load_approach, read_toml, with_overrides
from testbed.flight.fly import FlightResult, fly
from testbed.outputs import OutputSet
from testbed.schema import ConfigError
from testbed.sim.preflight import check_output_file, check_output_folder
from testbed.sim.setup import load_terrain_for
from testbed.sim.truth_io import write_truth

if TYPE_CHECKING:  # pragma: no cover
    from testbed.sim.loop import LoopResult

__all__ = ["Approach", "FlightResult", "RunResult", "check_file", "export_rinex", "fly_approach", "list_approaches",
           "load_approach", "load_terrain_for", "monitor_rinex", "print_flight_summary", "print_run_summary",
           "run_approach"]


def fly_approach(approach: str | Path | Approach, *, gust_seed: int | None = None,
                 truth_path: str | Path | None = None) -> FlightResult:
    """Load (if needed) and fly an approach; optionally write its truth trajectory."""
    from testbed.sim.preflight import preflight

    ap = approach if isinstance(approach, Approach) else load_approach(approach)
    check_run_arguments(gust_seed=gust_seed)
    check_output_file(truth_path, "--truth", TRUTH_SUFFIXES)
    setup = preflight(ap)
    result = fly(ap.flight_plan, setup.terrain, gust_seed=gust_seed)
    if truth_path is not None:
        write_truth(result.truth, truth_path)
    return result


def monitor_rinex(obs_path: str | Path, nav_path: str | Path, **kw):
    """``testbed monitor``: GPS RAIM (FDE, PLs) over a RINEX observation file (:func:`testbed.replay.run.monitor_rinex`;
    keywords ``config``, ``out_dir``, ``rrd_path``, ``reference``, ``table_format``)."""
    from testbed.replay.run import monitor_rinex as run

    return run(obs_path, nav_path, **kw)


def is_campaign_file(path: str | Path) -> bool:
    """A campaign spec names ``approaches`` and ``trials`` (either will do: a spec missing one is still a
    spec, to be told what it misses); an approach file has a ``[path]``."""
    try:
        data = read_toml(Path(path))
    except ConfigError:
        return False
    return ("trials" in data or "approaches" in data) and "path" not in data


def check_file(path: str | Path) -> list[str]:
    """Every problem with an approach or campaign file (empty list when it is valid)."""
    try:
        if is_campaign_file(path):
            from testbed.campaign.sampling import check_sampling
            from testbed.campaign.spec import expand_cells, load_spec

            loaded = load_spec(path)
            check_sampling(loaded, expand_cells(loaded))  # every cell's approach too, and the sampling plan
            return []
        from testbed.sim.preflight import preflight

        preflight(load_approach(path))  # everything the run will load, the trim included
    except ConfigError as exc:  # a problem of another file (the aircraft, a spec's approach) names it
        same = Path(exc.source).resolve() == Path(path).resolve()
        return exc.problems if same else [f"{exc.source}: {p}" for p in exc.problems]
    return []


def print_flight_summary(result: FlightResult, *, speed: bool = True) -> None:
    """The flight's table; ``speed``: with the flight's own real-time factor (a run with sensors and
    monitors prints the whole loop's instead)."""
    from rich.console import Console
    from rich.table import Table

    s = result.summary
    t = Table(title=f"{s.approach} ({s.aircraft})", show_header=False)
    factor = f", {s.realtime_factor:.0f}x real time" if speed else ""
    rows = [
        ("duration", f"{s.duration_s:.1f} s ({s.steps} steps{factor})"),
        ("reached threshold", "yes" if s.reached_end else "NO"),
        ("cross-track after capture", f"RMS {s.xtk_rms_m:.2f} m, max {s.xtk_max_m:.2f} m"),
        ("vertical path after capture", f"RMS {s.vert_rms_m:.2f} m, max {s.vert_max_m:.2f} m"),
        ("at threshold", f"{s.end_height_above_m:.1f} m above, {s.end_lateral_m:+.1f} m lateral, "
                         f"{s.end_cas_kt:.0f} kt CAS, sink {s.end_sink_rate_ms:.1f} m/s"),
        ("attitude", f"max bank {s.max_bank_deg:.1f} deg, pitch {s.pitch_range_deg[0]:.1f}..{s.pitch_range_deg[1]:.1f} deg"),
        ("min height above terrain", f"{s.min_agl_m:.0f} m"),
    ]
    for k, v in rows:
        t.add_row(k, v)
    Console().print(t)


@dataclass(frozen=True)
class RunResult:
    """A flight with sensors and monitors in the loop, evaluated against truth."""

    loop: "LoopResult"
    summaries: dict
    rrd_path: Path | None
    live_url: str | None
    wall_s: float
    faults: tuple = ()  # the approach's fault schedule
    first_compiled: tuple[str, ...] = ()  # monitors whose kernels this run compiled for the first time
    prepare_s: float = 0.0  # seconds spent preparing (compiling) the monitors

    @property
    def flight(self) -> FlightResult:
        return self.loop.flight

    @property
    def outputs(self) -> dict:
        return self.loop.outputs


def default_rrd_path(approach: Approach, seed: int) -> Path:
    return Path("runs") / f"{approach.name}-seed{seed}.rrd"


def run_approach(approach: str | Path | Approach, *, seed: int = 0, rrd_path: str | Path | None = "default",
                 live: bool = False, bind_ip: str = "127.0.0.1", port: int = 9876, block_s: float = 5.0,
                 monitors: list[str] | None = None, faults: list[dict] | None = None,
                 gust_seed: int | None = None, truth_path: str | Path | None = None, linger_s: float = 0.0,
                 on_landed: Callable[[RunResult], None] | None = None,
                 progress: Callable[[str], None] | None = None, outputs: OutputSet | None = None) -> RunResult:
    """Fly an approach with sensors and monitors in the loop; record it; evaluate it.

    Every input and output path is checked before the flight; the recording and the truth are
    moved into place together, and only when the whole run succeeded (a failure leaves earlier
    files untouched and removes its partial output).

    Parameters
    ----------
    approach : shipped name, TOML path or a loaded :class:`Approach`.
    seed : seeds every sensor draw (same seed, same results, bit for bit).
    rrd_path : the recording; ``"default"`` = ``runs/<approach>-seed<seed>.rrd``; None = no file.
    live : also serve the stream to a Rerun viewer (gRPC on ``bind_ip:port``, loopback by default;
        another address is served unauthenticated to its network, with a warning).
    block_s : simulated seconds between live updates.
    monitors : override the approach's monitor list.
    faults : ``[[faults]]`` tables appended to the approach's schedule (:func:`testbed.config.fault_from_option`
        makes one from the command line's one-line form).
    truth_path : also write the full-rate truth (.npz, .csv, .parquet).
    linger_s : with ``live``, keep the server up this long after landing (the outputs are in
        place by then; ``on_landed(result)`` is called first, e.g. to print the summary).
    progress : called with a notice before a long step (the first compilation of the kernels).
    outputs : the caller's :class:`~testbed.outputs.OutputSet` (the caller commits, e.g. in ``on_landed``);
        by default the recording and the truth are committed together before ``on_landed``.
    """
    with OutputSet.using(outputs) as outs:
        return _run_approach(approach, seed, rrd_path, live, bind_ip, port, block_s, monitors, faults, gust_seed,
                             truth_path, linger_s, on_landed, progress, outs, own=outputs is None)


def _run_approach(approach, seed, rrd_path, live, bind_ip, port, block_s, monitors, faults, gust_seed, truth_path,
                  linger_s, on_landed, progress, outs: OutputSet, own: bool) -> RunResult:
    import time

    from testbed.sim.evaluate import summarise_monitor
    from testbed.sim.loop import gnss_fault_onset, run_loop
    from testbed.integrity.monitor import ANTENNA
    from testbed.sim.preflight import preflight
    from testbed.sim.setup import build_scene, prepare_monitors

    ap = approach if isinstance(approach, Approach) else load_approach(approach)
    ap = with_overrides(ap, monitors=monitors, faults=faults)
    wall0 = time.perf_counter()
    if rrd_path == "default":
        rrd_path = default_rrd_path(ap, seed)
    check_run_arguments(seed=seed, block_s=block_s, port=port, linger_s=linger_s, gust_seed=gust_seed)
    rrd_path = _declared(outs, rrd_path, "--rrd", (".rrd",))
    truth_path = _declared(outs, truth_path, "--truth", TRUTH_SUFFIXES)
    if live:
        _check_live_address(bind_ip, port)
    setup = preflight(ap)
    t_prep = time.perf_counter()
    first_compiled = prepare_monitors(setup, announce=progress)
    prepare_s = time.perf_counter() - t_prep
    sinks, sink = [], None
    if rrd_path is not None or live:
        from testbed.viz.rerun_sink import RerunSink

        sink = RerunSink(outs.staged(rrd_path) if rrd_path is not None else None, live=live, bind_ip=bind_ip, port=port,
                         recording_id=f"{ap.name}-seed{seed}",
                         start_time_ns=int(ap.config.start_time_utc.timestamp() * 1e9))
        sink.start(build_scene(setup, setup.vision.camera.build()))
        sinks.append(sink)
    ok = False
    try:
        loop = run_loop(setup, seed=seed, sinks=sinks, block_s=block_s, gust_seed=gust_seed)
        if truth_path is not None:
            write_truth(loop.flight.truth, outs.staged(truth_path))
        ok = True
    finally:
        if sink is not None and not (ok and live and linger_s > 0):
            sink.close(ok=ok)
    onset = gnss_fault_onset(setup)
    if onset is None and setup.faults:
        onset = min(f.onset_s for f in setup.faults)
    truth_cg = setup.frame.ecef_to_enu(loop.truth_at_gnss.pos_ecef)
    truth_ant = setup.frame.ecef_to_enu(loop.gnss_truth.antenna_pos_ecef)
    summaries = {}
    for mon in setup.monitors:
        pos = truth_ant if mon.reference == ANTENNA else truth_cg
        summaries[mon.name] = summarise_monitor(loop.outputs[mon.name], pos, reference=mon.reference,
                                                fault_onset_s=onset)
    result = RunResult(loop, summaries, Path(rrd_path) if rrd_path is not None else None,
                       sink.live_url if sink is not None else None, time.perf_counter() - wall0,
                       tuple(setup.faults), first_compiled, prepare_s)
    if sink is not None and live and linger_s > 0:
        try:
            sink.commit()
            if own:
                outs.commit()
            if on_landed is not None:
                on_landed(result)
            _linger(linger_s)
        finally:
            sink.close()
    else:
        if own:
            outs.commit()
        if on_landed is not None:
            on_landed(result)
    return result


def _declared(outs: OutputSet, path, option: str, suffixes: tuple[str, ...]) -> Path | None:
    """``path`` as an output of ``outs`` (declared here unless the caller declared it); None stays None."""
    if path is None:
        return None
    return Path(path) if outs.declares(path) else outs.file(path, option, suffixes)


TRUTH_SUFFIXES = (".npz", ".csv", ".parquet")


def check_run_arguments(*, seed: int = 0, block_s: float = 5.0, port: int = 9876, linger_s: float = 0.0,
                        gust_seed: int | None = None) -> None:
    """Numbers a caller hands a run, checked before any work (a ConfigError naming the option)."""
    import math

    problems = []
    for name, v in (("--seed", seed), ("--gust-seed", gust_seed)):
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or not 0 <= v < 2**63):
            problems.append(f"{name} = {v!r}: expected a whole number from 0 to 2^63 - 1")
    if not (isinstance(block_s, (int, float)) and math.isfinite(block_s) and 0 < block_s <= 3600):
        problems.append(f"--block = {block_s!r}: expected simulated seconds between live updates, > 0 and <= 3600")
    if not (isinstance(port, int) and 1 <= port <= 65535):
        problems.append(f"--port = {port!r}: expected a TCP port from 1 to 65535")
    if not (isinstance(linger_s, (int, float)) and math.isfinite(linger_s) and 0 <= linger_s <= 86400):
        problems.append(f"--linger = {linger_s!r}: expected seconds from 0 to 86400")
    if problems:
        raise ConfigError("command line", problems)


def _check_live_address(bind_ip: str, port: int) -> None:
    """The live server's address is free (else the run would fail at landing), and loopback or warned about."""
    import ipaddress
    import socket
    import warnings

    try:
        loopback = ipaddress.ip_address(bind_ip).is_loopback
    except ValueError:
        raise ConfigError("command line", [f"--bind = {bind_ip!r}: expected an IP address such as 127.0.0.1"]) from None
    if not loopback:
        warnings.warn(f"--bind {bind_ip}: the live stream is served UNAUTHENTICATED to every host that can reach "
                      f"{bind_ip}:{port}; use the default 127.0.0.1 unless you mean it", UserWarning, stacklevel=3)
    fam = socket.AF_INET6 if ":" in bind_ip else socket.AF_INET
    with socket.socket(fam, socket.SOCK_STREAM) as s:
        try:
            s.bind((bind_ip, port))
        except OSError as exc:
            raise ConfigError("command line", [f"--port = {port}: {bind_ip}:{port} is not free ({exc.strerror}); "
                                               "expected a free port (another live run or viewer?)"]) from None


def _linger(seconds: float) -> None:
    import time

    print(f"live server stays up {seconds:.0f} s more (Ctrl-C to stop)", flush=True)
    try:
        time.sleep(seconds)
    except KeyboardInterrupt:
        pass


def print_run_summary(result: RunResult) -> None:
    """The flight summary, one table row per monitor, the injected faults and why a monitor never served."""
    from rich.console import Console
    from rich.table import Table

    import numpy as np

    from testbed.integrity.gps_only import GPS_ONLY_MONITORS
    from testbed.sensors.gnss.orbits import SYSTEM_NAMES
    from testbed.sim.evaluate import describe_faults, unavailable_reason

    print_flight_summary(result.flight, speed=False)
    t = Table(title="integrity monitors (evaluated against truth)")
    t.add_column("")
    names = list(result.summaries)
    for name in names:
        t.add_column(name, justify="right")
    S = [result.summaries[n] for n in names]

    def nan(x, fmt):
        return "-" if x != x else fmt.format(x)

    # a vertical-only monitor (no HPL by design) serves no level's horizontal limit: its availability is the
    # vertical one alone, and says so
    v_only = [result.outputs[n].dimensions == ("V",) for n in names]
    rows = [("reference", [s.reference for s in S])]
    systems = tuple(dict.fromkeys(np.asarray(result.loop.gnss.system).tolist()))
    if len(systems) > 1:  # which satellites each monitor read: GPS RAIM all, the others GPS alone
        every = "+".join(SYSTEM_NAMES[c] for c in systems)
        rows.append(("satellites (median used)", [
            f"{'GPS only' if n in GPS_ONLY_MONITORS else every} ({np.nanmedian(result.outputs[n].n_used):.0f})"
            for n in names]))
    for lv in (S[0].availability if S else {}):
        rows.append((f"available {lv}", [f"{100 * s.availability[lv]:.0f} %" + (" (V only)" if v else "")
                                          for s, v in zip(S, v_only)]))
    rows += [
        ("HPL max / p95", [f"{nan(s.hpl_max, '{:.1f}')} / {nan(s.hpl_p95, '{:.1f}')} m" for s in S]),
        ("VPL max / p95", [f"{nan(s.vpl_max, '{:.1f}')} / {nan(s.vpl_p95, '{:.1f}')} m" for s in S]),
        ("HPE95 / VPE95", [f"{nan(s.hpe95, '{:.1f}')} / {nan(s.vpe95, '{:.1f}')} m" for s in S]),
        ("alert epochs", [f"{s.alert_epochs} / {s.epochs}" for s in S]),
        ("excluded epochs", [f"{s.excluded_epochs}" for s in S]),
        ("time to alert", [nan(s.time_to_alert_s, "{:.1f} s") for s in S]),
        ("misleading (err > PL, no alert)", [str(s.mi_epochs) for s in S]),
        ("hazardously misleading", [str(s.hmi_epochs) for s in S]),
    ]
    own = [result.outputs[n].diagnostics.summary_rows() if result.outputs[n].diagnostics is not None else {}
           for n in names]  # a monitor's own rows (ARAIM's EMT, σ_acc, fault modes); "-" for the others
    rows += [(label, [o.get(label, "-") for o in own]) for label in dict.fromkeys(k for o in own for k in o)]
    for label, vals in rows:
        t.add_row(label, *vals)
    con = Console()
    con.print(t)
    loop = result.loop
    for line in describe_faults(result.faults, loop.gnss.prn, loop.gnss_truth.faulty, loop.gnss.visible, loop.gnss.t,
                                loop.gnss.system):
        con.print(line, highlight=False)
    for name in names:
        why = unavailable_reason(result.outputs[name])
        if why is not None:
            con.print(f"{name}: unavailable at every epoch: {why}", highlight=False)
    tm = loop.timings
    sim_s = result.flight.summary.duration_s
    loop_s = tm.flight + tm.sensors + tm.monitors + tm.logging
    compiled = (f" (of which {result.prepare_s:.1f} s compiling the kernels of {', '.join(result.first_compiled)} "
                "for the first time)" if result.first_compiled else "")
    con.print(f"loop: {sim_s:.0f} s simulated in {loop_s:.2f} s ({sim_s / loop_s:.0f}x real time): flight "
              f"{tm.flight:.2f} s, sensors {tm.sensors:.2f} s, monitors {tm.monitors:.2f} s, logging {tm.logging:.2f} s; "
              f"set-up and evaluation {max(result.wall_s - loop_s, 0.0):.2f} s{compiled}", highlight=False)
    if result.rrd_path is not None:
        con.print(f"recording: {result.rrd_path}  (replay: rerun {result.rrd_path})")


def export_rinex(approach: str | Path | Approach, out_dir: str | Path, *, seed: int = 0,
                 gust_seed: int | None = None) -> tuple[Path, Path]:
    """Fly an approach, synthesise its GNSS observations and write RINEX obs + nav files (3.04 GPS; 3.05 mixed
    when the approach's constellation holds Galileo or BeiDou satellites: :func:`testbed.sensors.gnss.rinex.write_rinex`).

    The observations are the ones a ``testbed fly`` run with the same seed sees
    (the same GNSS stream of the same seed), including the approach's GNSS faults. Returns the
    ``(obs_path, nav_path)``; the truth trajectory is written beside them as
    ``<name>.truth.csv`` (the true antenna position at the true GPS time of each epoch: a
    ``testbed monitor --reference`` file).
    """
    import numpy as np

    from testbed.sensors.gnss.rinex import write_rinex
    from testbed.sensors.gnss.synth import gnss_geometry
    from testbed.sim.pipeline import draw_gnss, sensor_plan
    from testbed.sim.streams import StreamTree
    from testbed.sim.preflight import preflight

    ap = approach if isinstance(approach, Approach) else load_approach(approach)
    check_run_arguments(seed=seed, gust_seed=gust_seed)
    check_output_folder(out_dir, "DIR")
    setup = preflight(ap)
    flight = fly(ap.flight_plan, setup.terrain, gust_seed=gust_seed)
    start = ap.config.start_time_utc
    plan = sensor_plan(setup)
    geom = gnss_geometry(flight.truth.decimate(setup.gnss.rate_hz), setup.antenna, setup.gnss, start_utc=start,
                         terrain=setup.terrain, constellation=plan.constellation)
    obs, gtruth = draw_gnss(plan, geom, StreamTree.of_run(seed))  # the flight's own GNSS draws
    paths = write_rinex(obs, geom, out_dir, name=ap.name, clock_bias_m=gtruth.clock_bias)
    lat, lon, h = (np.asarray(v) for v in __import__("testbed.frames", fromlist=["x"]).ecef_to_geodetic(
        gtruth.antenna_pos_ecef))
    np.savetxt(Path(out_dir) / f"{ap.name}.truth.csv",
               np.column_stack([obs.t_gps, gtruth.antenna_pos_ecef, lat, lon, h]), delimiter=",",
               header="t_gps,pos_ecef_x,pos_ecef_y,pos_ecef_z,lat_deg,lon_deg,h_m", comments="",
               fmt="%.6f")
    return paths

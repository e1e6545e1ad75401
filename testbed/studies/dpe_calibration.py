"""``testbed calibrate-dpe``: the DPE's K from fault-free sorties, checked on held-out ones (docs/design/dpe.md §6).

The DPE and correlator settings are the approach's; the sorties fly its trajectory or, with
``trajectories``, those approaches' (set C of docs/design/dpe.md §6.4: the runway-05 final, the RNP
approach and the VA-RAIM paper's sortie), each flown once. Sortie j of a set flies trajectory ``(j // 6) mod n``
at ``j · 24 h / sorties`` after the approach's start (the validation set half a spacing later),
with its own GNSS and correlator draws (``SeedSequence(seed, spawn_key=(set, j))``) and the
C/N0 offset ``j mod 3`` and multipath setting ``(j // 3) mod 2`` of the strata; the dpe monitor
runs on it and z = (e − m)/σ is kept on every epoch with a solution. K is fitted on C
(:func:`~testbed.integrity.dpe.calibration.fit_k_tail`), raised to the worst stratum's if one
needs more (C/N0 × multipath, trajectory, satellites in view, VDOP tercile), and checked on V;
the file records K with its provenance, and the monitor reads it (``[dpe] k_factor = "path.json"``).

Work is cut in chunks of sorties, each a pure function of (run, set, chunk): with a work folder
they are stored as they finish (atomically), a killed run resumes where it stopped, and a Dask
scheduler can run them (the full size of docs/design/dpe.md §6.7, 36 000 sorties a set, is ~12 h on
two cores at the ~0.6 s a sortie set C took). The result does not depend on the chunk size or on where chunks ran.

Epochs count as independent (N_eff = N): the SIS error and the correlator noise are white from
epoch to epoch in this model (stated in the file). A short run extrapolates from shallower tails,
and the file says how deep its levels went.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import functools
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np
from pydantic import ConfigDict, Field

from testbed.campaign.store import StoredRecord
from testbed.integrity.dpe.calibration import (DEFAULT_P_HMI, MIN_TAIL_EPOCHS, KFit, fit_k_tail,
                                               settings_fingerprint, validate)
from testbed.monitors import monitor_options
from testbed.schema import ConfigError, read_json

#: strata cycled over the sorties (docs/design/dpe.md §6.4)
CN0_OFFSETS_DB = (0.0, -3.0, -6.0)
MULTIPATH = ("off", "ground")
ASSUMPTION = ("the normalised errors' tails beyond the deepest measured level are no heavier than the Gaussian "
              "fitted to the measured ones; epochs independent (white SIS and correlator noise per epoch)")
#: set C of docs/design/dpe.md §6.4: the trajectories its sorties fly
SET_C_TRAJECTORIES = ("zunz-rwy05-final", "zunz-rwy05-rnp", "va-raim-2015")
CHUNK_SORTIES = 25
#: a stratum is fitted on its own from this many epochs
MIN_STRATUM_EPOCHS = 1000


@dataclasses.dataclass(frozen=True)
class CalibrationRun:
    """What fixes a calibration's sorties (a work folder's manifest): approach (its DPE and correlator
    settings, by path), the trajectories flown (approach paths; empty: its own), sorties per set, seed,
    sorties per chunk."""

    approach: str
    trajectories: tuple[str, ...]
    sorties: int
    seed: int
    chunk: int

    @property
    def n_chunks(self) -> int:
        return -(-self.sorties // self.chunk)


class WorkManifest(StoredRecord):
    """A work folder's ``manifest.json``: the :class:`CalibrationRun` its chunks belong to."""

    model_config = ConfigDict(extra="forbid")
    approach: str
    trajectories: list[str]
    sorties: int = Field(ge=1)
    seed: int = Field(ge=0)
    chunk: int = Field(ge=1)


def sortie_plan(j: int, sorties: int, n_trajectories: int, shift_s: float = 0.0) -> tuple[int, float, float, str, int]:
    """Sortie j of a set: (trajectory index, start offset s, C/N0 offset dB, multipath, C/N0 × multipath stratum)."""
    cn0, mp = j % 3, (j // 3) % 2
    return (j // 6) % n_trajectories, j * 86400.0 / sorties + shift_s, CN0_OFFSETS_DB[cn0], MULTIPATH[mp], cn0 + 3 * mp


@functools.lru_cache(maxsize=8)
def _trajectory(approach: str, trajectory: str):
    """(approach, set-up, GNSS-rate truth, dpe monitor) of a trajectory flown with the approach's DPE and
    correlator settings (K = 1: the one being fitted replaces the approach's); once per process."""
    from testbed.config import load_approach
    from testbed.flight.fly import fly
    from testbed.integrity.dpe.monitor import DpeMonitor
    from testbed.integrity.monitor import MonitorContext
    from testbed.sim.preflight import preflight

    src = load_approach(approach)
    dpe = monitor_options("dpe", src.config.monitor).model_copy(update={"k_factor": 1.0})
    ap = src if trajectory == approach else load_approach(trajectory)
    gnss = ap.config.gnss.model_copy(update={"correlators": src.config.gnss.correlators})
    ap = dataclasses.replace(ap, config=ap.config.model_copy(update={"monitor": {**ap.config.monitor, "dpe": dpe}, "gnss": gnss}
                                                              | ({} if ap is src else {"monitors": ["dpe"]})))
    setup = preflight(ap)
    mon = DpeMonitor("dpe", MonitorContext(frame=setup.frame, integrity=setup.integrity), dpe)
    mon.prepare()
    truth_g = fly(ap.flight_plan, setup.terrain).truth.decimate(setup.gnss.rate_hz)
    return ap, setup, truth_g, mon


def _sortie_errors(ap, setup, truth_g, mon, offset_s: float, cn0_db: float, multipath: str, key: tuple[int, int],
                   seed: int) -> dict[str, np.ndarray]:
    """One sortie on its epochs with a solution: z, e, σ, m, satellites in view and VDOP."""
    from testbed.integrity.monitor import Observations
    from testbed.sensors.gnss.correlators import synthesize_correlators
    from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss

    cs = setup.gnss.correlators.model_copy(update={"cn0_offset_db": setup.gnss.correlators.cn0_offset_db + cn0_db,
                                                   "multipath": multipath})
    gs = setup.gnss.model_copy(update={"correlators": cs})
    start = ap.config.start_time_utc + dt.timedelta(seconds=offset_s)
    geom = gnss_geometry(truth_g, setup.antenna, gs, start_utc=start, terrain=setup.terrain)
    ss = np.random.SeedSequence(seed, spawn_key=key)
    g_gnss, g_corr = ss.spawn(2)
    g, gt = sample_gnss(geom, gs, rng=np.random.default_rng(g_gnss))
    corr, _ = synthesize_correlators(g, gt, truth_g, gs, g_corr.generate_state(4))
    out, _ = mon.step(Observations(g, correlators=corr), mon.initial_state())
    d = out.diagnostics
    ok = out.reason == 0
    true_u = setup.frame.ecef_to_enu(gt.antenna_pos_ecef)[:, 2]
    e = out.pos_enu[:, 2] - true_u
    sigma = np.hypot(d.sigma_ob, d.sigma_sis_u) if mon.settings.sis == "add" else d.sigma_ob
    vis = np.asarray(g.visible, bool)
    return {"z": ((e - d.median_m) / sigma)[ok], "e": e[ok], "sigma": sigma[ok], "m": d.median_m[ok],
            "n_sat": vis.sum(-1)[ok].astype(np.int16),
            "vdop": vdop(setup.frame, np.asarray(g.sat_pos_ecef, float), vis, np.asarray(gt.antenna_pos_ecef))[ok]}


def vdop(frame, sat_ecef: np.ndarray, visible: np.ndarray, ant_ecef: np.ndarray) -> np.ndarray:
    """(T,) the vertical DOP of the satellites in view (unit weights; NaN where the geometry is unsolvable):
    the monitors' own weighted fit (:func:`testbed.integrity.lsq.wls_geometry`) and DOPs."""
    from testbed.integrity import lsq

    los = sat_ecef - ant_ecef[:, None, :]
    u = frame.vec_ecef_to_enu(los / np.linalg.norm(los, axis=-1, keepdims=True))
    G = np.concatenate([-u, np.ones(u.shape[:-1] + (1,))], -1)
    with np.errstate(invalid="ignore"):
        geom = lsq.wls_geometry(G, np.ones(visible.shape), visible)
        return np.where(geom.solvable, lsq.dops(geom)["vdop"], np.nan)


def chunk_sorties(run: CalibrationRun, set_key: int, chunk: int, held_out: bool, one_sortie: Callable
                  ) -> list[tuple[dict[str, np.ndarray], int, int]]:
    """Each sortie of one chunk of set ``set_key``, in sortie order: ``(one_sortie(...)'s arrays, its stratum, its
    trajectory)``; the held-out set's start times are shifted half a step (disjoint from the calibration's).
    ``one_sortie(approach, setup, truth, monitor, offset_s, cn0_offset_db, multipath, key, seed)``."""
    trajectories = run.trajectories or (run.approach,)
    shift = 0.5 * 86400.0 / run.sorties if held_out else 0.0
    out = []
    for j in range(chunk * run.chunk, min((chunk + 1) * run.chunk, run.sorties)):
        t, offset, cn0, mp, stratum = sortie_plan(j, run.sorties, len(trajectories), shift)
        ap, setup, truth_g, mon = _trajectory(run.approach, trajectories[t])
        out.append((one_sortie(ap, setup, truth_g, mon, offset, cn0, mp, (set_key, j), run.seed), stratum, t))
    return out


def calibration_chunk(run: CalibrationRun, set_key: int, chunk: int) -> dict[str, np.ndarray]:
    """The errors of one chunk of sorties of set ``set_key`` (0 calibration, 1 validation), in sortie order."""
    parts = []
    for one, stratum, t in chunk_sorties(run, set_key, chunk, set_key != 0, _sortie_errors):
        one["stratum"] = np.full(one["z"].size, stratum, np.int8)
        one["trajectory"] = np.full(one["z"].size, t, np.int8)
        parts.append(one)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def run_provenance(approach: str, trajectories: list[str], sorties: int, seed: int, spacing: float,
                   seed_keys: dict[str, str], fingerprint, cover, assumption: str) -> dict[str, Any]:
    """What a K record says of the sorties it was fitted and checked on: approach, trajectories, sizes, seeds and
    their stream keys, start times, strata, the settings it is for, the assumption, the date."""
    return {
        "approach": approach, "trajectories": trajectories, "sorties_per_set": sorties, "seed": seed,
        "seed_keys": seed_keys,
        "start_offsets_s": {"calibration": f"sortie * {spacing:g}", "validation": f"sortie * {spacing:g} + {spacing / 2:g}"},
        "strata_cycle": {"cn0_offset_db": list(CN0_OFFSETS_DB), "multipath": list(MULTIPATH),
                         "trajectory": "(sortie // 6) mod the number of trajectories"},
        "fingerprint": fingerprint, "settings": cover, "assumption": assumption,
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }


def calibration_run(approach: str | Path, trajectories: tuple[str | Path, ...], sorties: int, seed: int, chunk: int,
                    p_hmi: float) -> CalibrationRun:
    """The run a calibration's arguments fix (approaches resolved to paths), or a ValueError naming the bad one."""
    from testbed.config import resolve_approach

    if sorties < 6:
        raise ValueError(f"sorties: expected at least 6 (one per stratum), got {sorties}")
    if chunk < 1:
        raise ValueError(f"chunk: expected at least 1 sortie per chunk, got {chunk}")
    if not 0 < p_hmi < 0.01:
        raise ValueError(f"p_hmi: expected a probability below 0.01, got {p_hmi}")
    src = str(resolve_approach(approach))
    trajs = tuple(str(resolve_approach(t)) for t in trajectories)
    return CalibrationRun(src, trajs if trajs != (src,) else (), sorties, seed, chunk)


class WorkFolder:
    """A calibration's chunks on disk: ``manifest.json`` (the run) and ``c<set>-<chunk>.npz``, each written
    beside its name and renamed. Opening a folder of another run is refused, naming what differs."""

    def __init__(self, path: Path, run: CalibrationRun, resume: bool) -> None:
        self.path = Path(path)
        manifest = self.path / "manifest.json"
        want = dataclasses.asdict(run) | {"trajectories": list(run.trajectories)}
        if manifest.exists():
            have = read_json(manifest, WorkManifest, what="a calibrate-dpe work folder's manifest",
                             remedy="give another --work folder (nothing was changed)").model_dump()
            if not resume:
                raise ConfigError(manifest, ["a calibration is stored here: --resume to continue it, or give "
                                             "another --work folder (nothing was changed)"])
            diff = [f"{k} = {have.get(k)!r} there, {v!r} here" for k, v in want.items() if have.get(k) != v]
            if diff:
                raise ConfigError(manifest, ["another calibration is stored here: " + "; ".join(diff) +
                                             "; expected the same run to resume (nothing was changed)"])
        else:
            self.path.mkdir(parents=True, exist_ok=True)
            write_record(want, manifest)

    def _file(self, set_key: int, chunk: int) -> Path:
        return self.path / f"c{set_key}-{chunk:05d}.npz"

    def load(self, set_key: int, chunk: int) -> dict[str, np.ndarray] | None:
        """A stored chunk, or None (absent or unreadable: computed again)."""
        try:
            with np.load(self._file(set_key, chunk)) as f:
                return {k: f[k] for k in f.files}
        except (OSError, ValueError, EOFError):
            return None

    def write(self, set_key: int, chunk: int, arrays: dict[str, np.ndarray]) -> None:
        part = self.path / f".c{set_key}-{chunk:05d}.part.npz"
        np.savez(part, **arrays)
        part.replace(self._file(set_key, chunk))


def _dask_chunk(run_json: str, set_key: int, chunk: int) -> dict[str, np.ndarray]:
    """Entry point on a Dask worker (the approach paths must be readable there)."""
    d = json.loads(run_json)
    return calibration_chunk(CalibrationRun(**d | {"trajectories": tuple(d["trajectories"])}), set_key, chunk)


def run_chunks(run: CalibrationRun, *, work: Path | None = None, resume: bool = False, scheduler=None,
               max_chunks: int | None = None, progress: Callable[[str], None] | None = None
               ) -> dict[str, dict[str, np.ndarray]] | None:
    """Every chunk of both sets (stored ones loaded); the sets' errors in sortie order, or None when
    ``max_chunks`` stopped the run before the end (it resumes from the work folder)."""
    say = progress or (lambda _: None)
    client, own = (None, False)
    if scheduler is not None:  # reachable before anything is written
        from testbed.campaign.runner import _client

        client, own = _client(scheduler)
    try:
        folder = WorkFolder(work, run, resume) if work is not None else None
    except BaseException:
        if own:
            client.close()
        raise
    plan = [(s, k) for s in (0, 1) for k in range(run.n_chunks)]
    got = {c: folder.load(*c) for c in plan} if folder is not None else {}
    todo = [c for c in plan if got.get(c) is None]
    if max_chunks is not None:
        todo = todo[:max_chunks]

    def done(c, arrays) -> None:
        got[c] = arrays
        if folder is not None:
            folder.write(*c, arrays)
        n = sum(1 for x in plan if got.get(x) is not None)
        say(f"{n}/{len(plan)} chunks of {run.chunk} sorties ({sum(a['z'].size for a in got.values() if a is not None)}"
            " epochs)")

    if client is None:
        for c in todo:
            done(c, calibration_chunk(run, *c))
    else:
        from distributed import as_completed

        try:
            rj = json.dumps(dataclasses.asdict(run))
            futs = {client.submit(_dask_chunk, rj, *c, pure=False): c for c in todo}
            for fut in as_completed(list(futs)):
                done(futs[fut], fut.result())
        finally:
            if own:
                client.close()
    if any(got.get(c) is None for c in plan):
        return None
    return {name: {k: np.concatenate([got[(s, j)][k] for j in range(run.n_chunks)]) for k in got[(s, 0)]}
            for s, name in ((0, "calibration"), (1, "validation"))}


def strata(c: dict[str, np.ndarray], trajectories: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Masks of the calibration set's strata (docs/design/dpe.md §6.5 (ii)): C/N0 × multipath, trajectory (more than
    one), satellites in view (4-5, 6-7, 8+), VDOP tercile (bounds from the set)."""
    out = {f"cn0 {CN0_OFFSETS_DB[s % 3]:+g} dB, multipath {MULTIPATH[s // 3]}": c["stratum"] == s for s in range(6)}
    if len(trajectories) > 1:
        out |= {f"trajectory {Path(t).stem}": c["trajectory"] == i for i, t in enumerate(trajectories)}
    n = c["n_sat"]
    out |= {"satellites 4-5": n <= 5, "satellites 6-7": (n >= 6) & (n <= 7), "satellites 8+": n >= 8}
    v = c["vdop"]
    lo, hi = np.nanquantile(v, [1 / 3, 2 / 3])
    out |= {f"VDOP {a:.2f}-{b:.2f}": (v >= a) & (v <= b) for a, b in ((np.nanmin(v), lo), (lo, hi), (hi, np.nanmax(v)))}
    return out


def _enough_epochs(approach: str, names: tuple[str, ...], sorties: int) -> None:
    """A ValueError before the sorties run when they cannot give the tail fit its epochs, even if every
    epoch of every sortie had a solution (the trajectories are flown here: the chunks reuse them)."""
    per = max(len(_trajectory(approach, t)[2].t) for t in names)
    if sorties * per <= MIN_TAIL_EPOCHS:
        raise ValueError(f"--sorties = {sorties}: at most {sorties * per} calibration epochs ({per} a sortie at "
                         f"most), and the tail fit needs more than {MIN_TAIL_EPOCHS}: expected at least "
                         f"{MIN_TAIL_EPOCHS // per + 1} sorties")


def calibrate_dpe(approach: str | Path = "zunz-rwy05-dpe", *, sorties: int = 60, p_hmi: float = DEFAULT_P_HMI, seed: int = 0,
                  trajectories: tuple[str | Path, ...] = (), chunk: int = CHUNK_SORTIES, work: Path | None = None,
                  resume: bool = False, scheduler=None, max_chunks: int | None = None,
                  progress: Callable[[str], None] | None = None) -> dict[str, Any] | None:
    """Fit K on ``sorties`` fault-free sorties and validate it on as many held-out ones (module doc).

    Returns the calibration record (what ``testbed calibrate-dpe`` writes), or None when ``max_chunks``
    stopped the run early (resume it with the same ``work`` folder).
    """
    from testbed.config import load_approach

    run = calibration_run(approach, trajectories, sorties, seed, chunk, p_hmi)
    src = run.approach
    names = run.trajectories or (src,)
    ap = load_approach(src)  # the settings K is for
    _enough_epochs(src, names, sorties)
    fingerprint, cover = settings_fingerprint(monitor_options("dpe", ap.config.monitor).model_copy(update={"k_factor": 1.0}),
                                              ap.config.gnss.correlators)
    sets = run_chunks(run, work=work, resume=resume, scheduler=scheduler, max_chunks=max_chunks, progress=progress)
    if sets is None:
        return None
    c, v = sets["calibration"], sets["validation"]
    overall = fit_k_tail(c["z"], p_hmi)
    fits = {name: fit_k_tail(c["z"][m], p_hmi) for name, m in strata(c, names).items()
            if m.sum() > MIN_STRATUM_EPOCHS}
    worst_name, worst = max(fits.items(), key=lambda kv: kv[1].k, default=("", overall))
    chosen: KFit = worst if worst.k > overall.k else overall
    check = validate(chosen, v["z"], np.abs(v["e"]) > chosen.k * v["sigma"] + np.abs(v["m"]))
    spacing = 86400.0 / sorties
    return {
        "what": "K of the dpe monitor's VPL = K*sigma + |median| (testbed calibrate-dpe)",
        "k": chosen.k, "sigma_z": chosen.sigma_z, "b_z": chosen.b_z, "p_hmi": p_hmi,
        "estimator": chosen.estimator, "binding": {"side": chosen.binding_side, "tail_level": chosen.binding_level},
        "k_from": f"stratum '{worst_name}'" if chosen is worst and worst is not overall else "all strata",
        "overall": {"k": overall.k, "sigma_z": overall.sigma_z, "b_z": overall.b_z},
        "strata": {n: {"k": f.k, "sigma_z": f.sigma_z, "n": f.n} for n, f in fits.items()},
        "n": chosen.n, "n_eff": chosen.n_eff, "n_calibration": int(c["z"].size), "deepest_level": 100.0 / overall.n_eff,
        "validation": {"passed": check.passed, "tails_hold": check.tails_hold, "worst_ratio": check.worst_ratio,
                       "levels_checked": check.levels_checked, "exceedances": check.exceedances,
                       "allowed": check.allowed, "epochs": check.epochs},
        **run_provenance(ap.name, [load_approach(t).name for t in names], sorties, seed, spacing,
                         {"calibration": "SeedSequence(seed, spawn_key=(0, sortie))",
                          "validation": "SeedSequence(seed, spawn_key=(1, sortie))"}, fingerprint, cover,
                         ASSUMPTION),
    }


def write_record(record: dict, path: Path) -> None:
    """Write beside the target, then rename (an interrupted write never replaces an earlier file)."""
    path = Path(path)
    part = path.with_name(path.name + ".part")
    part.write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
    part.replace(path)

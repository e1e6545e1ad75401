"""The estimated cost of a campaign, a paper reproduction and a DPE calibration, before any work
(:mod:`testbed.sim.budget` holds the model, its measured constants and the refusal).

A campaign's peak memory is its processes': each holds the interpreter and kernels, the cells' shared
geometry (per sky window of the sorties), and the draw blocks running side by side (one per thread in this
process, one per worker process), each ``block_trials`` x epochs x (satellites, landmarks, monitors); the
driver then consolidates a cell's trial rows. Its time is cells x trials x epochs x the seconds a
trial-epoch costs, over the cores, plus the flights and the geometry.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from testbed.campaign.sorties import sky_repeat_s, sky_windows, sortie_offsets
from testbed.campaign.spec import SKY_REPEAT_S, LoadedSpec
from testbed.integrity.batching import available_cores, physical_memory_bytes
from testbed.memo import DEFAULT_LIMIT_BYTES
from testbed.sim.budget import (BASE_BYTES, FLIGHT_SECONDS_PER_S, PARALLEL_EFFICIENCY, Estimate, Shape,
                                correlator_trial_bytes, feature_bytes, feature_seconds,
                                sortie_shape, trial_epoch_bytes, trial_epoch_seconds, unshared_parts)

#: the cached GNSS geometry, bytes per sky window, epoch and satellite (positions, lines of sight, masks)
GEOMETRY_BYTES_PER_SAT = 150.0
#: seconds to compute it per sky window, epoch and satellite (terrain masking included)
GEOMETRY_SECONDS_PER_SAT = 15e-6
#: one stored trial row of one monitor while the driver consolidates a cell (Arrow columns, sort, write)
TRIAL_ROW_BYTES = 600.0
#: a cell's context besides its geometry: its set-up, monitors and cached records
CELL_BYTES = 2e6
#: the report (and a reproduction's summary) reads an experiment's trial rows at once, bytes per row (one
#: monitor's sortie): fitted to the paper-scale VA-RAIM reproduction, whose 1.8e7-row experiment peaked at
#: 12.4 GB resident
REPORT_ROW_BYTES = 660.0
#: with common random numbers, the cells of a sweep share their draws and the monitors' shared steps
#: (testbed.memo): a cell-sortie-epoch cost this many times less than alone in the paper-scale VA-RAIM
#: reproduction (1.63 h of computing for 1.13e9 cell-sortie-epochs on 2 worker processes; 4.4x what the
#: per-monitor figures give without sharing). Not the parts no cell shares (testbed.sim.budget.unshared_parts:
#: the correlograms and the DPE, 3x under-estimated when they were divided too)
SHARED_SPEEDUP = 4.4


def _seconds_shared(shape: Shape, speedup: float) -> float:
    """One thread's seconds per trial-epoch of a cell, the parts its cells can share ``speedup`` times cheaper."""
    own = unshared_parts(shape)
    return sum(v if k in own else v / speedup for k, v in trial_epoch_seconds(shape).items())


def parallelism(p: int) -> float:
    """How much faster ``p`` blocks or processes side by side run than one."""
    return 1.0 + PARALLEL_EFFICIENCY * (max(int(p), 1) - 1)


def stored_chunks(out_dir: str | Path | None) -> set[tuple[int, int]]:
    """The chunks a run stored in ``out_dir`` (by their folder names; nothing is read)."""
    parts = Path(out_dir) / "parts" if out_dir is not None else None
    out = set()
    if parts is None or not parts.is_dir():
        return out
    for p in parts.iterdir():
        if p.is_dir() and p.name.startswith("c") and ".tmp-" not in p.name:
            try:
                out.add(tuple(int(x) for x in p.name[1:].split("-k")))
            except ValueError:
                continue
    return out


def sky_window_count(spec, repeat_s: float = SKY_REPEAT_S) -> int:
    """Sky windows the sorties of a cell fly in (each a computed geometry; 1 with a fixed start), the sky
    repeating after ``repeat_s`` (:func:`~testbed.campaign.sorties.sky_repeat_s` of its constellations)."""
    if spec.sorties.start == "fixed":
        return 1
    offsets = sortie_offsets(spec, np.arange(spec.trials))
    return int(np.unique(sky_windows(offsets, spec.sorties.window_s, repeat_s)).size)


def _shapes(loaded: LoadedSpec, cells) -> list[Shape]:
    """Each cell's :class:`Shape` (cells of one resolved configuration but their faults share one)."""
    memo: dict[str, Shape] = {}
    out = []
    for c in cells:
        key = str(c.approach.source) + json.dumps(c.config.model_dump(mode="json", exclude={"faults"}),
                                                  sort_keys=True, default=str)
        if key not in memo:
            memo[key] = sortie_shape(c.approach, loaded.spec.duration_s)
        out.append(memo[key])
    return out


def campaign_estimate(loaded: LoadedSpec, *, workers: int | str = "auto", scheduler=None, out_dir=None,
                      resume: bool = False, report: bool = True, cores: int | None = None,
                      memory_bytes: int | None = None) -> Estimate:
    """The estimated peak memory and wall time of ``testbed campaign`` on ``loaded`` (the chunks stored in
    ``out_dir`` excluded with ``resume``), with its ``workers`` on this machine's ``cores``; ``report``: and
    the report drawn from its tables."""
    from testbed.campaign.plan import cells_of, chunk_plan, local_workers

    spec = loaded.spec
    cells = cells_of(loaded)
    shapes = _shapes(loaded, cells)
    plan = chunk_plan(loaded)
    done = stored_chunks(out_dir) if resume else set()
    todo = [p for p in plan if (p[0], p[1]) not in done]
    cores = available_cores() if cores is None else cores
    memory_bytes = physical_memory_bytes() if memory_bytes is None else memory_bytes
    procs = local_workers(workers, todo, cores, memory_bytes) if scheduler is None else 1
    blocks_per_chunk = max(spec.chunk_trials // spec.block_trials, 1)
    side_by_side = 1 if procs > 1 else min(cores, blocks_per_chunk)  # blocks on threads in this process

    n_block = min(spec.block_trials, spec.trials)
    block = max(n_block * s.epochs * sum(trial_epoch_bytes(s).values()) + correlator_trial_bytes(s) for s in shapes)
    geometry = {}
    for c, s in zip(cells, shapes):  # the cells of one geometry key share it (a fault sweep's)
        key = (str(c.approach.source), c.params["start_time_utc"], c.config.gnss.model_dump_json())
        windows = sky_window_count(spec, sky_repeat_s(c.config.gnss.constellations))
        geometry[key] = windows * s.epochs * s.satellites * GEOMETRY_BYTES_PER_SAT
    contexts = sum(geometry.values()) + CELL_BYTES * len(cells) + max(feature_bytes(s) for s in shapes)
    memo = min(DEFAULT_LIMIT_BYTES, 2 * block) if spec.common_random_numbers else 0.0
    per_process = BASE_BYTES + contexts + side_by_side * block + memo
    rows = spec.trials * len(spec.monitors) * TRIAL_ROW_BYTES
    if report:
        rows = max(rows, len(cells) * spec.trials * len(spec.monitors) * REPORT_ROW_BYTES)
    memory = {"process and kernels": BASE_BYTES * (1 + procs if procs > 1 else 1),
              f"draw blocks ({side_by_side * procs} x {n_block} trials side by side)": procs * side_by_side * block,
              "cell geometry and contexts": procs * contexts,
              "the trial rows (consolidated, reported)": rows}
    if memo:
        memory["shared draws (common random numbers)"] = procs * memo
    # the consolidation runs after the blocks are freed: the peak is the larger phase
    if rows > procs * (per_process - BASE_BYTES):
        memory = {"process and kernels": BASE_BYTES, "the trial rows (consolidated, reported)": rows}
    else:
        memory.pop("the trial rows (consolidated, reported)")

    by_cell: dict[int, int] = {}
    for c, _, n in todo:
        by_cell[c] = by_cell.get(c, 0) + n
    shared = SHARED_SPEEDUP if spec.common_random_numbers and len(cells) > 1 else 1.0
    work = sum(n * shapes[c].epochs * _seconds_shared(shapes[c], shared) for c, n in by_cell.items())
    trajectories = {str(c.approach.source): s.flight_s for c, s in zip(cells, shapes)}
    setup_s = (sum(trajectories.values()) * FLIGHT_SECONDS_PER_S
               + sum(geometry.values()) / GEOMETRY_BYTES_PER_SAT * GEOMETRY_SECONDS_PER_SAT
               + max(feature_seconds(s) for s in shapes))
    p = procs if procs > 1 else side_by_side
    trial_epochs = sum(n * shapes[c].epochs for c, n in by_cell.items())
    time = {f"sorties ({len(by_cell)} cells, {trial_epochs:,} sortie-epochs)": work / parallelism(p),
            "flights and geometry": setup_s * (procs if procs > 1 else 1) / parallelism(p)}
    shrink = [f"fewer trials (--trials N; now {spec.trials} per cell) or fewer cells (the sweep's axes: "
              f"{len(cells)} cells)",
              f"a smaller block_trials (now {spec.block_trials}: a block holds block_trials x {shapes[0].epochs} "
              "epochs of every array)"]
    if procs > 1:
        shrink.append(f"--workers 1 (now {procs} processes, each with its own blocks and geometry)")
    if spec.duration_s is None:
        shrink.append("duration_s (fly a segment of each approach)")
    return Estimate(f"campaign {spec.name}", memory, time, tuple(shrink), cores=p)


def sequence_estimate(what: str, parts: list[Estimate]) -> Estimate:
    """Estimates run one after the other: the largest peak, the sum of the times."""
    peak = max(parts, key=lambda e: e.peak_bytes)
    time: dict[str, float] = {}
    for e in parts:
        time[e.what] = e.wall_s
    return Estimate(what, dict(peak.memory), time, peak.shrink, cores=max(e.cores for e in parts))

"""Benchmark: ARAIM epochs/s for 10, 20 and 30 satellites over 1–3 constellations, and the ratio to sidereon.

Usage::

    python benchmarks/bench_araim.py [--repeats 3] [--epochs-scale 1.0] [--pfa-epochs 0]

For each case, random skies (satellites uniform over the sky above 5°, split evenly between the
constellations, one row structure per case as along a flight between rises and sets): the median
wall time of :func:`testbed.integrity.araim.araim` over a batch, as epochs/s, with the number of fault
modes monitored and the wall time per mode (fault-free included). The kernels run the epochs on numba's
threads (``NUMBA_NUM_THREADS``, all cores by default), set as the command line sets them
(:func:`testbed.threads.sleep_idle_threads`: beside busy neighbours, spinning idle threads made the
same run 3-100× slower); the first line says how many threads, and the load average (the host may be
shared). The ISM is ``wgc_lpv200`` (P_sat 1e-5, P_const 1e-4); one constellation alone gets
P_const = 1e-8 (with 1e-4 it cannot be monitored and the epoch ends before any subset is solved).

In the same run and on identical rows, ``sidereon.araim`` (MIT, PyPI) called per epoch, our per-row σ
passed as its effective sigmas, against ours batched, both at the ADD v3.1 allocation
(``AraimSettings.add_v31()``, sidereon's ``lpv_200()``): the ratio of the per-epoch times. sidereon
monitors single events only (and a few pairs), so at 3 constellations it evaluates ~30 modes where the
ADD (and we) evaluate hundreds; its figures are printed with its own mode count. Ours is timed on all
threads and on one (sidereon runs on one).

``--pfa-epochs N`` adds the long fault-free false-alert run at the real allocation (P_FA,V 3.9e-6,
P_FA,H 9e-8 per independent sample: ``add_v31()``, N_ES = 1, so each epoch is a sample; N = 6e6 expects
at most ~24 alerts): residuals drawn from N(0, C_acc) on a fixed GPS + Galileo sky, the alert count's
binomial 99 % interval against the allocation.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))  # this checkout's testbed, not whichever one is installed
from test_araim import sidereon_araim  # noqa: E402
from timing import median_time  # noqa: E402

from testbed.integrity.araim import AraimRows, AraimSettings, ConstellationIsm, araim  # noqa: E402
from testbed.threads import sleep_idle_threads  # noqa: E402

CASES = [(n, c) for n in (10, 20, 30) for c in (1, 2, 3)]
#: epochs per case at scale 1: about a second of work each
EPOCHS = {10: 4000, 20: 1500, 30: 600}


def random_rows(rng, n_epochs: int, n_sat: int, n_const: int, settings: AraimSettings,
                residual: bool = True) -> AraimRows:
    """``n_epochs`` random skies of ``n_sat`` satellites split evenly over ``n_const`` systems."""
    az = rng.uniform(0.0, 2 * np.pi, (n_epochs, n_sat))
    el = np.arcsin(rng.uniform(np.sin(np.radians(5.0)), 1.0, (n_epochs, n_sat)))  # uniform over the sky
    los = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    system = np.arange(n_sat) % n_const
    rows = AraimRows.from_elevation(los, system, np.ones((n_epochs, n_sat), bool), settings)
    if residual:
        rows = AraimRows(rows.los_enu, rows.system, rows.used, rows.c_int, rows.c_acc, rows.b_nom, rows.b_cont,
                         rng.standard_normal((n_epochs, n_sat)) * np.sqrt(rows.c_acc))
    return rows


def first_epoch(rows: AraimRows) -> AraimRows:
    return AraimRows(*(a if a is None or np.ndim(a) == 1 else np.asarray(a)[:1] for a in
                       (rows.los_enu, rows.system, rows.used, rows.c_int, rows.c_acc, rows.b_nom, rows.b_cont,
                        rows.residual)))


def settings_for(n_const: int, add_v31: bool = False) -> AraimSettings:
    p_const = 1e-8 if n_const == 1 else 1e-4
    ism = {s: ConstellationIsm(p_const=p_const) for s in ("GPS", "Galileo", "BeiDou")}
    return AraimSettings.add_v31(ism=ism) if add_v31 else AraimSettings(ism=ism)


def throughput(repeats: int, scale: float) -> None:
    print(f"numba threads {numba.get_num_threads()}, load average {' / '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'sats':>4} {'const':>5} {'modes':>6} {'epochs/s':>10} {'ms/epoch':>9} {'ns/mode':>8}   (ISM wgc_lpv200, "
          "default allocation: T_EXP 150 s, N_ES 25, consolidation)")
    rng = np.random.default_rng(0)
    for n, c in CASES:
        st = settings_for(c)
        rows = random_rows(rng, max(int(EPOCHS[n] * scale), 10), n, c, st)
        modes = int(araim(first_epoch(rows), st).n_modes[0])  # the mode table of this structure, built once
        E = rows.used.shape[0]
        wall = median_time(lambda: araim(rows, st), repeats)
        print(f"{n:4d} {c:5d} {modes:6d} {E / wall:10.0f} {1e3 * wall / E:9.3f} {1e9 * wall / E / (modes + 1):8.0f}")


def against_sidereon(repeats: int, n_epochs: int) -> None:
    try:
        import sidereon as sd
    except ImportError:
        print("sidereon not installed (pip install sidereon): ratio skipped")
        return
    threads = numba.get_num_threads()
    print(f"\nsame rows, ADD v3.1 allocation: ours batched ({threads} threads, and 1) vs sidereon.araim per epoch "
          f"({n_epochs} epochs a case)")
    print(f"{'sats':>4} {'const':>5} {'our modes':>9} {'its modes':>9} {'ours ms':>8} {'1 thr ms':>8} {'its ms':>8}"
          f" {'ratio':>6} {'1 thr':>6} {'its avail':>9}")
    rng = np.random.default_rng(1)
    for n, c in CASES:
        st = settings_for(c, add_v31=True)
        rows = random_rows(rng, n_epochs, n, c, st, residual=False)
        ism = {k: st.ism[name] for k, name in enumerate(("GPS", "Galileo", "BeiDou")) if k < c}
        araim(rows, st)  # mode table built
        ours = median_time(lambda: araim(rows, st), repeats) / n_epochs
        numba.set_num_threads(1)
        try:
            ours_1 = median_time(lambda: araim(rows, st), repeats) / n_epochs
        finally:
            numba.set_num_threads(threads)

        def theirs():
            out = []
            for e in range(n_epochs):
                out.append(sidereon_araim(sd, rows.los_enu[e], rows.system, rows.c_int[e], rows.c_acc[e], ism)[0])
            return out

        t0 = time.perf_counter()
        res = theirs()
        its = (time.perf_counter() - t0) / n_epochs
        our_modes = int(araim(rows, st).n_modes[0])
        its_modes = len(res[0].fault_modes) - 1
        avail = np.mean([math.isfinite(r.vpl_m) for r in res])
        print(f"{n:4d} {c:5d} {our_modes:9d} {its_modes:9d} {1e3 * ours:8.3f} {1e3 * ours_1:8.3f} {1e3 * its:8.3f}"
              f" {its / ours:6.1f} {its / ours_1:6.1f} {100 * avail:8.0f}%")


def false_alerts(n_epochs: int, block: int = 200_000) -> None:
    """The long fault-free run at the real allocation (see the module doc)."""
    st = AraimSettings.add_v31()
    rng = np.random.default_rng(2)
    sky = random_rows(np.random.default_rng(5), 1, 16, 2, st, residual=False)
    alerts, done, t0 = 0, 0, time.perf_counter()
    while done < n_epochs:
        n = min(block, n_epochs - done)
        b = lambda a: np.broadcast_to(a[0] if np.ndim(a) > 1 else a, (n,) + np.shape(a)[-1:])  # noqa: E731
        rows = AraimRows(np.broadcast_to(sky.los_enu[0], (n,) + sky.los_enu.shape[1:]), sky.system, b(sky.used),
                         b(sky.c_int), b(sky.c_acc), b(sky.b_nom), b(sky.b_cont),
                         rng.standard_normal((n, sky.used.shape[-1])) * np.sqrt(sky.c_acc[0]))
        alerts += int(araim(rows, st).alert.sum())
        done += n
    allocated = st.p_fa_vert + st.p_fa_hor  # per epoch (N_ES = 1)
    lo, hi = stats.binomtest(alerts, n_epochs).proportion_ci(0.99)
    verdict = "not exceeded" if lo <= allocated else "EXCEEDED"
    print(f"\nfault-free false alerts at the real allocation: {alerts} in {n_epochs} epochs = {alerts / n_epochs:.3g} "
          f"(99 % interval {lo:.3g}–{hi:.3g}); allocated per epoch P_FA,V + P_FA,H = {allocated:.3g}: "
          f"{verdict} ({time.perf_counter() - t0:.0f} s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--epochs-scale", type=float, default=1.0, help="scale the epochs of every case")
    ap.add_argument("--sidereon-epochs", type=int, default=200, help="epochs per case for the sidereon ratio")
    ap.add_argument("--pfa-epochs", type=int, default=0, help="long fault-free run at the real allocation (0: off)")
    a = ap.parse_args()
    sleep_idle_threads()  # as the command line: idle OpenMP threads sleep (set before numba starts them)
    throughput(a.repeats, a.epochs_scale)
    against_sidereon(a.repeats, a.sidereon_epochs)
    if a.pfa_epochs:
        false_alerts(a.pfa_epochs)


if __name__ == "__main__":
    main()

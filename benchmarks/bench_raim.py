"""Benchmark: batched GPS-only RAIM vs a straightforward per-epoch numpy loop.

Geometry: the DO-229 24-satellite almanac seen from the ZUNZ RWY05 approach,
epochs spread over a day, the VA-RAIM paper's eq. 27 sigmas, Gaussian noise. The
reference loops over epochs with plain numpy (Gauss-Newton to 1 mm, slopes,
seed-variant PLs, SSE); the script asserts both give the same numbers on the
epochs the reference runs (all of them up to ``--ref-max`` epochs).

Run:  /work/venv/bin/python benchmarks/bench_raim.py [--sizes 10000 100000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_integrity_core_helpers import make_gnss  # noqa: E402  (almanac geometry helper)

from testbed.integrity.raim import gps_raim  # noqa: E402
from testbed.integrity.settings import IntegritySettings  # noqa: E402
from testbed.heap import keep_freed_memory  # noqa: E402

keep_freed_memory()  # as the CLI and campaigns do (off with TESTBED_SYSTEM_MALLOC=1)
from testbed.world.airport import runway_frame  # noqa: E402

FRAME = runway_frame()
RX_ENU = np.array([-4000.0, -2800.0, 350.0])


def reference_raim(sat_enu, pr, sigma, vis, p_fa, p_md):
    """Per-epoch loop, plain numpy: returns pos (E, 3), clock, sse, hpl, vpl (seed variant)."""
    E = pr.shape[0]
    pos = np.full((E, 3), np.nan)
    clk = np.full(E, np.nan)
    sse = np.full(E, np.nan)
    hpl = np.full(E, np.nan)
    vpl = np.full(E, np.nan)
    k_md = stats.norm.isf(p_md / 2)
    T_cache: dict[int, float] = {}
    for e in range(E):
        m = vis[e]
        n = int(m.sum())
        if n < 5:
            continue
        s, z, w = sat_enu[e][m], pr[e][m], 1.0 / sigma[e][m] ** 2
        x = np.zeros(4)
        for _ in range(8):
            d = s - x[:3]
            r = np.linalg.norm(d, axis=1)
            G = np.column_stack([-d / r[:, None], np.ones(n)])
            W = np.diag(w)
            J = np.linalg.inv(G.T @ W @ G)
            dx = J @ G.T @ W @ (z - (r + x[3]))
            x = x + dx
            if np.linalg.norm(dx[:3]) < 1e-3:
                break
        d = s - x[:3]
        r = np.linalg.norm(d, axis=1)
        G = np.column_stack([-d / r[:, None], np.ones(n)])
        W = np.diag(w)
        J = np.linalg.inv(G.T @ W @ G)
        A = J @ G.T @ W
        S = np.eye(n) - G @ A
        res = z - (r + x[3])
        WS = np.diag(W @ S)
        hs = np.hypot(A[0], A[1]) / np.sqrt(WS)
        vs = np.abs(A[2]) / np.sqrt(WS)
        if n - 4 not in T_cache:
            T_cache[n - 4] = float(np.sqrt(stats.chi2.isf(p_fa, n - 4)))
        T = T_cache[n - 4]
        pos[e], clk[e] = x[:3], x[3]
        sse[e] = res @ W @ res
        hpl[e] = hs.max() * T + k_md * np.sqrt(J[0, 0] + J[1, 1])
        vpl[e] = vs.max() * T + k_md * np.sqrt(J[2, 2])
    return pos, clk, sse, hpl, vpl


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--ref-max", type=int, default=5_000, help="epochs the per-epoch reference runs on")
    args = ap.parse_args()
    st = IntegritySettings(pl_variant="seed")
    rng = np.random.default_rng(2024)
    print(f"{'epochs':>8} {'batched ep/s':>14} {'reference ep/s':>15} {'ratio':>7}  (medians of {args.repeat})")
    for n in args.sizes:
        n_geo = 1000  # distinct geometries over a day; trials fill the rest
        trials = max(1, n // n_geo)
        tow = 344063.0 + np.linspace(0.0, 86400.0, n_geo, endpoint=False)
        gnss, _, _ = make_gnss(FRAME, np.broadcast_to(RX_ENU, (n_geo, 3)), tow, rng, batch=(trials,))
        n_ep = trials * n_geo
        t_b = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            out = gps_raim(gnss, FRAME, st)
            t_b.append(time.perf_counter() - t0)
        # reference on the first ref-max epochs (flattened)
        k = min(args.ref_max, n_ep)
        sat_enu = FRAME.ecef_to_enu(gnss.sat_pos_ecef.reshape(-1, 24, 3)[:k])
        pr = gnss.pseudorange.reshape(-1, 24)[:k]
        sg = gnss.sigma.reshape(-1, 24)[:k]
        vis = gnss.visible.reshape(-1, 24)[:k]
        t_r = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            ref = reference_raim(sat_enu, pr, sg, vis, st.p_fa, st.p_md)
            t_r.append(time.perf_counter() - t0)
        pos, clk, sse, hpl, vpl = ref
        np.testing.assert_allclose(out.pos_enu.reshape(-1, 3)[:k], pos, atol=1e-6)
        np.testing.assert_allclose(out.clock.reshape(-1)[:k], clk, atol=1e-6)
        np.testing.assert_allclose(out.test_stat.reshape(-1)[:k], sse, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(out.hpl.reshape(-1)[:k], hpl, rtol=1e-9)
        np.testing.assert_allclose(out.vpl.reshape(-1)[:k], vpl, rtol=1e-9)
        eps_b = n_ep / np.median(t_b)
        eps_r = k / np.median(t_r)
        print(f"{n_ep:>8d} {eps_b:>14.0f} {eps_r:>15.0f} {eps_b / eps_r:>7.1f}   (reference checked equal on {k} epochs)")


if __name__ == "__main__":
    main()

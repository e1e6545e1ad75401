"""Benchmark: VA-RAIM's solve and calibration kernels, epochs side by side against one epoch at a time.

Inputs: one draw block (100 sorties x 61 epochs) of the VA-RAIM reproduction's where-vision-pays
experiment (f = 1e4 px, 300 m triangle), captured as VA-RAIM passes them to its integrated
(GPS + vision) solve, of the epochs it solves (those with a vision row; the others take step 1's
answer). Times, as the median of ``--repeat`` calls:

* the weighted fit (``kernels.wls_epochs``) against ``kernels.wls_one`` called on each epoch in a
  compiled loop (the work of the per-epoch gufunc it replaced);
* the range Gauss-Newton (``kernels.range_gauss_newton_tiles``) against the per-epoch kernel
  (``kernels.range_gauss_newton``);
* the cosine-rule Gauss-Newton of the vision ranges (``kernels.cosine_gauss_newton_tiles``) against
  the per-epoch kernel (``kernels.cosine_gauss_newton``);
* what follows the cosine solve: A, A⁺, Σ_V, residual statistics and branch gate
  (``kernels.cosine_rule_products_tiles``) against the per-epoch kernel (``kernels.cosine_rule_products``);
* the GPS calibration of the vision ranges (``kernels.calibrate_tiles``) against the per-epoch kernel
  (``kernels.calibrate_epochs``);

and checks that each pair gives the same bytes.

Run:  python benchmarks/bench_kernels.py [--repeat 25]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import median_time  # noqa: E402

from testbed.integrity.kernels.geometry import wls_one  # noqa: E402


@njit(cache=True, nogil=True)
def _one_at_a_time(G, h, z, wd, Wb, mask, max_cond, J, A, ws, cond, r, sse, hslope, vslope, hmax, vmax, n_used,
                   n_states, reason):
    K = G.shape[2]
    for p in range(G.shape[0]):  # scratch per epoch, as the gufunc allocated it
        wls_one(G[p], h[p], z[p], wd[p], Wb[p], mask[p], max_cond, J[p], A[p], ws[p], cond[p:p + 1], r[p],
                sse[p:p + 1], hslope[p], vslope[p], hmax[p:p + 1], vmax[p:p + 1], n_used[p:p + 1],
                n_states[p:p + 1], reason[p:p + 1], np.empty((4, K, K)), np.empty((3, K)), np.empty(K))


def captured_inputs():
    """The integrated solve's Gauss-Newton and fit inputs and the cosine solve's, one where-vision-pays block,
    flat (P, ...)."""
    from testbed.studies.reproduce import loaded_experiments
    from testbed.campaign.blocks import run_block
    from testbed.campaign.context import cell_context
    from testbed.campaign.spec import expand_cells
    from testbed.integrity import kernels

    got = {}
    gn, fit, cos, cal = (kernels.range_gauss_newton_tiles, kernels.wls_epochs, kernels.cosine_gauss_newton_tiles,
                         kernels.calibrate_tiles)
    prod = kernels.cosine_rule_products_tiles

    def solved(args: tuple, epochs: np.ndarray) -> tuple:
        """The per-epoch inputs at the epochs the kernel was asked to solve (the rest as they are)."""
        P = args[0].shape[0]  # the batch (a landmark table (L, 3) is not per epoch: L < P)
        return tuple((np.array(x[epochs]) if x.ndim and x.shape[0] == P else np.array(x))
                     if isinstance(x, np.ndarray) else x for x in args)

    def spy_gn(*a):
        if a[9].shape[1] > 0:  # the integrated solve (vision rows), not step 1
            got["gn"] = solved(a[:12], a[12]) + a[13:15]
        return gn(*a)

    def spy_fit(*a):
        if a[4].shape[1] > 0:
            got["fit"] = solved(a[:7], a[7])
        return fit(*a)

    def spy_cos(*a):
        got["cos"] = tuple(np.array(x) if isinstance(x, np.ndarray) else x for x in a[:8])
        return cos(*a)

    def spy_cal(*a):
        got["cal"] = tuple(np.array(x) for x in a[:13])
        return cal(*a)

    def spy_prod(*a):
        got["prod"] = tuple(np.array(x) for x in a[:9])
        return prod(*a)

    kernels.range_gauss_newton_tiles, kernels.wls_epochs = spy_gn, spy_fit
    kernels.cosine_gauss_newton_tiles, kernels.calibrate_tiles = spy_cos, spy_cal
    kernels.cosine_rule_products_tiles = spy_prod
    try:
        le = loaded_experiments(200)["where-vision-pays"]
        cell = next(c for c in expand_cells(le) if c.params["focal_px"] == 1e4 and c.params["landmark_set"] == 1
                    and c.params["fault_size"] == 0.0)
        run_block(cell_context(cell, le.spec), le.spec, 0)
    finally:
        kernels.range_gauss_newton_tiles, kernels.wls_epochs = gn, fit
        kernels.cosine_gauss_newton_tiles, kernels.calibrate_tiles = cos, cal
        kernels.cosine_rule_products_tiles = prod
    return got["gn"], got["fit"], got["cos"], got["cal"], got["prod"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=25)
    args = ap.parse_args()
    from testbed.integrity import kernels

    gn_in, fit_in, cos_in, cal_in, prod_in = captured_inputs()
    P = gn_in[0].shape[0]  # the integrated solve's epochs (those with a vision row)
    Pv = cos_in[0].shape[0]  # the vision step's: every epoch of the block
    NG, R = gn_in[2].shape[1], gn_in[8].shape[1]

    def gn_out():
        return [np.empty((P, 4)), np.empty(P, bool), np.empty(P, np.int64), np.empty((P, NG + R)),
                np.empty((P, NG + R, 4))]

    N = fit_in[0].shape[1]

    def fit_out():
        f = lambda *s: np.empty((P,) + s)  # noqa: E731
        return [f(4, 4), f(4, N), f(N), f(), f(N), f(), f(N), f(N), f(), f(), np.empty(P, np.int64),
                np.empty(P, np.int64), np.empty(P, np.int8)]

    L = cos_in[3].shape[1]

    def cos_out():
        return [np.empty((Pv, L)), np.empty(Pv, np.int64), np.empty(Pv, bool), np.empty(Pv, bool)]

    Bt, T = cal_in[1].shape[:2]

    def cal_out():
        return [np.empty((Bt, T, L)), np.empty((Bt, T, L)), np.empty((Bt, T, L, L)), np.empty((Bt, T, L, L))]

    nc = prod_in[1].shape[1]

    def prod_out():
        f = lambda *s: np.empty((Pv,) + s)  # noqa: E731
        return [f(nc, L), f(nc), f(L, nc), np.empty(Pv, bool), f(), f(L, L), f(), f(), np.full(Pv, np.nan),
                np.zeros(Pv, bool)]  # the gate's outputs as vision_pseudoranges sets them (untouched without a prior)

    every = np.arange(P)  # the tiled kernels solve the epochs listed: all of them here

    def fit_tiles(*a):
        return kernels.wls_epochs(*a[:7], every, *a[7:])

    def gn_tiles(*a):
        return kernels.range_gauss_newton_tiles(*a[:12], every, *a[12:])

    rows = []
    for name, new, old, inputs, outs, n in (
            ("weighted fit", fit_tiles, _one_at_a_time, fit_in, fit_out, P),
            ("range Gauss-Newton", gn_tiles, kernels.range_gauss_newton, gn_in, gn_out, P),
            ("cosine Gauss-Newton", kernels.cosine_gauss_newton_tiles, kernels.cosine_gauss_newton, cos_in, cos_out,
             Pv),
            ("cosine products", kernels.cosine_rule_products_tiles, kernels.cosine_rule_products, prod_in, prod_out,
             Pv),
            ("GPS calibration", kernels.calibrate_tiles, kernels.calibrate_epochs, cal_in, cal_out, Pv)):
        a, b = outs(), outs()
        new(*inputs, *a)
        old(*inputs, *b)
        assert all(x.tobytes() == y.tobytes() for x, y in zip(a, b)), f"{name}: the two kernels disagree"
        t_new = median_time(lambda: new(*inputs, *a), args.repeat)
        t_old = median_time(lambda: old(*inputs, *b), args.repeat)
        rows.append((name, t_old / n * 1e9, t_new / n * 1e9))
    print(f"VA-RAIM's kernels on one where-vision-pays block ({Pv} epochs; the integrated solve on the {P} with a "
          f"vision row), one thread, median of {args.repeat}:")
    for name, old_ns, new_ns in rows:
        print(f"  {name:20s} one epoch at a time {old_ns:6.0f} ns/epoch, side by side {new_ns:6.0f} ns/epoch: "
              f"{old_ns / new_ns:.2f}x (the same bytes)")


if __name__ == "__main__":
    main()

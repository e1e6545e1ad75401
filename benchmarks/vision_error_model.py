"""Where the seed's linear vision-range error model holds (docs/findings/va-raim-2015.md, What the physics says).

Usage::

    python benchmarks/vision_error_model.py [--trials 2000] [--repro DIR]

1. On the VA-RAIM paper's scenario (tests/test_va_raim_scenario.py: 3400 px focal length,
   3 landmarks at 6-8 km), for growing pixel noise: the vision-range error's spread and
   excess kurtosis, and a KS test of VA-RAIM's fault-free SSE against chi-square(n - 4)
   over the epochs with vision rows.
2. A pixel bias on one landmark from 20 s (in 720-dpi pixels, 1 px noise): the fraction of
   faulted epochs with an alert and with vision dropped by the P3P branch gate.
3. With ``--repro DIR`` (a ``testbed reproduce`` output): the same KS test on the stored
   fault-free per-epoch records of the ``gps-faults`` experiment, per monitor and setting.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_va_raim_scenario import K_CAM, make_scenario  # noqa: E402

from testbed.integrity.va_raim import VaRaimSettings, va_raim  # noqa: E402
from testbed.integrity.vision_ranges import VisionReason  # noqa: E402

F_720DPI_PX = 992.0  # focal length of the va-raim-2015 camera at 720 dpi


def linearity(trials: int) -> None:
    print(f"seed scenario, f = {K_CAM[0, 0]:.0f} px, {trials} trials x 13 epochs:")
    for sigma_px, lpe in ((1.0, 0.05), (6.0, 0.05), (6.0, 0.0), (24.0, 0.0)):
        sc = make_scenario(np.random.default_rng(5), (trials,), sigma_px=sigma_px, survey_sigma_m=lpe, rate_hz=0.2)
        out = va_raim(sc.gnss, sc.vision, sc.frame, VaRaimSettings(variant="seed"))  # the seed's error model
        used = out.diagnostics.vision_rows_used & (out.reason == 0)
        u = stats.chi2.cdf(out.test_stat[used], (out.n_used - 4)[used])
        err = (out.diagnostics.vision_m - sc.m_true).ravel()
        err = err[np.isfinite(err)]
        print(f"  sigma {sigma_px:4.1f} px, LPE {lpe:.2f} m: range error sd {err.std():6.0f} m, excess kurtosis "
              f"{stats.kurtosis(err):6.2f}; SSE vs chi2: KS p {stats.kstest(u, 'uniform').pvalue:.3g} on {used.sum()} "
              f"epochs, P(u > 0.999) {np.mean(u > 0.999):.4f} (theory 0.001)")


def pixel_bias(trials: int) -> None:
    scale = K_CAM[0, 0] / F_720DPI_PX
    sc = make_scenario(np.random.default_rng(5), (trials,), sigma_px=scale)
    print(f"pixel bias on landmark 0 from 20 s ({trials} trials, 720-dpi pixels, 1 px noise):")
    for bias in (5.0, 20.0, 50.0):
        uv = sc.vision.pixel_uv.copy()
        uv[:, 20:, 0, 0] += bias * scale
        out = va_raim(sc.gnss, replace(sc.vision, pixel_uv=uv), sc.frame, VaRaimSettings(variant="seed"))
        gate = out.diagnostics.vision_reason[:, 20:] == VisionReason.BRANCH_JUMP
        print(f"  {bias:4.0f} px: alerts at {out.alert[:, 20:].mean():.3f} of faulted epochs, vision dropped by "
              f"the branch gate at {gate.mean():.3f}")


def reproduction(d: Path) -> None:
    import pyarrow.parquet as pq

    g = d / "gps-faults"
    cells = pq.read_table(g / "cells.parquet").to_pandas()
    ep = pq.read_table(g / "epochs.parquet").to_pandas()
    dofs = np.arange(1, 60)
    print(f"{g}: fault-free SSE vs chi2 (dof recovered from the P_FA = 1e-5 threshold):")
    t2 = stats.chi2.isf(1e-5, dofs)
    for _, c in cells[cells.fault_size == 0].iterrows():
        for m in ("gps_raim", "va_raim"):
            s = ep[(ep.cell == c.cell) & (ep.monitor == m) & np.isfinite(ep.test_stat)]
            dof = dofs[np.abs(t2[None, :] - s.threshold.to_numpy()[:, None]).argmin(1)]
            u = stats.chi2.cdf(s.test_stat.to_numpy(), dof)
            print(f"  {m:8s} {c.dpi:5.0f} dpi DE {c.sigma_px:.0f} px: KS p {stats.kstest(u, 'uniform').pvalue:.3g} "
                  f"on {len(u)} epochs")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=2000)
    ap.add_argument("--repro", type=Path, default=None, help="a `testbed reproduce va-raim-2015` output folder")
    args = ap.parse_args(argv)
    linearity(args.trials)
    pixel_bias(min(args.trials, 200))
    if args.repro is not None:
        reproduction(args.repro)


if __name__ == "__main__":
    main()

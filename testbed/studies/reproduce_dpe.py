"""``testbed reproduce dpe-vertical``: the DPE paper's claims (Chu & Gao, DPE vertical integrity) with a verdict each.

Experiments (docs/design/dpe.md §4.3, §7.3):

1. **The reference epoch** (8 satellites at 75…10°, 45.25–39.5 dB-Hz, N_b = 50, no SIS, the grid
   centre [8, −5, 12, 20] m off the truth), both variants: the solution's error, σ_ob, its median,
   whether an overbound about the solution is feasible, against √J_UU; nominal, a 60 m and a 300 m
   code bias on the 35° satellite, and a −6 dB in-phase echo at 0.1 chip on the two lowest.
   ``epochs`` independent draws of each case.
2. **The calibration record** the shipped approach uses (``approaches/calibration/dpe-k.json``):
   K, σ_z and the held-out check.
3. **DPE beside GPS RAIM** (the ``dpe-vs-raim`` campaign at ``trials`` sorties per cell): HMI per
   cell under a GPS step of 0–300 m.

``reproduce.md`` ends with the claims table: each claim, our figure, a verdict and the assumption
behind any difference.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from testbed.markdown import table as md_table
from testbed.outputs import OutputSet

#: the DPE paper's claims, in the abstract's order (docs/design/dpe.md §1)
CLAIMS = (
    ("position-domain overbound", "The overbounding distribution is derived in the position domain, without "
                                  "Gaussian pseudorange error models"),
    ("receiver-side effects", "Receiver-side faults such as multipath are seen in the likelihood manifold"),
    ("no convolution-born HMI", "No HMI is born of convolving range-domain bounds into the position domain"),
    ("factored VPL", "The VPL is established by factoring the overbound, VPL = K·σ_ob"),
)

CASES = {"nominal": {}, "60 m bias, 35° satellite": {"bias": (3, 60.0)},
         "300 m bias, 35° satellite": {"bias": (3, 300.0)},
         "−6 dB echo at 0.1 chip, 2 lowest": {"echo": ((6, 7), 0.1, 10 ** (-6 / 20))}}
OFFSET = np.array([8.0, -5.0, 12.0, 20.0])


def _epoch(case: dict, variant: str, seed: int):
    """One draw of a case: (vertical error, σ_ob, median, about-solution feasible, √J_UU or NaN)."""
    from testbed.correlation import CHIP_M, amplitude_sq
    from testbed.integrity.dpe.manifold import epoch_manifold
    from testbed.integrity.dpe.overbound import gaussian_overbound
    from testbed.integrity.dpe.seed_variant import solve_epoch_seed
    from testbed.integrity.dpe.solve import solve_epoch
    from testbed.sensors.gnss.correlators import epoch_statistic, cn0_at, delay_grid
    from testbed.sensors.gnss.settings import CorrelatorSettings

    from testbed.frames import LocalFrame

    frame = LocalFrame(29.2958478, 94.3224478, 2939.0)
    el = np.radians([75.0, 55.0, 40.0, 35.0, 25.0, 20.0, 15.0, 10.0])
    az = np.radians(np.arange(8) * 45.0 + 17.0)
    los = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    truth = np.array([0.0, 0.0, 500.0])
    sat = frame.enu_to_ecef(truth + 2.2e7 * los)
    rng_m = np.linalg.norm(sat - frame.enu_to_ecef(truth), axis=-1)
    stat_kind = "mag" if variant == "seed" else "pow"
    cs = CorrelatorSettings(synthesis="exact" if variant == "seed" else "fast", statistic=stat_kind)
    grid = delay_grid(cs)
    A = np.sqrt(amplitude_sq(cn0_at(el, cs), cs.coherent_s))
    rng = np.random.default_rng(seed)
    rho_ref = np.round((rng_m + rng.normal(0.0, 3.0, 8)) / grid.step_m) * grid.step_m
    delay = rng_m - rho_ref
    if "bias" in case:
        k, b = case["bias"]
        delay[k] += b
    echo_delay, alpha = np.zeros(8), np.zeros(8)
    if "echo" in case:
        idx, chips, amp = case["echo"]
        echo_delay[list(idx)], alpha[list(idx)] = chips * CHIP_M, amp
    stat = epoch_statistic(rng, cs, grid, A, delay, echo_delay, alpha, np.zeros((8, cs.n_noncoherent)))
    mf = epoch_manifold(frame, sat, rho_ref, stat, truth + OFFSET[:3], OFFSET[3], stat_kind=stat_kind,
                        n_blocks=cs.n_noncoherent, bandwidth_chips=cs.bandwidth_chips, delay0_m=grid.delay0_m,
                        step_m=grid.step_m)
    if variant == "seed":
        s = solve_epoch_seed(mf, passes=1)
        u, v, crb_u, x = -s.slice_u[::-1], s.slice_values[::-1], np.nan, s.x_mean
        mass = "sum"
    else:
        s = solve_epoch(mf, A * A, cs.n_noncoherent, cs.bandwidth_chips)
        u, v, crb_u, x, mass = s.offsets, s.marginal, float(np.sqrt(s.J[2, 2])), s.x_mean, "density"
    ob = gaussian_overbound(u, v, mass=mass)
    return float(OFFSET[2] + x[2]), float(ob.sigma), float(ob.median), bool(ob.about_solution), crb_u


def epoch_cases(epochs: int = 20, seed: int = 0) -> list[dict]:
    """Experiment 1: per case and variant, the medians over ``epochs`` draws."""
    rows = []
    for name, case in CASES.items():
        for variant in ("seed", "likelihood"):
            r = np.array([_epoch(case, variant, seed + i) for i in range(epochs)], float)
            rows.append({"case": name, "variant": variant, "epochs": epochs,
                         "vertical_error_m": float(np.median(r[:, 0])), "rms_vertical_error_m": float(np.sqrt(np.mean(r[:, 0] ** 2))),
                         "sigma_ob_m": float(np.median(r[:, 1])), "median_m": float(np.median(r[:, 2])),
                         "about_solution_feasible": float(np.mean(r[:, 3])), "crb_u_m": float(np.median(r[:, 4]))})
    return rows


def _campaign_hmi(d: Path) -> list[dict]:
    import pyarrow.parquet as pq

    t = pq.read_table(d / "trials.parquet").to_pandas()
    c = pq.read_table(d / "cells.parquet").to_pandas()[["cell", "fault_size"]]
    g = t.merge(c, on="cell").groupby(["fault_size", "monitor"])[["epochs", "mi_epochs", "hmi_epochs"]].sum()
    return [{"fault_size": float(k[0]), "monitor": k[1], **{n: int(v) for n, v in row.items()}} for k, row in g.iterrows()]


def reproduce_dpe_vertical(out_dir: str | Path, *, trials: int = 30, epochs: int = 20, progress: bool = True,
                           restart: bool = False, outputs: OutputSet | None = None) -> Path:
    """Run the three experiments into ``out_dir`` and write ``reproduce.md`` (module doc).

    The campaign stored there is completed (of the same size), or with ``restart`` discarded and run again.
    Its chunks are stored as they finish; its report, ``results.json`` and ``reproduce.md``
    are committed together, before this returns or with the caller's ``outputs`` at its commit."""
    from testbed.campaign.report import write_report
    from testbed.campaign.runner import run_campaign
    from testbed.campaign.spec import load_spec
    from testbed.resources import approaches_dir

    out = Path(out_dir)
    with OutputSet.using(outputs) as outs:
        if not outs.declares(out):
            outs.folder(out, "out_dir", kept="the campaign's chunks finished so far are stored there")
        cases = epoch_cases(epochs)
        k_rec = json.loads((approaches_dir() / "calibration" / "dpe-k.json").read_text())
        loaded = load_spec("dpe-vs-raim", trials=trials)
        camp = out / "dpe-vs-raim"
        run_campaign(loaded, camp, resume=(camp / "manifest.json").exists() and not restart, restart=restart,
                     progress=progress)
        write_report(camp, outputs=outs)
        hmi = _campaign_hmi(camp)
        outs.staged(out / "results.json").write_text(json.dumps({"cases": cases, "calibration": k_rec, "hmi": hmi},
                                                                indent=1))
        p = out / "reproduce.md"
        outs.staged(p).write_text("\n".join(summary(cases, k_rec, hmi, trials)) + "\n")
        return p


def summary(cases: list[dict], k_rec: dict, hmi: list[dict], trials: int) -> list[str]:
    """``reproduce.md``: the experiments' tables and the claims table."""
    md = ["# Reproduction of the DPE paper (Chu & Gao, DPE vertical integrity)", "",
          "Experiments and assumptions: `testbed/studies/reproduce_dpe.py` (module docstring) and "
          "docs/design/dpe.md §7.3.", "",
          "## 1. The reference epoch, both variants (medians over the draws)", ""]
    md += md_table(["case", "variant", "vertical error (m)", "RMS (m)", "σ_ob (m)", "median (m)", "about-solution feasible",
                    "√J_UU (m)"],
                   [[r["case"], r["variant"], f"{r['vertical_error_m']:+.2f}", f"{r['rms_vertical_error_m']:.2f}",
                     f"{r['sigma_ob_m']:.2f}", f"{r['median_m']:+.3f}", f"{100 * r['about_solution_feasible']:.0f} %",
                     "-" if not np.isfinite(r["crb_u_m"]) else format(r["crb_u_m"], ".2f")] for r in cases])
    v = k_rec["validation"]
    md += ["", "## 2. K (the shipped calibration record)", "",
           f"K = {k_rec['k']:.3f} for P_HMI = {k_rec['p_hmi']:g} per epoch ({k_rec['k_from']}; σ_z {k_rec['sigma_z']:.3f}, "
           f"b_z {k_rec['b_z']:+.3f}; {k_rec['n_calibration']} calibration epochs); held-out {v['epochs']} epochs: "
           f"{'passed' if v['passed'] else 'FAILED'} ({v['exceedances']} with |e| > VPL, {v['allowed']} allowed).", "",
           f"## 3. DPE beside GPS RAIM, GPS step from 20 s ({trials} sorties per cell)", ""]
    md += md_table(["step (m)", "monitor", "epochs", "MI", "HMI", "HMI per epoch"],
                   [[f"{r['fault_size']:g}", r["monitor"], r["epochs"], r["mi_epochs"], r["hmi_epochs"],
                     f"{r['hmi_epochs'] / max(r['epochs'], 1):.2e}"] for r in hmi])
    md += ["", "## Claims", ""]
    md += md_table(["claim", "our figure", "verdict", "assumption behind any difference"],
                   [[text, *_claim(key, cases, k_rec, hmi)] for key, text in CLAIMS])
    return md


def _case(cases, name, variant):
    return next(r for r in cases if r["case"] == name and r["variant"] == variant)


def _claim(key: str, cases, k_rec, hmi) -> tuple[str, str, str]:
    nom_s, nom_l = _case(cases, "nominal", "seed"), _case(cases, "nominal", "likelihood")
    if key == "position-domain overbound":
        return (f"seed: σ_ob {nom_s['sigma_ob_m']:.1f} m against √J_UU {nom_l['crb_u_m']:.2f} m (the grid's extent); "
                f"likelihood: σ_ob {nom_l['sigma_ob_m']:.2f} m, RMS error {nom_l['rms_vertical_error_m']:.2f} m",
                "holds with the likelihood form; not as written",
                "the paper's weighted mean over a ±110 m grid of a ≥ 293 m-wide correlation stays at the "
                "initialisation and its σ_ob measures the grid (docs/design/dpe.md F1, F2)")
    if key == "receiver-side effects":
        e = _case(cases, "−6 dB echo at 0.1 chip, 2 lowest", "likelihood")
        b60 = _case(cases, "60 m bias, 35° satellite", "likelihood")
        return (f"echo: error {e['vertical_error_m']:+.2f} m with σ_ob {e['sigma_ob_m']:.2f} m (nominal "
                f"{nom_l['sigma_ob_m']:.2f}); 60 m bias: σ_ob {b60['sigma_ob_m']:.2f} m, error {b60['vertical_error_m']:+.2f} m",
                "partly: the manifold moves, the overbound hardly widens",
                "an echo or bias shifts the peak coherently; the likelihood's width is set by C/N0 and geometry, "
                "not by the shift (docs/design/dpe.md F6)")
    if key == "no convolution-born HMI":
        free = [r for r in hmi if r["fault_size"] == 0.0 and r["monitor"] == "dpe"]
        worst = max((r for r in hmi if r["monitor"] == "dpe"), key=lambda r: r["hmi_epochs"] / max(r["epochs"], 1))
        raim = [r for r in hmi if r["monitor"] == "gps_raim" and r["fault_size"] == worst["fault_size"]]
        n0 = free[0]["epochs"] if free else 0
        h0 = free[0]["hmi_epochs"] if free else 0
        return (f"fault-free: {h0} HMI in {n0} epochs; {worst['fault_size']:g} m step: {worst['hmi_epochs']} HMI in "
                f"{worst['epochs']} epochs (GPS RAIM: "
                f"{raim[0]['hmi_epochs'] if raim else '-'} in {raim[0]['epochs'] if raim else '-'})",
                "holds fault-free; not under a satellite fault",
                "DPE bounds what its manifold sees and detects nothing: a code-phase fault within ~1.5 chip pulls "
                "the peak, and the SIS error is outside the manifold (carried by σ_SIS,U and K)")
    v = k_rec["validation"]
    return (f"K = {k_rec['k']:.2f} (σ_z {k_rec['sigma_z']:.3f}), plus the median's magnitude; held-out {v['exceedances']} of "
            f"{v['epochs']} above the VPL; about-solution overbound feasible in "
            f"{100 * nom_l['about_solution_feasible']:.0f} % of epochs",
            "holds with a calibrated K and the median term",
            "a zero-mean Gaussian about the solution cannot bound a curve whose median is not 0 (docs/design/dpe.md F3); "
            "K extrapolates the measured tails (stated in the record)")

"""``testbed reproduce dpe-vertical``: the experiments' pieces and the claims table (the full command,
2-3 min, is run by hand: docs/design/dpe.md §7.3)."""

from __future__ import annotations

import json

import numpy as np

from testbed.studies.reproduce_dpe import CLAIMS, epoch_cases, summary
from testbed.resources import approaches_dir


def test_the_notes_epoch_reproduces_f1_f2_and_the_likelihood_tracks_the_crb():
    rows = {(r["case"], r["variant"]): r for r in epoch_cases(epochs=2)}
    seed, like = rows[("nominal", "seed")], rows[("nominal", "likelihood")]
    assert 55 < seed["sigma_ob_m"] < 66  # F2: the grid's extent, read as the seed's sum
    assert abs(seed["vertical_error_m"] - 12.0) < 2.5  # F1: the solution stays near the centre's 12 m offset
    assert 0.8 < like["sigma_ob_m"] / like["crb_u_m"] < 1.3
    assert abs(rows[("300 m bias, 35° satellite", "likelihood")]["vertical_error_m"]) < 4.0  # it drops out
    assert all(r["about_solution_feasible"] == 0.0 for r in rows.values())  # F3


def test_the_claims_table_has_a_row_per_claim_and_well_formed_cells():
    cases = epoch_cases(epochs=1)
    k_rec = json.loads((approaches_dir() / "calibration" / "dpe-k.json").read_text())
    hmi = [{"fault_size": 0.0, "monitor": "dpe", "epochs": 100, "mi_epochs": 0, "hmi_epochs": 0},
           {"fault_size": 80.0, "monitor": "dpe", "epochs": 100, "mi_epochs": 60, "hmi_epochs": 40},
           {"fault_size": 80.0, "monitor": "gps_raim", "epochs": 100, "mi_epochs": 3, "hmi_epochs": 2}]
    md = summary(cases, k_rec, hmi, trials=5)
    from record_checks import markdown_table_problems

    assert markdown_table_problems("\n".join(md)) == []
    start = md.index("## Claims")
    rows = [line for line in md[start:] if line.startswith("| ") and not line.startswith("| claim")]
    assert len(rows) == len(CLAIMS)
    cells = [len(r.split("|")) for r in rows]
    assert len(set(cells)) == 1 and cells[0] == 6  # 4 columns: no stray pipe inside a cell
    assert "40 HMI in 100 epochs" in "\n".join(rows) and np.isfinite(k_rec["k"])
    assert "(GPS RAIM: 2 in 100)" in "\n".join(rows)  # RAIM's own count at that step, not a constant

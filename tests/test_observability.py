"""The observability analysis (testbed.navigation.observability) against docs/design/nav-filter.md §9.

The tables were first computed by an independent model; these are exact
integer counts, so the checks are equalities, plus the null spaces against the
analytic unobservable directions (a common translation of vehicle and features,
the yaw about gravity, and on an unaccelerated flight the scale).
"""

from __future__ import annotations

import numpy as np
import pytest

from testbed.navigation.observability import (consistent_observability, consistent_tom, null_space, racetrack,
                                              rf_turn, seed_observability, straight_final, table_a)

#: Table A (seed model): case -> (n, LOM, SOM, TOM)
TABLE_A = {"vision/INS, J = 1": (12, 8, 9, 9), "vision/INS, J = 2": (15, 11, 12, 12),
           "1 sat, clock estimated": (14, 10, 11, 11), "2 sat, clock estimated": (14, 11, 12, 12),
           "3 sat, clock estimated": (14, 12, 13, 13), "4 sat, clock estimated": (14, 13, 14, 14),
           "1 sat, clock known": (12, 9, 10, 10), "2 sat, clock known": (12, 10, 11, 11),
           "3 sat, clock known": (12, 11, 12, 12), "4 sat, clock known": (12, 11, 12, 12)}


def test_table_a_the_seeds_model_gives_its_table_1_as_ranks():
    """E1 (docs/design/nav-filter.md §10): the paper's "unobservable states" 11/12/13/14 and 10/11/12/12 are TOM ranks."""
    rows = {r["case"]: (r["n"], r["lom"], r["som"], r["tom"]) for r in table_a()}
    assert rows == TABLE_A


@pytest.fixture(scope="module")
def trajectories():
    return {"racetrack": racetrack(), "rf": rf_turn(), "straight": straight_final()}


#: Table B: trajectory -> clock -> unobservable directions for 0..4 satellites (J = 1)
TABLE_B = {"racetrack": {"estimated": [4, 3, 2, 1, 0], "known": [4, 2, 1, 0, 0]},
           "rf": {"estimated": [4, 3, 2, 1, 0], "known": [4, 2, 1, 0, 0]},
           "straight": {"estimated": [5, 5, 3, 1, 0], "known": [5, 3, 1, 0, 0]}}
#: Table C (with IMU bias states): (trajectory, J) -> clock -> counts
TABLE_C = {("racetrack", 1): {"estimated": [4, 3, 2, 1, 0], "known": [4, 2, 1, 0, 0]},
           ("straight", 1): {"estimated": [9, 8, 5, 3, 1], "known": [9, 6, 3, 1, 1]},
           ("straight", 3): {"estimated": [7, 7, 5, 3, 1], "known": [7, 5, 3, 1, 1]}}


@pytest.mark.parametrize("name", sorted(TABLE_B))
def test_table_b_consistent_model_without_biases(trajectories, name):
    for clock, want in TABLE_B[name].items():
        got = [consistent_observability(trajectories[name], k, clock == "known")["unobservable"] for k in range(5)]
        assert got == want, (name, clock, got)


@pytest.mark.parametrize("key", sorted(TABLE_C))
def test_table_c_consistent_model_with_bias_states(trajectories, key):
    name, J = key
    for clock, want in TABLE_C[key].items():
        got = [consistent_observability(trajectories[name], k, clock == "known", J=J, biases=True)["unobservable"]
               for k in range(5)]
        assert got == want, (key, clock, got)


def test_counts_hold_for_more_features_other_draws_and_camera_pitches(trajectories):
    tr = trajectories["racetrack"]
    for J, seed, pitch in ((2, 1, -30.0), (3, 2, -45.0)):
        got = [consistent_observability(tr, k, False, J=J, camera_pitch_deg=pitch, seed=seed)["unobservable"]
               for k in range(5)]
        assert got == TABLE_B["racetrack"]["estimated"], (J, seed, pitch, got)


def _analytic_null(tr, m: np.ndarray, scale: bool) -> np.ndarray:
    """Columns: translations (3), yaw about up, and (unaccelerated) scale; state [p, v, ψ, m_1..m_J]."""
    J = m.shape[0]
    n = 9 + 3 * J
    cols = []
    for a in range(3):
        c = np.zeros(n)
        c[a] = 1.0
        c[9 + a::3] = 1.0
        cols.append(c)
    k = np.array([0.0, 0.0, 1.0])
    c = np.concatenate([np.cross(k, tr.p[0]), np.cross(k, tr.v[0]), k, np.cross(k, m).ravel()])
    cols.append(c)
    if scale:
        cols.append(np.concatenate([tr.p[0], tr.v[0], np.zeros(3), m.ravel()]))
    return np.array(cols).T


@pytest.mark.parametrize("name,scale", [("racetrack", False), ("straight", True)])
def test_null_space_is_translation_yaw_and_on_a_straight_scale(trajectories, name, scale):
    """T-OBS-3: with no satellite the computed null space spans the analytic directions (residual of
    projecting each onto it < 1e-9 relative)."""
    tr = trajectories[name]
    tom, m = consistent_tom(tr, 0, True, J=2)
    N = null_space(tom)
    A = _analytic_null(tr, m, scale)
    assert N.shape[1] == A.shape[1]
    for col in A.T:
        resid = col - N @ np.linalg.lstsq(N, col, rcond=None)[0]
        assert np.linalg.norm(resid) < 1e-9 * np.linalg.norm(col)
        assert np.linalg.norm(tom @ col) < 1e-9 * np.linalg.norm(tom) * np.linalg.norm(col)


def test_seed_model_counts_do_not_depend_on_the_draw():
    for seed in (1, 2):
        assert seed_observability(2, False, seed=seed)["tom"] == 12
        assert seed_observability(0, True, J=1, seed=seed)["lom"] == 8


@pytest.mark.slow
def test_cli_prints_the_tables(capsys):
    from testbed.cli import main

    assert main(["observability"]) == 0
    out = capsys.readouterr().out
    assert "Table A" in out and "Table C" in out and "LinZhi straight final" in out

"""Observability of the Won et al. paper's GNSS/vision/INS system (docs/design/nav-filter.md §9–§10).

Two models, both linear error-state models whose observability matrices are
stacked and ranked (rank after column equilibration, relative tolerance 1e-9):

* the **paper's simplified model** (its eq. 17 and 19: C = I, Φ = I + FΔt, a
  three-row "relative position" vision sensor with a random h_V per segment,
  one feature): LOM = [H; HF; HF²; HF³] of one segment, the paper's "TOM" =
  LOMs of several segments stacked without transitions (SOM), and the true
  TOM = H_k Φ_{k,0} over every epoch of every segment. Its ranks are the paper's
  Table 1 (which prints ranks as "unobservable states": docs/design/nav-filter.md §10, E1);
* the **consistent model** along a trajectory: state [δp, δv, δψ, (δb_a, δb_g),
  δc_b, δc_d, δm_1..δm_J], the exact piecewise-constant transition (docs/design/nav-filter.md §5 (5.3)) (no
  Earth rate, no gravity gradient: they would make yaw and position weakly
  observable over hours, not over an approach), pseudorange rows −eᵢᵀδp + δc_b
  for static lines of sight, two bearing rows per feature (the tangent-plane
  unit vectors of the camera ray). The unobservable directions it finds: with
  no satellite a common translation of vehicle and features and the yaw about
  gravity (4), plus a scale when the flight is unaccelerated (5).

:func:`table_a` and :func:`table_bc` compute Tables A–C (docs/design/nav-filter.md §9.4);
``testbed observability`` prints them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.inertial import skew, so3_exp
from testbed.navigation.ekf import transition

RTOL = 1e-9
G0 = 9.80665


def numerical_rank(M: NDArray, rtol: float = RTOL) -> int:
    """Rank of M after scaling its columns to unit norm (zero columns stay zero)."""
    norms = np.linalg.norm(M, axis=0)
    Ms = M / np.where(norms > 0, norms, 1.0)
    s = np.linalg.svd(Ms, compute_uv=False)
    return int(np.sum(s > rtol * s[0])) if s.size and s[0] > 0 else 0


def null_space(M: NDArray, rtol: float = RTOL) -> NDArray:
    """Orthonormal basis (n, k) of M's (column-equilibrated) null space, in the original coordinates' scaling."""
    norms = np.linalg.norm(M, axis=0)
    d = np.where(norms > 0, norms, 1.0)
    _, s, Vt = np.linalg.svd(M / d, full_matrices=True)
    r = int(np.sum(s > rtol * s[0]))
    N = Vt[r:].T / d[:, None]  # back to the unscaled state: M (N_scaled / d) = 0
    return N / np.linalg.norm(N, axis=0)


# --------------------------------------------------------------------------- the paper's model (Table A)


def _random_los(rng: np.random.Generator, n: int) -> NDArray:
    """n unit lines of sight above 15° elevation, well apart."""
    az = rng.uniform(0, 2 * np.pi) + np.arange(n) * 2 * np.pi / max(n, 1)
    el = np.radians(rng.uniform(15, 75, n))
    return np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)


def _seed_blocks(n_sat: int, clock_known: bool, J: int, f: NDArray, h_V: NDArray, e: NDArray, dt: float):
    """(Φ, H) of the paper's eq. 17 / 19 for one segment: state [p, v, Ψ, (c_b, c_d), m_1..m_J]."""
    nc = 0 if clock_known else 2
    n = 9 + nc + 3 * J
    F = np.eye(n)
    F[0:3, 3:6] = dt * np.eye(3)
    F[3:6, 6:9] = dt * skew(f)
    if nc:
        F[9, 10] = dt
    rows = []
    # pseudorange and range rate (the paper's signs, docs/design/nav-filter.md §10 E4: rank-neutral)
    for i in range(n_sat):
        r = np.zeros(n)
        r[0:3] = e[i]
        if nc:
            r[9] = 1.0
        rows.append(r)
        r = np.zeros(n)
        r[3:6] = -e[i]
        if nc:
            r[10] = 1.0
        rows.append(r)
    for j in range(J):  # eq. 19: −I on p, h_V on Ψ, I on m_j
        B = np.zeros((3, n))
        B[:, 0:3] = -np.eye(3)
        B[:, 6:9] = h_V
        B[:, 9 + nc + 3 * j: 12 + nc + 3 * j] = np.eye(3)
        rows.extend(B)
    return F, np.array(rows).reshape(-1, n)


def seed_observability(n_sat: int, clock_known: bool = False, J: int = 1, segments: int = 4, steps: int = 4,
                       seed: int = 0, dt: float = 0.1) -> dict[str, int]:
    """Ranks of the paper's LOM, SOM (its "TOM") and the true TOM, and the state dimension."""
    rng = np.random.default_rng(seed)
    e = _random_los(rng, n_sat)
    loms, tom, Phi = [], [], None
    for _ in range(segments):
        f = np.array([0.0, 0.0, -G0]) + rng.normal(0.0, 2.0, 3)
        h_V = rng.normal(0.0, 1.0, (3, 3))
        F, H = _seed_blocks(n_sat, clock_known, J, f, h_V, e, dt)
        Phi = np.eye(F.shape[0]) if Phi is None else Phi
        lom = [H @ np.linalg.matrix_power(F, k) for k in range(steps)]
        loms.append(np.vstack(lom))
        for _ in range(steps):
            tom.append(H @ Phi)
            Phi = F @ Phi
    n = F.shape[0]
    return {"n": n, "lom": numerical_rank(loms[0]), "som": numerical_rank(np.vstack(loms)),
            "tom": numerical_rank(np.vstack(tom))}


# --------------------------------------------------------------------------- trajectories


@dataclass(frozen=True)
class Trajectory:
    """A kinematic flight in the world frame (ENU): positions, velocities, attitudes, specific forces."""

    name: str
    t: NDArray  # (T,)
    p: NDArray  # (T, 3)
    v: NDArray  # (T, 3)
    C: NDArray  # (T, 3, 3) body FRD -> world
    f: NDArray  # (T, 3) specific force, world axes


def _level_attitude(heading: NDArray, pitch: NDArray | float = 0.0, bank: NDArray | float = 0.0) -> NDArray:
    """C_b^w (T, 3, 3) for FRD body axes at a heading (from north, clockwise), pitch and bank."""
    ned_to_enu = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    h, p, b = np.broadcast_arrays(np.asarray(heading, float), np.asarray(pitch, float), np.asarray(bank, float))
    R = so3_exp(np.stack([np.zeros_like(h), np.zeros_like(h), h], -1)) @ \
        so3_exp(np.stack([np.zeros_like(p), p, np.zeros_like(p)], -1)) @ \
        so3_exp(np.stack([b, np.zeros_like(b), np.zeros_like(b)], -1))
    return ned_to_enu @ R


def _integrate(name: str, t: NDArray, accel: NDArray, p0: NDArray, v0: NDArray, pitch: float = 0.0,
               bank: NDArray | float = 0.0) -> Trajectory:
    """A trajectory whose samples obey the transition's own kinematics, p ← p + vΔt + ½aΔt², v ← v + aΔt
    (so the analytic null vectors of docs/design/nav-filter.md §9.5 are null to round-off, not to the sampling's
    O(Δt³))."""
    p, v = [np.asarray(p0, float)], [np.asarray(v0, float)]
    for k in range(t.size - 1):
        dt = t[k + 1] - t[k]
        p.append(p[-1] + v[-1] * dt + 0.5 * accel[k] * dt**2)
        v.append(v[-1] + accel[k] * dt)
    p, v = np.array(p), np.array(v)
    heading = np.arctan2(v[:, 0], v[:, 1])
    return Trajectory(name, t, p, v, _level_attitude(heading, pitch, bank), accel - np.array([0.0, 0.0, -G0]))


def racetrack(duration_s: float = 300.0, rate_hz: float = 2.0, straight_m: float = 150.0, radius_m: float = 30.0,
              height_m: float = 10.0) -> Trajectory:
    """The paper's route: two straights and two left half circles at constant speed, twice in ``duration_s``."""
    lap = 2 * straight_m + 2 * np.pi * radius_m
    speed = 2 * lap / duration_s
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / rate_hz)
    s = (speed * t) % lap
    turning = ((s >= straight_m) & (s < straight_m + np.pi * radius_m)) | (s >= 2 * straight_m + np.pi * radius_m)
    # centripetal acceleration to the left of the velocity, built step by step with the velocity
    accel = np.zeros((t.size, 3))
    v = np.array([speed, 0.0, 0.0])
    for k in range(t.size):
        if turning[k]:
            accel[k] = speed**2 / radius_m * np.array([-v[1], v[0], 0.0]) / np.hypot(v[0], v[1])
        if k + 1 < t.size:
            v = v + accel[k] * (t[k + 1] - t[k])
    return _integrate("racetrack", t, accel, np.array([0.0, 0.0, height_m]), np.array([speed, 0.0, 0.0]))


def rf_turn(duration_s: float = 60.0, rate_hz: float = 10.0, radius_m: float = 3000.0, speed: float = 75.0
            ) -> Trajectory:
    """A level constant-radius left turn (the RNP approach's RF leg), banked."""
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / rate_hz)
    accel = np.zeros((t.size, 3))
    v = np.array([speed, 0.0, 0.0])
    for k in range(t.size):
        accel[k] = speed**2 / radius_m * np.array([-v[1], v[0], 0.0]) / np.hypot(v[0], v[1])
        if k + 1 < t.size:
            v = v + accel[k] * (t[k + 1] - t[k])
    bank = -np.arctan2(speed**2 / radius_m, G0)
    return _integrate("RF turn R 3 km", t, accel, np.array([0.0, 0.0, 700.0]), np.array([speed, 0.0, 0.0]),
                      bank=bank)


def straight_final(duration_s: float = 60.0, rate_hz: float = 10.0, speed: float = 75.0, path_deg: float = 3.0
                   ) -> Trajectory:
    """An unaccelerated 3° descent on the runway-05 course (the LinZhi final)."""
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / rate_hz)
    g, c = np.radians(path_deg), np.radians(54.65)
    v0 = speed * np.array([np.cos(g) * np.sin(c), np.cos(g) * np.cos(c), -np.sin(g)])
    p0 = np.array([-4000.0 * np.sin(c), -4000.0 * np.cos(c), 700.0])
    return _integrate("LinZhi straight final (3°)", t, np.zeros((t.size, 3)), p0, v0, pitch=0.05)


# --------------------------------------------------------------------------- the consistent model (Tables B, C)


def _camera_to_body(pitch_deg: float) -> NDArray:
    """Camera axes (x right, y down, z forward) -> body FRD, pitched down by ``-pitch_deg``."""
    cam0 = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return so3_exp(np.array([0.0, np.radians(pitch_deg), 0.0])) @ cam0


def consistent_observability(traj: Trajectory, n_sat: int, clock_known: bool = False, J: int = 1,
                             biases: bool = False, camera_pitch_deg: float = -45.0, seed: int = 0) -> dict[str, int]:
    """Unobservable directions of the consistent model along ``traj`` (module doc): n, TOM rank, nullity."""
    tom, _ = consistent_tom(traj, n_sat, clock_known, J, biases, camera_pitch_deg, seed)
    r = numerical_rank(tom)
    return {"n": tom.shape[1], "rank": r, "unobservable": tom.shape[1] - r}


def consistent_tom(traj: Trajectory, n_sat: int, clock_known: bool = False, J: int = 1, biases: bool = False,
                   camera_pitch_deg: float = -45.0, seed: int = 0) -> tuple[NDArray, NDArray]:
    """The total observability matrix (rows, n) of the consistent model and the features (J, 3) it used.

    State order: δp, δv, δψ, [δb_a, δb_g], [δc_b, δc_d], δm_1..δm_J (at the first epoch).
    """
    rng = np.random.default_rng(seed)
    e = _random_los(rng, n_sat)
    nb = 6 if biases else 0
    nc = 0 if clock_known or n_sat == 0 else 2  # without a satellite nothing sees the clock: no clock states
    i_c, i_m = 9 + nb, 9 + nb + nc  # clock and feature columns (biases at 9..14 when present)
    n = i_m + 3 * J
    # features near the ground ahead of and around the flight
    lo, hi = traj.p.min(0), traj.p.max(0)
    span = np.maximum(hi - lo, 60.0)
    m = np.stack([rng.uniform(lo[0] - 0.2 * span[0], hi[0] + 0.2 * span[0], J),
                  rng.uniform(lo[1] - 0.2 * span[1], hi[1] + 0.2 * span[1], J), rng.uniform(-5.0, 5.0, J)], -1)
    Rcb = _camera_to_body(camera_pitch_deg)
    idx = np.arange(traj.t.size)
    Phi = np.eye(n)
    rows = []
    for a, k in enumerate(idx):
        C, p = traj.C[k], traj.p[k]
        H = np.zeros((n_sat + 2 * J, n))
        for i in range(n_sat):
            H[i, 0:3] = -e[i]
            if nc:
                H[i, i_c] = 1.0
        for j in range(J):
            d = m[j] - p
            mc = Rcb.T @ C.T @ d
            u = mc / np.linalg.norm(mc)
            B = np.linalg.svd(np.eye(3) - np.outer(u, u))[0][:, :2]  # the tangent plane of the ray
            A = B.T / np.linalg.norm(mc) @ Rcb.T @ C.T  # (2, 3): d(bearing)/d(m − p) in world axes
            r = n_sat + 2 * j
            H[r:r + 2, 0:3] = -A
            H[r:r + 2, 6:9] = A @ skew(d)
            H[r:r + 2, i_m + 3 * j:i_m + 3 * j + 3] = A
        rows.append(H @ Phi)
        if a + 1 < idx.size:
            dt = traj.t[idx[a + 1]] - traj.t[k]
            Phi = _transition(traj.f[k], C, dt, n, nb, nc) @ Phi
    return np.vstack(rows), m


def _transition(f: NDArray, C: NDArray, dt: float, n: int, nb: int, nc: int) -> NDArray:
    """The filter's own transition (:func:`.ekf.transition`) without Earth rate, bias decay or gravity
    gradient, on this model's states (biases and clock only when present), features held."""
    full = transition(C[None], f[None], dt, np.zeros(3), np.inf, np.inf, 0.0)[0]  # 17 × 17
    keep = list(range(9)) + (list(range(9, 15)) if nb else []) + ([15, 16] if nc else [])
    Phi = np.eye(n)
    Phi[:len(keep), :len(keep)] = full[np.ix_(keep, keep)]
    return Phi


# --------------------------------------------------------------------------- the tables


def table_a(seed: int = 0) -> list[dict]:
    """Table A (docs/design/nav-filter.md §9.4): the paper's model, ranks (LOM / SOM / TOM), with the state
    dimension."""
    rows = []
    for J in (1, 2):
        r = seed_observability(0, clock_known=True, J=J, seed=seed)
        rows.append({"case": f"vision/INS, J = {J}", **r, "unobservable": r["n"] - r["tom"]})
    for known in (False, True):
        for k in (1, 2, 3, 4):
            r = seed_observability(k, clock_known=known, J=1, seed=seed)
            rows.append({"case": f"{k} sat, clock {'known' if known else 'estimated'}", **r,
                         "unobservable": r["n"] - r["tom"]})
    return rows


def table_bc(biases: bool, J: int = 1, camera_pitch_deg: float = -45.0, seed: int = 0) -> list[dict]:
    """Tables B (no bias states) and C (with them): unobservable directions per trajectory, clock and satellites."""
    trajs = (racetrack(), rf_turn(), straight_final())
    rows = []
    for tr in trajs:
        for known in (False, True):
            row = {"trajectory": tr.name, "clock": "known" if known else "estimated"}
            for k in (0, 1, 2, 3, 4):
                r = consistent_observability(tr, k, known, J, biases, camera_pitch_deg, seed)
                row[k] = r["unobservable"]
                row["n"] = 9 + (6 if biases else 0) + (0 if known else 2)  # vehicle + clock with satellites
            rows.append(row)
    return rows


def format_tables(seed: int = 0) -> str:
    """Tables A–C as text (``testbed observability``)."""
    out = ["Table A - the Won et al. paper's simplified model (eq. 17 + 19): ranks of the local (LOM), stacked-segment",
           "(SOM = the paper's \"TOM\") and total (TOM) observability matrices; n = state dimension",
           "", f"{'case':<28}{'n':>4}{'LOM':>6}{'SOM':>6}{'TOM':>6}{'unobservable':>14}"]
    for r in table_a(seed):
        out.append(f"{r['case']:<28}{r['n']:>4}{r['lom']:>6}{r['som']:>6}{r['tom']:>6}{r['unobservable']:>14}")
    for biases, name in ((False, "B"), (True, "C")):
        out += ["", f"Table {name} - the consistent model along a trajectory{' with IMU bias states' if biases else ''}:"
                    " unobservable directions (J = 1 feature, its 3 states not in n; no clock states without a satellite)",
                "", f"{'trajectory':<30}{'clock':<11}{'n':>4}" + "".join(f"{k if k < 4 else '>=4':>6}" for k in range(5))]
        for r in table_bc(biases, seed=seed):
            out.append(f"{r['trajectory']:<30}{r['clock']:<11}{r['n']:>4}" + "".join(f"{r[k]:>6}" for k in range(5)))
    return "\n".join(out)

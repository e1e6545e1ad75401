"""K for the DPE's VPL = K·σ + |m| from fault-free normalised errors (docs/design/dpe.md §6): the statistics.

z_i = (e_i − m_i)/σ_i, e the vertical error of the solution, m and σ the epoch's median and
overbound (σ with the SIS term when the monitor adds it). Two estimators:

* ``tail`` (the default): b_z = median(z); at 50 log-spaced tail levels per side, from 0.1 down
  to 100/N_eff, the order statistic z_(i) with its tail replaced by the Clopper-Pearson upper
  bound U_i (confidence 1 − 0.05/100, for the 100 levels at once); σ_z = max |z_(i) − b_z|/Q⁻¹(U_i);
  K = σ_z·Q⁻¹(P/2) + |b_z|. The core is left out on purpose. **Assumption**: the tails beyond the
  deepest level are no heavier than the Gaussian fitted to the measured ones (extrapolation).
* ``quantile`` (the seed's empirical K): the smallest k with #{|z| > k}/N ≤ P; refused unless
  N·P ≥ 10 (P = 1e-7 needs N ≥ 1e8).

:func:`validate` checks a K on a held-out set: the fitted N(b_z, σ_z²) tail holds at every level with
≥ 10 expected exceedances (Clopper-Pearson lower bounds), and the count of |e| > VPL is within its
one-sided binomial 5 % bound.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats
from scipy.special import ndtri

LEVELS_PER_SIDE = 50
CONFIDENCE = 1.0 - 0.05 / (2 * LEVELS_PER_SIDE)
#: the per-epoch HMI probability K is calibrated for by default (docs/design/dpe.md §6: Annex 10's 2e-7 per approach)
DEFAULT_P_HMI = 1e-7


@dataclass(frozen=True)
class KFit:
    """A fitted K: ``k`` for per-epoch probability ``p_hmi``; σ_z, b_z the Gaussian that bounds the
    measured tails; n samples, n_eff independent ones; the binding tail level (side, probability)."""

    k: float
    sigma_z: float
    b_z: float
    p_hmi: float
    n: int
    n_eff: float
    estimator: str
    binding_side: str = ""
    binding_level: float = float("nan")


def _clean(z: ArrayLike) -> NDArray:
    z = np.asarray(z, float).ravel()
    z = z[np.isfinite(z)]
    if z.size < 100:
        raise ValueError(f"K calibration: expected at least 100 finite normalised errors, got {z.size}")
    return z


def _q_inv(p: NDArray) -> NDArray:
    return -ndtri(np.asarray(p, float))  # Q⁻¹(p), exact for tiny p


def gaussian_k(p_hmi: float) -> float:
    """K = Q⁻¹(P/2): the factor of a zero-mean Gaussian overbound's σ that bounds a two-sided tail
    of ``p_hmi`` (5.33 at 1e-7), what the seed's VPL = K·σ_ob assumes."""
    return float(_q_inv(p_hmi / 2.0))


#: the tail levels run from 10 % down to 100/N_eff: more independent epochs than this are needed for one
MIN_TAIL_EPOCHS = 1000


def fit_k_tail(z: ArrayLike, p_hmi: float, n_eff: float | None = None) -> KFit:
    """The ``tail`` estimator (module doc)."""
    z = _clean(z)
    n = z.size
    n_eff = float(n if n_eff is None else min(n_eff, n))
    b = float(np.median(z))
    deepest = 100.0 / n_eff
    if n_eff <= MIN_TAIL_EPOCHS:
        raise ValueError(f"K calibration: N_eff = {n_eff:.0f} leaves no tail levels (need N_eff > {MIN_TAIL_EPOCHS})")
    levels = np.geomspace(0.1, deepest, LEVELS_PER_SIDE)
    best = (0.0, "", float("nan"))
    for side, x in (("upper", np.sort(z - b)[::-1]), ("lower", np.sort(b - z)[::-1])):
        i = np.maximum(np.ceil(levels * n).astype(int), 1)  # exceedances counted at the order statistic
        count = i * (n_eff / n)  # in independent samples
        upper = stats.beta.ppf(CONFIDENCE, count + 1.0, n_eff - count)
        xi = x[i - 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            need = np.where(xi > 0, xi / _q_inv(upper), 0.0)
        j = int(np.argmax(need))
        if need[j] > best[0]:
            best = (float(need[j]), side, float(levels[j]))
    sigma = best[0]
    return KFit(k=sigma * float(_q_inv(p_hmi / 2.0)) + abs(b), sigma_z=sigma, b_z=b, p_hmi=p_hmi, n=n, n_eff=n_eff,
                estimator="tail", binding_side=best[1], binding_level=best[2])


def fit_k_quantile(z: ArrayLike, p_hmi: float) -> KFit:
    """The seed's empirical K: the smallest k with #{|z| > k}/N ≤ P (refused unless N·P ≥ 10)."""
    z = _clean(z)
    n = z.size
    if n * p_hmi < 10:
        raise ValueError(f"K calibration (quantile): N·P = {n}·{p_hmi:g} = {n * p_hmi:.3g} < 10; an empirical "
                         f"quantile at P = {p_hmi:g} needs N ≥ {10 / p_hmi:.0e} (use the tail estimator)")
    a = np.sort(np.abs(z))[::-1]
    allowed = int(np.floor(n * p_hmi))  # at most this many above k
    k = float(a[allowed]) if allowed < n else 0.0
    return KFit(k=k, sigma_z=float("nan"), b_z=0.0, p_hmi=p_hmi, n=n, n_eff=float(n), estimator="quantile")


@dataclass(frozen=True)
class Validation:
    """A held-out check of a fit: ``tails_hold`` (every level with ≥ 10 expected exceedances),
    the worst level's observed/bound ratio, and the count of |e| > VPL against its allowed maximum."""

    tails_hold: bool
    worst_ratio: float
    levels_checked: int
    exceedances: int
    allowed: int
    epochs: int

    @property
    def passed(self) -> bool:
        return self.tails_hold and self.exceedances <= self.allowed


def validate(fit: KFit, z: ArrayLike, exceed_vpl: ArrayLike) -> Validation:
    """Check ``fit`` on held-out ``z`` and the held-out epochs' ``|e| > VPL`` flags
    (docs/design/dpe.md §6.5 (i), (iii))."""
    z = _clean(z)
    n = z.size
    worst, checked, ok = 0.0, 0, True
    tails = () if not np.isfinite(fit.sigma_z) else (np.sort(z - fit.b_z)[::-1], np.sort(fit.b_z - z)[::-1])
    for x in tails:  # a quantile fit has no Gaussian to check: its count alone is checked
        # the fitted tail at each order statistic; a level counts when it expects ≥ 10 exceedances
        for i in np.unique(np.geomspace(10, n / 10, 40).astype(int)):
            p_fit = float(stats.norm.sf(x[i - 1] / fit.sigma_z))
            if n * p_fit < 10:
                continue
            lower = float(stats.beta.ppf(1.0 - CONFIDENCE, i, n - i + 1))  # CP lower bound of the observed tail
            checked += 1
            worst = max(worst, lower / p_fit)
            ok &= lower <= p_fit
    ex = np.asarray(exceed_vpl, bool).ravel()
    allowed = int(stats.binom.ppf(0.95, ex.size, fit.p_hmi))
    return Validation(tails_hold=bool(ok), worst_ratio=worst, levels_checked=checked, exceedances=int(ex.sum()),
                      allowed=allowed, epochs=int(ex.size))


#: correlator settings a K depends on (C/N0 and multipath are strata, not part of the fingerprint)
_CORRELATOR_KEYS = ("bandwidth_chips", "coherent_s", "n_noncoherent", "delay_step_m", "half_window_m", "synthesis",
                    "statistic")


def settings_fingerprint(dpe_settings, correlators) -> tuple[str, dict]:
    """(hash, the settings it covers): the DPE options except K, and the correlator settings a K depends on."""
    cover = {"dpe": dpe_settings.model_dump(mode="json", exclude={"k_factor"}),
             "correlators": {k: getattr(correlators, k) for k in _CORRELATOR_KEYS}}
    text = json.dumps(cover, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16], cover


def _differences(recorded: dict, current: dict, prefix: str = "") -> list[str]:
    """Keys of ``recorded`` whose value differs in ``current`` (keys added since are not compared)."""
    out = []
    for k, v in recorded.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict) and isinstance(current.get(k), dict):
            out += _differences(v, current[k], name + ".")
        elif k not in current or current[k] != v:
            out.append(f"{name} = {v!r} there, {current.get(k)!r} here")
    return out


def read_k_file(path: Path, settings: dict) -> float:
    """K from a calibration record, if it was calibrated for these ``settings`` (the cover of
    :func:`settings_fingerprint`); else ValueError naming every setting that differs."""
    try:
        rec = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"file {path}: cannot be read as a calibration record ({exc})") from None
    problems = record_problems(rec)
    if problems:
        raise ValueError(f"file {path}: not a valid `testbed calibrate-dpe` record: {'; '.join(problems)}")
    current = json.loads(json.dumps(settings))
    diff = _differences(rec["settings"], current) + [
        f"{name} missing there, {value!r} here" for name, value in _missing(rec["settings"], current)]
    if diff:
        raise ValueError(f"file {path} was calibrated for other settings ({'; '.join(diff)}); calibrate again "
                         f"(testbed calibrate-dpe) or use the settings it was made for")
    return float(rec["k"])


#: the plausible range of a calibrated K (a Gaussian's two-sided 1e-12 quantile is 7.1; tails heavier
#: than that are measured in units of σ_ob, not of thousands of them)
K_RANGE = (0.5, 100.0)


def record_problems(rec) -> list[str]:
    """What makes ``rec`` not a record `testbed calibrate-dpe` wrote, checked as strictly as an approach
    file: the kinds and ranges of ``k``, ``p_hmi`` and ``n``, and ``settings`` whole (the DPE and the
    correlator tables) and consistent with its ``fingerprint`` (an edited table no longer matches)."""
    if not isinstance(rec, dict):
        return [f"expected a JSON table, got {type(rec).__name__}"]
    out = []
    k = rec.get("k")
    if isinstance(k, bool) or not isinstance(k, (int, float)) or not (K_RANGE[0] <= k <= K_RANGE[1]):
        out.append(f"k = {k!r}: expected a number from {K_RANGE[0]:g} to {K_RANGE[1]:g}")
    p = rec.get("p_hmi")
    if isinstance(p, bool) or not isinstance(p, float) or not 0.0 < p < 1.0:
        out.append(f"p_hmi = {p!r}: expected a probability between 0 and 1")
    n = rec.get("n")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        out.append(f"n = {n!r}: expected a count of calibration epochs (an integer >= 1)")
    out += _provenance_problems(rec)
    st = rec.get("settings")
    if not (isinstance(st, dict) and set(st) == {"dpe", "correlators"}
            and all(isinstance(v, dict) and v for v in st.values())):
        out.append(f"settings = {st!r}: expected the tables 'dpe' and 'correlators' the record was fitted for")
    elif rec.get("fingerprint") != hashlib.sha256(json.dumps(st, sort_keys=True).encode()).hexdigest()[:16]:
        out.append(f"fingerprint = {rec.get('fingerprint')!r}: does not match its settings (edited by hand?)")
    return out


#: the estimators a record may name (docs/design/dpe.md §6.2, §6.3, §6.8)
ESTIMATORS = ("tail", "quantile", "importance")


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x)


def _provenance_problems(rec: dict) -> list[str]:
    """The estimator's name, and for a K at a measured tail (``importance``) the measurement's provenance:
    its interval (at most ``p_hmi`` at its upper end: what "measured" means), trials, effective sample size,
    proposal and a passed held-out check."""
    est = rec.get("estimator", "tail")
    if est not in ESTIMATORS:
        return [f"estimator = {est!r}: expected one of {', '.join(ESTIMATORS)}"]
    if est != "importance":
        return []
    out = []
    p = rec.get("p_hmi")
    iv = rec.get("interval")
    if not (isinstance(iv, list) and len(iv) == 2 and all(_number(x) for x in iv) and 0.0 <= iv[0] <= iv[1]
            and (not _number(p) or iv[1] <= p)):
        out.append(f"interval = {iv!r}: expected [lower, upper] of the measured tail at k, 0 <= lower <= upper <= "
                   f"p_hmi")
    n = rec.get("trials")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        out.append(f"trials = {n!r}: expected the number of importance-sampled epochs (an integer >= 1)")
    ess = rec.get("n_eff")
    if not (_number(ess) and ess > 0):
        out.append(f"n_eff = {ess!r}: expected the weights' effective sample size (a number > 0)")
    if not isinstance(rec.get("proposal"), dict):
        out.append(f"proposal = {rec.get('proposal')!r}: expected the table of the proposal the tail was measured with")
    v = rec.get("validation")
    if not (isinstance(v, dict) and v.get("passed") is True):
        out.append(f"validation.passed = {v.get('passed') if isinstance(v, dict) else v!r}: expected true (a K "
                   "whose held-out check failed is not used)")
    return out


def _missing(recorded: dict, current: dict, prefix: str = "") -> list[tuple[str, object]]:
    """Keys of ``current`` that ``recorded`` lacks (a setting the record does not say it was fitted for)."""
    out = []
    for k, v in current.items():
        name = f"{prefix}{k}"
        if k not in recorded:
            out.append((name, v))
        elif isinstance(v, dict) and isinstance(recorded[k], dict):
            out += _missing(recorded[k], v, name + ".")
    return out

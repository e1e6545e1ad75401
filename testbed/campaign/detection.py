"""Detection statistics of a campaign's trials: rates with binomial intervals, the faults that were never
exercised, and the minimal detectable bias (MDB).

**Exercised.** A trial of a faulty cell exercises its fault, for a monitor, when the fault reached its
observations (the runner's ``fault_target`` ≥ 0: a satellite or landmark carries it) and at least one
epoch from the onset on carries it (its satellite in view, its landmark detected) while the monitor gives
a solution (``onset_epochs`` > 0). A trial that does not (the satellite never rose, the landmark never
entered the image, the monitor had no solution while it was faulty) says nothing about detection: it is
*not exercised*, left out of the detection rates (per sortie and per epoch) and counted apart, never a
missed detection. Fault-free cells count every trial (their rate is the false-alarm rate).

**MDB** at power P: the smallest fault size whose detection rate reaches P. Only sizes are measured, so
the MDB is known to lie in a bracket ``(low, high]`` of measured sizes: ``high`` the first size whose rate
reaches P, ``low`` the measured size before it. It is interpolated linearly inside the bracket only when
the bracket resolves it: the two sizes are adjacent in the sweep (no unmeasured size between them) and the
rate at ``low`` is at least 1/2. A detection curve is concave above its midpoint (a Gaussian test
statistic's is), so there the chord lies below the curve and the interpolated MDB is at or above the true
one, on the safe side. Otherwise the MDB is given as its bracket ("between 0 and 20 m", "> 20 m (not
reached)"), never as a point read off a line across the whole rise of the curve. With the rates'
confidence bounds it also carries the bracket they support (pointwise): ``ci_high`` the smallest size
whose lower bound reaches P, ``ci_low`` the largest size below it whose upper bound stays under P.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NAN, INF = float("nan"), float("inf")


def binomial_interval(k: np.ndarray, n: np.ndarray, confidence: float = 0.95,
                      method: str = "clopper-pearson") -> tuple[np.ndarray, np.ndarray]:
    """Two-sided confidence interval of a binomial proportion k/n (arrays, any shape)."""
    from scipy import stats

    k, n = np.asarray(k, float), np.asarray(n, float)
    a = 1.0 - confidence
    if method == "wilson":
        z = stats.norm.ppf(1 - a / 2)
        p = np.where(n > 0, k / np.maximum(n, 1), np.nan)
        den = 1 + z**2 / n
        c = (p + z**2 / (2 * n)) / den
        h = z * np.sqrt(p * (1 - p) / n + z**2 / (4 * n**2)) / den
        return np.clip(c - h, 0, 1), np.clip(c + h, 0, 1)
    with np.errstate(invalid="ignore"):
        lo = np.where(k > 0, stats.beta.ppf(a / 2, k, n - k + 1), 0.0)
        hi = np.where(k < n, stats.beta.ppf(1 - a / 2, k + 1, n - k), 1.0)
    return lo, hi


def _names(t) -> list[str]:
    return list(t) if isinstance(t, dict) else t.column_names


def _column(t, name: str) -> np.ndarray:
    return t[name] if isinstance(t, dict) else t.column(name).to_numpy(zero_copy_only=False)


def detection_table(cells: list[dict], trials, confidence: float = 0.95, method: str = "clopper-pearson") -> list[dict]:
    """Per cell and monitor, both definitions of detection with their binomial intervals.

    ``trials`` : a pyarrow Table or a dict of numpy columns (``cell``, ``monitor``, ``detected``, and
    ``onset_epochs``, ``onset_alerts``, ``fault_target`` where stored).

    Per sortie: ``n`` trials, of them ``n_ex`` exercised (``not_exercised`` the rest; every trial of a
    fault-free cell, and of a store written before the per-epoch columns, counts as exercised), ``k`` of
    the exercised with any alert from the onset on, ``rate`` = k / n_ex in [``lo``, ``hi``] (NaN when no
    trial was exercised). Per epoch: ``n_ep`` faulty epochs (from the onset, the fault in the observations)
    at which the monitor gives a solution, ``k_ep`` of them alerted, ``rate_ep`` in [``lo_ep``, ``hi_ep``]
    (fault-free cells: the per-epoch false-alarm rate; NaN without such epochs or columns).
    """
    per_epoch = "onset_epochs" in _names(trials)
    targeted = "fault_target" in _names(trials)
    c = {n: _column(trials, n) for n in ["cell", "monitor", "detected"]
         + (["onset_epochs", "onset_alerts"] if per_epoch else []) + (["fault_target"] if targeted else [])}
    faulty = np.array([cell["fault_kind"] != "none" for cell in cells], bool)
    rows = []
    for m in sorted(set(c["monitor"].tolist())):
        sel_m = c["monitor"] == m
        cells_m = np.asarray(c["cell"][sel_m], np.int64)

        def total(values: np.ndarray) -> np.ndarray:
            return np.bincount(cells_m, weights=np.asarray(values, float), minlength=len(cells))

        cnt = np.bincount(cells_m, minlength=len(cells))
        if per_epoch:
            # a block whose fault reached no observation at all has every epoch marked as carrying it (the
            # runner's fault-free convention), so the target decides too: -1, no satellite or landmark hit
            reached = np.asarray(c["fault_target"][sel_m]) >= 0 if targeted else True
            exercised = ((np.asarray(c["onset_epochs"][sel_m]) > 0) & reached) | ~faulty[cells_m]
            n_ep = total(np.where(exercised, c["onset_epochs"][sel_m], 0))
            k_ep = total(np.where(exercised, c["onset_alerts"][sel_m], 0))
            lo_ep, hi_ep = binomial_interval(k_ep, np.maximum(n_ep, 1), confidence, method)
        else:
            exercised = np.ones(cells_m.size, bool)
            n_ep = k_ep = lo_ep = hi_ep = np.full(len(cells), np.nan)
        n_ex = total(exercised)
        det = total(np.asarray(c["detected"][sel_m], bool) & exercised)
        lo, hi = binomial_interval(det, np.maximum(n_ex, 1), confidence, method)
        for cell in cells:
            i = cell["cell"]
            if cnt[i] == 0:
                continue
            some, some_ep = n_ex[i] > 0, n_ep[i] > 0
            rows.append({**cell, "monitor": m, "n": int(cnt[i]), "n_ex": int(n_ex[i]),
                         "not_exercised": int(cnt[i] - n_ex[i]), "k": int(det[i]),
                         "rate": det[i] / n_ex[i] if some else NAN, "lo": float(lo[i]) if some else NAN,
                         "hi": float(hi[i]) if some else NAN, "n_ep": float(n_ep[i]), "k_ep": float(k_ep[i]),
                         "rate_ep": float(k_ep[i] / n_ep[i]) if some_ep else NAN,
                         "lo_ep": float(lo_ep[i]) if some_ep else NAN, "hi_ep": float(hi_ep[i]) if some_ep else NAN})
    return rows


@dataclass(frozen=True)
class MDB:
    """A minimal detectable bias read off measured detection rates (module doc).

    ``value``: interpolated, NaN when the bracket does not resolve it. ``low`` < MDB ≤ ``high``: the
    bracket of measured sizes (``low`` NaN: reached at the smallest measured size; ``high`` inf: not
    reached up to ``low``, the largest measured size; both NaN: no size measured). ``ci_low`` < MDB ≤
    ``ci_high``: the bracket the rates' confidence bounds support (NaN / inf: no such size)."""

    power: float
    value: float = NAN
    low: float = NAN
    high: float = NAN
    ci_low: float = NAN
    ci_high: float = INF

    @property
    def measured(self) -> bool:
        return not (np.isnan(self.low) and np.isnan(self.high))

    @property
    def resolved(self) -> bool:
        return bool(np.isfinite(self.value))

    @property
    def reached(self) -> bool:
        """The rate reached the power at a measured size."""
        return bool(np.isfinite(self.high))

    @property
    def upper(self) -> float:
        """What the MDB is at most: the interpolated value, else the bracket's top (inf: not reached)."""
        return self.value if self.resolved else self.high

    @property
    def lower(self) -> float:
        """What the MDB is more than: the interpolated value, else the bracket's bottom (0: below the
        smallest measured size)."""
        if self.resolved:
            return self.value
        return 0.0 if np.isnan(self.low) else self.low

    def text(self, unit: str = "", fmt: str = "{:.1f}") -> str:
        """The MDB in words: ``17.6 m (measured 15-20)``, ``between 0 and 20 m``, ``≤ 5 m (the smallest
        size)``, ``> 20 m (not reached)``, ``-`` (nothing measured)."""
        u = f" {unit}" if unit else ""
        if not self.measured:
            return "-"
        if self.resolved:
            return f"{fmt.format(self.value)}{u} (measured {self.low:g}-{self.high:g})"
        if not self.reached:
            return f"> {self.low:g}{u} (not reached)"
        if np.isnan(self.low):
            return f"≤ {self.high:g}{u} (the smallest size)"
        return f"between {self.low:g} and {self.high:g}{u}"

    def short(self, fmt: str = "{:.2f}") -> str:
        """The MDB for a narrow table cell: ``17.60``, ``15-20``, ``≤ 5``, ``> 80``, ``-``."""
        if not self.measured:
            return "-"
        if self.resolved:
            return fmt.format(self.value)
        if not self.reached:
            return f"> {self.low:g}"
        return f"≤ {self.high:g}" if np.isnan(self.low) else f"{self.low:g}-{self.high:g}"

    def ci_text(self, unit: str = "") -> str:
        """The confidence bracket: ``(10, 30] m``, ``> 10 m``, ``≤ 30 m`` or ``-``."""
        u = f" {unit}" if unit else ""
        has_low, has_high = np.isfinite(self.ci_low), np.isfinite(self.ci_high)
        if has_low and has_high:
            return f"({self.ci_low:g}, {self.ci_high:g}]{u}"
        if has_low:
            return f"> {self.ci_low:g}{u}"
        return f"≤ {self.ci_high:g}{u}" if has_high else "-"


def minimal_detectable_bias(size, rate, power: float, lo=None, hi=None) -> MDB:
    """The MDB at ``power`` from detection rates measured at swept sizes (module doc).

    size, rate : (N,) the swept sizes and their rates; a NaN rate is a size not measured (its fault not
    exercised). lo, hi : (N,) the rates' confidence bounds, for the confidence bracket (optional).
    """
    o = np.argsort(np.asarray(size, float), kind="stable")
    s, r = np.asarray(size, float)[o], np.asarray(rate, float)[o]
    ok = np.isfinite(r)
    if not ok.any():
        return MDB(power)
    ci_low, ci_high = NAN, INF
    if lo is not None and hi is not None:
        l_, h_ = np.asarray(lo, float)[o], np.asarray(hi, float)[o]
        sure = np.flatnonzero(ok & (l_ >= power))
        ci_high = float(s[sure[0]]) if sure.size else INF
        under = np.flatnonzero(ok & (h_ < power) & (s < ci_high))
        ci_low = float(s[under[-1]]) if under.size else NAN
    hit = np.flatnonzero(ok & (r >= power))
    if hit.size == 0:
        return MDB(power, low=float(s[ok][-1]), high=INF, ci_low=ci_low, ci_high=ci_high)
    i = hit[0]
    below = np.flatnonzero(ok[:i])
    if below.size == 0:
        return MDB(power, low=NAN, high=float(s[i]), ci_low=ci_low, ci_high=ci_high)
    j = below[-1]
    value = NAN
    if j == i - 1 and r[j] >= 0.5:  # adjacent sizes, on the curve's concave upper half (r[j] < power <= r[i])
        value = float(s[j] + (power - r[j]) * (s[i] - s[j]) / (r[i] - r[j]))
    return MDB(power, value=value, low=float(s[j]), high=float(s[i]), ci_low=ci_low, ci_high=ci_high)

"""The tightest zero-mean Gaussian CDF overbound of a sampled distribution (DeCleene 2000; docs/design/dpe.md §5).

N(0, σ²) overbounds F when Φ(x/σ) ≥ F(x) for x < 0 and Φ(x/σ) ≤ F(x) for x ≥ 0.
Feasibility is monotone in σ, so bisection finds the smallest σ exactly.

The curve is given as values ℓ_j ≥ 0 at sorted offsets u_j. Each value owns the cell
between the midpoints to its neighbours (the outer cells mirrored); its mass is ℓ_j·width_j
(``density``: ℓ is a density) or ℓ_j (``sum``: ℓ is already a mass), and the CDF is
piecewise linear inside the cells (a step CDF would need σ ≥ 2× the truth for fine
cells: docs/design/dpe.md F4). The curve is centred on its median m first — centring on the
solution instead is infeasible whenever m ≠ 0 (at x = 0 both sides ask Φ(0) = ½ = F(0)),
which is why the VPL is K·σ + |m|. Left tails come from a cumulative sum and right tails
from a reverse one (1 − F would lose the far right tail to rounding).

Inside a cell, the margin Φ(x/σ) − L(x) (left of 0) or Q(x/σ) − R(x) (right of 0) is
convex, so it is enough to test the cell's ends and the one stationary point
|x*| = σ·√(2 ln(1/(σρ√(2π)))) where the Gaussian density equals the cell's density ρ.

Everything runs lock-step over a batch of curves (no per-curve Python loop).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtr, ndtri

#: a Gaussian tail short of the curve's tail by at most this fraction of it counts as bounding
#: (relative, so the far tails, down to 1e-300, still bind)
TOLERANCE = 1e-12
#: tails below this are rounding (subnormal floats), not distribution: they bind nothing
TAIL_FLOOR = 1e-300
_GROW, _MAX_GROW, _BISECTIONS = 1.5, 200, 48


@dataclass(frozen=True)
class Overbound:
    """The overbound of each curve (shapes: the batch's).

    sigma : the smallest σ of N(0, σ²) that overbounds the median-centred curve (NaN if the
        curve has no mass, or no σ was found: the monitor reports the epoch infeasible).  median : m, the curve's median (offset units).
    binding : index of the cell where the bound is tightest at ``sigma``.
    about_solution : whether a zero-mean Gaussian about offset 0 (not the median) could
        overbound the curve at all (only when m = 0).
    """

    sigma: NDArray
    median: NDArray
    binding: NDArray
    about_solution: NDArray


@dataclass(frozen=True)
class _Cells:
    edges: NDArray  # (..., n + 1) shifted by the centre
    rho: NDArray  # (..., n) density of each cell
    left: NDArray  # (..., n + 1) mass left of each edge
    right: NDArray  # (..., n + 1) mass right of each edge


def _cells(u: NDArray, ell: NDArray, mass: str) -> tuple[NDArray, NDArray, NDArray]:
    mid = 0.5 * (u[..., 1:] + u[..., :-1])
    first = u[..., :1] - (mid[..., :1] - u[..., :1])
    last = u[..., -1:] + (u[..., -1:] - mid[..., -1:])
    edges = np.concatenate([first, mid, last], axis=-1)
    width = np.diff(edges, axis=-1)
    m = ell * width if mass == "density" else ell.copy()
    total = m.sum(axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = m / total
    return edges, m, width


def _median(edges: NDArray, m: NDArray, width: NDArray) -> NDArray:
    cdf = np.cumsum(m, axis=-1)
    j = np.minimum(np.argmax(cdf >= 0.5, axis=-1), m.shape[-1] - 1)[..., None]
    before = np.take_along_axis(cdf, j, -1) - np.take_along_axis(m, j, -1)
    mj = np.take_along_axis(m, j, -1)
    frac = np.divide(0.5 - before, mj, out=np.full(mj.shape, 0.5), where=mj > 0)
    return (np.take_along_axis(edges, j, -1) + np.clip(frac, 0.0, 1.0) * np.take_along_axis(width, j, -1))[..., 0]


def _prepare(edges: NDArray, m: NDArray, width: NDArray, centre: NDArray) -> _Cells:
    zero = np.zeros(m.shape[:-1] + (1,))
    left = np.concatenate([zero, np.cumsum(m, axis=-1)], axis=-1)
    right = np.concatenate([np.cumsum(m[..., ::-1], axis=-1)[..., ::-1], zero], axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(width > 0, m / width, 0.0)
    return _Cells(edges - centre[..., None], rho, left, right)


def _margins(c: _Cells, sigma: NDArray) -> NDArray:
    with np.errstate(invalid="ignore", over="ignore"):  # empty cells (ρ = 0) and points off a cell
        return _cell_margins(c, sigma)


def _cell_margins(c: _Cells, sigma: NDArray) -> NDArray:
    """(..., n) the smallest margin of each cell at σ (both of its sides of 0), tolerance included."""
    s = sigma[..., None]
    lo, hi = c.edges[..., :-1], c.edges[..., 1:]
    rho = c.rho
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        arg = s * rho * np.sqrt(2.0 * np.pi)
        xs = np.where((arg < 1.0) & (arg > 1e-300), s * np.sqrt(2.0 * np.log(1.0 / arg)), np.nan)
    best = np.full(rho.shape, np.inf)
    # left of zero: Φ(x/σ) − [left(lo) + ρ(x − lo)] on [lo, min(hi, 0)]
    a, b = lo, np.minimum(hi, 0.0)
    has = a < 0.0
    for x in (a, b, -xs):
        inside = has & (x >= a) & (x <= b)
        tail = c.left[..., :-1] + rho * (x - lo)
        mg = np.where(tail < TAIL_FLOOR, 0.0, ndtr(x / s) - (1.0 - TOLERANCE) * tail)
        best = np.where(inside, np.minimum(best, mg), best)
    # right of zero: Q(x/σ) − [right(hi) + ρ(hi − x)] on [max(lo, 0), hi]
    a, b = np.maximum(lo, 0.0), hi
    has = hi > 0.0
    for x in (a, b, xs):
        inside = has & (x >= a) & (x <= b)
        tail = c.right[..., 1:] + rho * (hi - x)
        mg = np.where(tail < TAIL_FLOOR, 0.0, ndtr(-x / s) - (1.0 - TOLERANCE) * tail)
        best = np.where(inside, np.minimum(best, mg), best)
    return best


def _feasible(c: _Cells, sigma: NDArray) -> NDArray:
    return np.all(_margins(c, sigma) >= 0.0, axis=-1)


def _sigma_floor(c: _Cells) -> NDArray:
    """max |e|/Q⁻¹(tail(e)) over the edges with a tail in (0, ½): a σ below it fails at that edge."""
    e = c.edges
    tail = np.where(e < 0.0, c.left, c.right)
    ok = (e != 0.0) & (tail > TAIL_FLOOR) & (tail < 0.5)
    with np.errstate(divide="ignore", invalid="ignore"):
        need = np.where(ok, np.abs(e) / -ndtri(np.where(ok, tail, 0.25)), 0.0)  # Q⁻¹(t) = −Φ⁻¹(t), exact for tiny t
    floor = need.max(axis=-1)
    scale = np.nanmax(np.abs(e), axis=-1)
    return np.maximum(floor, 1e-9 * scale)


def gaussian_overbound(offsets: ArrayLike, values: ArrayLike, *, mass: str = "density") -> Overbound:
    """The tightest median-centred zero-mean Gaussian overbound of each curve.

    offsets : (..., n) sorted ascending (n ≥ 2).  values : (..., n) ≥ 0 (densities or masses).
    mass : "density" (cell mass ℓ·width) or "sum" (cell mass ℓ, the seed's literal reading).
    """
    u = np.asarray(offsets, float)
    ell = np.asarray(values, float)
    if u.shape != ell.shape or u.shape[-1] < 2:
        raise ValueError(f"offsets and values: expected equal shapes (..., n ≥ 2), got {u.shape} and {ell.shape}")
    if mass not in ("density", "sum"):
        raise ValueError(f"mass: expected 'density' or 'sum', got {mass!r}")
    edges, m, width = _cells(u, ell, mass)
    empty = ~np.isfinite(m).all(axis=-1) | (np.nansum(m, axis=-1) <= 0)
    m = np.where(empty[..., None], 1.0 / m.shape[-1], m)  # placeholder; reported NaN
    med = _median(edges, m, width)
    cells = _prepare(edges, m, width, med)
    lo = _sigma_floor(cells)
    hi = 1.01 * lo
    for _ in range(_MAX_GROW):
        bad = ~_feasible(cells, hi)
        if not bad.any():
            break
        hi = np.where(bad, hi * _GROW, hi)
    empty = empty | ~_feasible(cells, hi)  # none found within 1.5^200 of the floor: reported NaN, not raised
    lo = np.minimum(lo, hi)
    for _ in range(_MAX_GROW):  # the floor is necessary, so at most a rounding step above the answer
        ok = _feasible(cells, lo)
        if not ok.any():
            break
        lo = np.where(ok, lo / _GROW, lo)
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        ok = _feasible(cells, mid)
        hi = np.where(ok, mid, hi)
        lo = np.where(ok, lo, mid)
        if np.all(hi - lo <= 1e-7 * hi):
            break
    binding = np.argmin(_margins(cells, hi), axis=-1)
    about = _feasible(_prepare(edges, m, width, np.zeros_like(med)), 1e3 * hi)
    nan = np.where(empty, np.nan, 1.0)
    return Overbound(sigma=hi * nan, median=med * nan, binding=binding, about_solution=about & ~empty)


def overbounds(sigma: float, offsets: ArrayLike, values: ArrayLike, *, centre: float | None = None,
               mass: str = "density") -> bool:
    """Whether N(centre, σ²) overbounds one curve (centre: its median by default); for tests and checks."""
    u = np.asarray(offsets, float)[None]
    edges, m, width = _cells(u, np.asarray(values, float)[None], mass)
    c = _median(edges, m, width) if centre is None else np.array([centre], float)
    return bool(_feasible(_prepare(edges, m, width, c), np.array([sigma], float))[0])

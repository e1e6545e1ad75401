"""Steady wind and a seeded gust model of our own.

JSBSim's built-in turbulence chooses its altitude band from height above MSL,
so at ZUNZ (2949 m) it gives almost nothing near the ground
(docs/design/physics-notes.md §jsbsim-turbulence-at-high-elevation). We
drive ``atmosphere/gust-*`` with first-order Markov gusts that use the
MIL-F-8785C low-altitude length scales and intensities (a "Markov
approximation" of the Dryden spectra: same variance and correlation length,
first-order roll-off for all three axes; say so when comparing spectra).
"""

from __future__ import annotations

import math

import numpy as np

from testbed.flight.settings import Gusts, Wind
from testbed.frames import FT, KT


def wind_ned(wind: Wind) -> np.ndarray:
    """Steady wind velocity (m/s, NED, the direction it blows TO)."""
    to = math.radians(wind.from_deg + 180.0)
    v = wind.speed_kt * KT
    return np.array([v * math.cos(to), v * math.sin(to), 0.0])


def dryden_low_altitude(agl_m: float, w20_ms: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis (u, v, w) gust sigma (m/s) and length scale (m), MIL-F-8785C low altitude.

    Valid 10–1000 ft AGL; above 1000 ft the 1000-ft values are kept (the
    medium-altitude model joins there with L = 1750 ft).
    """
    h = min(max(agl_m / FT, 10.0), 1000.0)  # ft
    k = 0.177 + 0.000823 * h
    sigma_w = 0.1 * w20_ms
    sigma_uv = sigma_w / k**0.4
    L_uv = h / k**1.2 * FT
    L_w = h * FT
    return np.array([sigma_uv, sigma_uv, sigma_w]), np.array([L_uv, L_uv, L_w])


class GustGenerator:
    """Seeded first-order Markov gusts in the aircraft's heading axes, returned in NED.

    ``step(dt, airspeed, agl, heading)`` advances the state by one time step.
    The innovations are pre-drawn from ``numpy.random.default_rng(seed)`` so the
    sequence is a pure function of the seed.
    """

    def __init__(self, gusts: Gusts, max_steps: int) -> None:
        self.w20 = gusts.w20() * KT
        self.enabled = self.w20 > 0
        self._noise = np.random.default_rng(gusts.seed).standard_normal((max_steps, 3)) if self.enabled else None
        # normalised state with unit variance from the start (stationary, not ramping up from calm)
        self._x = self._noise[0].copy() if self.enabled else np.zeros(3)
        self._k = 1

    def step(self, dt: float, airspeed: float, agl: float, heading: float) -> np.ndarray:
        if not self.enabled:
            return np.zeros(3)
        sigma, L = dryden_low_altitude(agl, self.w20)
        a = np.exp(-max(airspeed, 1.0) * dt / L)
        self._x = a * self._x + np.sqrt(1.0 - a * a) * self._noise[self._k % len(self._noise)]
        self._k += 1
        u, v, w = sigma * self._x
        c, s = math.cos(heading), math.sin(heading)
        return np.array([u * c - v * s, u * s + v * c, w])

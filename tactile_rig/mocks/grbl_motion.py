"""Trapezoidal motion profiles for the GRBL mock: one straight block at a time.

GRBL's planner limits each axis to its own maximum rate and acceleration: a block along unit
direction ``u`` may go at most ``min_i(rate_i / |u_i|)`` and accelerate at most ``min_i(acc_i /
|u_i|)``. The mock runs each block from its entry speed to a stop (no junction blending: GRBL
would carry speed through shallow corners, so the mock's moves take a little longer than the real
machine's; that errs on the safe side for timeouts). A profile is a list of constant-acceleration
phases, so a feed hold or an override re-plans from the current speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Profile:
    """Motion along a line from ``p0`` in direction ``u``: phases of (duration_s, v_start, accel)."""

    p0: np.ndarray
    u: np.ndarray
    length: float
    t0_s: float
    phases: list[tuple[float, float, float]] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return sum(p[0] for p in self.phases)

    @property
    def t_end_s(self) -> float:
        return self.t0_s + self.duration_s

    def at(self, t_s: float) -> tuple[float, float]:
        """(distance along the line, speed) at ``t_s``; both clamped to the profile."""
        dt = max(0.0, t_s - self.t0_s)
        d = 0.0
        for dur, v, a in self.phases:
            if dt <= dur:
                return min(self.length, d + v * dt + 0.5 * a * dt * dt), max(0.0, v + a * dt)
            d += v * dur + 0.5 * a * dur * dur
            dt -= dur
        return self.length, 0.0

    def point(self, dist: float) -> np.ndarray:
        return self.p0 + self.u * dist

    def time_at_distance(self, dist: float) -> float:
        """When the motion first reaches ``dist`` along the line (bisection: the profile is monotone)."""
        lo, hi = self.t0_s, self.t_end_s
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if self.at(mid)[0] < dist:
                lo = mid
            else:
                hi = mid
        return hi


def line_limits(u: np.ndarray, max_rate_mm_per_min: np.ndarray, accel_mm_per_s2: np.ndarray,
                feed_mm_per_min: float | None) -> tuple[float, float]:
    """(max speed mm/s, acceleration mm/s²) along unit direction ``u`` (``feed`` None: a rapid)."""
    au = np.abs(u)
    moving = au > 1e-12
    v = float(np.min(max_rate_mm_per_min[moving] / 60.0 / au[moving]))
    if feed_mm_per_min is not None:
        v = min(v, feed_mm_per_min / 60.0)
    a = float(np.min(accel_mm_per_s2[moving] / au[moving]))
    return v, a


def trapezoid(length: float, v0: float, vmax: float, accel: float) -> list[tuple[float, float, float]]:
    """Phases to cover ``length`` starting at ``v0``, at most ``vmax``, stopping at the end."""
    if length <= 0:
        return []
    vmax = max(vmax, 1e-9)
    stop_d = v0 * v0 / (2 * accel)
    if stop_d >= length:  # cannot stop in time at the nominal deceleration: brake harder
        a = v0 * v0 / (2 * length)
        return [(v0 / a, v0, -a)]
    phases: list[tuple[float, float, float]] = []
    if v0 > vmax:
        phases.append(((v0 - vmax) / accel, v0, -accel))
        d1 = (v0 * v0 - vmax * vmax) / (2 * accel)
        vpk = vmax
    else:
        vpk = min(vmax, math.sqrt((2 * accel * length + v0 * v0) / 2))
        phases.append(((vpk - v0) / accel, v0, accel))
        d1 = (vpk * vpk - v0 * v0) / (2 * accel)
    d3 = vpk * vpk / (2 * accel)
    cruise = max(0.0, length - d1 - d3)
    if cruise > 0:
        phases.append((cruise / vpk, vpk, 0.0))
    phases.append((vpk / accel, vpk, -accel))
    return [p for p in phases if p[0] > 0]

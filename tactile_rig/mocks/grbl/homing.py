"""GRBL 1.1h's homing cycle (limits.c ``limits_go_home``) as a plan of timed legs.

Per cycle (θ's Z channel first, then X and Y together: ``HOMING_CYCLE_0/1``) the firmware runs four
moves, each a planned line from rest to rest with ``$26`` debounce milliseconds after it:

1. seek toward the switches at ``$25`` over 1.5 × the largest ``$13x`` travel; each axis stops dead
   (its steps masked) as its switch closes, the others go on; no switch by the end: ALARM:9;
2. pull off ``$27`` at ``$25``; a switch still closed after it: ALARM:8;
3. locate at ``$24`` over at most 5 × ``$27``, stopping again on the switches;
4. pull off ``$27`` at ``$25``.

Rates are multiplied by √n for n axes so each axis moves at the homing rate. The machine position
of each homed axis is then −``$27`` (or −``$13x`` + ``$27`` with its ``$23`` bit set): GRBL's
machine space is negative. Positions here are physical (the stage's), in mm or degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tactile_rig.mocks.grbl.planner import Profile, block_phases, limit_by_axis_maximum

SEARCH_SCALAR = 1.5
LOCATE_SCALAR = 5.0


@dataclass
class HomingLeg:
    """One homing move: physical positions along it, and when each axis locked."""

    kind: str  # seek | pulloff | locate
    axes: tuple[int, ...]
    phys0: np.ndarray
    direction: np.ndarray  # ±1 on the cycle axes, 0 elsewhere
    profile: Profile  # along the line; distance s covers s/√n on every axis
    lock_s: dict[int, float] = field(default_factory=dict)  # axis → line distance at which it stopped
    axis_travel: dict[int, float] = field(default_factory=dict)  # axis → whole-step travel of a full move
    t_end_s: float = 0.0  # when the motion ends (before the debounce pause)
    alarm: int | None = None  # ALARM code raised at t_end_s

    def position_at(self, t_s: float) -> np.ndarray:
        s, _ = self.profile.at(min(t_s, self.t_end_s))
        root_n = math.sqrt(len(self.axes))
        frac = s / self.profile.length if self.profile.length > 0 else 1.0
        p = self.phys0.copy()
        for i in self.axes:
            if i in self.lock_s:
                p[i] += self.direction[i] * min(s, self.lock_s[i]) / root_n
            else:  # a pull-off runs whole steps on each axis
                p[i] += self.direction[i] * frac * self.axis_travel[i]
        return p

    def speed_at(self, t_s: float) -> float:
        """Per-axis speed (mm/s) while moving: what ``FS:`` would print."""
        if t_s >= self.t_end_s:
            return 0.0
        return self.profile.at(t_s)[1] / math.sqrt(len(self.axes))


@dataclass
class HomingSetup:
    """What a homing cycle reads: settings (per axis arrays in mm, mm/min, mm/s²) and the switches."""

    max_travel_mm: np.ndarray
    max_rate_mm_per_min: np.ndarray
    accel_mm_per_s2: np.ndarray
    seek_mm_per_min: float
    feed_mm_per_min: float
    pulloff_mm: float
    debounce_s: float
    dir_negative: np.ndarray  # $23 bits
    switch_at: np.ndarray  # physical trip point on the homing side of each axis (mm / deg)
    steps_per_mm: np.ndarray | None = None
    switches_work: bool = True  # False: no switch closes (ALARM:9)


def _move(kind: str, axes: tuple[int, ...], phys0: np.ndarray, direction: np.ndarray, travel: float,
          rate_mm_per_min: float, setup: HomingSetup, t0: float) -> HomingLeg:
    n = len(axes)
    unit = np.zeros(len(phys0))
    unit[list(axes)] = 1.0 / math.sqrt(n)
    length = travel * math.sqrt(n)
    accel = limit_by_axis_maximum(setup.accel_mm_per_s2, unit)
    v = min(rate_mm_per_min * math.sqrt(n), limit_by_axis_maximum(setup.max_rate_mm_per_min, unit)) / 60.0
    prof = Profile(np.zeros(1), np.ones(1), length, t0, block_phases(length, 0.0, v, 0.0, accel))
    leg = HomingLeg(kind, axes, phys0.copy(), direction, prof, t_end_s=prof.t_end_s)
    for i in axes:
        spm = float(setup.steps_per_mm[i]) if setup.steps_per_mm is not None else 0.0
        leg.axis_travel[i] = math.floor(travel * spm + 0.5) / spm if spm > 0 else travel
    if kind in ("seek", "locate"):
        for i in axes:
            gap = (setup.switch_at[i] - phys0[i]) * direction[i] if setup.switches_work else math.inf
            leg.lock_s[i] = max(0.0, gap) * math.sqrt(n)
        last = max(leg.lock_s.values())
        if last <= length:
            leg.t_end_s = prof.time_at_distance(last) if last > 0 else t0
        else:
            leg.alarm = 9
    return leg


def plan_cycle(phys: np.ndarray, axes: tuple[int, ...], setup: HomingSetup, t0: float) -> list[HomingLeg]:
    """The legs of one homing cycle over ``axes`` from physical position ``phys`` at ``t0``.
    The last leg carries the alarm if the cycle fails; the cycle ends at the last leg's
    ``t_end_s`` + ``debounce_s`` when it succeeds."""
    toward = np.zeros(len(phys))
    for i in axes:
        toward[i] = -1.0 if setup.dir_negative[i] else 1.0
    search = SEARCH_SCALAR * max(float(setup.max_travel_mm[i]) for i in axes)
    legs: list[HomingLeg] = []
    t, p = t0, np.array(phys, float)
    plan = [("seek", toward, search, setup.seek_mm_per_min),
            ("pulloff", -toward, setup.pulloff_mm, setup.seek_mm_per_min),
            ("locate", toward, setup.pulloff_mm * LOCATE_SCALAR, setup.feed_mm_per_min),
            ("pulloff", -toward, setup.pulloff_mm, setup.seek_mm_per_min)]
    for kind, direction, travel, rate in plan:
        leg = _move(kind, axes, p, direction, travel, rate, setup, t)
        legs.append(leg)
        p = leg.position_at(leg.t_end_s)
        if kind == "pulloff" and any(p[i] * toward[i] >= setup.switch_at[i] * toward[i] - 1e-12 for i in axes):
            leg.alarm = 8
        if leg.alarm is not None:
            return legs
        t = leg.t_end_s + setup.debounce_s
    return legs


def homed_machine_position(axis: int, setup: HomingSetup) -> float:
    """The machine position a homed axis is given: −pull-off, or −travel + pull-off with ``$23``."""
    if setup.dir_negative[axis]:
        return -float(setup.max_travel_mm[axis]) + setup.pulloff_mm
    return -setup.pulloff_mm

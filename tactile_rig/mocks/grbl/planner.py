"""GRBL 1.1h's motion planning as pure numerics: the look-ahead planner and its velocity profiles.

* :class:`Planner` is planner.c: a 16-slot ring (15 usable) of line blocks in whole steps, each
  with its per-axis-limited rate and acceleration; a new block's maximum entry speed comes from
  the junction deviation ``$11`` (``v² = a·δ·sin(θ/2)/(1 − sin(θ/2))``, 0 for a reversal, no limit
  for a straight continuation); every new block re-runs the reverse and forward passes, so corners
  are taken at speed and only the last block plans a stop.
* A block's motion is a trapezoid from its entry to its exit speed (:func:`block_phases`), as the
  stepper's segment generator traces it; feed hold decelerates at the block's acceleration
  (:func:`stop_phases`).
* :func:`arc_points` is mc_arc: the chord count from ``$12`` and the end points of each segment.

Speeds here are mm/s and accelerations mm/s² (GRBL keeps mm/min and mm/min²; the ratios are equal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SOME_LARGE_VALUE = 1.0e38
MINIMUM_JUNCTION_SPEED = 0.0  # mm/min, config.h
MINIMUM_FEED_RATE = 1.0  # mm/min, config.h
ARC_ANGULAR_TRAVEL_EPSILON = 5e-7
BLOCK_BUFFER_SIZE = 16


@dataclass
class Limits:
    """The axis settings the planner reads: $100+ steps/mm, $110+ mm/min, $120+ mm/s², $11 mm."""

    steps_per_mm: np.ndarray
    max_rate_mm_per_min: np.ndarray
    accel_mm_per_s2: np.ndarray
    junction_deviation_mm: float


@dataclass
class PlanBlock:
    """One planned line (a ``plan_block_t``); ``millimeters`` shrinks as the stepper runs it."""

    start_mm: np.ndarray  # where the block starts (whole steps, machine mm)
    target_mm: np.ndarray  # where it ends (whole steps, machine mm)
    unit: np.ndarray
    millimeters: float
    accel: float  # mm/s² along the line
    rapid_rate: float  # mm/s along the line
    programmed_rate: float  # mm/s (G93 already converted)
    rapid: bool = False
    no_feed_override: bool = False
    max_junction_sqr: float = 0.0
    max_entry_sqr: float = 0.0
    entry_sqr: float = 0.0
    kind: str = "line"  # line | jog | probe
    tag: object = None  # the firmware's own note (e.g. which line queued it)
    length_mm: float = field(init=False)

    def __post_init__(self) -> None:
        self.length_mm = self.millimeters


def limit_by_axis_maximum(max_values: np.ndarray, unit: np.ndarray) -> float:
    """planner.c ``limit_value_by_axis_maximum``: the largest value along ``unit`` within every axis' limit."""
    out = SOME_LARGE_VALUE
    for m, u in zip(max_values, unit):
        if u != 0.0:
            out = min(out, abs(float(m) / float(u)))
    return out


class Planner:
    """planner.c: ``buffer_line`` and the re-planning passes; ``blocks[0]`` is the one executing."""

    def __init__(self, n_axes: int, capacity: int = BLOCK_BUFFER_SIZE) -> None:
        self.capacity = capacity
        self.blocks: list[PlanBlock] = []
        self.position_steps = np.zeros(n_axes, dtype=np.int64)
        self.prev_unit = np.zeros(n_axes)
        self.prev_nominal = 0.0  # mm/s

    # -- buffer bookkeeping -----------------------------------------------------------------------
    def reset(self, position_steps: np.ndarray) -> None:
        """``plan_reset`` + ``plan_sync_position``."""
        self.blocks.clear()
        self.position_steps = np.array(position_steps, dtype=np.int64)
        self.prev_unit = np.zeros(len(self.position_steps))
        self.prev_nominal = 0.0

    def full(self) -> bool:
        return len(self.blocks) >= self.capacity - 1

    def available(self) -> int:
        """``plan_get_block_buffer_available``, the ``Bf:`` planner field."""
        return self.capacity - 1 - len(self.blocks)

    # -- planning ------------------------------------------------------------------------------------
    @staticmethod
    def nominal_speed(b: PlanBlock, feed_ovr: int, rapid_ovr: int) -> float:
        """``plan_compute_profile_nominal_speed`` (mm/s)."""
        if b.rapid:
            v = b.rapid_rate * 0.01 * rapid_ovr
        else:
            v = b.programmed_rate
            if not b.no_feed_override:
                v *= 0.01 * feed_ovr
            v = min(v, b.rapid_rate)
        return max(v, MINIMUM_FEED_RATE / 60.0)

    def buffer_line(self, target_mm: np.ndarray, rate_mm_per_min: float | None, lim: Limits, *,
                    feed_ovr: int = 100, rapid_ovr: int = 100, inverse_time: bool = False,
                    no_feed_override: bool = False, kind: str = "line", tag: object = None) -> PlanBlock | None:
        """``plan_buffer_line``: queue a line to ``target_mm`` (None rate: a rapid). None: zero length."""
        target_steps = np.array([int(round_half_away(t * s)) for t, s in zip(target_mm, lim.steps_per_mm)],
                                dtype=np.int64)
        delta_steps = target_steps - self.position_steps
        if not np.any(delta_steps):
            return None
        delta_mm = delta_steps / lim.steps_per_mm
        millimeters = float(np.sqrt(np.sum(delta_mm ** 2)))
        unit = delta_mm / millimeters
        accel = limit_by_axis_maximum(lim.accel_mm_per_s2, unit)
        rapid_rate = limit_by_axis_maximum(lim.max_rate_mm_per_min, unit) / 60.0
        if rate_mm_per_min is None:
            programmed = rapid_rate
        else:
            programmed = rate_mm_per_min / 60.0 * (millimeters if inverse_time else 1.0)
        start_mm = self.position_steps / lim.steps_per_mm
        b = PlanBlock(start_mm=start_mm, target_mm=target_steps / lim.steps_per_mm, unit=unit, millimeters=millimeters,
                      accel=accel, rapid_rate=rapid_rate, programmed_rate=programmed,
                      rapid=rate_mm_per_min is None, no_feed_override=no_feed_override, kind=kind, tag=tag)
        if not self.blocks:
            b.max_junction_sqr = 0.0  # starting from rest
        else:
            b.max_junction_sqr = junction_speed_sqr(self.prev_unit, unit, lim)
        nominal = self.nominal_speed(b, feed_ovr, rapid_ovr)
        b.max_entry_sqr = min(min(nominal, self.prev_nominal) ** 2, b.max_junction_sqr)
        self.prev_nominal = nominal
        self.prev_unit = unit
        self.position_steps = target_steps
        self.blocks.append(b)
        self.recalculate()
        return b

    def update_overrides(self, feed_ovr: int, rapid_ovr: int) -> None:
        """``plan_update_velocity_profile_parameters``: new nominal speeds after an override."""
        prev = SOME_LARGE_VALUE
        for b in self.blocks:
            nominal = self.nominal_speed(b, feed_ovr, rapid_ovr)
            b.max_entry_sqr = min(min(nominal, prev) ** 2, b.max_junction_sqr)
            prev = nominal
        self.prev_nominal = prev if self.blocks else self.prev_nominal

    def recalculate(self) -> None:
        """Reverse pass (each block can still stop by the end of the buffer), then forward pass
        (each block reaches its entry speed from the previous one). ``blocks[0]`` keeps its entry."""
        bs = self.blocks
        if len(bs) < 2:
            return
        last = bs[-1]
        last.entry_sqr = min(last.max_entry_sqr, 2 * last.accel * last.millimeters)
        for i in range(len(bs) - 2, 0, -1):
            cur, nxt = bs[i], bs[i + 1]
            cur.entry_sqr = min(cur.max_entry_sqr, nxt.entry_sqr + 2 * cur.accel * cur.millimeters)
        for i in range(len(bs) - 1):
            cur, nxt = bs[i], bs[i + 1]
            if cur.entry_sqr < nxt.entry_sqr:
                nxt.entry_sqr = min(nxt.entry_sqr, cur.entry_sqr + 2 * cur.accel * cur.millimeters)

    def exit_speed_sqr(self) -> float:
        """``plan_get_exec_block_exit_speed_sqr``: the executing block ends at the next one's entry."""
        return self.blocks[1].entry_sqr if len(self.blocks) > 1 else 0.0


def round_half_away(x: float) -> float:
    """C's ``lround``."""
    return math.floor(x + 0.5) if x >= 0 else -math.floor(-x + 0.5)


def junction_speed_sqr(prev_unit: np.ndarray, unit: np.ndarray, lim: Limits) -> float:
    """Maximum junction speed² (mm²/s²) between two unit directions by junction deviation ``$11``."""
    cos_theta = -float(np.dot(prev_unit, unit))
    if cos_theta > 0.999999:
        return (MINIMUM_JUNCTION_SPEED / 60.0) ** 2  # a reversal: stop
    if cos_theta < -0.999999:
        return SOME_LARGE_VALUE  # straight on
    ju = unit - prev_unit
    ju = ju / float(np.sqrt(np.sum(ju ** 2)))
    a = limit_by_axis_maximum(lim.accel_mm_per_s2, ju)
    sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
    return max((MINIMUM_JUNCTION_SPEED / 60.0) ** 2, a * lim.junction_deviation_mm * sin_half / (1.0 - sin_half))


# -- velocity profiles: lists of (duration_s, v_start, accel) ---------------------------------------------
Phase = tuple[float, float, float]


def block_phases(length: float, v0: float, v_nominal: float, v_exit: float, accel: float) -> list[Phase]:
    """A trapezoid over ``length``: from ``v0`` up to at most ``v_nominal``, down to ``v_exit`` at the end.

    Like the stepper's ramps: an entry above the nominal speed (a lowered override) first decelerates
    to it; an exit faster than ``accel`` allows is capped; an exit slower than ``accel`` can reach in
    the remaining length is reached by braking harder over the whole block.
    """
    if length <= 0:
        return []
    a = max(accel, 1e-9)
    v_nominal = max(v_nominal, 1e-9)
    v_exit = min(v_exit, math.sqrt(v0 * v0 + 2 * a * length), max(v_nominal, v0))
    if v0 * v0 - v_exit * v_exit >= 2 * a * length:  # all braking (a hold, or a lowered override)
        if v0 <= v_exit:
            return [(length / v0, v0, 0.0)] if v0 > 0 else []
        a_brake = (v0 * v0 - v_exit * v_exit) / (2 * length)
        return [((v0 - v_exit) / a_brake, v0, -a_brake)]
    phases: list[Phase] = []
    if v0 > v_nominal:  # decelerate to the (overridden) nominal speed first
        d_first = (v0 * v0 - v_nominal * v_nominal) / (2 * a)
        phases.append(((v0 - v_nominal) / a, v0, -a))
        v_start, rest = v_nominal, length - d_first
    else:
        v_start, rest = v0, length
    v_peak = min(v_nominal, math.sqrt(max((2 * a * rest + v_start * v_start + v_exit * v_exit) / 2, 0.0)))
    v_peak = max(v_peak, v_start, v_exit)
    d_up = (v_peak * v_peak - v_start * v_start) / (2 * a)
    d_down = (v_peak * v_peak - v_exit * v_exit) / (2 * a)
    cruise = max(0.0, rest - d_up - d_down)
    if v_peak > v_start:
        phases.append(((v_peak - v_start) / a, v_start, a))
    if cruise > 0:
        phases.append((cruise / v_peak, v_peak, 0.0))
    if v_peak > v_exit:
        phases.append(((v_peak - v_exit) / a, v_peak, -a))
    return [p for p in phases if p[0] > 0]


def stop_phases(v0: float, accel: float) -> list[Phase]:
    """Feed hold / motion cancel: decelerate from ``v0`` to rest at ``accel``."""
    if v0 <= 0:
        return []
    return [(v0 / accel, v0, -accel)]


def phases_distance(phases: list[Phase]) -> float:
    return sum(d * v + 0.5 * a * d * d for d, v, a in phases)


def phases_duration(phases: list[Phase]) -> float:
    return sum(p[0] for p in phases)


@dataclass
class Profile:
    """Motion along a line from ``p0`` in direction ``u``: phases starting at ``t0_s``."""

    p0: np.ndarray
    u: np.ndarray
    length: float
    t0_s: float
    phases: list[Phase] = field(default_factory=list)

    @property
    def t_end_s(self) -> float:
        return self.t0_s + phases_duration(self.phases)

    def at(self, t_s: float) -> tuple[float, float]:
        """(distance along the line, speed) at ``t_s``, clamped to the profile."""
        dt = max(0.0, t_s - self.t0_s)
        d = 0.0
        for dur, v, a in self.phases:
            if dt <= dur:
                return min(self.length, d + v * dt + 0.5 * a * dt * dt), max(0.0, v + a * dt)
            d += v * dur + 0.5 * a * dur * dur
            dt -= dur
        end_v = self.phases[-1][1] + self.phases[-1][2] * self.phases[-1][0] if self.phases else 0.0
        return min(self.length, d), max(0.0, end_v)

    def point(self, dist: float) -> np.ndarray:
        return self.p0 + self.u * dist

    def time_at_distance(self, dist: float) -> float:
        """When the motion first reaches ``dist`` (the profile is monotone in distance)."""
        lo, hi = self.t0_s, self.t_end_s
        if self.at(hi)[0] < dist:
            return math.inf
        for _ in range(64):
            mid = 0.5 * (lo + hi)
            if self.at(mid)[0] < dist:
                lo = mid
            else:
                hi = mid
        return hi


def arc_points(position: np.ndarray, target: np.ndarray, offset: np.ndarray, radius: float,
               axes: tuple[int, int, int], clockwise: bool, tolerance_mm: float,
               n_correction: int = 12) -> list[np.ndarray]:
    """mc_arc: the end point of every chord of an arc (the last one is ``target``), for ``$12``."""
    a0, a1, al = axes
    cx, cy = position[a0] + offset[a0], position[a1] + offset[a1]
    r0, r1 = -offset[a0], -offset[a1]
    rt0, rt1 = target[a0] - cx, target[a1] - cy
    travel = math.atan2(r0 * rt1 - r1 * rt0, r0 * rt0 + r1 * rt1)
    if clockwise:
        if travel >= -ARC_ANGULAR_TRAVEL_EPSILON:
            travel -= 2 * math.pi
    elif travel <= ARC_ANGULAR_TRAVEL_EPSILON:
        travel += 2 * math.pi
    segments = int(math.floor(abs(0.5 * travel * radius) /
                              math.sqrt(tolerance_mm * (2 * radius - tolerance_mm)))) if radius > tolerance_mm / 2 else 0
    out: list[np.ndarray] = []
    pos = np.array(position, float)
    if segments:
        theta = travel / segments
        lin = (target[al] - position[al]) / segments if al < len(position) else 0.0
        cos_t = 2.0 - theta * theta
        sin_t = theta * 0.16666667 * (cos_t + 4.0)
        cos_t *= 0.5
        count = 0
        for i in range(1, segments):
            if count < n_correction:
                ri = r0 * sin_t + r1 * cos_t
                r0 = r0 * cos_t - r1 * sin_t
                r1 = ri
                count += 1
            else:
                cti, sti = math.cos(i * theta), math.sin(i * theta)
                r0 = -offset[a0] * cti + offset[a1] * sti
                r1 = -offset[a0] * sti - offset[a1] * cti
                count = 0
            pos[a0] = cx + r0
            pos[a1] = cy + r1
            if al < len(pos):
                pos[al] += lin
            out.append(pos.copy())
    out.append(np.array(target, float))
    return out

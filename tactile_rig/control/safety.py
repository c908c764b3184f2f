"""The collision-stop speed cap, derived from how fast and how late the robot can feel.

The thesis capped the arm at 0.016 m/s: its sensing ran at 16 Hz and it allowed 1 mm of travel
between two looks. Generalised, the worst case after first contact is:

    travel = detection_travel + v (1/rate + latency + stop_latency) + v² / (2 decel)

(contact just after a frame was captured: the next frame comes one period later, reaches the
controller ``latency`` after that, the stop command takes ``stop_latency`` to act, then the axis
brakes). The cap is the largest ``v`` keeping that within the allowed overtravel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from tactile_rig.core.clock import Clock
from tactile_rig.core.errors import LimitError, check_range


def collision_speed_cap_mps(allowed_overtravel_mm: float, sensing_rate_hz: float, latency_s: float = 0.0,
                            *, stop_latency_s: float = 0.0, decel_mps2: float = math.inf,
                            detection_travel_mm: float = 0.0) -> float:
    """Largest approach speed (m/s) whose worst-case travel past contact stays ≤ the allowance.

    ``detection_travel_mm`` is how far past contact the skin must be pressed before the force
    change exceeds the threshold (f_ε / contact stiffness). Returns 0 when even that uses up the
    allowance. 1 mm at 16 Hz with no latency gives the thesis's 0.016 m/s.
    """
    check_range("allowed_overtravel_mm", allowed_overtravel_mm, 0.0, 1e4, "mm")
    check_range("sensing_rate_hz", sensing_rate_hz, 1e-3, 1e6, "Hz")
    check_range("latency_s", latency_s, 0.0, 60.0, "s")
    check_range("stop_latency_s", stop_latency_s, 0.0, 60.0, "s")
    check_range("detection_travel_mm", detection_travel_mm, 0.0, 1e4, "mm")
    if not decel_mps2 > 0:
        raise ValueError(f"decel_mps2={decel_mps2!r} must be > 0 (math.inf for an instant stop)")
    budget_m = (allowed_overtravel_mm - detection_travel_mm) / 1000.0
    if budget_m <= 0:
        return 0.0
    dead_s = 1.0 / sensing_rate_hz + latency_s + stop_latency_s
    if math.isinf(decel_mps2):
        return budget_m / dead_s
    # v²/(2a) + v·dead − budget = 0, positive root, written to stay accurate for small v
    a = 1.0 / (2.0 * decel_mps2)
    return 2.0 * budget_m / (dead_s + math.sqrt(dead_s * dead_s + 4.0 * a * budget_m))


def worst_case_overtravel_mm(speed_mps: float, sensing_rate_hz: float, latency_s: float = 0.0, *,
                             stop_latency_s: float = 0.0, decel_mps2: float = math.inf,
                             detection_travel_mm: float = 0.0) -> float:
    """The travel past contact that the cap formula predicts at ``speed_mps`` (mm)."""
    dead_s = 1.0 / sensing_rate_hz + latency_s + stop_latency_s
    brake_m = 0.0 if math.isinf(decel_mps2) else speed_mps ** 2 / (2.0 * decel_mps2)
    return detection_travel_mm + 1000.0 * (speed_mps * dead_s + brake_m)


def check_speed(speed_mps: float, cap_mps: float, *, who: str = "collision_stop") -> float:
    """Return ``speed_mps`` if 0 < speed ≤ cap, else raise :class:`LimitError` saying the cap and why."""
    if not (speed_mps > 0 and math.isfinite(speed_mps)):
        raise LimitError(f"speed_mps={speed_mps!r} must be a positive finite speed", device=who)
    if speed_mps > cap_mps * (1 + 1e-9):
        raise LimitError(
            f"speed_mps={speed_mps:.4g} is above the collision-stop cap of {cap_mps:.4g} m/s "
            "(derived from the sensing rate, the latency and the allowed overtravel; sense faster "
            "or allow more overtravel to raise it)", device=who)
    return speed_mps


@dataclass
class SensingRate:
    """Measured sensing: frames per second and capture-to-delivery latency (s)."""

    rate_hz: float
    latency_s: float
    n_frames: int


def measure_sensing(sensor: Any, clock: Clock, *, n_frames: int = 8, timeout_s: float = 1.0) -> SensingRate:
    """Read ``n_frames`` frames and measure the rate (from their capture times) and the latency
    (delivery time minus capture time, on ``clock``). The sensor's results must carry ``t_s``."""
    if n_frames < 2:
        raise ValueError(f"n_frames={n_frames!r} must be ≥ 2 to measure a rate")
    stamps: list[float] = []
    lags: list[float] = []
    last = None
    while len(stamps) < n_frames:
        r = sensor.read(timeout_s)
        t = getattr(r, "t_s", None)
        if t is None:
            raise ValueError(f"{type(r).__name__} has no t_s: cannot measure the sensing rate")
        if last is not None and t <= last:
            continue  # the same frame twice: not a new look
        last = t
        stamps.append(float(t))
        lags.append(clock.now_s() - float(t))
    span = stamps[-1] - stamps[0]
    rate = (len(stamps) - 1) / span if span > 0 else math.inf
    return SensingRate(rate_hz=rate, latency_s=max(0.0, max(lags)), n_frames=len(stamps))

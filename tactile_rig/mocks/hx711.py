"""The HX711 load-cell ADC as the scale sketch sees it: when a conversion is ready, and its value.

The same model, to the count, as the simulated board's (``firmware/sim/scale_board.c``), so the
scale mock and the compiled sketch on that board print identical lines for the same load:

* Conversions every ``1/rate_sps`` s on a grid that starts when the chip leaves reset (power-up, or
  PD_SCK low again after being held high > 60 us). Its sinc4 filter needs 4 periods to settle, so
  the first data is presented 4 periods after a reset; after that every period.
* Each period's input is the bridge output at the conversion instant, in counts at gain 128:
  ``floor(offset + counts_per_g * grams + drift + 0.5)``. The output weighs the last four inputs by
  the filter's response over each period, ``(1, 11, 11, 1) / 24`` (newest first), so a load step
  shows as 1/24, 12/24, 23/24 and then all of it; then white noise, a rare glitch (a flipped bit,
  the "sign flip" users report), and the 24-bit two's complement clamp (0x800000..0x7FFFFF).
* Channel A at gain 128 only: the sketch never asks for another (the simulated board models the
  25/26/27-pulse channel and gain selection, and the timing rules, for any sketch).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

RAW_MIN = -(1 << 23)
RAW_MAX = (1 << 23) - 1
SETTLE_PERIODS = 4
_WEIGHTS = (1, 11, 11, 1)  # newest first; sum 24


class Hx711:
    """One HX711 on channel A, gain 128.

    ``input_counts(t_s)`` gives the bridge output in counts at ``t_s`` (load, offset and drift);
    ``noise_counts`` is the output noise (rms counts), ``spike_prob`` the chance a conversion is
    glitched. All times in seconds on the caller's clock.
    """

    def __init__(self, rate_sps: int, input_counts: Callable[[float], float], *, noise_counts: float = 0.0,
                 spike_prob: float = 0.0, rng: np.random.Generator | None = None) -> None:
        if rate_sps not in (10, 80):
            raise ValueError(f"HX711 rate_sps={rate_sps!r}: the RATE pin gives 10 or 80 samples/s")
        if not (noise_counts >= 0.0 and math.isfinite(noise_counts)):
            raise ValueError(f"HX711 noise_counts={noise_counts!r} must be a finite number >= 0")
        if not (0.0 <= spike_prob <= 1.0):
            raise ValueError(f"HX711 spike_prob={spike_prob!r} must be a probability in [0, 1]")
        self.rate_sps = int(rate_sps)
        self.period_s = 1.0 / self.rate_sps
        self.input_counts = input_counts
        self.noise_counts = float(noise_counts)
        self.spike_prob = float(spike_prob)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.connected = True
        self.powered = False
        self._t0_s = 0.0  # when the chip left reset
        self._k = 0  # conversions since then
        self._hist: list[int] = []

    def reset(self, t_s: float) -> None:
        """The chip leaves reset (power-up, or PD_SCK low after > 60 us high) at ``t_s``."""
        self.powered = self.connected
        self._t0_s = float(t_s)
        self._k = 0
        self._hist = []

    def disconnect(self) -> None:
        """Unplugged: no more conversions (DOUT reads high through the sketch's pull-up)."""
        self.connected = False
        self.powered = False

    def connect(self, t_s: float) -> None:
        """Plugged in again at ``t_s``: it powers up."""
        self.connected = True
        self.reset(t_s)

    def _conversion_time(self, k: int) -> float:
        # Computed from the reset time (not accumulated) so the grid matches the board's to the cycle.
        return self._t0_s + k * self.period_s

    def next_data_s(self) -> float | None:
        """When the next conversion is presented (DOUT falls), or None while unpowered."""
        if not self.powered:
            return None
        return self._conversion_time(max(self._k + 1, SETTLE_PERIODS))

    def convert_until(self, t_s: float) -> list[tuple[float, int]]:
        """Run the converter up to ``t_s``; return the conversions presented, ``(time, counts)``."""
        out: list[tuple[float, int]] = []
        while self.powered:
            tk = self._conversion_time(self._k + 1)
            if tk > t_s:
                break
            self._k += 1
            x = math.floor(self.input_counts(tk) + 0.5)
            self._hist.insert(0, x)
            del self._hist[SETTLE_PERIODS:]
            if self._k < SETTLE_PERIODS:
                continue
            v = (sum(w * h for w, h in zip(_WEIGHTS, self._hist)) + 12) // 24
            if self.noise_counts > 0.0:
                v += math.floor(self.noise_counts * float(self.rng.normal()) + 0.5)
            if self.spike_prob and self.rng.random() < self.spike_prob:
                v ^= 1 << int(self.rng.integers(17, 23))
            out.append((tk, min(max(v, RAW_MIN), RAW_MAX)))
        return out

"""A small world model of stirring (thesis 3.4.2): a spoon in the gripper stirs a cup of something.

The spoon is held between FingerVision fingertips and moved in circles at ``stir_hz``. The
substance drags on the spoon; what one fingertip's marker-force estimator reports (px) over time:

- a periodic shear ``A(η) · sin(2π f t + φ)`` whose amplitude grows with the logarithm of the
  viscosity ``η`` (mPa·s), times the trial's fill level and stirring-speed factor;
- a steady offset ``0.3 · A`` (the spoon leans against the flow);
- sloshing: a high-frequency (5–9 Hz) fluctuation strongest for thin liquids, ``slosh_px · e^{−η/50}``;
- stick-slip bursts for very viscous substances (honey), a few per second;
- sensor noise ``noise_px`` on every sample (stated; per sample std).

Per-trial variation: fill level U(0.4, 1.0), speed factor N(1, 0.15), phase U(0, 2π), and the
substance's own viscosity spread (lognormal, σ = 0.6: batches, temperature). Only what the classifier needs is modelled.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: substance → nominal viscosity in mPa·s
SUBSTANCES: dict[str, float] = {"empty": 0.0, "water": 1.0, "oil": 80.0, "honey": 5000.0}


@dataclass(frozen=True)
class StirTrial:
    """One stirring trial: label, time (s) and marker force/torque series (T × 3: fx, fy, tz)."""

    label: str
    t_s: np.ndarray
    series: np.ndarray


@dataclass(frozen=True)
class StirringScene:
    """Parameters of the stirring world (see the module doc)."""

    substances: dict[str, float] = field(default_factory=lambda: dict(SUBSTANCES))
    stir_hz: float = 1.0
    rate_hz: float = 30.0
    duration_s: float = 6.0
    amp_px: float = 0.4
    slosh_px: float = 0.25
    noise_px: float = 0.08
    viscosity_spread: float = 0.6

    def trial(self, label: str, rng: np.random.Generator) -> StirTrial:
        if label not in self.substances:
            raise ValueError(f"substance {label!r} is unknown; known: {', '.join(self.substances)}")
        eta = self.substances[label] * float(np.exp(self.viscosity_spread * rng.standard_normal()))
        fill = rng.uniform(0.4, 1.0) if self.substances[label] > 0 else 0.0
        speed = 1.0 + 0.15 * rng.standard_normal()
        phase = rng.uniform(0, 2 * np.pi)
        t = np.arange(0.0, self.duration_s, 1.0 / self.rate_hz)
        n = t.size
        amp = self.amp_px * fill * speed * np.log10(1.0 + eta)
        w = 2 * np.pi * self.stir_hz * speed
        fy = amp * np.sin(w * t + phase) + 0.3 * amp
        fx = 0.5 * amp * np.cos(w * t + phase)
        if fill > 0:
            slosh_hz = rng.uniform(5.0, 9.0)
            fy = fy + self.slosh_px * fill * np.exp(-eta / 50.0) * np.sin(2 * np.pi * slosh_hz * t
                                                                          + rng.uniform(0, 2 * np.pi))
        if eta > 1000:  # stick-slip: the spoon sticks, the skin loads, then it slips
            n_bursts = rng.poisson(2.0 * self.duration_s)
            for k in rng.integers(0, n, size=n_bursts):
                fy[k:k + 3] += rng.uniform(0.3, 0.8) * amp * np.array([1.0, -0.6, 0.2])[: n - k]
        tz = 2.0 * fy * (1 + 0.1 * rng.standard_normal())
        series = np.column_stack([fx, fy, tz]) + self.noise_px * rng.standard_normal((n, 3))
        return StirTrial(label, t, series)

    def trials(self, per_substance: int, seed: int = 0) -> list[StirTrial]:
        """``per_substance`` trials of every substance, interleaved, from one seed."""
        rng = np.random.default_rng(seed)
        return [self.trial(lbl, rng) for _ in range(per_substance) for lbl in self.substances]

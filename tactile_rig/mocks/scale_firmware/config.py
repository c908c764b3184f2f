"""The simulated board's parameters (:class:`BoardConfig`), which the Python mock takes as well."""

from __future__ import annotations

from dataclasses import dataclass

from tactile_rig.devices import scale as sp
from tactile_rig.mocks.scale.sketch import BOOTLOADER_S

__all__ = ["BOOTLOADER_S", "BoardConfig", "CPU_HZ"]

CPU_HZ = 16_000_000  # the Uno's ATmega328P clock


@dataclass(frozen=True)
class BoardConfig:
    """What is on the simulated bench: the HX711's rate and the load cell seen through it.

    ``offset_counts`` and ``counts_per_g`` describe the bridge at gain 128, ``drift_counts`` its
    warm-up (reached with time constant ``drift_tau_s``), ``noise_counts`` the HX711's output noise
    (rms counts; the mock's per-rate default when None), ``spike_prob`` the chance of a glitched
    conversion: all as the Python mock has them. ``bootloader_s`` is the Uno's silence after a
    reset, ``boot_junk`` how many glitch bytes the host reads at a reset.
    """

    rate_sps: int = 80
    force_n: float = 0.0
    counts_per_g: float = sp.DEFAULT_CAL_FACTOR
    offset_counts: float = 84_000.0
    noise_counts: float | None = None
    drift_counts: float = 1_500.0
    drift_tau_s: float = 180.0
    spike_prob: float = 0.002
    channel_b_counts: float = 0.0
    bootloader_s: float = BOOTLOADER_S
    boot_junk: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        if self.rate_sps not in sp.RATES_SPS:
            raise ValueError(f"scale firmware rate_sps={self.rate_sps!r}: an HX711 runs at 10 or 80")
        if not (0.0 <= self.bootloader_s <= 10.0):
            raise ValueError(f"scale firmware bootloader_s={self.bootloader_s!r} must be within [0, 10] s")
        if not (0 <= self.boot_junk <= 16):
            raise ValueError(f"scale firmware boot_junk={self.boot_junk!r} must be 0..16 bytes")
        if not (0.0 <= self.spike_prob <= 1.0):
            raise ValueError(f"scale firmware spike_prob={self.spike_prob!r} must be a probability in [0, 1]")
        if not (0.0 < self.drift_tau_s < 1e9):
            raise ValueError(f"scale firmware drift_tau_s={self.drift_tau_s!r} must be a positive number of seconds")
        for name in ("force_n", "counts_per_g", "offset_counts", "channel_b_counts", "drift_counts"):
            v = getattr(self, name)
            if not (abs(v) < 1e12):  # rejects NaN and inf too
                raise ValueError(f"scale firmware {name}={v!r} must be a finite number")
        if self.noise_counts is not None and not (0.0 <= self.noise_counts < 1e7):
            raise ValueError(f"scale firmware noise_counts={self.noise_counts!r} must be >= 0 counts")

    @property
    def noise(self) -> float:
        # The mock's default: HX711 input noise roughly doubles from 10 to 80 SPS.
        if self.noise_counts is not None:
            return float(self.noise_counts)
        return 20.0 if self.rate_sps == 10 else 40.0

    def args(self) -> list[str]:
        return ["--rate", str(self.rate_sps), "--force-n", repr(float(self.force_n)),
                "--counts-per-g", repr(float(self.counts_per_g)), "--offset-counts", repr(float(self.offset_counts)),
                "--noise-counts", repr(self.noise), "--channel-b-counts", repr(float(self.channel_b_counts)),
                "--drift-counts", repr(float(self.drift_counts)), "--drift-tau-s", repr(float(self.drift_tau_s)),
                "--spike-prob", repr(float(self.spike_prob)),
                "--bootloader-ms", repr(self.bootloader_s * 1000.0), "--boot-junk", str(self.boot_junk),
                "--seed", str(int(self.seed) & 0xFFFFFFFFFFFFFFFF)]

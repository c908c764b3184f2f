"""Sensor read noise for rendered frames, cheap enough to add to every frame."""

from __future__ import annotations

import numpy as np

__all__ = ["SensorNoise"]


class SensorNoise:
    """Gaussian read noise of ``sigma`` grey levels, drawn once and served as random crops.

    Drawing fresh noise for every frame costs more than the rest of the rendering; a random
    window into one larger noise field is statistically the same for a perception test (no two
    consecutive frames share their noise) at the cost of a view.
    """

    MARGIN_PX = 32

    def __init__(self, shape: tuple[int, ...], sigma: float | np.ndarray, rng: np.random.Generator, *,
                 mono: bool = False) -> None:
        """``sigma``: a scalar or one per channel; ``mono``: the same noise in every channel (luminance
        noise, as MJPG's subsampled chroma leaves it)."""
        self.shape = tuple(int(v) for v in shape)
        self._rng = rng
        big = (self.shape[0] + self.MARGIN_PX, self.shape[1] + self.MARGIN_PX, *self.shape[2:])
        if mono and len(big) == 3:
            one = rng.standard_normal(big[:2], dtype=np.float32)
            self._field = np.repeat(one[..., None], big[2], axis=2) * np.asarray(sigma, dtype=np.float32)
        else:
            self._field = rng.standard_normal(big, dtype=np.float32) * np.asarray(sigma, dtype=np.float32)

    def reseed(self, rng: np.random.Generator) -> None:
        """Draw the crops from ``rng`` from now on (the field itself stays: it depends on the seed only)."""
        self._rng = rng

    def sample(self) -> np.ndarray:
        """A (read-only) noise frame of ``shape``: rows are contiguous, so OpenCV takes it without a copy."""
        dy, dx = (int(v) for v in self._rng.integers(0, self.MARGIN_PX + 1, size=2))
        return self._field[dy:dy + self.shape[0], dx:dx + self.shape[1]]

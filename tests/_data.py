"""Where the tests find real sensor data.

MIT-licensed fixtures are copied under ``tests/data``; GPL ones stay in ``../shared/data/real`` and
the tests that use them skip cleanly when that folder is absent.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tactile_rig.perception.gelsight import calibrate_from_presses, load_presses

TESTS_DATA = Path(__file__).resolve().parent / "data"


def _find_shared_real() -> Path | None:
    env = os.environ.get("TACTILE_RIG_SHARED_DATA")
    candidates = [Path(env)] if env else []
    here = Path(__file__).resolve()
    for parent in here.parents:
        candidates.append(parent / "shared" / "data" / "real")
        candidates.append(parent.parent / "shared" / "data" / "real")
    for c in candidates:
        if c.is_dir():
            return c
    return None


SHARED_REAL: Path | None = _find_shared_real()


def require_shared(name: str) -> Path:
    """Return ``../shared/data/real/<name>`` or skip the calling test when it is absent."""
    if SHARED_REAL is None or not (SHARED_REAL / name).is_dir():
        pytest.skip(f"shared data folder {name!r} is not present (../shared/data/real)")
    return SHARED_REAL / name


def test_data(name: str) -> Path:
    """Return ``tests/data/<name>`` (an MIT fixture shipped with the tests)."""
    path = TESTS_DATA / name
    if not path.is_dir():
        raise FileNotFoundError(f"test fixture folder {path} is missing")
    return path


test_data.__test__ = False  # type: ignore[attr-defined]  # not a pytest test


TAXIM_MM_PER_PX = 0.1245  # the Taxim ball presses' pixel pitch
TAXIM_BALL_RADIUS_MM = 2.0


@functools.lru_cache(maxsize=None)
def taxim_presses() -> Any:
    """The 30 real Taxim GelSight ball presses (MIT), loaded once per test session: treat as read-only."""
    return load_presses(test_data("taxim_gelsight_ball") / "presses")


@functools.lru_cache(maxsize=None)
def taxim_calibration(method: str = "lut", bins: int = 32) -> Any:
    """A calibration fitted on all the Taxim presses (``bins`` for the LUT method), fitted once per
    test session (an MLP fit costs seconds): treat as read-only."""
    hyper = {"bins": bins} if method == "lut" else {}
    return calibrate_from_presses(taxim_presses(), TAXIM_MM_PER_PX, TAXIM_BALL_RADIUS_MM, method, **hyper)


EXTREME_KINDS = ("patch", "noise", "constant", "gain", "clip")


def extreme_frame(base: Any, kind: str, value: int, rng: Any) -> Any:
    """A BGR uint8 frame of ``base``'s size pushed to an extreme: a random block of one colour
    (patch), sensor noise of sigma ``value``/4 (noise), one grey level everywhere (constant), an
    exposure gain of ``value``/128 (gain), or up to a third of the pixels' one channel set to
    ``value`` (clip: below or above the refusal fractions)."""
    h, w = base.shape[:2]
    if kind == "patch":
        frame = base.copy()
        bh, bw = int(rng.integers(1, h)), int(rng.integers(1, w))
        y, x = int(rng.integers(0, h - bh + 1)), int(rng.integers(0, w - bw + 1))
        frame[y:y + bh, x:x + bw] = rng.integers(0, 256, 3)
        return frame
    if kind == "noise":
        return np.clip(base.astype(int) + rng.normal(0, value / 4 + 0.1, base.shape), 0, 255).astype(np.uint8)
    if kind == "constant":
        return np.full_like(base, value)
    if kind == "gain":
        return np.clip(base.astype(np.float32) * (value / 128.0), 0, 255).astype(np.uint8)
    if kind == "clip":
        frame = base.copy()
        n = int(rng.integers(1, h * w // 3))
        ys, xs = rng.integers(0, h, n), rng.integers(0, w, n)
        frame[ys, xs, int(rng.integers(0, 3))] = value
        return frame
    raise ValueError(f"kind must be one of {EXTREME_KINDS}, got {kind!r}")

"""Synthetic test inputs built from real reconstructions: textured mosaics and jig-style moves.

Used by the tests and benchmarks to apply the Li 2014 jig protocol (rotations and shifts) to real
height maps without a jig.
"""

from __future__ import annotations

import cv2
import numpy as np


def mosaic(patches: list[np.ndarray], shape: tuple[int, int], count: int, seed: int = 0,
           scale_range: tuple[float, float] = (0.6, 1.4)) -> np.ndarray:
    """A textured height map (mm, float32): ``count`` patches (random choice, random rotation and
    height scale) added at random places into a zero canvas of ``shape``."""
    if not patches:
        raise ValueError("patches must not be empty")
    rng = np.random.default_rng(seed)
    canvas = np.zeros(shape, np.float32)
    h, w = shape
    for _ in range(count):
        p = patches[int(rng.integers(len(patches)))].astype(np.float32)
        ph, pw = p.shape
        rot = cv2.getRotationMatrix2D(((pw - 1) / 2.0, (ph - 1) / 2.0), float(rng.uniform(0, 360)), 1.0)
        p = cv2.warpAffine(p, rot, (pw, ph), flags=cv2.INTER_LINEAR) * float(rng.uniform(*scale_range))
        y = int(rng.integers(-ph // 3, h - 2 * ph // 3))
        x = int(rng.integers(-pw // 3, w - 2 * pw // 3))
        y0, x0 = max(y, 0), max(x, 0)
        y1, x1 = min(y + ph, h), min(x + pw, w)
        canvas[y0:y1, x0:x1] = np.maximum(canvas[y0:y1, x0:x1], p[y0 - y:y1 - y, x0 - x:x1 - x])
    return canvas


def jig_move(height_mm: np.ndarray, rotation_deg: float, shift_mm: tuple[float, float],
             mm_per_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Touch B of the same surface after a jig move: the map rotated by ``rotation_deg`` about its
    centre and shifted by ``shift_mm`` (x right, y down), resampled into a frame of the same size.

    Returns (B, truth) where truth is the 2x3 matrix in mm (from each map's centre) mapping a point
    of B into A's frame: the answer :func:`register(A, B)` must give.
    """
    h, w = height_mm.shape
    c = ((w - 1) / 2.0, (h - 1) / 2.0)
    fwd = cv2.getRotationMatrix2D(c, -rotation_deg, 1.0)  # A px -> B px (OpenCV angle is clockwise-positive in y-down)
    fwd[:, 2] += np.array(shift_mm) / mm_per_px
    b = cv2.warpAffine(height_mm.astype(np.float32), fwd, (w, h), flags=cv2.INTER_LINEAR, borderValue=0.0)
    inv = cv2.invertAffineTransform(fwd)
    r = inv[:, :2]
    cvec = np.array(c)
    t_mm = (r @ cvec + inv[:, 2] - cvec) * mm_per_px
    return b, np.hstack([r, t_mm[:, None]])


def tile(heights: list[np.ndarray], grid: tuple[int, int] = (2, 2)) -> np.ndarray:
    """A larger textured height map (mm, float32): ``grid`` rows x cols of same-size height maps
    (e.g. reconstructed real presses: their domes plus the gel's real fine texture)."""
    rows, cols = grid
    if len(heights) < rows * cols:
        raise ValueError(f"need {rows * cols} height maps for a {rows}x{cols} tile, got {len(heights)}")
    shape = heights[0].shape
    if any(h.shape != shape for h in heights[: rows * cols]):
        raise ValueError(
            f"all tiled height maps must have the shape of the first, {shape}; got "
            f"{sorted({h.shape for h in heights[: rows * cols]})}"
        )
    return np.block([[heights[r * cols + c] for c in range(cols)] for r in range(rows)]).astype(np.float32)


def touch_at(surface_mm: np.ndarray, rotation_deg: float, center_px: tuple[float, float],
             shape: tuple[int, int]) -> np.ndarray:
    """A touch of ``shape`` cut from a larger surface: centred on ``center_px`` (x, y) of the
    surface and rotated by ``rotation_deg`` (OpenCV sense) about it."""
    h, w = shape
    m = cv2.getRotationMatrix2D((float(center_px[0]), float(center_px[1])), rotation_deg, 1.0)
    m[:, 2] += ((w - 1) / 2.0 - center_px[0], (h - 1) / 2.0 - center_px[1])
    return cv2.warpAffine(surface_mm.astype(np.float32), m, (w, h), flags=cv2.INTER_LINEAR)

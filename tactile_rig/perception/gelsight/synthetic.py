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


def crop_contact(height_mm: np.ndarray, center_px: tuple[float, float], half_px: int) -> np.ndarray:
    """Square patch of side 2*half_px+1 around a contact centre (zero-padded at the edges)."""
    pad = np.pad(height_mm.astype(np.float32), half_px + 1)
    cx, cy = int(round(center_px[0])) + half_px + 1, int(round(center_px[1])) + half_px + 1
    return pad[cy - half_px:cy + half_px + 1, cx - half_px:cx + half_px + 1].copy()


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

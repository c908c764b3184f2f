"""Where a ball press touches a GelSight frame: the contact's centroid, unbiased by the lighting.

A calibration session labels each ball press with its contact centre; these functions find it from the
frame and the no-contact background alone (pure image maths, pixels in and out).
"""

from __future__ import annotations

import math
from typing import Sequence

import cv2
import numpy as np

__all__ = ["contact_centroid_px", "even_colour_direction"]


def contact_centroid_px(frame_bgr: np.ndarray, background_bgr: np.ndarray, min_diff: float = 12.0,
                        direction_bgr: np.ndarray | None = None) -> tuple[float, float] | None:
    """Centre (x, y) px of the largest region that differs from the background, or None.

    Weighted by the colour difference: ``sum |Δ|`` over the channels, or ``|Δ · direction_bgr|``
    when a colour direction is given (see :func:`even_colour_direction`: with it the weights are
    symmetric about a ball's centre, so the centroid is the contact centre).
    """
    diff = frame_bgr.astype(np.float32) - background_bgr.astype(np.float32)
    d = cv2.GaussianBlur(np.abs(diff).sum(axis=2), (0, 0), 2.0)
    mask = (d > min_diff).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[k, cv2.CC_STAT_AREA] < 20:
        return None
    region = labels == k
    if direction_bgr is not None:
        # The region is found on all the colour change; the weights use only its even part.
        d = cv2.GaussianBlur(np.abs(diff @ np.asarray(direction_bgr, np.float32).reshape(3)), (0, 0), 2.0)
        region = cv2.dilate(region.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    w = np.where(region, d, 0.0)
    total = float(w.sum())
    if not total > 0:
        return None
    ys, xs = np.mgrid[0:d.shape[0], 0:d.shape[1]]
    return float((w * xs).sum() / total), float((w * ys).sum() / total)


def even_colour_direction(frames: Sequence[np.ndarray], background_bgr: np.ndarray,
                          centres_px: Sequence[Sequence[float]], radius_px: float) -> np.ndarray:
    """The colour direction (unit BGR vector) blind to the surface slopes' odd part.

    Under the LEDs a press changes the colour by ``gx·a + gy·b + (n_z − 1)·c``; ``gx, gy`` are odd
    about the contact centre and ``n_z − 1`` even. ``a`` and ``b`` are estimated as the colour
    changes' first moments along x and y around approximate centres; the direction ``a × b`` keeps
    only the even part, so a centroid weighted by it is not pulled toward the brighter LED.
    """
    bg = background_bgr.astype(np.float32)
    u = np.zeros(3)
    v = np.zeros(3)
    h, w = bg.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    for f, c in zip(frames, centres_px):
        dx, dy = xs - float(c[0]), ys - float(c[1])
        m = dx * dx + dy * dy < (1.5 * radius_px) ** 2
        d = (f.astype(np.float32) - bg)[m]
        u += (d * dx[m][:, None]).sum(axis=0)
        v += (d * dy[m][:, None]).sum(axis=0)
    n = np.cross(u, v)
    norm = float(np.linalg.norm(n))
    if not np.isfinite(norm) or norm == 0:
        return np.ones(3) / math.sqrt(3.0)
    return n / norm

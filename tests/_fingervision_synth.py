"""A small synthetic FingerVision frame maker with exact ground truth.

Dark anti-aliased discs at known sub-pixel positions on a light textured background, an optional
textured elliptical object of known centre and orientation behind them, dark "print" (QR-like
squares, a large dark patch), light gain (flicker) and sensor noise. Used by the FingerVision tests
and by ``benchmarks/bench_fingervision.py``; independent of the mocks' renderer on purpose.
"""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np

W, H = 320, 240
BG_BGR = np.array([200.0, 215.0, 205.0])
MARKER_BGR = np.array([22.0, 24.0, 20.0])
OBJECT_BGR = np.array([60.0, 130.0, 225.0])  # orange
PRINT_BGR = np.array([70.0, 90.0, 60.0])  # dark green print, like the real QR code


def lattice(nx: int = 6, ny: int = 5, x0: float = 35.0, y0: float = 30.0, dx: float = 50.0, dy: float = 45.0,
            jitter_seed: int | None = 0) -> np.ndarray:
    """Marker rest positions (N, 2) px, with a sub-pixel jitter so no centre sits on the pixel grid."""
    xs, ys = np.meshgrid(x0 + dx * np.arange(nx), y0 + dy * np.arange(ny))
    pts = np.column_stack([xs.ravel(), ys.ravel()]).astype(float)
    if jitter_seed is not None:
        pts += np.random.default_rng(jitter_seed).uniform(-0.5, 0.5, pts.shape)
    return pts


@dataclass(frozen=True)
class Ellipse:
    """Object behind the skin: centre px, semi-axes px, orientation deg (from +x towards +y)."""

    cx: float
    cy: float
    a: float
    b: float
    angle_deg: float


def _texture(seed: int, w: int, h: int, amp: float) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    coarse = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 6)
    fine = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 1.0)
    t = coarse / (coarse.std() + 1e-9) * amp + fine / (fine.std() + 1e-9) * amp * 0.3
    return t


_TEX_CACHE: dict[tuple[int, int, int], np.ndarray] = {}


def render(
    markers_px: np.ndarray | None = None,
    marker_r_px: float | np.ndarray = 4.0,
    obj: Ellipse | None = None,
    obj_texture_offset_px: tuple[float, float] = (0.0, 0.0),
    gain: float = 1.0,
    noise: float = 2.0,
    seed: int = 0,
    dark_print: bool = False,
    size_wh: tuple[int, int] = (W, H),
) -> np.ndarray:
    """One BGR uint8 frame. ``obj_texture_offset_px`` moves the object's texture with the object."""
    w, h = size_wh
    key = (seed, w, h)
    if key not in _TEX_CACHE:
        _TEX_CACHE[key] = _texture(seed + 1000, w, h, 8.0)
    img = np.empty((h, w, 3), np.float32)
    img[:] = BG_BGR
    img += _TEX_CACHE[key][:, :, None]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    if dark_print:
        # QR-like modules of 5 px and a large dark patch, at fixed places
        rng = np.random.default_rng(7)
        for i in range(12):
            for j in range(12):
                if rng.random() < 0.5:
                    x, y = 150 + 5 * i, 60 + 5 * j
                    img[y:y + 5, x:x + 5] = PRINT_BGR
        img[150:215, 20:110] = PRINT_BGR * 0.85
    if obj is not None:
        th = np.deg2rad(obj.angle_deg)
        u = (xx - obj.cx) * np.cos(th) + (yy - obj.cy) * np.sin(th)
        v = -(xx - obj.cx) * np.sin(th) + (yy - obj.cy) * np.cos(th)
        q = np.sqrt((u / obj.a) ** 2 + (v / obj.b) ** 2)
        cover = np.clip((1.0 - q) * min(obj.a, obj.b) + 0.5, 0.0, 1.0)
        ox, oy = obj_texture_offset_px
        tex = 1.0 + 0.18 * np.sin((xx - ox) * 0.35) * np.cos((yy - oy) * 0.27) + 0.1 * np.sin((xx - ox + yy - oy) * 0.15)
        colour = OBJECT_BGR[None, None, :] * tex[:, :, None]
        img = img * (1 - cover[:, :, None]) + colour * cover[:, :, None]
    if markers_px is not None and len(markers_px):
        radii = np.broadcast_to(np.asarray(marker_r_px, dtype=float), (len(markers_px),))
        for (mx, my), r in zip(np.asarray(markers_px, float), radii):
            x0, x1 = int(max(0, np.floor(mx - r - 2))), int(min(w, np.ceil(mx + r + 3)))
            y0, y1 = int(max(0, np.floor(my - r - 2))), int(min(h, np.ceil(my + r + 3)))
            if x0 >= x1 or y0 >= y1:
                continue
            d = np.hypot(xx[y0:y1, x0:x1] - mx, yy[y0:y1, x0:x1] - my)
            c = np.clip(r + 0.5 - d, 0.0, 1.0)[:, :, None]
            img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - c) + MARKER_BGR * c
    img *= gain
    if noise > 0:
        img += np.random.default_rng(seed * 7919 + 13).normal(0, noise, img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def angle_err(a: float, b: float) -> float:
    """Orientation difference modulo 180 degrees."""
    return abs((a - b + 90.0) % 180.0 - 90.0)


def ellipse_mask(e: Ellipse, shape=(240, 320)) -> np.ndarray:
    m = np.zeros(shape, np.uint8)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    th = math.radians(e.angle_deg)
    u = (xx - e.cx) * math.cos(th) + (yy - e.cy) * math.sin(th)
    v = -(xx - e.cx) * math.sin(th) + (yy - e.cy) * math.cos(th)
    m[(u / e.a) ** 2 + (v / e.b) ** 2 <= 1.0] = 255
    return m

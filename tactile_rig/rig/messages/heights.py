"""GelSight height maps as a ``foxglove.PointCloud`` in the sensor frame (mm): the tactile point cloud.

Each point is one pixel of the map (every ``stride``-th row and column, so a map has at most
``max_points``): x, y about the image centre at the calibration's mm/px, z = -height (the skin pressed
in towards the camera, whose optical axis is +z), and the height itself (mm) as a field to colour by.
"""

from __future__ import annotations

import math

import numpy as np

from tactile_rig.rig.messages.base import SchemaDef, foxglove_messages, foxglove_schema, timestamp
from tactile_rig.rig.messages.geometry import pose

__all__ = ["height_point_cloud", "height_stride", "POINT_FIELDS", "MAX_POINTS"]

MAX_POINTS = 20_000
POINT_FIELDS = ("x", "y", "z", "height_mm")  # float32 each, 16 bytes a point


def height_stride(shape: tuple[int, int], max_points: int = MAX_POINTS) -> int:
    """The smallest row/column step that keeps a ``shape`` map to at most ``max_points`` points."""
    if max_points < 1:
        raise ValueError(f"max_points={max_points!r} must be >= 1")
    h, w = shape
    step = max(1, math.ceil(math.sqrt(h * w / max_points)))
    while math.ceil(h / step) * math.ceil(w / step) > max_points:  # a thin map rounds up its short side
        step += 1
    return step


def height_point_cloud(camera: str, height_mm: np.ndarray, mm_per_px_x: float, mm_per_px_y: float,
                       log_time_ns: int, *, max_points: int = MAX_POINTS) -> tuple[SchemaDef, bytes]:
    """A height map (H x W, mm) as a PointCloud in frame ``camera``; NaN pixels are left out."""
    h = np.asarray(height_mm)
    if h.ndim != 2 or h.size == 0:
        raise ValueError(f"height map of camera {camera!r} must be a non-empty H x W array, got shape {h.shape}")
    if not (mm_per_px_x > 0 and mm_per_px_y > 0):
        raise ValueError(f"mm_per_px ({mm_per_px_x!r}, {mm_per_px_y!r}) must be > 0 mm/px")
    fm = foxglove_messages()
    step = height_stride(h.shape, max_points)
    sub = h[::step, ::step].astype(np.float32)
    rows, cols = np.mgrid[0: h.shape[0]: step, 0: h.shape[1]: step]
    pts = np.empty(sub.shape + (4,), np.float32)
    pts[..., 0] = (cols - (h.shape[1] - 1) / 2.0) * mm_per_px_x
    pts[..., 1] = (rows - (h.shape[0] - 1) / 2.0) * mm_per_px_y
    pts[..., 2] = -sub
    pts[..., 3] = sub
    flat = pts.reshape(-1, 4)
    flat = flat[np.isfinite(flat).all(axis=1)]
    f32 = fm.PackedElementFieldNumericType.Float32
    fields = [fm.PackedElementField(name=n, offset=4 * i, type=f32) for i, n in enumerate(POINT_FIELDS)]
    msg = fm.PointCloud(timestamp=timestamp(log_time_ns), frame_id=camera, pose=pose(), point_stride=16,
                        fields=fields, data=np.ascontiguousarray(flat, "<f4").tobytes())
    return foxglove_schema("PointCloud"), msg.encode()

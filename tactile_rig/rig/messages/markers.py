"""FingerVision's marker field: ``foxglove.ImageAnnotations`` over the camera image (each marker, its
id, its displacement) and a ``foxglove.SceneUpdate`` of arrows in the sensor frame (mm), one per
marker (its displacement) plus the net force.

Displacements of a tenth of a millimetre would be invisible at true length: arrows and image lines
are drawn ``displacement_gain`` times longer (default 10; the gain is in each entity's metadata),
and the net force arrow is ``force_mm_per_n`` mm long per newton (default 5).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from tactile_rig.rig.messages.base import SchemaDef, foxglove_messages, foxglove_schema, timestamp
from tactile_rig.rig.messages.geometry import pixels_to_sensor_mm, pose

__all__ = ["marker_annotations", "marker_arrows", "DISPLACEMENT_GAIN", "FORCE_MM_PER_N"]

DISPLACEMENT_GAIN = 10.0
FORCE_MM_PER_N = 5.0
_GREEN = (0.2, 0.9, 0.3, 1.0)
_RED = (1.0, 0.25, 0.2, 1.0)
_ORANGE = (1.0, 0.6, 0.1, 1.0)
_BLUE = (0.2, 0.5, 1.0, 1.0)


def _color(c: tuple[float, float, float, float]) -> Any:
    return foxglove_messages().Color(r=c[0], g=c[1], b=c[2], a=c[3])


def _as_points(points_px: Any) -> np.ndarray:
    pts = np.asarray(points_px if points_px is not None else [], float).reshape(-1, 2)
    return pts


def marker_annotations(camera: str, markers_px: Any, log_time_ns: int, *, displacements_px: Any = None,
                       valid: Sequence[bool] | None = None, ids: bool = True,
                       displacement_gain: float = DISPLACEMENT_GAIN) -> tuple[SchemaDef, bytes]:
    """The markers over the image: points (green tracked, red lost), their displacement as lines
    (``displacement_gain`` times longer) and, with ``ids``, each marker's index."""
    fm = foxglove_messages()
    pts = _as_points(markers_px)
    ok = np.ones(len(pts), bool) if valid is None else np.asarray(valid, bool).reshape(-1)[: len(pts)]
    if len(ok) < len(pts):
        ok = np.concatenate([ok, np.zeros(len(pts) - len(ok), bool)])
    finite = np.isfinite(pts).all(axis=1)
    stamp = timestamp(log_time_ns)
    points = []
    for mask, color in ((ok & finite, _GREEN), (~ok & finite, _RED)):
        if mask.any():
            points.append(fm.PointsAnnotation(
                timestamp=stamp, type=fm.PointsAnnotationType.Points, thickness=6.0,
                points=[fm.Point2(x=float(x), y=float(y)) for x, y in pts[mask]],
                outline_color=_color(color), fill_color=_color(color)))
    if displacements_px is not None:
        d = _as_points(displacements_px)[: len(pts)]
        seg = []
        for (x, y), (dx, dy), good in zip(pts, d, ok):
            if good and math.isfinite(dx) and math.isfinite(dy) and math.isfinite(x) and math.isfinite(y):
                base = (x - dx, y - dy)  # where the marker rests
                seg += [fm.Point2(x=float(base[0]), y=float(base[1])),
                        fm.Point2(x=float(base[0] + displacement_gain * dx), y=float(base[1] + displacement_gain * dy))]
        if seg:
            points.append(fm.PointsAnnotation(
                timestamp=stamp, type=fm.PointsAnnotationType.LineList, thickness=2.0, points=seg,
                outline_color=_color(_ORANGE),
                metadata=[fm.KeyValuePair(key="displacement_gain", value=f"{displacement_gain:g}")]))
    texts = []
    if ids:
        for i, (x, y) in enumerate(pts):
            if finite[i]:
                texts.append(fm.TextAnnotation(timestamp=stamp, position=fm.Point2(x=float(x) + 4.0, y=float(y) - 4.0),
                                               text=str(i), font_size=10.0, text_color=_color(_GREEN),
                                               background_color=fm.Color(r=0.0, g=0.0, b=0.0, a=0.0)))
    msg = fm.ImageAnnotations(timestamp=stamp, points=points, texts=texts)
    return foxglove_schema("ImageAnnotations"), msg.encode()


def marker_arrows(camera: str, markers_px: Any, displacements_px: Any, image_size_px: tuple[int, int],
                  mm_per_px: float, log_time_ns: int, *, valid: Sequence[bool] | None = None,
                  force_n: Sequence[float] | None = None, displacement_gain: float = DISPLACEMENT_GAIN,
                  force_mm_per_n: float = FORCE_MM_PER_N) -> tuple[SchemaDef, bytes]:
    """Arrows in the sensor frame ``camera`` (mm): each tracked marker's displacement from where it
    rests (x ``displacement_gain``), and, with ``force_n`` (x, y, z in N), the net force on the
    sensor from its origin (``force_mm_per_n`` mm per N)."""
    if not mm_per_px > 0:
        raise ValueError(f"mm_per_px={mm_per_px!r} must be > 0 mm/px")
    fm = foxglove_messages()
    pts = _as_points(markers_px)
    d = _as_points(displacements_px)[: len(pts)] if displacements_px is not None else np.zeros_like(pts)
    ok = np.ones(len(pts), bool) if valid is None else np.asarray(valid, bool).reshape(-1)[: len(pts)]
    xy = pixels_to_sensor_mm(pts, image_size_px, mm_per_px) if len(pts) else pts
    dmm = d * float(mm_per_px)
    stamp = timestamp(log_time_ns)
    arrows = []
    for k in range(min(len(pts), len(d), len(ok))):
        dx, dy = dmm[k]
        length = math.hypot(dx, dy) * displacement_gain
        if not ok[k] or not np.isfinite(xy[k]).all() or not math.isfinite(length) or length <= 1e-6:
            continue
        x0, y0 = xy[k] - dmm[k]  # the arrow starts where the marker rests
        arrows.append(_arrow(x0, y0, 0.0, dx, dy, 0.0, length, _ORANGE))
    entities = [fm.SceneEntity(timestamp=stamp, frame_id=camera, id=f"{camera}/markers", frame_locked=True,
                               arrows=arrows,
                               metadata=[fm.KeyValuePair(key="displacement_gain", value=f"{displacement_gain:g}"),
                                         fm.KeyValuePair(key="unit", value="mm")])]
    if force_n is not None:
        f = np.asarray(force_n, float).reshape(-1)[:3]
        mag = float(np.linalg.norm(f))
        if len(f) == 3 and math.isfinite(mag) and mag > 1e-9:
            entities.append(fm.SceneEntity(
                timestamp=stamp, frame_id=camera, id=f"{camera}/force", frame_locked=True,
                arrows=[_arrow(0.0, 0.0, 0.0, f[0], f[1], f[2], mag * force_mm_per_n, _BLUE)],
                metadata=[fm.KeyValuePair(key="force_n", value=f"{f[0]:.5g} {f[1]:.5g} {f[2]:.5g}"),
                          fm.KeyValuePair(key="force_mm_per_n", value=f"{force_mm_per_n:g}")]))
    return foxglove_schema("SceneUpdate"), fm.SceneUpdate(entities=entities).encode()


def _arrow(x: float, y: float, z: float, dx: float, dy: float, dz: float, length_mm: float,
           color: tuple[float, float, float, float]) -> Any:
    """An arrow from (x, y, z) along (dx, dy, dz), ``length_mm`` long (Foxglove's arrows point along
    their pose's +x: the orientation turns +x onto the direction)."""
    fm = foxglove_messages()
    q = _quaternion_from_x(np.array([dx, dy, dz], float))
    head = min(0.35 * length_mm, 1.0)
    width = max(0.05, min(0.2, 0.15 * length_mm))
    return fm.ArrowPrimitive(pose=pose(x, y, z, q), shaft_length=max(length_mm - head, 0.0),
                             shaft_diameter=width, head_length=head, head_diameter=2.5 * width,
                             color=_color(color))


def _quaternion_from_x(v: np.ndarray) -> tuple[float, float, float, float]:
    """The shortest rotation taking +x onto ``v`` (x, y, z, w): half a turn about the half-way
    vector between the two (stable even for ``v`` close to -x, where 1 + cos loses its digits)."""
    u = v / float(np.linalg.norm(v))
    half = np.array([1.0 + u[0], u[1], u[2]])
    n = float(np.linalg.norm(half))
    if n < 1e-12:
        return (0.0, 0.0, 1.0, 0.0)  # exactly opposite: half a turn about z
    h = half / n
    return (0.0, float(-h[2]), float(h[1]), float(h[0]))  # (x × h, x · h)

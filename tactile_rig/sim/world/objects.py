"""Objects the fingertips touch: height fields in millimetres, primitives, textured parts, pose.

An object is a :class:`HeightField`: the height of its top surface (mm, ≥ 0) on a regular grid of
``mm_per_px``, in the object's own frame (origin at the grid centre, x along columns, y along rows).
:func:`view_in_sensor` samples it on a sensor's pixel grid for a stage pose ``(x_mm, y_mm,
theta_deg)``; :func:`pressed_indentation_mm` turns that into what the gel feels at a press depth.

Pose convention (shared with the stage model and the jig sessions): a sensor point ``p_s`` (mm, x to
the right along image columns, y down along image rows, origin at the image centre) sees the object
point ``p_o = R(-theta) (p_s - (x_mm, y_mm))``, with ``R(a) = [[cos a, -sin a], [sin a, cos a]]``
in those image axes. So ``x_mm > 0`` moves the object to the right in the image, ``y_mm > 0`` down,
and ``theta_deg > 0`` turns it clockwise as seen on screen (image y points down).

The functions here are pure; the world model kinds ``height_field_object`` and ``primitive_object``
wrap them for scenes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import cv2
import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.sim.base import register_model

__all__ = [
    "HeightField",
    "ball",
    "cylinder",
    "box",
    "cone",
    "plate_with_features",
    "usb_connector_part",
    "sensor_to_object_px",
    "view_in_sensor",
    "pressed_indentation_mm",
    "make_primitive",
    "ObjectModel",
]


@dataclass(frozen=True)
class HeightField:
    """An object's top surface: ``height_mm[row, col] ≥ 0`` on a grid of ``mm_per_px``.

    The grid centre is the object's origin. ``colour_bgr`` is how the object looks through a clear
    skin (FingerVision); GelSight sees only the shape.
    """

    height_mm: np.ndarray
    mm_per_px: float
    name: str = "object"
    colour_bgr: tuple[int, int, int] = (60, 60, 200)

    def __post_init__(self) -> None:
        h = np.asarray(self.height_mm, dtype=np.float32)
        if h.ndim != 2 or h.shape[0] < 2 or h.shape[1] < 2:
            raise ValueError(f"{self.name}: height_mm must be a 2-D array of at least 2x2, got shape {h.shape}")
        if not np.all(np.isfinite(h)):
            raise ValueError(f"{self.name}: height_mm contains NaN or inf")
        check_range(f"{self.name}.mm_per_px", float(self.mm_per_px), 1e-4, 10.0, "mm/px")
        object.__setattr__(self, "height_mm", np.maximum(h, 0.0))

    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) of the grid in mm."""
        rows, cols = self.height_mm.shape
        return cols * self.mm_per_px, rows * self.mm_per_px

    @property
    def max_height_mm(self) -> float:
        return float(self.height_mm.max())


def _grid_mm(width_mm: float, length_mm: float, mm_per_px: float) -> tuple[np.ndarray, np.ndarray]:
    cols = max(2, int(math.ceil(width_mm / mm_per_px)))
    rows = max(2, int(math.ceil(length_mm / mm_per_px)))
    x = (np.arange(cols, dtype=np.float32) - (cols - 1) / 2.0) * mm_per_px
    y = (np.arange(rows, dtype=np.float32) - (rows - 1) / 2.0) * mm_per_px
    return np.meshgrid(x, y)


def ball(radius_mm: float = 2.0, mm_per_px: float = 0.05, *, name: str = "ball") -> HeightField:
    """The upper half of a sphere of ``radius_mm``: ``h = sqrt(R² - r²)``."""
    check_range("radius_mm", radius_mm, 0.05, 200.0, "mm")
    xx, yy = _grid_mm(2 * radius_mm + 2 * mm_per_px, 2 * radius_mm + 2 * mm_per_px, mm_per_px)
    h = np.sqrt(np.maximum(radius_mm**2 - xx**2 - yy**2, 0.0))
    return HeightField(h, mm_per_px, name=name)


def cylinder(radius_mm: float = 3.0, height_mm: float = 2.0, mm_per_px: float = 0.05, *,
             name: str = "cylinder") -> HeightField:
    """A flat-topped cylinder standing on its base (sharp edge: the gel rounds it)."""
    check_range("radius_mm", radius_mm, 0.05, 200.0, "mm")
    xx, yy = _grid_mm(2 * radius_mm + 4 * mm_per_px, 2 * radius_mm + 4 * mm_per_px, mm_per_px)
    h = np.where(xx**2 + yy**2 <= radius_mm**2, height_mm, 0.0)
    return HeightField(h, mm_per_px, name=name)


def box(width_mm: float = 6.0, length_mm: float = 4.0, height_mm: float = 2.0, mm_per_px: float = 0.05, *,
        name: str = "box") -> HeightField:
    """A rectangular block, ``width_mm`` along x and ``length_mm`` along y."""
    check_range("width_mm", width_mm, 0.05, 500.0, "mm")
    check_range("length_mm", length_mm, 0.05, 500.0, "mm")
    xx, yy = _grid_mm(width_mm + 4 * mm_per_px, length_mm + 4 * mm_per_px, mm_per_px)
    inside = (np.abs(xx) <= width_mm / 2) & (np.abs(yy) <= length_mm / 2)
    return HeightField(np.where(inside, height_mm, 0.0), mm_per_px, name=name)


def cone(radius_mm: float = 3.0, height_mm: float = 2.0, mm_per_px: float = 0.05, *, name: str = "cone") -> HeightField:
    """A cone: steep flanks and a sharp tip (tests grazing normals)."""
    check_range("radius_mm", radius_mm, 0.05, 200.0, "mm")
    xx, yy = _grid_mm(2 * radius_mm + 2 * mm_per_px, 2 * radius_mm + 2 * mm_per_px, mm_per_px)
    h = height_mm * np.maximum(0.0, 1.0 - np.sqrt(xx**2 + yy**2) / radius_mm)
    return HeightField(h, mm_per_px, name=name)


def plate_with_features(width_mm: float = 30.0, length_mm: float = 24.0, thickness_mm: float = 2.0,
                        mm_per_px: float = 0.05, *, seed: int = 7, name: str = "plate") -> HeightField:
    """A flat plate with holes, ridges, a slot, bosses and fine knurling: texture for registration.

    Every feature is asymmetric in placement (seeded), so a rotation or shift of the plate is
    identifiable from any sensor-sized window.
    """
    xx, yy = _grid_mm(width_mm, length_mm, mm_per_px)
    rng = np.random.default_rng(seed)
    h = np.full(xx.shape, thickness_mm, dtype=np.float32)
    half_w, half_l = width_mm / 2, length_mm / 2
    # Holes of several diameters (drilled through: height 0 inside).
    for _ in range(14):
        cx, cy = rng.uniform(-half_w + 2, half_w - 2), rng.uniform(-half_l + 2, half_l - 2)
        r = rng.uniform(0.5, 1.6)
        h[(xx - cx) ** 2 + (yy - cy) ** 2 <= r * r] = 0.0
    # Ridges: raised bars at various angles (0.3 mm above the plate, 0.6-1.0 mm wide).
    for _ in range(8):
        cx, cy = rng.uniform(-half_w, half_w), rng.uniform(-half_l, half_l)
        ang = rng.uniform(0, math.pi)
        length, width = rng.uniform(4, 10), rng.uniform(0.6, 1.0)
        u = (xx - cx) * math.cos(ang) + (yy - cy) * math.sin(ang)
        v = -(xx - cx) * math.sin(ang) + (yy - cy) * math.cos(ang)
        h[(np.abs(u) <= length / 2) & (np.abs(v) <= width / 2)] = thickness_mm + 0.3
    # Bosses: low domes.
    for _ in range(6):
        cx, cy = rng.uniform(-half_w, half_w), rng.uniform(-half_l, half_l)
        r = rng.uniform(0.8, 1.5)
        d2 = (xx - cx) ** 2 + (yy - cy) ** 2
        dome = thickness_mm + 0.35 * np.sqrt(np.maximum(0.0, 1 - d2 / (r * r)))
        h = np.where(d2 <= r * r, np.maximum(h, dome), h)
    # Knurled patch: fine cross-hatch 0.1 mm deep (period 0.8 mm).
    patch = (xx > half_w * 0.2) & (yy < -half_l * 0.2)
    knurl = 0.05 * (np.sin(2 * np.pi * (xx + yy) / 0.8) + np.sin(2 * np.pi * (xx - yy) / 0.8))
    h = np.where(patch & (h >= thickness_mm - 1e-6), h + knurl.astype(np.float32), h)
    return HeightField(np.maximum(h, 0.0), mm_per_px, name=name, colour_bgr=(160, 160, 170))


def usb_connector_part(mm_per_px: float = 0.05, *, name: str = "usb_connector_part") -> HeightField:
    """A 28 x 22 mm panel (larger than a GelSight field of view) with a USB-A-like receptacle.

    Heights in mm above the part's base; the top face is flat (2 mm) so a press touches all of it
    and the features show as edges: the receptacle (a 12 x 4.5 mm cavity, 1.5 mm deep, with its
    tongue 0.15 mm below the face and two latch windows), five mounting holes of different sizes, a
    scale bar of three grooves of decreasing length, a 2 x 3 grid of pits, a slot, a knurled patch,
    a chamfered edge and a notched corner, so no rotation or mirror of the part looks like another
    and every sensor-sized window holds several features.
    """
    width_mm, length_mm, plate = 28.0, 22.0, 2.0
    xx, yy = _grid_mm(width_mm, length_mm, mm_per_px)
    h = np.full(xx.shape, plate, dtype=np.float32)
    # Chamfer the outer 1 mm so the plate edge is a slope, not a cliff.
    edge = np.minimum(width_mm / 2 - np.abs(xx), length_mm / 2 - np.abs(yy))
    h = np.where(edge < 1.0, plate * np.clip(0.4 + 0.6 * edge, 0.0, 1.0), h)
    h[(xx > width_mm / 2 - 5) & (yy < -length_mm / 2 + 4)] = 0.0  # corner notch
    # Receptacle: a cavity with the tongue inside and latch windows on one long side.
    sx, sy, w, l = -3.0, 2.0, 12.0, 4.5
    h[(np.abs(xx - sx) <= w / 2) & (np.abs(yy - sy) <= l / 2)] = plate - 1.5
    h[(np.abs(xx - sx) <= w / 2 - 1.2) & (yy - sy >= -0.3) & (yy - sy <= 0.9)] = plate - 0.15
    for lx in (sx - 3.0, sx + 3.0):
        h[(np.abs(xx - lx) <= 0.8) & (yy - sy >= -l / 2 - 0.9) & (yy - sy < -l / 2)] = plate - 0.8
    # Mounting holes (through).
    for hx, hy, hr in ((9.5, 5.5, 1.2), (-10.0, -6.0, 1.2), (-9.5, 7.0, 0.8), (4.0, -7.5, 0.6), (11.0, -2.0, 0.9)):
        h[(xx - hx) ** 2 + (yy - hy) ** 2 <= hr * hr] = 0.0
    # Scale bar: grooves of decreasing length.
    for i, length in enumerate((6.0, 4.0, 2.5)):
        ry = -3.5 - 1.4 * i
        h[(np.abs(yy - ry) <= 0.3) & (xx >= -4.0) & (xx <= -4.0 + length)] = plate - 0.3
    # A 2 x 3 grid of pits beside the receptacle.
    for i in range(3):
        for j in range(2):
            h[(xx - (5.5 + 1.3 * i)) ** 2 + (yy - (1.0 + 1.3 * j)) ** 2 <= 0.4**2] = plate - 0.4
    # A slanted slot.
    u = (xx + 8.0) * math.cos(0.6) + (yy - 1.0) * math.sin(0.6)
    v = -(xx + 8.0) * math.sin(0.6) + (yy - 1.0) * math.cos(0.6)
    h[(np.abs(u) <= 2.5) & (np.abs(v) <= 0.45)] = plate - 1.0
    # Knurled patch: shallow cross-hatch (0.8 mm period, 0.1 mm deep) in one quadrant.
    patch = (xx > 1.0) & (xx < 8.0) & (yy > 4.5) & (yy < 9.5)
    knurl = 0.05 * (np.sin(2 * np.pi * (xx + yy) / 0.8) + np.sin(2 * np.pi * (xx - yy) / 0.8)) - 0.1
    h = np.where(patch, h + knurl.astype(np.float32), h)
    return HeightField(h, mm_per_px, name=name, colour_bgr=(90, 90, 95))


_PRIMITIVES: dict[str, Callable[..., HeightField]] = {"sphere": ball, "ball": ball, "cylinder": cylinder, "box": box, "cone": cone}


def make_primitive(primitive: str, mm_per_px: float = 0.05, **size_mm: float) -> HeightField:
    """Build a primitive by name: ``sphere``/``ball`` (radius_mm), ``cylinder``/``cone``
    (radius_mm, height_mm), ``box`` (width_mm, length_mm, height_mm)."""
    try:
        fn = _PRIMITIVES[primitive]
    except KeyError:
        raise ValueError(f"primitive={primitive!r} is unknown; expected one of {sorted(_PRIMITIVES)}") from None
    return fn(mm_per_px=mm_per_px, **size_mm)


def sensor_to_object_px(obj: HeightField, shape_px: tuple[int, int], sensor_mm_per_px: float,
                        x_mm: float = 0.0, y_mm: float = 0.0, theta_deg: float = 0.0) -> np.ndarray:
    """The affine map (2x3) from a sensor pixel ``(u, v)`` to the object pixel it sees, for a sensor
    grid of ``shape_px`` (rows, cols) at ``sensor_mm_per_px`` and the pose of :func:`view_in_sensor`."""
    rows, cols = int(shape_px[0]), int(shape_px[1])
    t = math.radians(theta_deg)
    c, sn = math.cos(t), math.sin(t)
    k = sensor_mm_per_px / obj.mm_per_px
    orows, ocols = obj.height_mm.shape
    px0 = -(cols - 1) / 2.0 * sensor_mm_per_px - x_mm
    py0 = -(rows - 1) / 2.0 * sensor_mm_per_px - y_mm
    return np.array([
        [c * k, sn * k, (c * px0 + sn * py0) / obj.mm_per_px + (ocols - 1) / 2.0],
        [-sn * k, c * k, (-sn * px0 + c * py0) / obj.mm_per_px + (orows - 1) / 2.0],
    ], dtype=np.float64)


def view_in_sensor(obj: HeightField, shape_px: tuple[int, int], sensor_mm_per_px: float,
                   x_mm: float = 0.0, y_mm: float = 0.0, theta_deg: float = 0.0) -> np.ndarray:
    """Sample ``obj`` on a sensor grid of ``shape_px`` (rows, cols) at the given pose (see module doc).

    Returns the object height in mm at each sensor pixel (0 off the object), float32. Bilinear.
    """
    rows, cols = int(shape_px[0]), int(shape_px[1])
    if rows < 1 or cols < 1:
        raise ValueError(f"shape_px={shape_px!r} must be positive (rows, cols)")
    check_range("sensor_mm_per_px", float(sensor_mm_per_px), 1e-4, 10.0, "mm/px")
    for name, v in (("x_mm", x_mm), ("y_mm", y_mm), ("theta_deg", theta_deg)):
        if not math.isfinite(v):
            raise ValueError(f"{name}={v!r} must be finite")
    # Sensor pixel (u, v) -> object pixel: an affine map, so one warpAffine does the sampling.
    m = sensor_to_object_px(obj, (rows, cols), sensor_mm_per_px, x_mm, y_mm, theta_deg)
    if not np.all(np.abs(m) < 1e9):
        return np.zeros((rows, cols), np.float32)  # the object is astronomically far away
    return cv2.warpAffine(obj.height_mm, m, (cols, rows), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)


def pressed_indentation_mm(object_height_mm: np.ndarray, press_depth_mm: float,
                           top_height_mm: float | None = None) -> np.ndarray:
    """How far each gel point is pushed in when the object's top is ``press_depth_mm`` past first touch.

    ``top_height_mm`` is the object's highest point (default: the maximum of the view); pass the
    whole object's maximum when the sensor sees only part of it, so a flat plate larger than the
    field of view reads as a uniform press, not as its visible maximum. The gel's own range limit
    and smoothing are the renderer's business.
    """
    h = np.asarray(object_height_mm, dtype=np.float32)
    if not math.isfinite(press_depth_mm) or press_depth_mm <= 0 or h.size == 0:
        return np.zeros(h.shape, np.float32)
    if top_height_mm is None:
        finite = h[np.isfinite(h)]
        top = float(finite.max()) if finite.size else 0.0
    else:
        top = float(top_height_mm)
    out = np.fmax(h - np.float32(top - press_depth_mm), np.float32(0.0))  # NaN -> 0
    out[np.isinf(out)] = 0.0
    return out


# --------------------------------------------------------------------------------------------
# World models


@dataclass
class ObjectModel:
    """A rigid object in a scene: its shape, how deep it is pressed, and its own pose.

    The pose here is used when the scene has no stage; with a stage, renderers compose the stage
    pose with it. ``press_depth_mm`` is the press past first contact (≤ 0: not touching).
    """

    shape: HeightField
    press_depth_mm: float = 0.0
    x_mm: float = 0.0
    y_mm: float = 0.0
    theta_deg: float = 0.0
    extras: dict[str, Any] = field(default_factory=dict)

    def advance_to(self, t_s: float) -> None:  # a passive object: nothing to integrate
        return None


_SHAPES: dict[str, Callable[..., HeightField]] = {"usb_connector": usb_connector_part, "plate": plate_with_features}


@register_model("height_field_object")
def _height_field_object(world: Any, rng: np.random.Generator, *, shape: str = "usb_connector",
                         mm_per_px: float = 0.05, press_depth_mm: float = 0.5, x_mm: float = 0.0,
                         y_mm: float = 0.0, theta_deg: float = 0.0, npy_path: str | None = None,
                         **shape_params: Any) -> ObjectModel:
    """Scene model: a textured part (``shape = "usb_connector" | "plate"``) or a height map from
    ``npy_path`` (a 2-D array of heights in mm at ``mm_per_px``)."""
    if npy_path is not None:
        hf = HeightField(np.load(npy_path), mm_per_px, name=str(npy_path))
    else:
        try:
            fn = _SHAPES[shape]
        except KeyError:
            raise ValueError(f"height_field_object: shape={shape!r} is unknown; expected one of {sorted(_SHAPES)} "
                             "or npy_path") from None
        hf = fn(mm_per_px=mm_per_px, **shape_params)
    return ObjectModel(hf, float(press_depth_mm), float(x_mm), float(y_mm), float(theta_deg))


@register_model("primitive_object")
def _primitive_object(world: Any, rng: np.random.Generator, *, primitive: str = "sphere",
                      mm_per_px: float = 0.05, press_depth_mm: float = 0.5, x_mm: float = 0.0,
                      y_mm: float = 0.0, theta_deg: float = 0.0,
                      colour_bgr: tuple[int, int, int] | list[int] | None = None,
                      **size_mm: float) -> ObjectModel:
    """Scene model: a primitive (sphere, cylinder, box, cone) with its size parameters in mm."""
    hf = make_primitive(primitive, mm_per_px, **size_mm)
    if colour_bgr is not None:
        hf = HeightField(hf.height_mm, hf.mm_per_px, name=hf.name, colour_bgr=(int(colour_bgr[0]), int(colour_bgr[1]), int(colour_bgr[2])))
    return ObjectModel(hf, float(press_depth_mm), float(x_mm), float(y_mm), float(theta_deg))

"""FingerVision renderer: black markers in a clear silicone skin, and the scene seen through it.

What a FingerVision camera sees (and what :meth:`FingerVisionRenderer.render` draws, in order):

- **The world behind the skin**: a bright, slightly green-grey view with a low-frequency lighting
  gradient, a specular highlight and a dark fish-eye rim (the lens sees the finger's housing).
- **An object** through the skin: a blurred ellipse or rectangle of the object's colour (the
  skin is a few mm thick and the object is out of focus), whose centroid, orientation and area are
  returned as ground truth for proximity vision.
- **A printed card** (``card``, :class:`FvCard`) pressed against the skin and sliding behind it:
  a light card with dark print (QR-like modules, text strokes and round dots the size of a marker),
  out of focus. Its print is what a marker detector must ignore; it carries no ground truth.
- **Markers**: dark dots printed in the silicone on a square grid, seen through a fish-eye lens
  (spacing and size shrink towards the rim), with manufacturing jitter in position and size.
  A contact's shear field displaces them (``markers_shift_px``) and normal load squashes the skin
  so the dots grow (``normal_load`` 0..1 → up to ``load_growth`` relative radius).
- **Lighting changes** (``light_gain``), sensor noise, 8-bit clipping.

Marker count, spacing and sizes default to what a blob detector finds in the real FingerVision
frames (``fingervision_demo_gpl3``: ~32 markers, diameters 4-11 px at 320x240). Rendering is pure;
:class:`FingerVisionRendererModel` (kind ``fingervision_renderer``) reads contact state from a scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import cv2
import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.sim.base import register_model
from tactile_rig.sim.render.noise import SensorNoise

__all__ = ["FvObject", "FvCard", "FingerVisionRenderer", "contact_shear_field", "FingerVisionRendererModel"]

ShiftSpec = np.ndarray | Callable[[np.ndarray], np.ndarray] | None


@dataclass(frozen=True)
class FvObject:
    """An object seen through the skin: an ellipse (or rectangle) in pixels, and its colour."""

    centre_px: tuple[float, float]
    axes_px: tuple[float, float]  # half-lengths along its own x and y
    angle_deg: float = 0.0  # of its own x axis, image axes (clockwise on screen)
    colour_bgr: tuple[int, int, int] = (40, 60, 200)
    shape: str = "ellipse"  # or "rect"
    blur_px: float = 3.0


@dataclass(frozen=True)
class FvCard:
    """A printed card behind the skin: top-left corner ``offset_px`` (x, y; move it to slide the card),
    size ``size_px`` (w, h), pattern ``seed``, print colour (default dark green, like the real QR card)."""

    offset_px: tuple[float, float] = (60.0, 40.0)
    size_px: tuple[int, int] = (200, 150)
    seed: int = 0
    ink_bgr: tuple[int, int, int] = (35, 60, 25)
    paper_bgr: tuple[int, int, int] = (215, 225, 220)
    blur_px: float = 1.2
    dots: bool = True
    """Also print round dots of a marker's size (the hardest print for a marker detector)."""


_CARD_CACHE: dict[tuple[int, int, int, bool, float], tuple[np.ndarray, np.ndarray]] = {}


def _card_layers(card: FvCard) -> tuple[np.ndarray, np.ndarray]:
    """(paper alpha, ink alpha) of the card, float32 in its own pixel grid, cached per pattern."""
    w, h = int(card.size_px[0]), int(card.size_px[1])
    key = (w, h, int(card.seed), bool(card.dots), float(card.blur_px))
    if key in _CARD_CACHE:
        return _CARD_CACHE[key]
    if not (8 <= w <= 4096 and 8 <= h <= 4096):
        raise ValueError(f"FvCard.size_px={card.size_px!r}: expected 8..4096 px each side")
    rng = np.random.default_rng(card.seed)
    paper = np.ones((h, w), np.float32)
    ink = np.zeros((h, w), np.uint8)
    module = 6
    qn = max(3, min(w, h) // (2 * module))
    qx, qy = w - qn * module - 6, h - qn * module - 6
    for i in range(qn):  # QR-like modules, three finder squares
        for j in range(qn):
            if rng.random() < 0.5:
                cv2.rectangle(ink, (qx + i * module, qy + j * module), (qx + (i + 1) * module - 1, qy + (j + 1) * module - 1), 255, -1)
    for fx, fy in ((qx, qy), (qx + (qn - 7) * module, qy), (qx, qy + (qn - 7) * module)):
        cv2.rectangle(ink, (fx, fy), (fx + 7 * module - 1, fy + 7 * module - 1), 255, -1)
        cv2.rectangle(ink, (fx + module, fy + module), (fx + 6 * module - 1, fy + 6 * module - 1), 0, -1)
        cv2.rectangle(ink, (fx + 2 * module, fy + 2 * module), (fx + 5 * module - 1, fy + 5 * module - 1), 255, -1)
    for _ in range(14):  # text-like strokes along the top
        x0, y0 = int(rng.integers(4, max(5, w - 30))), int(rng.integers(4, max(5, h // 3)))
        cv2.line(ink, (x0, y0), (x0 + int(rng.integers(6, 24)), y0 + int(rng.integers(-6, 7))), 255, int(rng.integers(2, 4)))
    if card.dots:
        for _ in range(6):  # full stops and bullets: round, dark, a marker's size
            cv2.circle(ink, (int(rng.integers(8, w - 8)), int(rng.integers(8, h - 8))), int(rng.integers(3, 6)), 255, -1)
    ink_a = ink.astype(np.float32) / 255.0
    if card.blur_px > 0:
        ink_a = cv2.GaussianBlur(ink_a, (0, 0), card.blur_px)
        paper = cv2.GaussianBlur(np.pad(paper, 4), (0, 0), card.blur_px)[4:-4, 4:-4]
    _CARD_CACHE[key] = (paper, ink_a)
    return paper, ink_a


def contact_shear_field(points_px: np.ndarray, centre_px: tuple[float, float], *, shift_px: tuple[float, float] = (0.0, 0.0),
                        twist_deg: float = 0.0, radius_px: float = 60.0) -> np.ndarray:
    """Marker displacements (N x 2, px) of a contact at ``centre_px``: a translation ``shift_px`` and a
    twist ``twist_deg`` about the centre, fading as a Gaussian of ``radius_px`` (the skin drags its
    neighbours along, less with distance)."""
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    check_range("radius_px", float(radius_px), 1e-3, 1e6, "px")
    rel = pts - np.asarray(centre_px, dtype=np.float64)
    w = np.exp(-0.5 * (rel**2).sum(1) / radius_px**2)[:, None]
    t = math.radians(twist_deg)
    rot = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
    twist = rel @ rot.T - rel
    return w * (np.asarray(shift_px, dtype=np.float64) + twist)


class FingerVisionRenderer:
    """Pure renderer: ``render(...) -> (frame_bgr, truth)``; see the module doc for the physics."""

    def __init__(self, shape_px: tuple[int, int] = (240, 320), *, grid_cols: int = 7, grid_rows: int = 4,
                 pitch_px: float | None = None, marker_radius_px: float | None = None, jitter_px: float = 1.5,
                 size_jitter: float = 0.1, fisheye_k: float = 1.0, load_growth: float = 0.35,
                 noise_sigma: float = 2.0, seed: int | np.random.Generator | None = 0) -> None:
        rows, cols = int(shape_px[0]), int(shape_px[1])
        if rows < 16 or cols < 16:
            raise ValueError(f"shape_px={shape_px!r} must be at least 16x16")
        self.shape_px = (rows, cols)
        scale = cols / 320.0
        self.pitch_px = float(pitch_px) if pitch_px is not None else 60.0 * scale
        self.marker_radius_px = float(marker_radius_px) if marker_radius_px is not None else 6.1 * scale
        check_range("pitch_px", self.pitch_px, 4.0, 1e4, "px")
        check_range("marker_radius_px", self.marker_radius_px, 0.5, self.pitch_px / 2, "px")
        self.fisheye_k = check_range("fisheye_k", float(fisheye_k), 0.0, 5.0)
        self.load_growth = check_range("load_growth", float(load_growth), 0.0, 3.0)
        self.noise_sigma = check_range("noise_sigma", float(noise_sigma), 0.0, 100.0)
        self._rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self.rest_px, self.radius_px = self._place_markers(grid_cols, grid_rows, jitter_px, size_jitter)
        self.background_bgr = np.clip(self._background() + 0.5, 0, 255).astype(np.uint8)
        self._shade = (self.background_bgr.astype(np.float32).mean(axis=2) / 150.0).astype(np.float32)
        self._ink = np.full((rows, cols, 3), 13, np.uint8)
        self._noise = SensorNoise((rows, cols, 3), self.noise_sigma, self._rng, mono=True) if self.noise_sigma > 0 else None

    # -- geometry -------------------------------------------------------------------------
    def _distort(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fish-eye: skin point (px from the centre) → image point and local size magnification.

        ``r_img = c·atan(r / c)`` (monotonic, compresses towards the rim); ``c`` = half diagonal /
        ``fisheye_k`` (``fisheye_k`` = 0: no distortion).
        """
        rows, cols = self.shape_px
        if self.fisheye_k <= 0:
            return p.copy(), np.ones(len(p))
        c = 0.5 * math.hypot(rows, cols) / self.fisheye_k
        r = np.maximum(np.linalg.norm(p, axis=1), 1e-9)
        r_img = c * np.arctan(r / c)
        radial = 1.0 / (1.0 + (r / c) ** 2)
        tangential = r_img / r
        return p * (r_img / r)[:, None], np.sqrt(radial * tangential)

    def _place_markers(self, n_cols: int, n_rows: int, jitter_px: float, size_jitter: float) -> tuple[np.ndarray, np.ndarray]:
        rows, cols = self.shape_px
        gx = (np.arange(n_cols + 2) - (n_cols + 1) / 2.0) * self.pitch_px
        gy = (np.arange(n_rows + 2) - (n_rows + 1) / 2.0) * self.pitch_px * 0.95
        skin = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
        skin = skin + self._rng.normal(0.0, jitter_px, skin.shape)
        img, mag = self._distort(skin)
        img = img + np.array([(cols - 1) / 2.0, (rows - 1) / 2.0])
        radius = self.marker_radius_px * mag**2 * (1.0 + self._rng.normal(0.0, size_jitter, len(mag)))
        radius = np.clip(radius, 0.6, None)
        # Only dots whose centre is in view: a sliver of an outside dot has no usable centre.
        keep = (img[:, 0] >= 0) & (img[:, 0] <= cols - 1) & (img[:, 1] >= 0) & (img[:, 1] <= rows - 1)
        return img[keep], radius[keep]

    def _background(self) -> np.ndarray:
        rows, cols = self.shape_px
        yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float32)
        u, v = (xx - cols / 2) / (cols / 2), (yy - rows / 2) / (rows / 2)
        base = np.array([150.0, 165.0, 150.0], dtype=np.float32)
        light = 1.0 + 0.18 * u - 0.12 * v + 0.35 * np.exp(-((u + 0.2) ** 2 + (v + 0.6) ** 2) / 0.08)
        rim = np.clip((np.sqrt(u * u * 0.9 + v * v * 0.75) - 1.0) / 0.25, 0.0, 1.0)
        texture = cv2.GaussianBlur(self._rng.normal(0.0, 12.0, (rows, cols)).astype(np.float32), (0, 0), 3.0)
        img = base[None, None, :] * light[..., None] * (1.0 - 0.7 * rim[..., None]) + texture[..., None]
        return img.astype(np.float32)

    # -- rendering ------------------------------------------------------------------------
    def marker_positions_px(self, markers_shift_px: ShiftSpec = None) -> np.ndarray:
        """True marker centres (N x 2, x then y) for a shift: an N x 2 array, a function of the rest
        positions, or None."""
        if markers_shift_px is None:
            return self.rest_px.copy()
        shift = markers_shift_px(self.rest_px) if callable(markers_shift_px) else markers_shift_px
        shift = np.asarray(shift, dtype=np.float64)
        if shift.shape != self.rest_px.shape:
            raise ValueError(f"markers_shift_px has shape {shift.shape}; expected {self.rest_px.shape} (one x, y per marker)")
        return self.rest_px + np.nan_to_num(shift, nan=0.0, posinf=0.0, neginf=0.0)

    def render(self, markers_shift_px: ShiftSpec = None, normal_load: float = 0.0, object: FvObject | None = None,  # noqa: A002
               light_gain: float = 1.0, card: FvCard | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Render one frame; returns ``(frame_bgr uint8, truth)`` with truth keys ``markers_px``,
        ``marker_radius_px``, ``object_centroid_px``, ``object_orientation_deg``, ``object_area_px``.
        ``card``: a printed card behind the skin (drawn over the object, under the markers)."""
        if not math.isfinite(normal_load):
            raise ValueError(f"normal_load={normal_load!r} must be finite (0 = no load, 1 = full load)")
        if not (math.isfinite(light_gain) and light_gain >= 0):
            raise ValueError(f"light_gain={light_gain!r} must be a finite number >= 0")
        load = min(max(float(normal_load), 0.0), 1.0)
        rows, cols = self.shape_px
        img = self.background_bgr.copy()
        truth: dict[str, Any] = {"object_centroid_px": None, "object_orientation_deg": None, "object_area_px": 0.0}
        if object is not None:
            self._composite_object(img, object, truth)
        if card is not None:
            img = self._composite_card(img, card)
        pos = self.marker_positions_px(markers_shift_px)
        radius = self.radius_px * (1.0 + self.load_growth * load)
        dots = np.zeros((rows, cols), np.uint8)
        for (x, y), r in zip(pos, radius):
            if -r <= x <= cols - 1 + r and -r <= y <= rows - 1 + r:
                cv2.circle(dots, (int(round(x * 16)), int(round(y * 16))), max(1, int(round(r * 16))), 255,
                           -1, cv2.LINE_AA, shift=4)
        ink = cv2.GaussianBlur(dots, (0, 0), 0.7).astype(np.float32) * np.float32(0.9 / 255.0)
        img = cv2.blendLinear(img, self._ink, 1.0 - ink, ink)  # dark ink: V falls to ~15-30
        if light_gain != 1.0:
            img = cv2.convertScaleAbs(img, alpha=float(light_gain))  # saturates at 255 like the sensor
        if self._noise is not None:
            img = cv2.add(img, self._noise.sample(), dtype=cv2.CV_8U)
        truth["markers_px"] = pos
        truth["marker_radius_px"] = radius
        return img, truth

    def _composite_card(self, img: np.ndarray, card: FvCard) -> np.ndarray:
        """Slide the card's paper and ink layers to ``card.offset_px`` (sub-pixel) and blend them in."""
        ox, oy = float(card.offset_px[0]), float(card.offset_px[1])
        if not (math.isfinite(ox) and math.isfinite(oy)):
            raise ValueError(f"FvCard.offset_px={card.offset_px!r} must be finite")
        rows, cols = self.shape_px
        paper, ink = _card_layers(card)
        m = np.array([[1, 0, ox], [0, 1, oy]], dtype=np.float32)
        pa = cv2.warpAffine(paper, m, (cols, rows), flags=cv2.INTER_LINEAR, borderValue=0)[..., None] * np.float32(0.9)
        ia = cv2.warpAffine(ink, m, (cols, rows), flags=cv2.INTER_LINEAR, borderValue=0)[..., None] * np.float32(0.9)
        out = img.astype(np.float32)
        paper_c = self._shade[..., None] * np.asarray(card.paper_bgr, np.float32)
        out = out * (1 - pa) + paper_c * pa
        out = out * (1 - ia) + np.asarray(card.ink_bgr, np.float32) * ia
        return np.clip(out, 0, 255).astype(np.uint8)

    def _composite_object(self, img: np.ndarray, obj: FvObject, truth: dict[str, Any]) -> None:
        """Blend the object into ``img`` (in place, inside its bounding box) and fill its ground truth."""
        rows, cols = self.shape_px
        mask = np.zeros((rows, cols), np.uint8)
        self._draw_object(mask, obj)
        x, y, w, h = cv2.boundingRect(mask)
        if w == 0 or h == 0:
            return
        m = cv2.moments(mask[y:y + h, x:x + w], binaryImage=True)
        truth.update(object_centroid_px=(x + m["m10"] / m["m00"], y + m["m01"] / m["m00"]),
                     object_orientation_deg=math.degrees(0.5 * math.atan2(2 * m["mu11"], m["mu20"] - m["mu02"])),
                     object_area_px=float(m["m00"]))
        pad = int(math.ceil(3 * obj.blur_px)) + 1
        x0, y0, x1, y1 = max(0, x - pad), max(0, y - pad), min(cols, x + w + pad), min(rows, y + h + pad)
        alpha = mask[y0:y1, x0:x1].astype(np.float32) * np.float32(0.85 / 255.0)
        if obj.blur_px > 0:
            alpha = cv2.GaussianBlur(alpha, (0, 0), obj.blur_px)
        # The object is lit like the background it hides (same LEDs, same vignetting).
        layer = self._shade[y0:y1, x0:x1, None] * np.asarray(obj.colour_bgr, dtype=np.float32)
        layer = np.clip(layer, 0, 255).astype(np.uint8)
        img[y0:y1, x0:x1] = cv2.blendLinear(img[y0:y1, x0:x1], layer, 1.0 - alpha, alpha)

    @staticmethod
    def _draw_object(mask: np.ndarray, obj: FvObject) -> None:
        cx, cy = obj.centre_px
        ax, ay = max(0.0, float(obj.axes_px[0])), max(0.0, float(obj.axes_px[1]))
        if not all(math.isfinite(v) for v in (cx, cy, ax, ay, obj.angle_deg)):
            raise ValueError(f"FvObject has a non-finite field: {obj!r}")
        big = 4 * max(mask.shape)  # keep cv2's int coordinates in range for huge or far objects
        cx, cy = float(np.clip(cx, -big, big)), float(np.clip(cy, -big, big))
        ax, ay = min(ax, big), min(ay, big)
        if obj.shape == "rect":
            box = cv2.boxPoints(((cx, cy), (2 * ax, 2 * ay), obj.angle_deg))
            cv2.fillPoly(mask, [np.round(box).astype(np.int32)], 255)
        elif obj.shape == "ellipse":
            cv2.ellipse(mask, (int(round(cx)), int(round(cy))), (int(round(ax)), int(round(ay))), obj.angle_deg,
                        0, 360, 255, -1)
        else:
            raise ValueError(f"FvObject.shape={obj.shape!r}; expected 'ellipse' or 'rect'")


class FingerVisionRendererModel:
    """Scene model (kind ``fingervision_renderer``).

    Reads, only if present: the object model ``object`` (pose ``x_mm, y_mm, theta_deg`` relative to
    the camera axis, its shape's footprint and colour) and a contact model ``contact`` (attributes
    ``normal_force_n``, ``shear_x_n``, ``shear_y_n``, ``torque_nmm``). Forces map to pixels by the
    skin stiffness parameters.
    """

    def __init__(self, world: Any, rng: np.random.Generator, *, shape_px: tuple[int, int] | list[int] = (240, 320),
                 mm_per_px: float = 0.1, object: str = "object", contact: str = "contact",  # noqa: A002
                 px_per_n_shear: float = 4.0, deg_per_nmm: float = 0.05, full_load_n: float = 10.0,
                 noise_sigma: float = 2.0, light_gain: float = 1.0) -> None:
        self.world = world
        self.renderer = FingerVisionRenderer((int(shape_px[0]), int(shape_px[1])), noise_sigma=noise_sigma, seed=rng)
        self.mm_per_px = check_range("mm_per_px", float(mm_per_px), 1e-4, 10.0, "mm/px")
        self.object_name, self.contact_name = object, contact
        self.px_per_n_shear, self.deg_per_nmm, self.full_load_n = px_per_n_shear, deg_per_nmm, full_load_n
        self.light_gain = float(light_gain)
        self.t_s = 0.0
        self.last_truth: dict[str, Any] = {}

    def advance_to(self, t_s: float) -> None:
        self.t_s = max(self.t_s, float(t_s))

    def render_now(self) -> np.ndarray:
        if self.world is not None:
            self.world.advance_to()
        rows, cols = self.renderer.shape_px
        centre = ((cols - 1) / 2.0, (rows - 1) / 2.0)
        fv_obj = None
        obj = self.world.get(self.object_name) if self.world is not None else None
        if obj is not None and hasattr(obj, "shape"):
            w_mm, l_mm = obj.shape.size_mm
            centre = (centre[0] + obj.x_mm / self.mm_per_px, centre[1] + obj.y_mm / self.mm_per_px)
            fv_obj = FvObject(centre, (w_mm / 2 / self.mm_per_px, l_mm / 2 / self.mm_per_px), obj.theta_deg,
                              obj.shape.colour_bgr, shape="rect" if "box" in obj.shape.name else "ellipse")
        contact = self.world.get(self.contact_name) if self.world is not None else None
        fn = float(getattr(contact, "normal_force_n", 0.0) or 0.0)
        shift = (float(getattr(contact, "shear_x_n", 0.0) or 0.0) * self.px_per_n_shear,
                 float(getattr(contact, "shear_y_n", 0.0) or 0.0) * self.px_per_n_shear)
        twist = float(getattr(contact, "torque_nmm", 0.0) or 0.0) * self.deg_per_nmm
        field = None
        if fn > 0:
            field = lambda p: contact_shear_field(p, centre, shift_px=shift, twist_deg=twist,  # noqa: E731
                                                  radius_px=0.35 * cols)
        frame, truth = self.renderer.render(field, normal_load=fn / self.full_load_n, object=fv_obj,
                                            light_gain=self.light_gain)
        truth["t_s"] = self.t_s
        self.last_truth = truth
        return frame


register_model("fingervision_renderer")(FingerVisionRendererModel)

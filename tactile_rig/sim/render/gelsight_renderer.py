"""GelSight renderer: an indentation height field → the BGR frame a photometric fingertip sees.

Physics, in the order it is applied (:meth:`GelSightRenderer.render`):

1. **Gel range.** The elastomer is a few mm thick and protrudes at most ``max_protrusion_mm``
   (about 1 mm); anything pressed deeper is clipped (the object bottoms out on the gel's backing).
2. **Elastomer smoothing.** The skin cannot follow sharp edges: the surface is the indentation
   blurred with a Gaussian of ``smoothing_mm`` (σ). 0.6 mm is what fits the Taxim presses best
   (held-out R² 0.71-0.75 per channel vs 0.55-0.6 at 0.12 mm).
3. **Normals** from the surface gradients (gx, gy) in mm/mm.
4. **Lighting.** Four LEDs (red, green, blue and white) shine from four sides at a low elevation.
   Under Lambertian shading each LED adds ``colour_k · (n·L_k − n₀·L_k)`` to the no-contact
   frame, which is linear in ``(n_x, n_y, n_z − 1)``; the four LEDs therefore collapse into one
   3x3 matrix from ``(gx, gy, n_z − 1)`` to the BGR change (:class:`LightingModel`). The default
   matrix :data:`TAXIM_LIGHTING` was fitted by :func:`~.ball_presses.fit_lighting` on real Taxim ball presses;
   :func:`lighting_from_leds` builds one from explicit LEDs. This is the forward model whose inverse
   a colour-to-gradient calibration learns.
5. **Composite** on a real no-contact frame (``assets/``), add sensor noise and an optional
   global illumination flicker, and clip to 0..255 as an 8-bit sensor saturates.

Everything here is pure and importable without a world; the scene model
(:class:`~tactile_rig.sim.render.gelsight.GelSightRendererModel`, kind ``gelsight_renderer``) reads the
object and the stage from a scene. The surface numerics are :mod:`.gel_surface`, the read noise
:mod:`.noise`, the ball-press data sets (fitting the lighting, rendering presses) :mod:`.ball_presses`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.sim.render.gel_surface import (
    blur_small,
    downsample_factor,
    gaussian_smooth,
    surface_gradients,
    upsample,
)
from tactile_rig.sim.render.noise import SensorNoise
from tactile_rig.sim.world.objects import HeightField, pressed_indentation_mm, view_in_sensor

ASSETS = Path(__file__).resolve().parent.parent / "assets"
BACKGROUNDS: dict[str, tuple[str, float]] = {
    # name -> (file, mm_per_px at the file's native size)
    "taxim": ("taxim_background_120x160.png", 0.1245),
    "gsmini": ("gsmini_background_240x320.png", 0.0634),
    "digit": ("digit_background_320x240.jpg", 0.0405),
}

__all__ = ["ASSETS", "BACKGROUNDS", "GelSightRenderer", "LightingModel", "TAXIM_LIGHTING", "TAXIM_NOISE_SIGMA",
           "lighting_from_leds", "load_background", "load_background_array_resized"]


@dataclass(frozen=True)
class LightingModel:
    """BGR change per unit of ``(gx, gy, n_z − 1)``: ``delta_bgr = [gx, gy, nz-1] @ matrix`` (3x3)."""

    matrix: np.ndarray

    def __post_init__(self) -> None:
        m = np.asarray(self.matrix, dtype=np.float32).reshape(3, 3)
        if not np.all(np.isfinite(m)):
            raise ValueError("LightingModel.matrix must be finite")
        object.__setattr__(self, "matrix", m)

    def shade(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        """BGR change (float32, rows x cols x 3) for surface gradients ``gx, gy`` (mm/mm)."""
        gx = np.asarray(gx, dtype=np.float32)
        gy = np.asarray(gy, dtype=np.float32)
        nz_minus_1 = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy) - 1.0
        feats = cv2.merge([gx, gy, nz_minus_1.astype(np.float32)])
        out = cv2.transform(feats, self.matrix.T)
        return out.reshape(*gx.shape, 3)


# Fitted by fit_lighting() on presses 00-14 of the Taxim pack (0.1245 mm/px, R = 2 mm,
# smoothing 0.6 mm, range 1 mm); rows: gx, gy, nz-1; columns: B, G, R. Held-out presses 15-29:
# see docs/cameras.md for the colour statistics.
TAXIM_LIGHTING = LightingModel(np.array([
    [60.39, 31.21, -106.68],
    [-113.02, 50.97, -2.75],
    [10.11, 111.41, 76.15],
], dtype=np.float32))


# Per-frame read noise (grey levels, B, G, R) of the Taxim sensor: the high-passed difference of a
# press frame and the no-contact frame away from the contact is 2.2 / 1.2 / 1.5 (median of 30
# presses), i.e. sqrt(2) times the noise of one frame.
TAXIM_NOISE_SIGMA = (1.55, 0.85, 1.05)


def lighting_from_leds(leds: Sequence[tuple[float, float, Sequence[float]]]) -> LightingModel:
    """Lighting from explicit LEDs: each ``(azimuth_deg, elevation_deg, colour_bgr)``.

    Azimuth in image axes (0° = from the right, +x; 90° = from below, +y); ``colour_bgr`` is the
    change in grey levels per unit of ``n·L`` in each channel.
    """
    m = np.zeros((3, 3), dtype=np.float64)
    for az_deg, el_deg, colour in leds:
        az, el = math.radians(az_deg), math.radians(el_deg)
        lx, ly, lz = math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)
        c = np.asarray(colour, dtype=np.float64).reshape(3)
        # n = (-gx, -gy, 1) * nz  ⇒  n·L − n0·L ≈ −lx·gx − ly·gy + lz·(nz − 1) to first order
        m += np.outer([-lx, -ly, lz], c)
    return LightingModel(m)


def load_background(name: str = "taxim", shape_px: tuple[int, int] | None = None) -> np.ndarray:
    """A real no-contact frame (BGR uint8) by name (``taxim``, ``gsmini``, ``digit``) or image path, resized to
    ``shape_px`` = (rows, cols) when given."""
    if name in BACKGROUNDS:
        path = ASSETS / BACKGROUNDS[name][0]
    else:
        path = Path(name)
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"background {name!r}: cannot read {path} (known names: {sorted(BACKGROUNDS)})")
    if shape_px is not None and tuple(img.shape[:2]) != tuple(shape_px):
        rows, cols = int(shape_px[0]), int(shape_px[1])
        if rows < 2 or cols < 2:
            raise ValueError(f"shape_px={shape_px!r} must be at least 2x2")
        interp = cv2.INTER_AREA if rows < img.shape[0] else cv2.INTER_LINEAR
        img = cv2.resize(img, (cols, rows), interpolation=interp)
    return img


def load_background_array_resized(bg: np.ndarray, shape_px: tuple[int, int]) -> np.ndarray:
    rows, cols = int(shape_px[0]), int(shape_px[1])
    interp = cv2.INTER_AREA if rows < bg.shape[0] else cv2.INTER_LINEAR
    return cv2.resize(bg, (cols, rows), interpolation=interp)


class GelSightRenderer:
    """Pure renderer: ``render(height_mm) -> frame_bgr`` (uint8, same size as the background).

    ``height_mm`` is the indentation the object would make in a perfectly compliant gel (≥ 0,
    None for no contact), on the sensor's pixel grid at ``mm_per_px``.
    """

    def __init__(
        self,
        background_bgr: np.ndarray | str = "taxim",
        mm_per_px: float = 0.1245,
        *,
        shape_px: tuple[int, int] | None = None,
        lighting: LightingModel = TAXIM_LIGHTING,
        smoothing_mm: float = 0.6,
        max_protrusion_mm: float = 1.0,
        noise_sigma: float | tuple[float, float, float] | list[float] = TAXIM_NOISE_SIGMA,
        flicker_sigma: float = 0.0,
        seed: int | np.random.Generator | None = 0,
    ) -> None:
        bg = load_background(background_bgr, shape_px) if isinstance(background_bgr, str) else background_bgr
        bg = np.asarray(bg)
        if bg.ndim != 3 or bg.shape[2] != 3:
            raise ValueError(f"background_bgr must be rows x cols x 3 (BGR), got shape {bg.shape}")
        if shape_px is not None and tuple(bg.shape[:2]) != tuple(shape_px):
            bg = load_background_array_resized(bg, shape_px)
        self.background_bgr = np.ascontiguousarray(bg, dtype=np.uint8)
        self._bg_f = self.background_bgr.astype(np.float32)
        self.mm_per_px = check_range("mm_per_px", float(mm_per_px), 1e-4, 10.0, "mm/px")
        self.lighting = lighting
        self.smoothing_mm = check_range("smoothing_mm", float(smoothing_mm), 0.0, 10.0, "mm")
        self.max_protrusion_mm = check_range("max_protrusion_mm", float(max_protrusion_mm), 0.01, 20.0, "mm")
        sig = np.broadcast_to(np.asarray(noise_sigma, dtype=np.float32), (3,)).copy()
        for c, v in zip("BGR", sig):
            check_range(f"noise_sigma[{c}]", float(v), 0.0, 100.0)
        self.noise_sigma = sig
        self.flicker_sigma = check_range("flicker_sigma", float(flicker_sigma), 0.0, 100.0)
        self._rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        rows, cols = self.shape_px
        self._noise = SensorNoise((rows, cols, 3), sig, self._rng) if sig.max() > 0 else None

    def reseed(self, rng: np.random.Generator) -> None:
        """Draw the per-frame noise (crops and flicker) from ``rng`` from now on, so a run that reseeds
        per step renders each step the same whatever came before it (a resumed run)."""
        self._rng = rng
        if self._noise is not None:
            self._noise.reseed(rng)

    @property
    def shape_px(self) -> tuple[int, int]:
        """(rows, cols) of the frames."""
        return int(self.background_bgr.shape[0]), int(self.background_bgr.shape[1])

    def _clipped(self, height_mm: np.ndarray | None) -> np.ndarray | None:
        """The indentation limited to the gel's range (None: no contact at all)."""
        if height_mm is None:
            return None
        rows, cols = self.shape_px
        h = np.asarray(height_mm, dtype=np.float32)
        if h.shape != (rows, cols):
            raise ValueError(f"height_mm has shape {h.shape}; the sensor is {rows}x{cols} (rows, cols)")
        h = np.fmax(h, np.float32(0.0))  # fmax maps NaN and -inf to 0
        np.minimum(h, np.float32(self.max_protrusion_mm), out=h)  # and +inf to the gel's range
        return h if h.any() else None

    def gel_surface_mm(self, height_mm: np.ndarray | None) -> np.ndarray:
        """The gel surface (mm) for an indentation: clipped to the gel's range, then smoothed."""
        h = self._clipped(height_mm)
        if h is None:
            return np.zeros(self.shape_px, dtype=np.float32)
        sigma_px = self.smoothing_mm / self.mm_per_px
        return gaussian_smooth(h, sigma_px) if sigma_px > 0.3 else h

    def shading_for(self, height_mm: np.ndarray | None) -> np.ndarray | None:
        """BGR change (float32) for an indentation, None without contact.

        When the elastomer's smoothing spans many pixels the surface, its normals and the shading
        vary slowly, so they are computed at 1/f resolution and the shading is interpolated back
        (same result within ~1 grey level, f² fewer pixels to shade).
        """
        h = self._clipped(height_mm)
        if h is None:
            return None
        sigma_px = self.smoothing_mm / self.mm_per_px
        f = downsample_factor(sigma_px)
        if f == 1:
            return self.shading_bgr(gaussian_smooth(h, sigma_px) if sigma_px > 0.3 else h)
        small, margin = blur_small(h, sigma_px, f)
        return upsample(self.lighting.shade(*surface_gradients(small, self.mm_per_px * f)), f, margin, self.shape_px)

    def shading_bgr(self, surface_mm: np.ndarray) -> np.ndarray:
        """BGR change (float32) that the LEDs make for a gel surface."""
        if not surface_mm.any():
            return np.zeros((*surface_mm.shape, 3), dtype=np.float32)
        return self.lighting.shade(*surface_gradients(surface_mm, self.mm_per_px))

    def render(self, height_mm: np.ndarray | None = None) -> np.ndarray:
        """The BGR uint8 frame for an indentation ``height_mm`` (None or zeros: no contact)."""
        delta = self.shading_for(height_mm)
        if self._noise is not None:
            noise = self._noise.sample()
            delta = noise if delta is None else cv2.add(delta, noise)
        if self.flicker_sigma > 0:
            flick = self._rng.normal(0.0, self.flicker_sigma, size=3).astype(np.float32)
            delta = np.broadcast_to(flick, (*self.shape_px, 3)).copy() if delta is None else delta + flick
        if delta is None:
            return self.background_bgr.copy()
        # An 8-bit sensor saturates: add, round and clip in one saturating step.
        return cv2.add(self.background_bgr, delta, dtype=cv2.CV_8U)

    def render_object(self, obj: HeightField, press_depth_mm: float, x_mm: float = 0.0, y_mm: float = 0.0,
                      theta_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Render ``obj`` pressed ``press_depth_mm`` past first touch at a pose; returns (frame, indentation_mm)."""
        view = view_in_sensor(obj, self.shape_px, self.mm_per_px, x_mm, y_mm, theta_deg)
        ind = pressed_indentation_mm(view, press_depth_mm, top_height_mm=obj.max_height_mm)
        return self.render(ind), ind

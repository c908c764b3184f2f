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
   matrix :data:`TAXIM_LIGHTING` was fitted by :func:`fit_lighting` on real Taxim ball presses;
   :func:`lighting_from_leds` builds one from explicit LEDs. This is the forward model whose inverse
   a colour-to-gradient calibration learns.
5. **Composite** on a real no-contact frame (``assets/``), add sensor noise and an optional
   global illumination flicker, and clip to 0..255 as an 8-bit sensor saturates.

Everything here is pure and importable without a world; :class:`GelSightRendererModel` (kind
``gelsight_renderer``) reads the object and the stage from a scene.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.sim.base import register_model
from tactile_rig.sim.world.objects import (
    HeightField,
    ObjectModel,
    pressed_indentation_mm,
    view_in_sensor,
)

ASSETS = Path(__file__).resolve().parent.parent / "assets"
BACKGROUNDS: dict[str, tuple[str, float]] = {
    # name -> (file, mm_per_px at the file's native size)
    "taxim": ("taxim_background_120x160.png", 0.1245),
    "gsmini": ("gsmini_background_240x320.png", 0.0634),
    "digit": ("digit_background_320x240.jpg", 0.0405),
}

__all__ = [
    "LightingModel",
    "TAXIM_LIGHTING",
    "TAXIM_NOISE_SIGMA",
    "lighting_from_leds",
    "fit_lighting",
    "load_background",
    "GelSightRenderer",
    "SensorNoise",
    "render_ball_press_dataset",
    "ball_press_height_mm",
    "read_labels",
    "surface_gradients",
    "gaussian_smooth",
    "downsample_factor",
    "GelSightRendererModel",
]


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


class SensorNoise:
    """Gaussian read noise of ``sigma`` grey levels, drawn once and served as random crops.

    Drawing fresh noise for every frame costs more than the rest of the rendering; a random
    window into one larger noise field is statistically the same for a perception test (no two
    consecutive frames share their noise) at the cost of a view.
    """

    MARGIN_PX = 32

    def __init__(self, shape: tuple[int, ...], sigma: float | np.ndarray, rng: np.random.Generator, *,
                 mono: bool = False) -> None:
        """``sigma``: a scalar or one per channel; ``mono``: the same noise in every channel (luminance
        noise, as MJPG's subsampled chroma leaves it)."""
        self.shape = tuple(int(v) for v in shape)
        self._rng = rng
        big = (self.shape[0] + self.MARGIN_PX, self.shape[1] + self.MARGIN_PX, *self.shape[2:])
        if mono and len(big) == 3:
            one = rng.standard_normal(big[:2], dtype=np.float32)
            self._field = np.repeat(one[..., None], big[2], axis=2) * np.asarray(sigma, dtype=np.float32)
        else:
            self._field = rng.standard_normal(big, dtype=np.float32) * np.asarray(sigma, dtype=np.float32)

    def reseed(self, rng: np.random.Generator) -> None:
        """Draw the crops from ``rng`` from now on (the field itself stays: it depends on the seed only)."""
        self._rng = rng

    def sample(self) -> np.ndarray:
        """A (read-only) noise frame of ``shape``: rows are contiguous, so OpenCV takes it without a copy."""
        dy, dx = (int(v) for v in self._rng.integers(0, self.MARGIN_PX + 1, size=2))
        return self._field[dy:dy + self.shape[0], dx:dx + self.shape[1]]


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
        small, margin = _blur_small(h, sigma_px, f)
        return _upsample(self.lighting.shade(*surface_gradients(small, self.mm_per_px * f)), f, margin, self.shape_px)

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


def _blur_small(img: np.ndarray, sigma_px: float, f: int) -> tuple[np.ndarray, int]:
    """``img`` averaged down by ``f`` and blurred so that, upsampled again, it matches a Gaussian of
    ``sigma_px`` at full resolution; returns (small image, margin in small pixels).

    The full image is first padded by ~3σ (replicating its edge, like the full-resolution blur's
    border rule), so the coarse grid's own border handling never reaches the picture.
    """
    rows, cols = img.shape
    m = int(math.ceil(3.0 * sigma_px / f))  # margin in small pixels
    pad = m * f
    padded = cv2.copyMakeBorder(img, pad, pad + (-rows) % f, pad, pad + (-cols) % f, cv2.BORDER_REPLICATE)
    small = cv2.resize(padded, (padded.shape[1] // f, padded.shape[0] // f), interpolation=cv2.INTER_AREA)
    # The box average and the bilinear upsampling each add blur (variance ~ f²/12 px² each).
    sigma_small = math.sqrt(max(sigma_px**2 - f * f / 6.0, (0.5 * f) ** 2)) / f
    return cv2.GaussianBlur(small, (0, 0), sigma_small, borderType=cv2.BORDER_REPLICATE), m


def _upsample(small: np.ndarray, f: int, margin: int, shape_px: tuple[int, int]) -> np.ndarray:
    """Back to full resolution (pixel-centre aligned) and cropped to ``shape_px``."""
    rows, cols = shape_px
    up = cv2.resize(small, (small.shape[1] * f, small.shape[0] * f), interpolation=cv2.INTER_LINEAR)
    pad = margin * f
    return up[pad:pad + rows, pad:pad + cols]


def downsample_factor(sigma_px: float) -> int:
    """How much coarser a Gaussian of ``sigma_px`` can be computed (1: at full resolution)."""
    f = int(sigma_px // 3)
    return f if f >= 2 else 1


def gaussian_smooth(img: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur of a float image; wide kernels run at a lower resolution (the result is smooth,
    so blurring at 1/f scale and interpolating back differs by < 1 % of the peak and is ~f² faster)."""
    f = downsample_factor(sigma_px)
    if f == 1:
        return cv2.GaussianBlur(img, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
    small, margin = _blur_small(img, sigma_px, f)
    return _upsample(small, f, margin, img.shape)


def surface_gradients(surface_mm: np.ndarray, mm_per_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Gradients (gx along columns, gy along rows) in mm/mm: central differences, one-sided on the
    border (as ``np.gradient``), float32."""
    s = np.asarray(surface_mm, dtype=np.float32)
    gx = np.empty_like(s)
    gy = np.empty_like(s)
    inv = np.float32(1.0 / mm_per_px)
    if s.shape[1] >= 2:
        gx[:, 1:-1] = (s[:, 2:] - s[:, :-2]) * (inv / 2)
        gx[:, 0] = (s[:, 1] - s[:, 0]) * inv
        gx[:, -1] = (s[:, -1] - s[:, -2]) * inv
    else:
        gx[:] = 0.0
    if s.shape[0] >= 2:
        gy[1:-1, :] = (s[2:, :] - s[:-2, :]) * (inv / 2)
        gy[0, :] = (s[1, :] - s[0, :]) * inv
        gy[-1, :] = (s[-1, :] - s[-2, :]) * inv
    else:
        gy[:] = 0.0
    return gx, gy


def load_background_array_resized(bg: np.ndarray, shape_px: tuple[int, int]) -> np.ndarray:
    rows, cols = int(shape_px[0]), int(shape_px[1])
    interp = cv2.INTER_AREA if rows < bg.shape[0] else cv2.INTER_LINEAR
    return cv2.resize(bg, (cols, rows), interpolation=interp)


def ball_press_height_mm(shape_px: tuple[int, int], mm_per_px: float, center_xy_px: tuple[float, float],
                         ball_radius_mm: float, contact_radius_px: float) -> np.ndarray:
    """Indentation of a ball whose contact circle has ``contact_radius_px`` (clamped below R)."""
    rows, cols = shape_px
    r_px = ball_radius_mm / mm_per_px
    a_px = min(float(contact_radius_px), 0.999 * r_px)
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float32)
    r2 = (xx - center_xy_px[0]) ** 2 + (yy - center_xy_px[1]) ** 2
    z_px = np.sqrt(np.maximum(r_px * r_px - r2, 0.0)) - math.sqrt(r_px * r_px - a_px * a_px)
    return (np.maximum(z_px, 0.0) * mm_per_px).astype(np.float32)


def fit_lighting(presses_dir: str | Path, *, mm_per_px: float = 0.1245, ball_radius_mm: float = 2.0,
                 files: Sequence[str] | None = None, smoothing_mm: float = 0.6,
                 max_protrusion_mm: float = 1.0, margin_px: int = 4) -> LightingModel:
    """Least-squares fit of the lighting matrix on real ball presses (a ``presses/`` folder).

    Uses the renderer's own geometry (clip, smoothing) on the labelled circles, over the contact
    disc dilated by ``margin_px``.
    """
    presses_dir = Path(presses_dir)
    bg = cv2.imread(str(presses_dir / "background.png"), cv2.IMREAD_COLOR)
    if bg is None:
        raise FileNotFoundError(f"{presses_dir}/background.png is missing")
    r = GelSightRenderer(bg, mm_per_px, smoothing_mm=smoothing_mm, max_protrusion_mm=max_protrusion_mm,
                         noise_sigma=0.0)
    xs, ys = [], []
    for row in read_labels(presses_dir):
        if files is not None and row["file"] not in files:
            continue
        img = cv2.imread(str(presses_dir / row["file"]), cv2.IMREAD_COLOR)
        h = ball_press_height_mm(r.shape_px, mm_per_px, (row["center_x_px"], row["center_y_px"]),
                                 ball_radius_mm, row["contact_radius_px"])
        gx, gy = surface_gradients(r.gel_surface_mm(h), mm_per_px)
        m = cv2.dilate((h > 0).astype(np.uint8), np.ones((2 * margin_px + 1,) * 2, np.uint8)) > 0
        nz1 = 1.0 / np.sqrt(1 + gx * gx + gy * gy) - 1.0
        xs.append(np.stack([gx[m], gy[m], nz1[m]], -1))
        ys.append((img.astype(np.float32) - bg.astype(np.float32))[m])
    if not xs:
        raise ValueError(f"fit_lighting: no presses selected in {presses_dir}")
    mat = np.linalg.lstsq(np.concatenate(xs), np.concatenate(ys), rcond=None)[0]
    return LightingModel(mat)


def read_labels(presses_dir: str | Path) -> list[dict[str, Any]]:
    """Rows of ``labels.csv``: file, center_x_px, center_y_px, contact_radius_px (floats)."""
    with open(Path(presses_dir) / "labels.csv", newline="", encoding="utf-8") as fh:
        return [{"file": r["file"], "center_x_px": float(r["center_x_px"]), "center_y_px": float(r["center_y_px"]),
                 "contact_radius_px": float(r["contact_radius_px"])} for r in csv.DictReader(fh)]


def render_ball_press_dataset(
    out_dir: str | Path,
    *,
    n_presses: int = 20,
    shape_px: tuple[int, int] = (120, 160),
    mm_per_px: float = 0.1245,
    ball_radius_mm: float = 2.0,
    press_depth_mm: tuple[float, float] = (0.4, 0.9),
    background: str | np.ndarray = "taxim",
    border_px: int | None = None,
    seed: int = 0,
    renderer: GelSightRenderer | None = None,
) -> list[dict[str, Any]]:
    """Write a ``presses/``-format data set: background.png, press_NN.png and labels.csv.

    Each press is a ball of ``ball_radius_mm`` pressed a depth drawn from ``press_depth_mm`` (kept
    within the gel's range so the labelled sphere cap is the true shape) at a random centre at
    least ``border_px`` (default: the contact radius) from the edge. ``contact_radius_px`` is the
    geometric contact radius ``sqrt(R² − (R − d)²) / mm_per_px``. Returns the label rows (with
    ``press_depth_mm`` added).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    r = renderer or GelSightRenderer(background, mm_per_px, shape_px=shape_px, seed=rng)
    if r.mm_per_px != mm_per_px or r.shape_px != tuple(shape_px):
        raise ValueError("render_ball_press_dataset: renderer's mm_per_px/shape_px differ from the arguments")
    lo, hi = float(press_depth_mm[0]), float(press_depth_mm[1])
    if not (0 < lo <= hi <= min(ball_radius_mm, r.max_protrusion_mm)):
        raise ValueError(f"press_depth_mm={press_depth_mm!r} must satisfy 0 < lo <= hi <= "
                         f"min(ball radius, gel range) = {min(ball_radius_mm, r.max_protrusion_mm)} mm")
    rows_px, cols_px = r.shape_px
    cv2.imwrite(str(out / "background.png"), r.render(None))
    labels: list[dict[str, Any]] = []
    for i in range(int(n_presses)):
        d = float(rng.uniform(lo, hi))
        a_px = math.sqrt(ball_radius_mm**2 - (ball_radius_mm - d) ** 2) / mm_per_px
        b = a_px if border_px is None else float(border_px)
        if 2 * b >= min(rows_px, cols_px):
            raise ValueError(f"border_px={b:.1f} leaves no room on a {rows_px}x{cols_px} sensor")
        cx = round(float(rng.uniform(b, cols_px - 1 - b)), 1)
        cy = round(float(rng.uniform(b, rows_px - 1 - b)), 1)
        h = ball_press_height_mm(r.shape_px, mm_per_px, (cx, cy), ball_radius_mm, a_px)
        name = f"press_{i:02d}.png"
        cv2.imwrite(str(out / name), r.render(h))
        labels.append({"file": name, "center_x_px": cx, "center_y_px": cy,
                       "contact_radius_px": round(a_px, 2), "press_depth_mm": round(d, 4)})
    with open(out / "labels.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["file", "center_x_px", "center_y_px", "contact_radius_px"])
        for lab in labels:
            w.writerow([lab["file"], lab["center_x_px"], lab["center_y_px"], lab["contact_radius_px"]])
    return labels


# --------------------------------------------------------------------------------------------
# World model


class GelSightRendererModel:
    """Scene model (kind ``gelsight_renderer``): renders what the gel sees of the scene's object.

    Reads, only if present: the object model named ``object`` (an :class:`ObjectModel`: shape,
    ``press_depth_mm`` and its own pose) and the stage named ``stage`` (attributes ``x_mm, y_mm,
    theta_deg`` and, if it has one, ``press_depth_mm`` or ``z_mm`` overriding the object's depth).
    The stage pose is added to the object's pose.
    """

    def __init__(self, world: Any, rng: np.random.Generator, *, background: str = "taxim",
                 shape_px: tuple[int, int] | list[int] | None = None, mm_per_px: float | None = None,
                 object: str = "object", stage: str = "stage", smoothing_mm: float = 0.6,  # noqa: A002
                 max_protrusion_mm: float = 1.0,
                 noise_sigma: float | tuple[float, float, float] | list[float] = TAXIM_NOISE_SIGMA,
                 flicker_sigma: float = 0.0) -> None:
        native = BACKGROUNDS.get(background)
        bg = load_background(background)
        shape = (int(shape_px[0]), int(shape_px[1])) if shape_px is not None else (bg.shape[0], bg.shape[1])
        if mm_per_px is None:
            if native is None:
                raise ValueError(f"gelsight_renderer: mm_per_px is required for background {background!r}")
            mm_per_px = native[1] * bg.shape[0] / shape[0]
        self.world = world
        self.object_name, self.stage_name = object, stage
        self.renderer = GelSightRenderer(bg, float(mm_per_px), shape_px=shape, smoothing_mm=smoothing_mm,
                                         max_protrusion_mm=max_protrusion_mm, noise_sigma=noise_sigma,
                                         flicker_sigma=flicker_sigma, seed=rng)
        self.t_s = 0.0
        self.last_truth: dict[str, Any] = {}

    def advance_to(self, t_s: float) -> None:
        self.t_s = max(self.t_s, float(t_s))

    def reseed(self, rng: np.random.Generator) -> None:
        """The renderer's per-frame noise from ``rng`` from now on (:meth:`GelSightRenderer.reseed`)."""
        self.renderer.reseed(rng)

    def contact_state(self) -> tuple[HeightField | None, float, float, float, float]:
        """(shape, press_depth_mm, x_mm, y_mm, theta_deg) from the scene (shape None: nothing to touch)."""
        obj = self.world.get(self.object_name) if self.world is not None else None
        if not isinstance(obj, ObjectModel):
            return None, 0.0, 0.0, 0.0, 0.0
        depth, x, y, th = obj.press_depth_mm, obj.x_mm, obj.y_mm, obj.theta_deg
        stage = self.world.get(self.stage_name)
        if stage is not None:
            x += float(getattr(stage, "x_mm", 0.0))
            y += float(getattr(stage, "y_mm", 0.0))
            th += float(getattr(stage, "theta_deg", 0.0))
            for attr in ("press_depth_mm", "z_mm"):
                if getattr(stage, attr, None) is not None:
                    depth = float(getattr(stage, attr))
                    break
        return obj.shape, depth, x, y, th

    def render_now(self) -> np.ndarray:
        """Advance the world to its clock's now and render; ground truth goes to ``last_truth``."""
        if self.world is not None:
            self.world.advance_to()
        shape, depth, x, y, th = self.contact_state()
        if shape is None:
            frame, ind = self.renderer.render(None), None
        else:
            frame, ind = self.renderer.render_object(shape, depth, x, y, th)
        self.last_truth = {"indentation_mm": ind, "press_depth_mm": depth, "x_mm": x, "y_mm": y,
                           "theta_deg": th, "t_s": self.t_s}
        return frame


register_model("gelsight_renderer")(GelSightRendererModel)

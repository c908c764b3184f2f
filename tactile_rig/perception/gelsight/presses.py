"""Labelled ball presses: the press folder, the sphere-cap ground truth, and the samples a model learns from.

Press folder format (Taxim pack): ``background.png``, ``press_NN.png`` and ``labels.csv`` with
``file, center_x_px, center_y_px, contact_radius_px`` (x = column, y = row). Slopes are dimensionless
dz/dx, dz/dy with x right, y down and z the indentation height (towards the ball) in mm. A model's
features are (dB, dG, dR, u, v): the frame minus the background / 255 and the position in -1..1.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from tactile_rig.core.errors import CalibrationError
from tactile_rig.perception.gelsight.models import COLOUR_SCALE

__all__ = ["DEFAULT_MAX_RADIUS_FRACTION", "FitOptions", "PressSet", "clamp_radius_px", "load_presses", "marker_mask",
           "pixel_features", "sphere_cap", "training_samples"]

# A labelled contact radius is clamped to this fraction of the ball radius: a contact circle as wide
# as the ball would mean the ball sank to its equator, and the source's labels overshoot the rim.
DEFAULT_MAX_RADIUS_FRACTION = 0.95


@dataclass
class PressSet:
    """Ball presses: background (HxWx3 uint8 BGR), frames, labelled centres (x, y px) and radii (px)."""

    background: np.ndarray
    frames: list[np.ndarray]
    centers_px: np.ndarray
    radii_px: np.ndarray
    names: list[str] = field(default_factory=list)

    def subset(self, indices: list[int] | np.ndarray) -> "PressSet":
        idx = [int(i) for i in indices]
        return PressSet(self.background, [self.frames[i] for i in idx], self.centers_px[idx],
                        self.radii_px[idx], [self.names[i] for i in idx])

    def resized(self, factor: int) -> "PressSet":
        """The same presses upsampled by an integer factor (labels scaled); for tests at other sizes."""
        def up(img: np.ndarray) -> np.ndarray:
            h, w = img.shape[:2]
            return cv2.resize(img, (w * factor, h * factor), interpolation=cv2.INTER_LINEAR)

        return PressSet(up(self.background), [up(f) for f in self.frames],
                        self.centers_px * factor + (factor - 1) / 2.0, self.radii_px * factor,
                        list(self.names))


def _read_bgr(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise CalibrationError(f"cannot read image {path}", device="gelsight.calibration")
    return img


def load_presses(press_dir: str | Path) -> PressSet:
    """Load a press folder (background.png, press images, labels.csv); raises CalibrationError."""
    d = Path(press_dir)
    if (d / "presses").is_dir() and not (d / "labels.csv").exists():
        d = d / "presses"
    labels = d / "labels.csv"
    if not labels.exists() or not (d / "background.png").exists():
        raise CalibrationError(f"{d} must hold background.png and labels.csv", device="gelsight.calibration")
    bg = _read_bgr(d / "background.png")
    frames, centers, radii, names = [], [], [], []
    with open(labels, newline="") as fh:
        for row in csv.DictReader(fh, skipinitialspace=True):
            frame = _read_bgr(d / row["file"])
            if frame.shape != bg.shape:
                raise CalibrationError(f"{row['file']}: shape {frame.shape} differs from the background "
                                       f"{bg.shape}", device="gelsight.calibration")
            frames.append(frame)
            centers.append((float(row["center_x_px"]), float(row["center_y_px"])))
            radii.append(float(row["contact_radius_px"]))
            names.append(row["file"])
    if not frames:
        raise CalibrationError(f"{labels} lists no presses", device="gelsight.calibration")
    return PressSet(bg, frames, np.array(centers, float), np.array(radii, float), names)


def clamp_radius_px(radius_px: float, ball_radius_mm: float, mm_per_px: float,
                    max_fraction: float = DEFAULT_MAX_RADIUS_FRACTION) -> float:
    """The labelled contact radius, clamped to ``max_fraction`` of the ball radius (both in px)."""
    return float(min(radius_px, max_fraction * ball_radius_mm / mm_per_px))


def sphere_cap(shape: tuple[int, int], center_px: tuple[float, float], radius_px: float,
               ball_radius_mm: float, mm_per_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ground truth of a press: height (mm), slopes gx, gy and the inside mask of the contact circle.

    z = sqrt(R^2 - r^2) - sqrt(R^2 - a^2) inside r < a, 0 outside.
    """
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    dx = (xx - center_px[0]) * mm_per_px
    dy = (yy - center_px[1]) * mm_per_px
    r2 = dx * dx + dy * dy
    a = radius_px * mm_per_px
    big_r = ball_radius_mm
    inside = r2 < a * a
    root = np.sqrt(np.maximum(big_r * big_r - r2, 1e-12))
    z = np.where(inside, root - np.sqrt(max(big_r * big_r - a * a, 0.0)), 0.0)
    gx = np.where(inside, -dx / root, 0.0)
    gy = np.where(inside, -dy / root, 0.0)
    return z, gx, gy, inside


def pixel_features(diff_bgr: np.ndarray) -> np.ndarray:
    """(H*W, 5) features: colour difference / 255 and position normalised to -1..1."""
    h, w = diff_bgr.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    u = 2.0 * u / max(w - 1, 1) - 1.0
    v = 2.0 * v / max(h - 1, 1) - 1.0
    return np.concatenate([diff_bgr.reshape(-1, 3).astype(np.float32) / COLOUR_SCALE,
                           u.reshape(-1, 1), v.reshape(-1, 1)], axis=1)


def marker_mask(frame_bgr: np.ndarray, threshold: float = 25.0, blur_px: int = 15) -> np.ndarray:
    """Dark gel markers: pixels darker than their blurred surroundings by more than ``threshold``."""
    grey = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)
    k = blur_px | 1
    local = cv2.GaussianBlur(grey, (k, k), 0)
    return (local - grey) > threshold


@dataclass(frozen=True)
class FitOptions:
    """Which pixels train the model.

    rim_px: pixels within this distance inside the (clamped) contact circle are left out (the label
    is least certain at the rim); outside_px: background pixels farther than this from the circle
    are used with slope 0, subsampled by ``outside_stride``.
    """

    rim_px: float = 2.0
    outside_px: float = 3.0
    outside_stride: int = 3
    max_radius_fraction: float = DEFAULT_MAX_RADIUS_FRACTION
    mask_markers: bool = False


def training_samples(presses: PressSet, mm_per_px: float, ball_radius_mm: float,
                     opts: FitOptions = FitOptions()) -> tuple[np.ndarray, np.ndarray]:
    """Features (N, 5) and slopes (N, 2) from labelled presses."""
    feats, slopes = [], []
    bg = presses.background.astype(np.float32)
    shape = bg.shape[:2]
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    for frame, c, r in zip(presses.frames, presses.centers_px, presses.radii_px):
        a = clamp_radius_px(r, ball_radius_mm, mm_per_px, opts.max_radius_fraction)
        _, gx, gy, _ = sphere_cap(shape, (c[0], c[1]), a, ball_radius_mm, mm_per_px)
        dist = np.hypot(xx - c[0], yy - c[1])
        use = dist < a - opts.rim_px
        outside = (dist > a + opts.outside_px) & (xx % opts.outside_stride == 0) & (yy % opts.outside_stride == 0)
        use |= outside
        if opts.mask_markers:
            use &= ~marker_mask(frame)
        f = pixel_features(frame.astype(np.float32) - bg)
        sel = use.ravel()
        feats.append(f[sel])
        slopes.append(np.stack([gx.ravel()[sel], gy.ravel()[sel]], axis=1))
    return np.concatenate(feats), np.concatenate(slopes).astype(np.float32)

"""Proximity vision: what the camera sees *through* the skin (object area, centroid, orientation, slip).

* A background HSV histogram (``set_background``) and an object histogram learnt from a mask or
  rectangles with the reference's update rule
  ``H+ = min(255, H- + f_gain * max(0, H_def - f_bg * H_bg))`` (histograms scaled so their peak is 255).
* Back-projection of the object histogram on a downsampled frame (after undoing a global light gain),
  threshold, erode/dilate, a closing over the marker bites and hole filling.
* Moments of the mask: area ``M00``, centroid, orientation ``theta = 1/2 atan2(2 mu11, mu20 - mu02)``
  (degrees in (-90, 90], from +x towards +y, i.e. clockwise on screen since y points down); ``None``
  for a round object, whose orientation is undefined. An empty mask is "no object": area 0 and None,
  never NaN.
* Slip: translation of the object pixels between consecutive frames, estimated on a coarse grid by
  iterative Lucas-Kanade over the object region (markers excluded, they do not move with the object),
  after normalising each frame's brightness so light flicker does not look like motion.

Units: pixels of the full-resolution frame (area px^2, positions px, slip px per frame), degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from tactile_rig.core.errors import InvalidFrame
from tactile_rig.perception.fingervision.markers import check_frame_bgr

__all__ = ["ProximityParams", "ObjectMoments", "ProximityResult", "ProximityVision", "object_moments", "estimate_shift"]



@dataclass(frozen=True)
class ProximityParams:
    """Proximity-vision knobs. Morphology sizes are in downsampled pixels."""

    downsample: int = 2
    """Back-projection runs on the frame shrunk by this factor (speed); moments are rescaled."""
    slip_downsample: int = 2
    """Slip runs on the frame shrunk by this factor (the coarse grid; 4 is faster but biased ~15 %)."""
    bins_h: int = 50
    bins_s: int = 10
    bins_v: int = 4
    """Coarse value bins (the reference uses 10): a light change or noise moves fewer pixels across a
    bin edge, which otherwise nibbles the mask and tilts the measured orientation by 2-3 deg."""
    f_bg: float = 1.0
    f_gain: float = 2.5
    backproj_scale: float = 5.0
    threshold: int = 150
    n_erode: int = 1
    n_dilate: int = 1
    close_px: int = 7
    """Closing (downsampled px) after the erode/dilate: wider than a marker seen at that scale."""
    light_compensation: bool = True
    """Scale the HSV value so the frame's median matches the background's (robust to light gain)."""
    fill_holes: bool = True
    """Fill holes inside the object mask (the markers in front of the object punch them)."""
    min_object_area_px: float = 100.0
    """Smaller back-projected areas (full-res px^2) count as no object."""
    round_tolerance: float = 0.03
    """Orientation is undefined when sqrt((mu20-mu02)^2 + 4 mu11^2) / (mu20+mu02) is below this
    (0 for a disc, (a^2-b^2)/(a^2+b^2) for an ellipse of axes a, b: 0.03 is an axis ratio of ~1.03)."""
    slip_threshold_px: float = 0.35
    """Object translation (full-res px per frame) from which slip is reported."""
    slip_min_pixels: int = 12
    """Coarse pixels with texture needed to estimate slip at all."""
    slip_iterations: int = 3


@dataclass(frozen=True)
class ObjectMoments:
    """Object area (px^2), centroid (x, y) px or None, orientation (deg, (-90, 90]) or None."""

    area_px: float
    centroid_px: tuple[float, float] | None
    orientation_deg: float | None


@dataclass(frozen=True)
class ProximityResult:
    """One frame of proximity vision."""

    moments: ObjectMoments
    slip: bool
    slip_magnitude_px: float
    slip_direction_deg: float | None
    mask: np.ndarray
    """Object mask at the downsampled resolution (uint8 0/255)."""


def _median_u8(channel: np.ndarray) -> float:
    """Median of a uint8 image through its histogram (cheaper than a sort)."""
    counts = np.bincount(channel.ravel(), minlength=256)
    return float(np.searchsorted(np.cumsum(counts), (channel.size + 1) // 2))


def object_moments(mask: np.ndarray, scale: float = 1.0, round_tolerance: float = 0.03) -> ObjectMoments:
    """Area, centroid and orientation of a binary mask whose pixels are ``scale`` full-res pixels wide.

    Valid input: any 2-D mask (an empty one is "no object": area 0, centroid and orientation None)."""
    m = cv2.moments(np.ascontiguousarray(mask, dtype=np.uint8), binaryImage=True)
    m00 = m["m00"]
    if not m00 > 0:
        return ObjectMoments(0.0, None, None)
    cx = (m["m10"] / m00 + 0.5) * scale - 0.5
    cy = (m["m01"] / m00 + 0.5) * scale - 0.5
    mu20, mu02, mu11 = m["mu20"] / m00, m["mu02"] / m00, m["mu11"] / m00
    spread = mu20 + mu02
    aniso = math.hypot(mu20 - mu02, 2.0 * mu11) / spread if spread > 0 else 0.0
    theta: float | None = None
    if aniso >= round_tolerance:
        theta = 0.5 * math.degrees(math.atan2(2.0 * mu11, mu20 - mu02))
        if theta <= -90.0:
            theta += 180.0
    return ObjectMoments(float(m00 * scale * scale), (float(cx), float(cy)), theta)


def estimate_shift(
    prev: np.ndarray, cur: np.ndarray, region: np.ndarray, iterations: int = 3, min_pixels: int = 12
) -> tuple[float, float] | None:
    """Translation (dx, dy) in pixels that moves ``prev`` onto ``cur`` over ``region`` (iterative LK).

    Each image is divided by its mean over the region first (robust to a light gain). Returns None
    when the region holds too few textured pixels to tell, or when the solution leaves the image
    (never a non-finite or out-of-frame shift). Valid input: three arrays of one shape.
    """
    if prev.shape != cur.shape or region.shape != cur.shape:
        raise ValueError(f"estimate_shift: shapes differ: prev {prev.shape}, cur {cur.shape}, region {region.shape}")
    reg8 = (region > 0).astype(np.uint8)
    if cv2.countNonZero(reg8) < min_pixels:
        return None
    # work on the region's bounding box only (plus a margin for the gradients and the warp)
    x, y, w, h = cv2.boundingRect(reg8)
    m = 4
    x0, y0, x1, y1 = max(0, x - m), max(0, y - m), min(cur.shape[1], x + w + m), min(cur.shape[0], y + h + m)
    sel = reg8[y0:y1, x0:x1] > 0
    a = prev[y0:y1, x0:x1].astype(np.float32)
    b = cur[y0:y1, x0:x1].astype(np.float32)
    ma, mb = float(a[sel].mean()), float(b[sel].mean())
    if ma <= 1e-3 or mb <= 1e-3:
        return None
    a /= ma
    b /= mb
    gx = cv2.Sobel(b, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(b, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    sx, sy = gx[sel].astype(np.float64), gy[sel].astype(np.float64)
    A = np.array([[sx @ sx, sx @ sy], [sx @ sy, sy @ sy]])
    if np.linalg.det(A) <= 1e-9 * max(1.0, np.trace(A)) ** 2 or np.trace(A) < 1e-6:
        return None
    Ainv = np.linalg.inv(A)
    d = np.zeros(2)
    h, w = b.shape
    for _ in range(max(1, iterations)):
        # warp prev forward by d: warped(x) = prev(x - d); residual against cur
        M = np.array([[1, 0, d[0]], [0, 1, d[1]]], dtype=np.float32)
        warped = cv2.warpAffine(a, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        it = (b - warped)[sel].astype(np.float64)
        step = -Ainv @ np.array([sx @ it, sy @ it])
        d += step
        if not np.all(np.isfinite(d)) or np.hypot(*d) > max(h, w):
            return None
        if np.hypot(*step) < 1e-3:
            break
    return float(d[0]), float(d[1])


class ProximityVision:
    """Object detection by histogram back-projection, moments and slip; see the module docstring."""

    def __init__(self, params: ProximityParams = ProximityParams()) -> None:
        if params.downsample < 1 or params.slip_downsample < 1:
            raise ValueError(
                f"ProximityParams: downsample factors must be >= 1, got {params.downsample}, {params.slip_downsample}"
            )
        self.params = params
        self.bg_hist: np.ndarray | None = None
        self.obj_hist: np.ndarray | None = None
        self._prev_small: np.ndarray | None = None
        self._prev_region: np.ndarray | None = None
        self._luts: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.bg_median_v: float | None = None
        self._bp_table: np.ndarray | None = None

    # -- histograms -----------------------------------------------------------------------------
    def _checked(self, frame_bgr: np.ndarray) -> np.ndarray:
        """The frame as uint8; :class:`InvalidFrame` when it is smaller than 2 x 2 downsampled pixels."""
        f = check_frame_bgr(frame_bgr)
        k = 2 * max(self.params.downsample, self.params.slip_downsample)
        if f.shape[0] < k or f.shape[1] < k:
            raise InvalidFrame(f"frame_bgr: proximity vision needs at least {k}x{k} px at downsample "
                               f"{self.params.downsample}/{self.params.slip_downsample}, got {f.shape[1]}x{f.shape[0]}",
                               device="fingervision.proximity")
        return f

    def _small_hsv(self, frame_bgr: np.ndarray, compensate: bool = True) -> np.ndarray:
        f = self._checked(frame_bgr)
        if f.ndim == 2 or f.shape[2] == 1:
            f = cv2.cvtColor(f.reshape(f.shape[:2]), cv2.COLOR_GRAY2BGR)
        k = self.params.downsample
        if k > 1:
            f = cv2.resize(f, (f.shape[1] // k, f.shape[0] // k), interpolation=cv2.INTER_AREA)
        hsv = cv2.cvtColor(f, cv2.COLOR_BGR2HSV)
        if compensate and self.params.light_compensation and self.bg_median_v is not None:
            # undo a global light gain: the median value of the frame (mostly background) is
            # brought back to the background's, so colours fall in the bins they were learnt in
            med = _median_u8(hsv[:, :, 2])
            if med > 0:
                gain = self.bg_median_v / med
                lut = np.clip(np.arange(256) * gain + 0.5, 0, 255).astype(np.uint8)
                hsv[:, :, 2] = cv2.LUT(hsv[:, :, 2], lut)
        return hsv

    def _bin_index(self, hsv: np.ndarray) -> np.ndarray:
        """Flat histogram bin of every pixel (H in 0..179, S and V in 0..255), via lookup tables."""
        p = self.params
        if self._luts is None:
            ramp = np.arange(256, dtype=np.float64)
            lut_h = np.minimum((ramp * p.bins_h / 180.0).astype(np.int32), p.bins_h - 1)
            lut_s = np.minimum((ramp * p.bins_s / 256.0).astype(np.int32), p.bins_s - 1)
            lut_v = np.minimum((ramp * p.bins_v / 256.0).astype(np.int32), p.bins_v - 1)
            self._luts = (lut_h * p.bins_s * p.bins_v, lut_s * p.bins_v, lut_v)
        lh, ls, lv = self._luts
        if p.bins_s * p.bins_v <= 256 and p.bins_h * p.bins_s * p.bins_v < 65536:
            # cv2.LUT on contiguous planes is several times faster than numpy fancy indexing
            h, sc, v = cv2.split(hsv)
            sv = cv2.add(cv2.LUT(sc, ls.astype(np.uint8)), cv2.LUT(v, lv.astype(np.uint8)))
            hb = cv2.LUT(h, (lh // (p.bins_s * p.bins_v)).astype(np.uint8)).astype(np.uint16)
            return hb * np.uint16(p.bins_s * p.bins_v) + sv
        return lh[hsv[:, :, 0]] + ls[hsv[:, :, 1]] + lv[hsv[:, :, 2]]

    def _hist(self, hsv: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
        """Flat H x S x V histogram scaled so that its peak is 255 (all zeros for an empty mask)."""
        p = self.params
        idx = self._bin_index(hsv)
        if mask is not None:
            idx = idx[mask > 0]
        hist = np.bincount(idx.ravel(), minlength=p.bins_h * p.bins_s * p.bins_v).astype(np.float64)
        peak = float(hist.max()) if hist.size else 0.0
        return hist * (255.0 / peak) if peak > 0 else hist

    def set_background(self, frames_bgr: list[np.ndarray]) -> None:
        """Background histogram: the mean of the histograms of frames with no object behind the skin."""
        if not frames_bgr:
            raise ValueError("set_background: expected at least one frame, got none")
        self.bg_median_v = None
        small = [self._small_hsv(f) for f in frames_bgr]
        self.bg_hist = np.mean([self._hist(h, None) for h in small], axis=0)
        self.bg_median_v = float(np.mean([_median_u8(h[:, :, 2]) for h in small]))

    def learn_object(
        self,
        frame_bgr: np.ndarray,
        mask: np.ndarray | None = None,
        rects: list[tuple[int, int, int, int]] | None = None,
    ) -> None:
        """Add the object seen in ``mask`` (full-res, non-zero = object) or in rects (x, y, w, h) px."""
        hsv = self._small_hsv(frame_bgr)
        k = self.params.downsample
        h, w = hsv.shape[:2]
        if mask is None and rects is None:
            raise ValueError("learn_object: expected a mask or rectangles, got neither")
        small = np.zeros((h, w), np.uint8)
        if mask is not None:
            if mask.shape[:2] != frame_bgr.shape[:2]:
                raise ValueError(f"learn_object: mask shape {mask.shape} != frame shape {frame_bgr.shape[:2]}")
            small = cv2.resize((mask > 0).astype(np.uint8) * 255, (w, h), interpolation=cv2.INTER_NEAREST)
        for x, y, rw, rh in rects or []:
            small[max(0, y // k): max(0, (y + rh) // k), max(0, x // k): max(0, (x + rw) // k)] = 255
        if not np.any(small):
            raise ValueError("learn_object: the mask/rectangles select no pixel of the frame; expected a "
                             "non-empty object region (rectangles as x, y, w, h px inside the frame)")
        h_def = self._hist(hsv, small)
        bg = self.bg_hist if self.bg_hist is not None else np.zeros_like(h_def)
        prev = self.obj_hist if self.obj_hist is not None else np.zeros_like(h_def)
        p = self.params
        self.obj_hist = np.minimum(255.0, prev + p.f_gain * np.maximum(0.0, h_def - p.f_bg * bg))
        self._bp_table = None

    def reset_object(self) -> None:
        self.obj_hist = None
        self._bp_table = None

    # -- per frame ------------------------------------------------------------------------------
    def object_mask(self, frame_bgr: np.ndarray) -> np.ndarray:
        """Back-projected object mask (uint8 0/255) at the downsampled resolution."""
        hsv = self._small_hsv(frame_bgr)
        if self.obj_hist is None:
            return np.zeros(hsv.shape[:2], np.uint8)
        p = self.params
        # back-projection by table look-up (cv2.calcBackProject returned zeros for a 3-D numpy histogram)
        if self._bp_table is None:
            self._bp_table = np.clip(self.obj_hist * p.backproj_scale, 0, 255).astype(np.uint8)
        bp = self._bp_table[self._bin_index(hsv)]
        mask = np.where(bp >= p.threshold, np.uint8(255), np.uint8(0))
        k3 = np.ones((3, 3), np.uint8)
        if p.n_erode:
            mask = cv2.erode(mask, k3, iterations=p.n_erode)
        if p.n_dilate:
            mask = cv2.dilate(mask, k3, iterations=p.n_dilate)
        if p.close_px > 1:
            # bridge the bites markers take out of the object's outline
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE,
                                    cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (p.close_px, p.close_px)))
        if p.fill_holes and np.any(mask):
            # markers (and their shadows) punch holes in the object: fill them so they do not skew the moments
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cv2.drawContours(mask, contours, -1, 255, thickness=cv2.FILLED)
        return mask

    def process(
        self,
        frame_bgr: np.ndarray,
        exclude_px: np.ndarray | None = None,
        exclude_radius_px: float = 6.0,
    ) -> ProximityResult:
        """Object moments and slip in one frame.

        ``exclude_px``: (N, 2) points (markers, which do not move with the object) whose
        neighbourhood of ``exclude_radius_px`` is left out of the slip estimate (non-finite ones are
        ignored). Valid input: frames of at least 2 x downsample px a side (:class:`InvalidFrame`
        otherwise); no object learnt gives "no object" and no slip.
        """
        p = self.params
        mask = self.object_mask(frame_bgr)
        mom = object_moments(mask, float(p.downsample), p.round_tolerance)
        if mom.area_px < p.min_object_area_px:
            mom = ObjectMoments(0.0, None, None)
        # slip on the coarse grid
        f = self._checked(frame_bgr)
        # luminance, not the HSV value: a saturated red channel would flatten an orange object's texture
        gray: np.ndarray = f.reshape(f.shape[:2]) if f.ndim == 2 or f.shape[2] == 1 else cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)
        ks = p.slip_downsample
        sh, sw = int(f.shape[0]) // ks, int(f.shape[1]) // ks
        small = cv2.resize(gray, (sw, sh), interpolation=cv2.INTER_AREA) if ks > 1 else gray.copy()
        region = cv2.resize(mask, (sw, sh), interpolation=cv2.INTER_NEAREST)
        if mom.area_px == 0:
            region[:] = 0
        if exclude_px is not None and len(exclude_px):
            pts = np.asarray(exclude_px, dtype=np.float64).reshape(-1, 2)
            pts = pts[np.isfinite(pts).all(axis=1)]
            k = int(np.ceil(exclude_radius_px / ks))
            cx = np.floor((pts[:, 0] + 0.5) / ks).astype(np.int64)
            cy = np.floor((pts[:, 1] + 0.5) / ks).astype(np.int64)
            offs = np.arange(-k, k + 1)
            xs = np.clip(cx[:, None, None] + offs[None, None, :], 0, sw - 1)
            ys = np.clip(cy[:, None, None] + offs[None, :, None], 0, sh - 1)
            region[np.broadcast_to(ys, (len(pts), 2 * k + 1, 2 * k + 1)),
                   np.broadcast_to(xs, (len(pts), 2 * k + 1, 2 * k + 1))] = 0
        slip, mag, direction = False, 0.0, None
        if self._prev_small is not None and self._prev_small.shape == small.shape and self._prev_region is not None:
            both = cv2.bitwise_or(region, self._prev_region)
            both = cv2.erode(both, np.ones((3, 3), np.uint8))  # keep away from the image border and marker holes
            shift = estimate_shift(self._prev_small, small, both, p.slip_iterations, p.slip_min_pixels)
            if shift is not None:
                dx, dy = shift[0] * ks, shift[1] * ks
                mag = math.hypot(dx, dy)
                direction = math.degrees(math.atan2(dy, dx)) if mag > 0 else None
                slip = mag >= p.slip_threshold_px
        self._prev_small, self._prev_region = small, region
        return ProximityResult(mom, slip, mag, direction, mask)

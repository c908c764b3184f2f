"""Gradients -> height map in mm by Poisson integration (DST Dirichlet, DCT Neumann, Frankot–Chellappa).

Gradients are dimensionless slopes (dz/dx, dz/dy; x right, y down). The height is in mm. Everything
that depends only on the frame shape (eigenvalue denominators, masks, FFT frequencies) is computed once
in :class:`HeightMapper` and reused for every frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np
from scipy import fft as sfft

from tactile_rig.core.errors import GradientOutOfRange
from tactile_rig.core.geometry import pitch_xy_mm

Solver = Literal["dst", "dct", "fc"]
SOLVERS: tuple[str, ...] = ("dst", "dct", "fc")
LOOKUPS: tuple[str, ...] = ("full", "reduced")


def _check_gradients(gx: np.ndarray, gy: np.ndarray) -> None:
    for name, g in (("gx", gx), ("gy", gy)):
        if not isinstance(g, np.ndarray) or g.ndim != 2:
            raise ValueError(f"{name}: expected a 2-D numpy array, got {type(g).__name__} "
                             f"with shape {getattr(g, 'shape', None)}")
        if not np.issubdtype(g.dtype, np.floating) and not np.issubdtype(g.dtype, np.integer):
            raise ValueError(f"{name}: expected a real numeric dtype, got {g.dtype}")
    if gx.shape != gy.shape:
        raise ValueError(f"gx and gy must have the same shape, got {gx.shape} and {gy.shape}")
    if min(gx.shape) < 3:
        raise ValueError(f"gradient maps must be at least 3x3 pixels, got {gx.shape}")


def _sanitise(g: np.ndarray, max_slope: float, name: str) -> np.ndarray:
    """Slopes as a new float32 array (callers may modify it in place), non-finite -> 0; a slope
    beyond +-max_slope raises :class:`GradientOutOfRange` (checked before the cast: no overflow)."""
    g = np.asarray(g)
    if g.dtype != np.float32:
        g = np.nan_to_num(g.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    elif not np.isfinite(g).all():
        g = np.nan_to_num(g, nan=0.0, posinf=0.0, neginf=0.0)
    else:
        g = g.copy()
    lo, hi = cv2.minMaxLoc(g if g.dtype == np.float32 else g.astype(np.float64))[:2]
    peak = max(-lo, hi)
    if peak > max_slope:
        raise GradientOutOfRange(f"{name}: a slope of {peak:.3g} exceeds max_slope={max_slope:g} "
                                 f"({np.degrees(np.arctan(max_slope)):.1f} deg); no gel surface is that steep, "
                                 "so the height would be invented (see IntegrationParams.max_slope)",
                                 device="gelsight.integration", value=float(peak), limit=float(max_slope))
    return g.astype(np.float32, copy=False)


# The automatic downsample keeps the reduced pixel within this pitch (mm).
AUTO_DOWNSAMPLE_PITCH_MM = 0.13


def auto_downsample(mm_per_px_x: float, mm_per_px_y: float | None = None) -> int:
    """The largest integer factor whose reduced pixel stays within AUTO_DOWNSAMPLE_PITCH_MM."""
    pitch = max(float(mm_per_px_x), float(mm_per_px_x if mm_per_px_y is None else mm_per_px_y))
    return max(1, int(AUTO_DOWNSAMPLE_PITCH_MM / pitch + 1e-9))


@dataclass(frozen=True)
class IntegrationParams:
    """Knobs of the integration (see docs/gelsight.md for the measured speed/accuracy trade).

    solver: "dst" (Dirichlet: height 0 on the border), "dct" (Neumann: border slopes honoured, mean 0)
    or "fc" (Frankot–Chellappa, periodic FFT). downsample: integer factor (>=1) applied to the
    gradients before solving (area reduction); the height is upsampled back. None (default): the
    largest factor that keeps the reduced pixel within AUTO_DOWNSAMPLE_PITCH_MM (0.13 mm: a GelSight
    Mini's 0.063 mm pixels are halved, a 0.12 mm sensor is solved at full resolution): the gel's own
    blur (0.5-0.7 mm) leaves nothing finer, and on the real presses the reduced solve is the more
    accurate one (docs/gelsight.md). border_px: slopes within this many pixels
    of the edge are zeroed (vignetted, unreliable border). max_slope: the steepest slope accepted
    (20 = 87 deg; a calibration's slopes stay below tan 1.5 rad ~ 14); a steeper one raises
    :class:`~tactile_rig.core.errors.GradientOutOfRange` instead of being integrated into a height
    of hundreds of mm. lookup (with a downsample > 1; :class:`~.pipeline.Reconstructor`): "full"
    (default) looks every pixel's colour up and area-reduces the slopes; "reduced" area-reduces the frame and
    looks up the reduced pixels only: about 40 % less work a frame at downsample 2, heights within
    1 % of the press depth RMS of "full" on the real presses (the table is not linear in colour, so
    not equal), normals ~0.1 deg worse on presses the calibration never saw (docs/speed_and_accuracy.md).
    """

    solver: str = "dct"
    downsample: int | None = None
    border_px: int = 0
    max_slope: float = 20.0
    lookup: str = "full"

    def __post_init__(self) -> None:
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {self.solver!r}")
        if self.downsample is not None and (int(self.downsample) != self.downsample or self.downsample < 1):
            raise ValueError(f"downsample must be None (auto) or an integer >= 1, got {self.downsample!r}")
        if self.border_px < 0:
            raise ValueError(f"border_px must be >= 0, got {self.border_px!r}")
        if not (self.max_slope > 0):
            raise ValueError(f"max_slope must be > 0, got {self.max_slope!r}")
        if self.lookup not in LOOKUPS:
            raise ValueError(f"lookup must be one of {LOOKUPS}, got {self.lookup!r}")


class HeightMapper:
    """Integrate gradient maps of one fixed shape into height maps in mm, reusing precomputed terms.

    shape: (rows, cols) of the gradient maps. mm_per_px_x / mm_per_px_y: pixel pitch in mm.
    """

    def __init__(self, shape: tuple[int, int], mm_per_px_x: float, mm_per_px_y: float | None = None,
                 params: IntegrationParams | None = None, **knobs: Any) -> None:
        if params is None:
            params = IntegrationParams(**knobs)
        elif knobs:
            raise ValueError("pass either params or individual knobs, not both")
        mm_per_px_y = mm_per_px_x if mm_per_px_y is None else mm_per_px_y
        for name, v in (("mm_per_px_x", mm_per_px_x), ("mm_per_px_y", mm_per_px_y)):
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite number of mm per pixel, got {v!r}")
        rows, cols = int(shape[0]), int(shape[1])
        if rows < 3 or cols < 3:
            raise ValueError(f"shape must be at least 3x3 pixels, got {shape}")
        self.shape = (rows, cols)
        self.params = params
        self.mm_per_px_x = float(mm_per_px_x)
        self.mm_per_px_y = float(mm_per_px_y)
        k = int(params.downsample) if params.downsample is not None else auto_downsample(mm_per_px_x, mm_per_px_y)
        self._k = k
        self._small = (max(3, rows // k), max(3, cols // k))
        # Slopes become height steps per (downsampled) pixel in mm.
        self._sx = np.float32(self.mm_per_px_x * cols / self._small[1])
        self._sy = np.float32(self.mm_per_px_y * rows / self._small[0])
        self._border = None
        if params.border_px > 0:
            b = int(params.border_px)
            border = np.zeros(self.shape, np.float32)
            border[b:rows - b, b:cols - b] = 1.0
            self._border = border
        self._denom = self._make_denominator(*self._small)

    def _make_denominator(self, h: int, w: int) -> np.ndarray:
        solver = self.params.solver
        if solver == "dst":
            # The interior is padded so that n + 1 is FFT-friendly (a 238-point DST-I is 4x slower
            # than a 255-point one); the Dirichlet edge then lies a few pixels beyond the bottom/right.
            ph = sfft.next_fast_len(h - 1, real=True) - 1
            pw = sfft.next_fast_len(w - 1, real=True) - 1
            self._dst_pad = (ph, pw)
            ky = 2.0 * np.cos(np.pi * np.arange(1, ph + 1) / (ph + 1)) - 2.0
            kx = 2.0 * np.cos(np.pi * np.arange(1, pw + 1) / (pw + 1)) - 2.0
            return (ky[:, None] + kx[None, :]).astype(np.float32)
        if solver == "dct":
            ky = 2.0 * np.cos(np.pi * np.arange(h) / h) - 2.0
            kx = 2.0 * np.cos(np.pi * np.arange(w) / w) - 2.0
            d = ky[:, None] + kx[None, :]
            d[0, 0] = 1.0  # the mean is free under Neumann conditions; fixed to 0 below
            self._dct_scale = (0.5 / d).astype(np.float32)  # a multiply is cheaper than a divide
            return d.astype(np.float32)
        wy = 2.0 * np.pi * sfft.fftfreq(h)
        wx = 2.0 * np.pi * sfft.rfftfreq(w)
        d = wy[:, None] ** 2 + wx[None, :] ** 2
        d[0, 0] = 1.0
        self._fc_wx = (1j * wx[None, :]).astype(np.complex64)
        self._fc_wy = (1j * wy[:, None]).astype(np.complex64)
        return d.astype(np.float32)

    def height_mm(self, gx: np.ndarray, gy: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """Height map in mm (float32, same shape as the gradients) from slopes gx = dz/dx, gy = dz/dy.

        Valid input: real 2-D arrays of the mapper's shape with |slope| <= ``max_slope``; non-finite
        slopes are unknown and treated as 0 (flat). A steeper slope raises
        :class:`~tactile_rig.core.errors.GradientOutOfRange`. The result is finite and bounded:
        |z| <= max_slope x (rows x mm_per_px_y + cols x mm_per_px_x).
        mask: optional boolean map; slopes outside it are set to 0 before integration (contact mask).
        """
        _check_gradients(gx, gy)
        if gx.shape != self.shape:
            raise ValueError(f"gradient shape {gx.shape} does not match the mapper's shape {self.shape}")
        p = self.params
        if mask is not None and mask.shape != self.shape:
            raise ValueError(f"mask shape {mask.shape} does not match {self.shape}")
        # Fresh float32 copies from here on: every step below works in place (no temporaries).
        gx = _sanitise(gx, p.max_slope, "gx")
        gy = _sanitise(gy, p.max_slope, "gy")
        if mask is not None:
            np.multiply(gx, mask, out=gx)
            np.multiply(gy, mask, out=gy)
        if self._border is not None:
            gx *= self._border
            gy *= self._border
        if self._k > 1:
            size = (self._small[1], self._small[0])
            return self._solve_reduced(cv2.resize(gx, size, interpolation=cv2.INTER_AREA),
                                       cv2.resize(gy, size, interpolation=cv2.INTER_AREA))
        gx *= self._sx
        gy *= self._sy
        return self._solve(gx, gy)

    def integrate_scaled(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Height map in mm (float32) of slopes the caller has already made safe: finite, within
        ``max_slope`` before scaling, masked, zero on the border and multiplied by the pixel pitch
        (``px = gx * mm_per_px_x``, ``py = gy * mm_per_px_y``); float32 2-D arrays of the mapper's shape
        (views are fine, they are not modified). Only without downsampling (raises ``ValueError``).
        This skips :meth:`height_mm`'s checks and copies for a caller that proved them once, e.g. on
        a calibration table every slope comes from."""
        if self._k != 1:
            raise ValueError("integrate_scaled needs downsample=1 (the slopes are scaled per output pixel)")
        if px.shape != self.shape or py.shape != self.shape:
            raise ValueError(f"slope shapes {px.shape}, {py.shape} do not match the mapper's shape {self.shape}")
        return self._solve(px, py)

    def integrate_reduced(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        """Height map in mm (float32) of slopes the caller has already made safe (finite, within
        ``max_slope``, masked, zero on the border) but not scaled, with downsampling (``ValueError``
        without): :meth:`height_mm`'s own steps after its checks and copies, in its order (area
        reduction, scaling per reduced pixel, the solve, bilinear back), so the same heights."""
        if self._k == 1:
            raise ValueError("integrate_reduced needs downsample > 1 (use integrate_scaled)")
        if gx.shape != self.shape or gy.shape != self.shape:
            raise ValueError(f"slope shapes {gx.shape}, {gy.shape} do not match the mapper's shape {self.shape}")
        size = (self._small[1], self._small[0])
        return self._solve_reduced(cv2.resize(gx, size, interpolation=cv2.INTER_AREA),
                                   cv2.resize(gy, size, interpolation=cv2.INTER_AREA))

    def integrate_reduced_pair(self, gxy: np.ndarray) -> np.ndarray:
        """:meth:`integrate_reduced` of both slopes as one (rows, cols, 2) float32 image (x then y),
        reduced in one pass (the same per-channel area averages)."""
        if self._k == 1:
            raise ValueError("integrate_reduced_pair needs downsample > 1 (use integrate_scaled)")
        if gxy.shape != (*self.shape, 2):
            raise ValueError(f"slope pair shape {gxy.shape} does not match the mapper's {(*self.shape, 2)}")
        small = cv2.resize(gxy, (self._small[1], self._small[0]), interpolation=cv2.INTER_AREA)
        return self._solve_reduced(np.ascontiguousarray(small[..., 0]), np.ascontiguousarray(small[..., 1]))

    def integrate_block_sums(self, sums: np.ndarray, count: int) -> np.ndarray:
        """:meth:`integrate_reduced` of slopes given as their sums over each reduced pixel's block:
        ``sums`` is complex (gx + 1j gy) of the reduced shape, each the sum of ``count`` full-size
        slopes (made safe as for :meth:`integrate_reduced`); only where the blocks tile the map
        exactly (rows and cols multiples of the factor), where it equals the area reduction."""
        if self._k == 1 or self.shape != (self._small[0] * self._k, self._small[1] * self._k):
            raise ValueError(f"integrate_block_sums needs a downsample that tiles {self.shape} exactly")
        if sums.shape != self._small or count != self._k * self._k:
            raise ValueError(f"block sums of shape {sums.shape} over {count} px do not match the reduced "
                             f"shape {self._small} of {self._k} x {self._k} blocks")
        mean = np.float32(1.0 / count)
        return self._solve_reduced(np.multiply(sums.real, mean, dtype=np.float32),
                                   np.multiply(sums.imag, mean, dtype=np.float32))

    def _solve_reduced(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Reduced slopes (modified in place): scaled per reduced pixel, solved, brought back bilinearly."""
        px *= self._sx
        py *= self._sy
        z = self._solve(px, py)
        return cv2.resize(z, (self.shape[1], self.shape[0]), interpolation=cv2.INTER_LINEAR)

    def _solve(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Height steps per pixel -> heights (float32) by the configured solver."""
        solver = self.params.solver
        if solver == "dst":
            z = self._solve_dst(px, py)
        elif solver == "dct":
            z = self._solve_dct(px, py)
        else:
            z = self._solve_fc(px, py)
        return z.astype(np.float32, copy=False)

    def _solve_dst(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        # Slopes averaged onto half-pixels, then differenced: the compact 5-point Laplacian with
        # no half-pixel shift of the result.
        h, w = px.shape
        f = np.zeros(self._dst_pad, np.float32)
        f[: h - 2, : w - 2] = 0.5 * ((px[1:-1, 2:] - px[1:-1, :-2]) + (py[2:, 1:-1] - py[:-2, 1:-1]))
        t = sfft.dstn(f, type=1, workers=1)
        t /= self._denom
        z = np.zeros_like(px)
        z[1:-1, 1:-1] = sfft.idstn(t, type=1, workers=1)[: h - 2, : w - 2]
        return z

    def _solve_dct(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        # Slopes live on the half-pixel between samples; outside flux is the given border slope,
        # which makes the Neumann problem consistent with a DCT-II diagonalisation.
        # The common factor 0.5 of the central differences is folded into the eigenvalues.
        f = np.empty_like(px)
        np.subtract(px[:, 2:], px[:, :-2], out=f[:, 1:-1])
        np.add(px[:, 1], px[:, 0], out=f[:, 0])
        np.add(px[:, -1], px[:, -2], out=f[:, -1])
        f[:, -1] *= -1.0
        f[1:-1, :] += py[2:, :]
        f[1:-1, :] -= py[:-2, :]
        f[0, :] += py[1, :]
        f[0, :] += py[0, :]
        f[-1, :] -= py[-1, :]
        f[-1, :] -= py[-2, :]
        t = sfft.dctn(f, type=2, norm="ortho", workers=1, overwrite_x=True)
        t *= self._dct_scale
        t[0, 0] = 0.0
        return sfft.idctn(t, type=2, norm="ortho", workers=1, overwrite_x=True)

    def _solve_fc(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        fx = sfft.rfft2(px, workers=1)
        fy = sfft.rfft2(py, workers=1)
        num = -(self._fc_wx * fx + self._fc_wy * fy)
        t = num / self._denom
        t[0, 0] = 0.0
        return sfft.irfft2(t, s=px.shape, workers=1)


def height_map_mm(gx: np.ndarray, gy: np.ndarray, mm_per_px: float | tuple[float, float],
                  method: str = "dct", mask: np.ndarray | None = None, **knobs: Any) -> np.ndarray:
    """One-shot height map in mm from slopes (builds a :class:`HeightMapper`; reuse one for video).

    mm_per_px: a scalar or (x, y) pitch in mm per pixel. method: "dst", "dct" or "fc". Valid input,
    bounds and errors as :meth:`HeightMapper.height_mm` (slopes beyond ``max_slope`` raise
    :class:`~tactile_rig.core.errors.GradientOutOfRange`).
    """
    _check_gradients(gx, gy)
    sx, sy = pitch_xy_mm(mm_per_px)
    mapper = HeightMapper(gx.shape, sx, sy, solver=method, **knobs)
    return mapper.height_mm(gx, gy, mask=mask)


def contact_mask(diff_bgr: np.ndarray, height_mm: np.ndarray | None = None,
                 colour_threshold: float = 12.0, height_threshold_mm: float | None = None,
                 close_px: int = 3) -> np.ndarray:
    """Boolean contact mask from the colour distance to the background (and optionally the height).

    diff_bgr: frame minus background (float, 0..255 scale). A pixel is in contact when its colour
    distance exceeds colour_threshold (after a morphological close of close_px) and, when
    height_threshold_mm is given, its height exceeds that threshold.
    """
    if diff_bgr.ndim != 3 or diff_bgr.shape[2] != 3:
        raise ValueError(f"diff_bgr must be HxWx3, got shape {diff_bgr.shape}")
    dist = np.sqrt(np.sum(np.square(diff_bgr, dtype=np.float32), axis=2))
    m = (dist > colour_threshold).astype(np.uint8)
    if close_px > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * close_px + 1, 2 * close_px + 1))
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, k)
    mask = m.astype(bool)
    if height_threshold_mm is not None and height_mm is not None:
        mask &= height_mm > height_threshold_mm
    return mask

"""Frame -> height map in mm: calibrated slopes, contact mask and Poisson integration, precomputed once."""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from tactile_rig.core.errors import HeightOutOfRange
from tactile_rig.perception.gelsight.calibration import (
    MAX_OUT_OF_RANGE_FRACTION,
    MAX_SATURATED_FRACTION,
    GelSightCalibration,
    PackedTable,
    _check_frame,
)
from tactile_rig.perception.gelsight.integration import HeightMapper, IntegrationParams


@dataclass(frozen=True)
class ContactParams:
    """Contact mask knobs: slopes are kept where the colour distance to the background exceeds
    ``colour_threshold`` (0..255 units), grown by ``dilate_px``; ``None`` threshold keeps every slope.
    Heights below ``min_height_mm`` are set to 0 after integration (``None``: keep all).

    Physical bounds (a refusal, not a clip, when broken): ``max_saturated_fraction`` and
    ``max_out_of_range_fraction`` of the frame's pixels may be clipped / beyond the calibration's
    colour range (:meth:`GelSightCalibration.check_range`); the height map's range (max - min) may not
    exceed ``max_height_range_mm``. A gel protrudes about 1 mm, so 3 mm leaves room for the solvers'
    offsets while an all-black or all-white frame (11-15 mm before these checks) is refused.
    """

    colour_threshold: float | None = 10.0
    dilate_px: int = 2
    min_height_mm: float | None = None
    max_saturated_fraction: float = MAX_SATURATED_FRACTION
    max_out_of_range_fraction: float = MAX_OUT_OF_RANGE_FRACTION
    max_height_range_mm: float | None = 3.0

    def __post_init__(self) -> None:
        for name in ("max_saturated_fraction", "max_out_of_range_fraction"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{name} must be a fraction in [0, 1], got {v!r}")
        if self.max_height_range_mm is not None and not self.max_height_range_mm > 0:
            raise ValueError(f"max_height_range_mm must be > 0 mm or None, got {self.max_height_range_mm!r}")
        if self.dilate_px < 0:
            raise ValueError(f"dilate_px must be >= 0, got {self.dilate_px!r}")


class Reconstructor:
    """Reusable frame -> height pipeline for one calibration (all per-shape terms precomputed)."""

    def __init__(self, calibration: GelSightCalibration, integration: IntegrationParams | None = None,
                 contact: ContactParams | None = None) -> None:
        self.calibration = calibration
        self.integration = integration or IntegrationParams()
        self.contact = contact or ContactParams()
        self.mapper = HeightMapper(calibration.shape, calibration.mm_per_px_x, calibration.mm_per_px_y,
                                   params=self.integration)
        d = int(self.contact.dilate_px)
        self._kernel = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * d + 1, 2 * d + 1)) if d > 0 else None)
        h, w = calibration.shape
        k = self.mapper._k
        self._reduced: Reconstructor | None = None
        if self.integration.lookup == "reduced" and k > 1:
            # The reduced frame through this calibration at the reduced pitch: its mask grown and its
            # border zeroed over at least the same distance in mm; the thresholds on heights and the
            # refusals of the whole frame stay here.
            self._reduced = Reconstructor(
                calibration.reduced(k),
                replace(self.integration, downsample=1, lookup="full", border_px=-(-self.integration.border_px // k)),
                replace(self.contact, dilate_px=-(-self.contact.dilate_px // k), min_height_mm=None,
                        max_saturated_fraction=1.0, max_out_of_range_fraction=1.0))
        self._packed = None if self._reduced is not None else self._packed_table()
        self._border_u8: np.ndarray | None = None
        if self.integration.border_px > 0:
            b = int(self.integration.border_px)
            self._border_u8 = np.zeros((h, w), np.uint8)
            self._border_u8[b:h - b, b:w - b] = 255

    def _packed_table(self) -> PackedTable | None:
        """The calibration's packed table, when the fast path gives the same heights (else None).

        Every slope of a frame is then an entry of this table: when all entries are finite and within
        ``max_slope`` (checked here, once), no frame can carry a slope the integration would refuse,
        so its per-frame check (a copy and a min/max of each slope map) is proven and skipped.
        """
        thr = self.contact.colour_threshold
        if thr is not None and not thr < 127:
            return None  # a threshold >= 127 needs |d| > 127, which the key's clipped colours cannot show
        packed = self.calibration.packed_table()
        if packed is None or not packed.peak_slope <= self.integration.max_slope:
            return None
        return packed

    def _max_diff(self, frame_bgr: np.ndarray) -> np.ndarray:
        b, g, r = cv2.split(cv2.absdiff(frame_bgr, self.calibration.background))
        return cv2.max(cv2.max(b, g), r)

    def contact_mask(self, frame_bgr: np.ndarray, max_diff_u8: np.ndarray | None = None) -> np.ndarray | None:
        """Boolean HxW mask of pixels whose colour differs from the background by more than the
        threshold in any channel (max-channel distance), grown by dilate_px (None: no masking)."""
        thr = self.contact.colour_threshold
        if thr is None:
            return None
        if max_diff_u8 is None:
            max_diff_u8 = self._max_diff(frame_bgr)
        _, m = cv2.threshold(max_diff_u8, float(thr), 1, cv2.THRESH_BINARY)
        if self._kernel is not None:
            m = cv2.dilate(m, self._kernel)
        return m.view(bool)

    def height_mm(self, frame_bgr: np.ndarray) -> np.ndarray:
        """Height map in mm (float32, HxW) of a BGR uint8 frame of the calibration's size.

        Valid input: a frame of this sensor whose colours lie within the calibration's range. A
        no-contact frame gives 0 mm everywhere. Raises :class:`~tactile_rig.core.errors.SaturatedFrame`
        (too many clipped pixels: black, white, over-exposed), :class:`GradientOutOfRange` (colours
        beyond the fitted range) or :class:`HeightOutOfRange` (a height range no gel can show), each
        with the measured value and the bound from :class:`ContactParams`; ``ValueError`` for a wrong
        type, dtype or size. The result's range is at most ``max_height_range_mm``.
        """
        if self._reduced is not None:
            return self._height_reduced(frame_bgr)
        if self._packed is not None:
            return self._height_packed(frame_bgr)
        cal = self.calibration
        c = self.contact
        diff = cal.diff(frame_bgr)
        max_diff = self._max_diff(frame_bgr)
        cal.check_range(frame_bgr, max_diff, c.max_saturated_fraction, c.max_out_of_range_fraction)
        gx, gy = cal._evaluate(diff)
        mask = self.contact_mask(frame_bgr, max_diff)
        z = self.mapper.height_mm(gx, gy, mask=mask)
        return self._bounded(z)

    def _bounded(self, z: np.ndarray) -> np.ndarray:
        c = self.contact
        if c.max_height_range_mm is not None:
            lo, hi = cv2.minMaxLoc(z)[:2]
            if hi - lo > c.max_height_range_mm:
                raise HeightOutOfRange(f"the height map spans {hi - lo:.2f} mm ({lo:.2f}..{hi:.2f}); a gel shows "
                                       f"at most {c.max_height_range_mm} mm (ContactParams.max_height_range_mm): "
                                       "the frame is not a contact this calibration can read",
                                       device="gelsight.reconstructor", value=hi - lo, limit=c.max_height_range_mm)
        if c.min_height_mm is not None:
            z = np.where(z > c.min_height_mm, z, np.float32(0))
        return z

    def _refusals(self, frame_bgr: np.ndarray, *diffs: np.ndarray) -> None:
        """The whole-frame refusals (:meth:`GelSightCalibration.check_range`): a frame with no clipped
        byte and no byte of ``diffs`` (|frame - background|, whole or as its positive and negative
        parts) beyond the colour range passes both after a few min/max passes; any other frame is
        counted pixel by pixel."""
        cal = self.calibration
        c = self.contact
        h, w = cal.shape
        limit = min(int(cal.colour_range), 255)
        lo, hi = cv2.minMaxLoc(frame_bgr.reshape(h, w * 3))[:2]
        if lo < 1 or hi > 254 or any(cv2.minMaxLoc(d.reshape(h, w * 3))[1] > limit for d in diffs):
            cal.check_range(frame_bgr, None, c.max_saturated_fraction, c.max_out_of_range_fraction)

    def _height_reduced(self, frame_bgr: np.ndarray) -> np.ndarray:
        """:meth:`height_mm` with ``lookup="reduced"``: the frame area-reduced, reconstructed at the
        reduced pitch, brought back bilinearly. The refusals read the whole frame first (one clipped
        pixel in four would average away)."""
        cal = self.calibration
        h, w = cal.shape
        _check_frame(frame_bgr, cal.shape, "frame_bgr")
        self._refusals(frame_bgr, cv2.absdiff(frame_bgr, cal.background))
        inner = self._reduced
        assert inner is not None
        hs, ws = inner.calibration.shape
        z = inner.height_mm(cv2.resize(frame_bgr, (ws, hs), interpolation=cv2.INTER_AREA))
        return self._bounded(cv2.resize(z, (w, h), interpolation=cv2.INTER_LINEAR))

    def _height_packed(self, frame_bgr: np.ndarray) -> np.ndarray:
        """:meth:`height_mm` through the packed table: the same checks, errors and heights (the
        slopes are the table's entries either way), about a third of the work per frame."""
        cal = self.calibration
        c = self.contact
        p = self._packed
        assert p is not None
        h, w = cal.shape
        _check_frame(frame_bgr, cal.shape, "frame_bgr")
        bg = cal.background
        pos = cv2.subtract(frame_bgr, bg)  # the positive and negative parts of frame - background
        neg = cv2.subtract(bg, frame_bgr)
        self._refusals(frame_bgr, pos, neg)
        # clip(d + 128, 0, 255) per channel, the table's colour coordinate
        b, g, r = cv2.split(cv2.subtract(cv2.add(pos, (128, 128, 128, 0)), neg))
        mask = None
        if c.colour_threshold is not None:
            # |s - 128| is |d| up to 127, so the max-channel threshold (< 127) reads the same pixels.
            dist = cv2.max(cv2.max(cv2.absdiff(b, 128), cv2.absdiff(g, 128)), cv2.absdiff(r, 128))
            _, mask = cv2.threshold(dist, float(c.colour_threshold), 255, cv2.THRESH_BINARY)
            if self._kernel is not None:
                mask = cv2.dilate(mask, self._kernel)
        if self._border_u8 is not None:
            mask = self._border_u8 if mask is None else cv2.bitwise_and(mask, self._border_u8)
        sh, nb = p.shift, p.bits
        wide = 3 * nb > 16  # more than 32 bins: 32-bit keys
        kd = np.uint32 if wide else np.uint16
        key = np.left_shift(np.right_shift(b, sh), 2 * nb, dtype=kd)
        key |= np.left_shift(np.right_shift(g, sh), nb, dtype=kd)
        key |= np.right_shift(r, sh)
        if mask is not None:  # outside the contact the key of a zero difference (slope 0)
            zero = kd(p.zero_key)
            key ^= zero
            key &= cv2.merge((mask,) * (4 if wide else 2)).view(kd).reshape(h, w)  # all ones in contact, else 0
            key ^= zero
        index = np.add(key, p.cell_offset)
        k = self.mapper._k
        if k > 1 and h % k == 0 and w % k == 0:
            # Each reduced pixel's slope is the mean of its k x k pixels' entries: gathered block
            # phase by block phase and summed, the area reduction without the full-size slope image.
            acc = np.take(p.table, index[0::k, 0::k])
            for i in range(k):
                for j in range(k):
                    if i or j:
                        acc += np.take(p.table, index[i::k, j::k])
            return self._bounded(self.mapper.integrate_block_sums(acc, k * k))
        slopes = np.take(p.table, index)
        if k > 1:  # reduced, then scaled per reduced pixel, as the checked path does
            # The complex slopes as a two-channel float32 image: one area reduction for both.
            z = self.mapper.integrate_reduced_pair(slopes.view(np.float32).reshape(h, w, 2))
            return self._bounded(z)
        # Contiguous copies (the solver's differences run faster on them than on strided views),
        # scaled to mm per pixel as the checked path does.
        px = np.ascontiguousarray(slopes.real)
        px *= self.mapper._sx
        py = np.ascontiguousarray(slopes.imag)
        py *= self.mapper._sy
        z = self.mapper.integrate_scaled(px, py)
        return self._bounded(z)

"""Frame -> height map in mm: calibrated slopes, contact mask and Poisson integration, precomputed once."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tactile_rig.perception.gelsight.calibration import GelSightCalibration
from tactile_rig.perception.gelsight.integration import HeightMapper, IntegrationParams


@dataclass(frozen=True)
class ContactParams:
    """Contact mask knobs: slopes are kept where the colour distance to the background exceeds
    ``colour_threshold`` (0..255 units), grown by ``dilate_px``; ``None`` threshold keeps every slope.
    Heights below ``min_height_mm`` are set to 0 after integration (``None``: keep all)."""

    colour_threshold: float | None = 10.0
    dilate_px: int = 2
    min_height_mm: float | None = None


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

    def contact_mask(self, frame_bgr: np.ndarray) -> np.ndarray | None:
        """Boolean HxW mask of pixels whose colour differs from the background by more than the
        threshold in any channel (max-channel distance), grown by dilate_px (None: no masking)."""
        thr = self.contact.colour_threshold
        if thr is None:
            return None
        a = cv2.absdiff(frame_bgr, self.calibration.background)
        b, g, r = cv2.split(a)
        _, m = cv2.threshold(cv2.max(cv2.max(b, g), r), float(thr), 1, cv2.THRESH_BINARY)
        if self._kernel is not None:
            m = cv2.dilate(m, self._kernel)
        return m.view(bool)

    def height_mm(self, frame_bgr: np.ndarray) -> np.ndarray:
        """Height map in mm (float32, HxW) of a BGR uint8 frame."""
        cal = self.calibration
        gx, gy = cal.gradients(frame_bgr)
        mask = self.contact_mask(frame_bgr)
        z = self.mapper.height_mm(gx, gy, mask=mask)
        if self.contact.min_height_mm is not None:
            z = np.where(z > self.contact.min_height_mm, z, np.float32(0))
        return z

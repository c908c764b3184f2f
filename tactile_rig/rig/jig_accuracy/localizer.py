"""The run's view of the bench (:class:`JigRig`: move, touch, truth) and of perception
(:class:`TouchLocalizer`: frame → height map → stage pose in the tactile map)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Protocol

import numpy as np

from tactile_rig.core.errors import CalibrationError
from tactile_rig.core.geometry import Pose
from tactile_rig.perception.gelsight.pipeline import Reconstructor
from tactile_rig.perception.gelsight.registration import RegistrationParams
from tactile_rig.perception.gelsight.tactile_map import TactileMap
from tactile_rig.rig.jig_accuracy.plan import (
    pose_from_touch_matrix,
    touch_matrix_from_pose,
)


class JigRig(Protocol):
    """What a jig accuracy run needs of the bench: move, touch, and (mocks) the truth."""

    def move_to(self, pose: Pose) -> None:
        """Move the jig to ``pose`` and return once it is idle there and settled."""
        ...

    def touch(self) -> np.ndarray:
        """A fresh GelSight frame (BGR uint8) of the object pressed at the current pose."""
        ...

    def truth(self, commanded: Pose) -> Pose:
        """The true pose: the world's stage pose on a mock, ``commanded`` on a bench."""
        ...

    def now_s(self) -> float:
        """The rig's clock (virtual time on mocks)."""
        ...

    def describe(self) -> dict[str, Any]:
        """JSON-able description (kind ``mock`` or ``bench``, devices, scene) for run.json."""
        ...

    # Optional: ``begin_step(step)`` is called before the map is built (step 0) and before each
    # point (step index + 1); a mock reseeds its noise from (seed, step) there, so every point sees
    # the same noise whatever came before it and a resumed run equals an uninterrupted one.


@dataclass
class TouchLocalization:
    """A touch localized in the map: the stage pose estimate (None: refused) and why."""

    pose: Pose | None
    confidence: float
    method: str
    reason: str | None = None
    raw: Any = None


class TouchLocalizer:
    """Frame → height map (calibrated GelSight model) → stage pose in the tactile map.

    The map is a :class:`~tactile_rig.perception.gelsight.tactile_map.TactileMap`: its frame is the
    first touch's sensor frame; later touches join it when their registration confidence exceeds
    ``min_map_confidence`` (the jig's commanded pose is passed as a hint for a dense check when the
    keypoints refuse).
    """

    def __init__(self, calibration: Any, registration: dict[str, Any] | None = None,
                 min_map_confidence: float = 0.98) -> None:
        self.calibration = calibration
        self.reconstructor = Reconstructor(calibration)
        self.params = RegistrationParams(**(registration or {}))
        self.min_map_confidence = float(min_map_confidence)
        mx, my = float(calibration.mm_per_px_x), float(calibration.mm_per_px_y)
        if abs(mx - my) > 1e-6 * max(mx, my):
            raise CalibrationError(f"the tactile map needs square pixels; the calibration has {mx} x {my} mm/px",
                                   device="jig_accuracy")
        self.map = TactileMap(mx, accept_confidence=self.min_map_confidence, params=self.params)
        self.on_height: Callable[[np.ndarray], None] | None = None  # sees every height map (the recording)

    def height_mm(self, frame_bgr: np.ndarray) -> np.ndarray:
        h = self.reconstructor.height_mm(frame_bgr)
        if self.on_height is not None:
            self.on_height(h)
        return h

    @property
    def map_size(self) -> int:
        return len(self.map.poses)

    def add_to_map(self, height_mm: np.ndarray, hint: Pose | None = None) -> TouchLocalization:
        """Add a touch: the first defines the map frame; later ones join when localized with c above threshold."""
        first = self.map.empty
        rec = self.map.add_touch(height_mm, None if hint is None else touch_matrix_from_pose(hint))
        res = rec.result
        if first:
            return TouchLocalization(Pose(), 1.0, "root", None, res)
        if not rec.accepted:
            reason = res.reason or f"confidence {res.confidence:.3f} <= {self.min_map_confidence}"
            return TouchLocalization(None, float(res.confidence), res.method, reason, res)
        assert res.matrix_mm is not None  # an accepted registration always carries its transform
        return TouchLocalization(pose_from_touch_matrix(res.matrix_mm), float(res.confidence), res.method, None, res)

    def localize(self, height_mm: np.ndarray) -> TouchLocalization:
        """The stage pose of a touch in the map frame (refused: ``pose`` None with a reason)."""
        if self.map.empty:
            raise CalibrationError("localize before any map touch", device="jig_accuracy")
        res = self.map.localize(height_mm)
        if not res.ok:
            return TouchLocalization(None, float(res.confidence), res.method, res.reason, res)
        assert res.matrix_mm is not None  # an accepted localization always carries its transform
        return TouchLocalization(pose_from_touch_matrix(res.matrix_mm), float(res.confidence), res.method, None, res)

    def save_map(self, path: str | Path) -> None:
        self.map.save(path)

    def load_map(self, path: str | Path) -> None:
        self.map = TactileMap.load(path, self.params)
"""Small shared values of the rig's sessions: the planar jig pose, angle wrapping, UTC stamps."""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class PlanarPose:
    """A jig / stage pose: millimetres and degrees in image axes (x right, y down, θ clockwise on screen)."""

    x_mm: float = 0.0
    y_mm: float = 0.0
    theta_deg: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return {"x_mm": float(self.x_mm), "y_mm": float(self.y_mm), "theta_deg": float(self.theta_deg)}

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> "PlanarPose | None":
        if d is None:
            return None
        return cls(float(d["x_mm"]), float(d["y_mm"]), float(d["theta_deg"]))


def wrap_deg(angle_deg: Any) -> Any:
    """Angle(s) wrapped into (−180, 180] degrees; a float for a scalar, an array for an array."""
    a = np.asarray(angle_deg, dtype=float)
    w = 180.0 - np.mod(180.0 - a, 360.0)
    return float(w) if w.ndim == 0 else w


def utc_now() -> str:
    """The current UTC time as an ISO 8601 string to the second (calibration and run stamps)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")

"""The model sensor's view of a grasped object: forces, torque, slip and orientation from the
friction model's history (what a FingerVision fingertip would report, calibrated to newtons)."""

from __future__ import annotations

import math
from typing import Any, Callable

from tactile_rig.control.protocols import TouchReading
from tactile_rig.sim.world.friction import GraspedObject


def grasp_probe(obj: GraspedObject, frame_period_s: float, *, slip_threshold_mm: float = 0.05,
                touch_threshold_n: float = 0.05, area_px: float = 2500.0) -> Callable[[float], TouchReading]:
    """``probe(t_s)``: the reading of one fingertip at capture time ``t_s``.

    ``slip`` flags motion over the skin since the previous frame (the slide, or the arc the rotation
    sweeps at the patch radius) above ``slip_threshold_mm``; ``slip_mm`` is the slide alone.
    """

    def probe(t_s: float) -> TouchReading:
        s = obj.state_at(t_s)
        prev = obj.state_at(max(0.0, t_s - frame_period_s))
        visible = bool(s.present)
        normal = s.squeeze_n + s.press_n
        touch = visible and normal > touch_threshold_n
        slid = abs(s.slip_mm - prev.slip_mm)  # translation over the skin (FingerVision: centroid shift)
        turned = obj.patch_mm * abs(math.radians(s.angle_deg - prev.angle_deg))  # arc at the patch edge
        slip = visible and max(slid, turned) > slip_threshold_mm
        return TouchReading(
            t_s=t_s, force_n=(0.0, s.friction_n / 2.0 if touch else 0.0, normal if visible else 0.0),
            torque_nmm=(0.0, 0.0, s.torque_nmm / 2.0 if touch else 0.0), contact=touch, slip=slip,
            slip_mm=slid if visible else 0.0, object_area_px=area_px if visible else 0.0,
            object_centroid_px=(80.0, 60.0) if visible else None,
            object_orientation_deg=s.angle_deg if visible else None)

    return probe


def frame_period_s(sensor_section: dict[str, Any]) -> float:
    return 1.0 / float(sensor_section.get("rate_hz", 30.0))

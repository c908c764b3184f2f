"""GelSight perception over numpy arrays (Li et al. 2014): calibration, height maps, registration, maps.

Typical use::

    cal = calibrate_from_presses("presses/", mm_per_px=0.1245, ball_radius_mm=2.0)
    rec = Reconstructor(cal)                 # precomputes the per-shape terms
    z_mm = rec.height_mm(frame_bgr)          # or: height_map_mm(*cal.gradients(frame), cal.mm_per_px_x)
    res = register(z_a_mm, z_b_mm, mm_per_px=0.1245)
    if res.ok: print(res.rotation_deg, res.translation_mm, res.confidence)
    else: print("refused:", res.reason)
"""

from tactile_rig.perception.gelsight.calibration import (
    FitOptions,
    GelSightCalibration,
    PressSet,
    calibrate_from_presses,
    clamp_radius_px,
    load_presses,
    marker_mask,
    sphere_cap,
)
from tactile_rig.perception.gelsight.integration import (
    HeightMapper,
    IntegrationParams,
    height_map_mm,
)
from tactile_rig.perception.gelsight.models import LutModel, MlpModel, PolyModel
from tactile_rig.perception.gelsight.pipeline import ContactParams, Reconstructor
from tactile_rig.perception.gelsight.registration import (
    INSUFFICIENT_TEXTURE,
    RegistrationParams,
    RegistrationResult,
    extract_features,
    homography_confidence,
    ransac_rigid,
    register,
    render_u8,
)
from tactile_rig.perception.gelsight.report import (
    CalibrationReport,
    cross_validate,
    press_error,
)
from tactile_rig.perception.gelsight.tactile_map import (
    ACCEPT_CONFIDENCE,
    TactileMap,
    TouchRecord,
)

__all__ = [
    "ACCEPT_CONFIDENCE", "CalibrationReport", "ContactParams", "FitOptions", "GelSightCalibration", "HeightMapper",
    "INSUFFICIENT_TEXTURE", "IntegrationParams", "LutModel", "MlpModel", "PolyModel", "PressSet", "Reconstructor",
    "RegistrationParams", "RegistrationResult", "TactileMap", "TouchRecord", "calibrate_from_presses",
    "clamp_radius_px", "cross_validate", "extract_features", "height_map_mm", "homography_confidence",
    "load_presses", "marker_mask", "press_error", "ransac_rigid", "register", "render_u8", "sphere_cap",
]

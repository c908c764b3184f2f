"""FingerVision perception: markers in the skin -> force/torque; the scene through the skin -> object, slip.

Pure numpy/OpenCV over BGR uint8 frames; pixel units unless a scale is given. Entry point:
:class:`FingerVision` (``process(frame_bgr, t_s=None) -> FingerVisionResult``).
"""

from tactile_rig.perception.fingervision.force import (
    ForceParams,
    ForceTorque,
    estimate_force_torque,
)
from tactile_rig.perception.fingervision.lattice import Lattice, LatticeParams, fit_lattice
from tactile_rig.perception.fingervision.markers import (
    Detections,
    MarkerBaseline,
    MarkerDetectorParams,
    ReferenceBlobParams,
    build_baseline,
    contrast_map,
    detect_markers,
    detect_markers_reference,
    refine_centroids,
)
from tactile_rig.perception.fingervision.processor import (
    FingerVision,
    FingerVisionParams,
    FingerVisionResult,
)
from tactile_rig.perception.fingervision.proximity import (
    ObjectMoments,
    ProximityParams,
    ProximityResult,
    ProximityVision,
    estimate_shift,
    object_moments,
)
from tactile_rig.perception.fingervision.tracking import (
    KalmanBank,
    MarkerTracker,
    TrackerParams,
    TrackState,
)

__all__ = [
    "Detections",
    "FingerVision",
    "FingerVisionParams",
    "FingerVisionResult",
    "ForceParams",
    "ForceTorque",
    "KalmanBank",
    "Lattice",
    "LatticeParams",
    "MarkerBaseline",
    "MarkerDetectorParams",
    "MarkerTracker",
    "ObjectMoments",
    "ProximityParams",
    "ProximityResult",
    "ProximityVision",
    "ReferenceBlobParams",
    "TrackState",
    "TrackerParams",
    "build_baseline",
    "contrast_map",
    "detect_markers",
    "detect_markers_reference",
    "estimate_force_torque",
    "estimate_shift",
    "fit_lattice",
    "object_moments",
    "refine_centroids",
]

"""One FingerVision processor: frame (BGR uint8) -> markers, force/torque, object moments, slip.

Markers get their ids on the first frame (``init="lattice"``, the default): the blob detector's
markers are fitted to the skin's marker lattice (:mod:`.lattice`), which drops dark print behind the
skin and finds the markers the detector missed, and the tracker measures every marker from that
frame on. The next ``n_calib_frames`` - 1 frames (no contact) refine the rest positions (the mean of
each marker's measured positions) while the ids already exist; meanwhile results carry
``calibrating=True`` and zero force. ``init="frames"`` is the older scheme kept as a baseline: the
first ``n_calib_frames`` frames build the baseline and report no ids.

After that every frame costs one closing (the contrast map), one vectorised window centroid per
marker, a back-projection on a half-size frame and a few Lucas-Kanade iterations on a half-size
frame; the full-frame blob detector runs only on the first frame.

Valid input: BGR (or grey) frames of at least 16 x 16 px, uint8 (floats are clipped to 0..255, NaN
reads as 0), all of one shape. Outputs are always finite: positions inside the frame, force in px
bounded by the frame size, torque in px^2 bounded by its square.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactile_rig.core.errors import InvalidFrame, MarkersNotFound
from tactile_rig.perception.fingervision.force import ForceParams, estimate_force_torque
from tactile_rig.perception.fingervision.lattice import LatticeParams, extend_lattice, fit_lattice
from tactile_rig.perception.fingervision.markers import (
    Detections,
    MarkerBaseline,
    MarkerDetectorParams,
    build_baseline,
    check_frame_bgr,
    contrast_map,
    detect_in_contrast,
)
from tactile_rig.perception.fingervision.proximity import (
    ProximityParams,
    ProximityVision,
)
from tactile_rig.perception.fingervision.tracking import MarkerTracker, TrackerParams

__all__ = ["FingerVisionParams", "FingerVisionResult", "FingerVision"]

_INITS = ("lattice", "frames")
_MIN_SIDE_PX = 16


@dataclass(frozen=True)
class FingerVisionParams:
    """All parameters of the processor (one dataclass per stage) and of the calibration."""

    detector: MarkerDetectorParams = field(default_factory=MarkerDetectorParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    force: ForceParams = field(default_factory=ForceParams)
    proximity: ProximityParams = field(default_factory=ProximityParams)
    lattice: LatticeParams = field(default_factory=LatticeParams)
    init: str = "lattice"
    """``lattice``: ids from the first frame; ``frames``: ids after ``n_calib_frames`` (the old scheme)."""
    n_calib_frames: int = 10
    """No-contact frames averaged into the baseline (the reference's NCalibPoints); with ``lattice``
    the ids exist from the first of them and these frames only refine the rest positions."""
    late_ids: bool = True
    """With ``lattice``: a marker hidden on the first frame that shows up on an empty lattice node in
    two of the refinement frames (same place) gets the next free id (costs a detector run per
    refinement frame)."""
    n_background_frames: int = 3
    """Of those, frames used for the background histogram (NCalibBGFrames)."""
    baseline_match_px: float = 3.0
    baseline_dist_max_px: float = 0.8
    baseline_size_max_px: float = 1.5
    baseline_min_fraction: float = 0.6
    """A marker found in fewer calibration frames than this fraction is flagged invalid."""
    marker_exclude_margin_px: float = 2.0
    """Marker discs (radius + margin) are left out of the slip estimate."""
    contact_threshold_px: float = 0.3
    """``contact`` is reported when |force_px| reaches this (force units: px unless scaled)."""

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> FingerVisionParams:
        """Build from a nested mapping (a parsed TOML/JSON config): sections ``detector``, ``tracker``,
        ``force``, ``proximity`` plus the top-level calibration keys. Unknown keys are errors."""
        if not isinstance(data, Mapping):
            raise ValueError(f"FingerVision config: expected a table/object, got {type(data).__name__}")
        sections = {f.name: f for f in dataclasses.fields(cls)}
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            if key not in sections:
                raise ValueError(f"FingerVision config: unknown key {key!r}; expected one of {sorted(sections)}")
            default = getattr(cls(), key)
            if dataclasses.is_dataclass(default):
                if not isinstance(value, Mapping):
                    raise ValueError(f"FingerVision config: [{key}] must be a table, got {value!r}")
                known = {f.name for f in dataclasses.fields(default)}
                bad = sorted(set(value) - known)
                if bad:
                    raise ValueError(f"FingerVision config: unknown key(s) {bad} in [{key}]; expected some of {sorted(known)}")
                kwargs[key] = dataclasses.replace(default, **dict(value))  # type: ignore[type-var]  # a dataclass instance
            else:
                kwargs[key] = value
        return cls(**kwargs)


@dataclass(frozen=True)
class FingerVisionResult:
    """Perception output of one frame. Positions are (x, y) pixels; force/torque units: see force.py."""

    t_s: float | None
    calibrating: bool
    marker_ids: np.ndarray
    marker_positions_px: np.ndarray
    marker_sizes_px: np.ndarray
    marker_valid: np.ndarray
    marker_found: np.ndarray
    force_px: np.ndarray
    """(fx, fy, fz) mean marker displacement / size growth, px (a force map on the rig converts to N)."""
    torque_px2: np.ndarray
    """Mean r x f about the image centre, px^2."""
    object_area_px: float
    object_centroid_px: tuple[float, float] | None
    object_orientation_deg: float | None
    """(-90, 90], from +x towards +y (clockwise on screen); None when no object or a round one."""
    slip: bool
    slip_magnitude_px: float
    """Object translation between this frame and the previous one, px per frame."""
    slip_direction_deg: float | None
    """Direction of that translation, degrees from +x towards +y (clockwise on screen); None if none."""
    contact: bool
    """|force_px| >= FingerVisionParams.contact_threshold_px."""
    timings_ms: dict[str, float]

    @property
    def n_markers(self) -> int:
        """Markers measured in this frame."""
        return int(np.count_nonzero(self.marker_found))

    @property
    def slip_magnitude(self) -> float:
        """Alias of ``slip_magnitude_px`` (px per frame)."""
        return self.slip_magnitude_px


class FingerVision:
    """Stateful per-sensor processor; see the module docstring."""

    def __init__(self, params: FingerVisionParams = FingerVisionParams()) -> None:
        if params.n_calib_frames < 1:
            raise ValueError(f"FingerVisionParams.n_calib_frames: expected >= 1, got {params.n_calib_frames}")
        if params.init not in _INITS:
            raise ValueError(f"FingerVisionParams.init: expected one of {_INITS}, got {params.init!r}")
        self.params = params
        self.proximity = ProximityVision(params.proximity)
        self.baseline: MarkerBaseline | None = None
        self.tracker: MarkerTracker | None = None
        self._calib: list[Detections] = []
        self._bg_frames: list[np.ndarray] = []
        self._shape: tuple[int, ...] | None = None
        # running sums of the measured positions/sizes while the baseline refines (lattice init)
        self._refine_left = 0
        self._sum_pos = np.zeros((0, 2))
        self._sum_size = np.zeros(0)
        self._n_seen = np.zeros(0, np.int64)
        # the lattice's indices per marker, its pitch and axis (lattice init), and markers seen on empty
        # nodes during the refinement frames, waiting for a second sighting at the same place
        self._lattice_ij = np.zeros((0, 2), np.int64)
        self._lattice_geom: tuple[tuple[float, float], float] = ((0.0, 0.0), 0.0)
        self._late: dict[tuple[int, int], tuple[np.ndarray, float]] = {}

    # -- calibration -----------------------------------------------------------------------------
    def calibrate(self, frames_bgr: list[np.ndarray]) -> MarkerBaseline:
        """Build the baseline (and the background histogram) from no-contact frames."""
        if not frames_bgr:
            raise ValueError("FingerVision.calibrate: expected at least one frame, got none")
        frames = [self._check(f) for f in frames_bgr]
        self.baseline, self.tracker = None, None
        self._calib, self._bg_frames = [], []
        if self.params.init == "frames":
            for f in frames:
                self._add_calibration_frame(f, *contrast_map(f, self.params.detector))
            base = self._finish_calibration()
        else:
            self._refine_left = 0
            for f in frames:
                self._lattice_step(f, *contrast_map(f, self.params.detector), refine_frames=len(frames))
            base = self._end_refinement()
        if not np.any(base.valid):
            raise MarkersNotFound(
                f"no markers found in {len(frames)} calibration frame(s); expected a lattice of dark dots "
                f"(the frames are black, white, flat or covered?)", device="fingervision")
        return base

    def set_baseline(self, baseline: MarkerBaseline) -> None:
        """Use a known baseline (e.g. loaded from disk) instead of calibrating."""
        self.baseline = baseline
        self.tracker = MarkerTracker(baseline, self.params.tracker)

    def learn_object(self, frame_bgr: np.ndarray, mask: np.ndarray | None = None,
                     rects: list[tuple[int, int, int, int]] | None = None) -> None:
        """Teach the object's colours from a mask or rectangles (see ProximityVision.learn_object)."""
        self.proximity.learn_object(frame_bgr, mask=mask, rects=rects)

    def _add_calibration_frame(self, frame: np.ndarray, value, bg, contrast) -> Detections:
        det = detect_in_contrast(value, bg, contrast, self.params.detector)
        self._calib.append(det)
        if len(self._bg_frames) < self.params.n_background_frames:
            self._bg_frames.append(frame)
        return det

    def _check(self, frame_bgr: np.ndarray) -> np.ndarray:
        try:
            frame = check_frame_bgr(frame_bgr)
        except ValueError as exc:
            raise InvalidFrame(str(exc), device="fingervision") from None
        if frame.shape[0] < _MIN_SIDE_PX or frame.shape[1] < _MIN_SIDE_PX:
            raise InvalidFrame(f"frame_bgr: expected at least {_MIN_SIDE_PX}x{_MIN_SIDE_PX} px, got "
                               f"{frame.shape[1]}x{frame.shape[0]}", device="fingervision")
        if self._shape is not None and frame.shape[:2] != self._shape:
            raise InvalidFrame(
                f"FingerVision.process: frame shape {frame.shape[:2]} differs from the first frame's {self._shape}",
                device="fingervision")
        return frame

    def _lattice_step(self, frame: np.ndarray, value, bg, contrast, refine_frames: int, t_s: float | None = None):
        """Lattice init and refinement for one frame; returns the tracker state (None: no lattice yet)."""
        if self.tracker is None:
            det = detect_in_contrast(value, bg, contrast, self.params.detector)
            lat = fit_lattice(det, contrast, value, self.params.lattice)
            if len(lat) == 0:
                return None
            n = len(lat)
            self.set_baseline(MarkerBaseline(lat.positions_px.copy(), lat.sizes_px.copy(), np.ones(n, bool)))
            self._refine_left = refine_frames
            self._sum_pos, self._sum_size, self._n_seen = np.zeros((n, 2)), np.zeros(n), np.zeros(n, np.int64)
            self._lattice_ij = lat.indices.copy()
            self._lattice_geom = (lat.pitch_px, lat.axis_deg)
            self._late = {}
        elif self._refine_left > 0 and self.params.late_ids:
            self._late_ids(value, bg, contrast)
        tracker = self.tracker
        assert tracker is not None
        # the refinement frames are still by definition: markers are measured around their rest positions
        st = tracker.update(contrast, t_s, at_rest=self._refine_left > 0)
        if self._refine_left > 0:
            if len(self._bg_frames) < self.params.n_background_frames:
                self._bg_frames.append(frame)
            f = st.found
            self._sum_pos[f] += st.positions_px[f]
            self._sum_size[f] += st.sizes_px[f]
            self._n_seen[f] += 1
            self._refine_left -= 1
            if self._refine_left == 0:
                self._end_refinement()
        return st

    def _late_ids(self, value, bg, contrast) -> None:
        """Markers hidden on the first frame that come into view during the refinement frames get ids:
        a detection on an empty node next to the lattice, at the same place (1 px) in two frames."""
        tracker = self.tracker
        assert tracker is not None
        det = detect_in_contrast(value, bg, contrast, self.params.detector)
        pitch, axis = self._lattice_geom
        seen = extend_lattice(self._lattice_ij, tracker.positions_px, det, pitch, axis, self.params.lattice)
        late: dict[tuple[int, int], tuple[np.ndarray, float]] = {}
        new_ij, new_pos, new_size = [], [], []
        for ij, p, size in seen:
            prev = self._late.get(ij)
            if prev is not None and float(np.hypot(*(p - prev[0]))) <= 1.0:
                new_ij.append(ij)
                new_pos.append(p)
                new_size.append(size)
            else:
                late[ij] = (p, size)
        self._late = late
        if new_pos:
            tracker.add_markers(np.array(new_pos), np.array(new_size))
            self.baseline = tracker.baseline
            k = len(new_pos)
            self._lattice_ij = np.vstack([self._lattice_ij, np.array(new_ij, np.int64)])
            self._sum_pos = np.vstack([self._sum_pos, np.zeros((k, 2))])
            self._sum_size = np.concatenate([self._sum_size, np.zeros(k)])
            self._n_seen = np.concatenate([self._n_seen, np.zeros(k, np.int64)])

    def _end_refinement(self) -> MarkerBaseline:
        """Rest positions := mean measured positions of the refinement frames; the ids stay."""
        base = self.baseline if self.baseline is not None else MarkerBaseline(
            np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool))
        if len(self._n_seen) == len(base) and len(base) and self.tracker is not None:
            seen = self._n_seen > 0
            pos = base.positions_px.copy()
            size = base.sizes_px.copy()
            pos[seen] = self._sum_pos[seen] / self._n_seen[seen, None]
            size[seen] = self._sum_size[seen] / self._n_seen[seen]
            # a marker never measured in the refinement frames has no trustworthy rest position
            base = MarkerBaseline(pos, size, base.valid & seen)
            self.baseline = base
            self.tracker.baseline = base
        if self._bg_frames:
            self.proximity.set_background(self._bg_frames)
        self._refine_left = 0
        self._sum_pos, self._sum_size, self._n_seen = np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64)
        self._bg_frames = []
        return base

    def _finish_calibration(self) -> MarkerBaseline:
        p = self.params
        base = build_baseline(self._calib, p.baseline_match_px, p.baseline_dist_max_px,
                              p.baseline_size_max_px, p.baseline_min_fraction)
        self.set_baseline(base)
        if self._bg_frames:
            self.proximity.set_background(self._bg_frames)
        self._calib, self._bg_frames = [], []
        return base

    # -- per frame -------------------------------------------------------------------------------
    def process(self, frame_bgr: np.ndarray, t_s: float | None = None) -> FingerVisionResult:
        """Process one frame; see :class:`FingerVisionResult`. Raises :class:`InvalidFrame` for a frame
        outside the valid input (see the module docstring)."""
        t0 = time.perf_counter()
        frame_bgr = self._check(frame_bgr)
        value, bg, contrast = contrast_map(frame_bgr, self.params.detector)
        self._shape = value.shape[:2]
        t1 = time.perf_counter()
        if self.params.init == "lattice" and (self.tracker is None or self._refine_left > 0):
            st = self._lattice_step(frame_bgr, value, bg, contrast, self.params.n_calib_frames, t_s)
            t2 = time.perf_counter()
            times = {"contrast": (t1 - t0) * 1e3, "track": (t2 - t1) * 1e3, "total": (t2 - t0) * 1e3}
            if st is None:
                z = np.zeros(0)
                return FingerVisionResult(
                    t_s, True, z.astype(np.int64), np.zeros((0, 2)), z, z.astype(bool), z.astype(bool),
                    np.zeros(3), np.zeros(3), 0.0, None, None, False, 0.0, None, False, times)
            return FingerVisionResult(
                t_s, True, st.ids, st.positions_px, st.sizes_px, st.valid, st.found,
                np.zeros(3), np.zeros(3), 0.0, None, None, False, 0.0, None, False, times)
        if self.tracker is None:
            det = self._add_calibration_frame(frame_bgr, value, bg, contrast)
            if len(self._calib) >= self.params.n_calib_frames:
                self._finish_calibration()
            n = len(det)
            t2 = time.perf_counter()
            return FingerVisionResult(
                t_s, True, np.full(n, -1), det.positions_px, det.sizes_px, np.zeros(n, bool), np.ones(n, bool),
                np.zeros(3), np.zeros(3), 0.0, None, None, False, 0.0, None, False,
                {"contrast": (t1 - t0) * 1e3, "detect": (t2 - t1) * 1e3, "total": (t2 - t0) * 1e3},
            )
        st = self.tracker.update(contrast, t_s)
        t2 = time.perf_counter()
        base = self.tracker.baseline
        h, w = value.shape[:2]
        ft = estimate_force_torque(base.positions_px, base.sizes_px, st.positions_px, st.sizes_px,
                                   st.valid, (w, h), self.params.force)
        t3 = time.perf_counter()
        radius = float(np.max(st.sizes_px, initial=0.0)) / 2 + self.params.marker_exclude_margin_px
        prox = self.proximity.process(frame_bgr, st.positions_px, radius)
        t4 = time.perf_counter()
        mom = prox.moments
        return FingerVisionResult(
            t_s, False, st.ids, st.positions_px, st.sizes_px, st.valid, st.found,
            ft.force_px, ft.torque_px2, mom.area_px, mom.centroid_px, mom.orientation_deg,
            prox.slip, prox.slip_magnitude_px, prox.slip_direction_deg,
            bool(np.linalg.norm(ft.force_px) >= self.params.contact_threshold_px),
            {"contrast": (t1 - t0) * 1e3, "track": (t2 - t1) * 1e3, "force": (t3 - t2) * 1e3,
             "proximity": (t4 - t3) * 1e3, "total": (t4 - t0) * 1e3},
        )

"""Perception live from a bench camera: FingerVision tracking and GelSight height maps, frame by frame,
with the frame rate measured as it runs and, optionally, everything on the live view.

:func:`run_live` owns the loop (open the camera, read each new frame, process, report, publish) and
the rate meter; :class:`FingerVisionStep` and :class:`GelSightHeightStep` are the per-frame work.
What a step returns is one JSON-able dict per frame; it is published on
``/perception/<camera>/<step>`` with the frame on ``/<camera>/image/compressed``, and the step's
:meth:`publish` adds its typed views (FingerVision: the markers over the image, their arrows and the
wrench; GelSight: the height map as a point cloud, the localized pose), all through the one mapping
of :mod:`tactile_rig.rig.messages`, so the live view and a recording of the same run look alike.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from tactile_rig.core.errors import CalibrationError
from tactile_rig.perception.fingervision import FingerVision, FingerVisionParams
from tactile_rig.perception.gelsight import GelSightCalibration, IntegrationParams, Reconstructor
from tactile_rig.rig.bench import Bench
from tactile_rig.rig.bench_camera import camera_name, open_camera
from tactile_rig.rig.camera_calibrations import CameraCalibrations, FingerVisionCalibration

RATE_WINDOW = 30  # frames the displayed rate is measured over
TACTILE_MAP_FRAME = "tactile_map"  # the frame of a tactile map's poses (mm, deg)


@dataclass
class RateMeter:
    """Frames per second over the last ``window`` frames, and the mean processing time (ms)."""

    window: int = RATE_WINDOW
    _t: deque = field(default_factory=lambda: deque(maxlen=RATE_WINDOW))
    _work: deque = field(default_factory=lambda: deque(maxlen=RATE_WINDOW))

    def add(self, t_s: float, work_s: float) -> None:
        self._t.append(float(t_s))
        self._work.append(float(work_s))

    @property
    def fps(self) -> float:
        if len(self._t) < 2 or self._t[-1] <= self._t[0]:
            return 0.0
        return (len(self._t) - 1) / (self._t[-1] - self._t[0])

    @property
    def work_ms(self) -> float:
        return 1e3 * sum(self._work) / len(self._work) if self._work else 0.0


class FingerVisionStep:
    """Marker tracking, force and torque, object and slip (:class:`FingerVision`) on each frame.

    With ``calibrations`` (the bench camera's, :func:`camera_calibrations`) the tracker starts from the
    stored marker baseline and a force map turns the marker force (px) into newtons (``force_n``,
    ``force_map_n``; the torque in N·mm with ``mm_per_px``). Without a stored baseline the first
    ``params.n_calib_frames`` frames build it (the skin must be untouched)."""

    name = "fingervision"

    def __init__(self, params: FingerVisionParams | None = None, calibrations: CameraCalibrations | None = None,
                 *, mm_per_px: float | None = None) -> None:
        cal = calibrations.calibration if calibrations is not None else None
        self.fv = cal.processor(params) if isinstance(cal, FingerVisionCalibration) else FingerVision(
            params or FingerVisionParams())
        self.force_map = calibrations.force_map if calibrations is not None else None
        self.mm_per_px = mm_per_px

    def publish(self, sink: Any, camera: str, image: np.ndarray, row: dict[str, Any], t_s: float) -> None:
        """The frame's markers over the image (``/<camera>/markers``), their displacement arrows and the
        net force in the sensor frame (``/<camera>/marker_arrows``, with ``mm_per_px``) and, in newtons,
        the wrench (``/<camera>/wrench``)."""
        force = row.get("force_n")
        sink.write_markers(camera, row["markers_px"], t_s=t_s, displacements_px=row.get("marker_displacements_px"),
                           valid=row.get("marker_valid"), image_size_px=(int(image.shape[1]), int(image.shape[0])),
                           mm_per_px=self.mm_per_px, force_n=force)
        if force is not None:
            sink.write_wrench(camera, force, torque_nmm=row.get("torque_nmm"), t_s=t_s)

    def __call__(self, image: np.ndarray, t_s: float) -> dict[str, Any]:
        r = self.fv.process(image, t_s)
        base = self.fv.tracker.baseline if self.fv.tracker is not None else None
        disp = None
        if base is not None and not r.calibrating:
            disp = (np.asarray(r.marker_positions_px) - np.asarray(base.positions_px)).round(3).tolist()
        out: dict[str, Any] = {"calibrating": r.calibrating, "marker_count": r.n_markers,
                "markers_px": np.asarray(r.marker_positions_px).round(3).tolist(),
                "marker_displacements_px": disp, "marker_valid": np.asarray(r.marker_valid).tolist(),
                "force_px": np.asarray(r.force_px).round(5).tolist(),
                "torque_px2": np.asarray(r.torque_px2).round(4).tolist(), "contact": r.contact, "slip": r.slip,
                "slip_magnitude_px": r.slip_magnitude_px, "object_area_px": r.object_area_px,
                "object_centroid_px": r.object_centroid_px, "timings_ms": r.timings_ms}
        if self.force_map is not None and not r.calibrating:
            f_n, tq_npx, magnitude_n = self.force_map.to_newtons(r.force_px, r.torque_px2)
            out["force_n"] = np.round(f_n, 5).tolist()
            out["force_map_n"] = round(float(magnitude_n), 5)
            if self.mm_per_px is not None:
                out["torque_nmm"] = np.round(tq_npx * self.mm_per_px, 5).tolist()
        return out


class GelSightHeightStep:
    """The height map (mm) of each frame from a GelSight calibration; reports its extremes and the
    contact area (pixels deeper than ``contact_mm``) in mm²; keeps the last map in :attr:`last`."""

    name = "height"

    def __init__(self, calibration: GelSightCalibration, *, contact_mm: float = 0.02,
                 integration: IntegrationParams | None = None) -> None:
        self.rec = Reconstructor(calibration, integration)
        self.mm_per_px = (float(calibration.mm_per_px_x), float(calibration.mm_per_px_y))
        self.mm2_per_px = self.mm_per_px[0] * self.mm_per_px[1]
        self.contact_mm = float(contact_mm)
        self.last: np.ndarray | None = None

    def publish(self, sink: Any, camera: str, image: np.ndarray, row: dict[str, Any], t_s: float) -> None:
        """The frame's height map as a point cloud in the sensor frame (``/<camera>/height/points``)."""
        if self.last is not None:
            sink.write_height(camera, self.last, *self.mm_per_px, t_s=t_s)

    def __call__(self, image: np.ndarray, t_s: float) -> dict[str, Any]:
        h = self.rec.height_mm(image)
        self.last = h
        iy, ix = np.unravel_index(int(np.argmax(h)), h.shape)
        return {"max_height_mm": round(float(h.max()), 5), "min_height_mm": round(float(h.min()), 5),
                "peak_px": [int(ix), int(iy)],
                "contact_area_mm2": round(float(np.count_nonzero(h > self.contact_mm)) * self.mm2_per_px, 4)}


class GelSightLocalizeStep:
    """Where each frame's touch lies in a tactile map (:meth:`TactileMap.localize`): rotation (deg),
    translation (mm), the paper's confidence, or the reason it was refused."""

    name = "localize"

    def __init__(self, calibration: GelSightCalibration, tactile_map: Any) -> None:
        self.rec = Reconstructor(calibration)
        self.map = tactile_map

    def publish(self, sink: Any, camera: str, image: np.ndarray, row: dict[str, Any], t_s: float) -> None:
        """A localized touch as a pose in the tactile map's frame (``/<camera>/localize/pose``)."""
        t = row.get("translation_mm")
        if row.get("ok") and t is not None and row.get("rotation_deg") is not None:
            sink.write_contact_pose(f"{camera}/localize", TACTILE_MAP_FRAME, float(t[0]), float(t[1]),
                                    float(row["rotation_deg"]), t_s=t_s)

    def __call__(self, image: np.ndarray, t_s: float) -> dict[str, Any]:
        return self.map.localize(self.rec.height_mm(image)).as_dict()


def height_image(h: np.ndarray, range_mm: float = 1.0) -> np.ndarray:
    """A height map as an 8-bit colour image for viewing (0..``range_mm`` → the turbo colormap)."""
    u8 = np.clip(h / max(range_mm, 1e-6) * 255.0, 0, 255).astype(np.uint8)
    return cv2.applyColorMap(u8, cv2.COLORMAP_TURBO)


def gelsight_calibration_for(bench: Bench, camera: str, path: str | Path | None) -> GelSightCalibration:
    """``path``, else the bench camera's ``calibration``; CalibrationError naming the command otherwise."""
    cal = path or bench.cameras[camera].calibration
    if cal is None:
        raise CalibrationError(f"{bench.source}: camera [{camera}] names no GelSight calibration; make one with: "
                               f"tactile-rig calibrate gelsight --bench {bench.source} (or pass a calibration file)",
                               device=camera)
    return GelSightCalibration.load(cal)


@dataclass
class LiveSummary:
    camera: str
    step: str
    frames: int
    duration_s: float
    fps: float
    work_ms: float


def run_live(bench: Bench, camera: str | None, step: Callable[[np.ndarray, float], dict[str, Any]], *,
             sensor: str | None = None, duration_s: float | None = None, max_frames: int | None = None,
             live: Any = None, on_frame: Callable[[dict[str, Any]], None] | None = None,
             publish_image: Callable[[np.ndarray], np.ndarray | None] | None = None) -> LiveSummary:
    """Run ``step`` on every new frame of the bench camera until ``duration_s`` or ``max_frames``
    (or Ctrl-C). ``on_frame`` gets each frame's dict with ``frame``, ``t_s``, ``fps`` and
    ``work_ms`` added. With ``live`` (a LiveServer, a Recorder, or a Tee of both), the frame, the dict
    and the step's typed views (its ``publish``) are written (and ``publish_image(image)``'s picture
    on ``/<camera>_<step>/image/compressed`` when it returns one)."""
    name = camera_name(bench, camera, sensor)
    if duration_s is not None and not duration_s > 0:
        raise ValueError(f"duration_s={duration_s!r} must be > 0 s")
    if max_frames is not None and max_frames < 1:
        raise ValueError(f"max_frames={max_frames!r} must be >= 1")
    step_name = getattr(step, "name", "perception")
    meter = RateMeter()
    n = 0
    t_start = None
    with open_camera(bench, name) as rig:
        cam = rig[name]
        timeout = max(2.0, 4.0 / float(cam.config.fps))
        try:
            while True:
                fr = cam.read(timeout_s=timeout)
                t_start = fr.t_host_s if t_start is None else t_start
                w0 = time.perf_counter()
                out = step(fr.image, fr.t_host_s)
                meter.add(fr.t_host_s, time.perf_counter() - w0)
                row = {"frame": n, "t_s": round(fr.t_host_s, 6), "fps": round(meter.fps, 2),
                       "work_ms": round(meter.work_ms, 2), **out}
                if live is not None:
                    live.write_frame(name, fr.image, t_s=fr.t_host_s, compress="jpeg")
                    live.write_perception(f"{name}/{step_name}", row, t_s=fr.t_host_s)
                    if hasattr(step, "publish"):
                        step.publish(live, name, fr.image, out, fr.t_host_s)
                    extra = publish_image(fr.image) if publish_image is not None else None
                    if extra is not None:
                        live.write_frame(f"{name}_{step_name}", extra, t_s=fr.t_host_s, compress="jpeg")
                if on_frame is not None:
                    on_frame(row)
                n += 1
                if max_frames is not None and n >= max_frames:
                    break
                if duration_s is not None and fr.t_host_s - t_start >= duration_s:
                    break
        except KeyboardInterrupt:
            pass
    return LiveSummary(name, step_name, n, round((fr.t_host_s - t_start) if n else 0.0, 4), round(meter.fps, 3),
                       round(meter.work_ms, 3))

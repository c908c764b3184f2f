"""The calibrations a bench names for each camera, loaded by default by every consumer.

A camera table of ``bench.toml`` names its files (relative paths are relative to the bench file)::

    [camera_left]
    sensor = "fingervision"
    calibration = "calib/fingervision.json"     # marker baseline (tactile-rig calibrate fingervision)
    force_map = "calib/force_map"               # marker forces → N (tactile-rig calibrate force-map)
    substance_model = "calib/substance"         # stirring → substance (tactile-rig calibrate substance)

    [camera]
    sensor = "gelsight"
    calibration = "calib/gelsight.npz"          # colour → gradient (tactile-rig calibrate gelsight)

The stable names (:mod:`tactile_rig.rig.calibrations`) always read the newest version. A
``[bench] force_map`` applies to every FingerVision camera without its own.

* :func:`load_fingervision_calibration`: ``calib/fingervision.npz`` + ``.json`` → a
  :class:`FingerVisionCalibration` that a :class:`FingerVision` processor starts from (no rebuilt
  baseline: the first frame is already tracked).
* :func:`camera_calibrations`: everything a bench names for one camera, loaded.
* :class:`CalibratedFingerVision`: a camera + the processor + the force map, a ``TactileSensor``
  whose readings (:class:`~tactile_rig.core.types.TouchReading`) are in newtons and N·mm, and whose
  perception messages in a recording carry ``force_n`` next to ``force_px``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactile_rig.core.errors import CalibrationError, DeviceTimeout
from tactile_rig.rig.files import load_npz
from tactile_rig.core.types import TouchReading
from tactile_rig.perception.fingervision import FingerVision, FingerVisionParams, MarkerBaseline
from tactile_rig.perception.gelsight.calibration import GelSightCalibration
from tactile_rig.rig.calibration_sessions import read_calibration
from tactile_rig.rig.calibrations import version_of
from tactile_rig.rig.learning import ForceMapModel, SubstanceModel, load_force_map, load_substance_model

__all__ = ["FingerVisionCalibration", "CameraCalibrations", "CalibratedFingerVision", "camera_calibrations",
           "describe_files", "load_fingervision_calibration", "load_gelsight_calibration", "DEFAULT_FILES"]

# Where the sessions write by default: used when no bench names a file.
DEFAULT_FILES = {"fingervision": Path("calib/fingervision.json"), "gelsight": Path("calib/gelsight.npz"),
                 "force_map": Path("calib/force_map"), "substance_model": Path("calib/substance")}


@dataclass
class FingerVisionCalibration:
    """A FingerVision marker baseline and proximity-vision background, as the session wrote them."""

    baseline: MarkerBaseline
    bg_hist: np.ndarray | None
    bg_median_v: float | None
    frame_shape: tuple[int, int]
    path: Path
    version: int | None = None

    def apply(self, fv: FingerVision) -> FingerVision:
        """Start ``fv`` from this baseline and background instead of calibrating on its first frames."""
        fv.set_baseline(self.baseline)
        if self.bg_hist is not None:
            fv.proximity.bg_hist = self.bg_hist
            fv.proximity.bg_median_v = self.bg_median_v
        return fv

    def check_frame(self, image: np.ndarray) -> None:
        """CalibrationError when ``image`` is not the size the baseline was made at (another camera
        or another format: its markers would be matched to the wrong rest positions)."""
        if self.frame_shape != (0, 0) and tuple(image.shape[:2]) != self.frame_shape:
            h, w = self.frame_shape
            raise CalibrationError(f"{self.path}: the marker baseline is for {w}x{h} frames, this camera "
                                   f"gives {image.shape[1]}x{image.shape[0]}; re-run: "
                                   "tactile-rig calibrate fingervision", device="fingervision")

    def processor(self, params: FingerVisionParams | None = None) -> FingerVision:
        return self.apply(FingerVision(params or FingerVisionParams()))


def load_fingervision_calibration(path: str | Path) -> FingerVisionCalibration:
    """Read ``calib/fingervision.json`` (or its ``.npz``; the stable name reads the newest version).

    Raises CalibrationError naming the file and the command that makes it.
    """
    p = Path(path)
    js = p.with_suffix(".json") if p.suffix in (".npz", "") else p
    values = read_calibration(js, "fingervision")
    npz = js.with_name(str(values.get("arrays") or js.with_suffix(".npz").name))
    if not npz.is_file():
        # The stable .json link points at name-vN.json whose arrays are name-vN.npz, in the same folder.
        npz = js.resolve().with_name(str(values.get("arrays") or ""))
    if not npz.is_file():
        raise CalibrationError(f"FingerVision calibration arrays {npz} are missing ({js} names them); re-run: "
                               "tactile-rig calibrate fingervision", device="fingervision")
    try:
        z = load_npz(npz, "FingerVision calibration arrays", required=("positions_px", "sizes_px", "valid"),
                     default={"kinds": "biuf", "min_size": 0})
        pos, sizes, valid = z["positions_px"], z["sizes_px"], z["valid"]
        bg = z["bg_hist"] if "bg_hist" in z else np.zeros(0)
    except (OSError, ValueError, KeyError) as exc:
        raise CalibrationError(f"{npz} is not a FingerVision calibration ({exc})", device="fingervision") from None
    n = int(np.asarray(pos).reshape(-1, 2).shape[0])
    if np.asarray(sizes).shape != (n,) or np.asarray(valid).shape != (n,):
        raise CalibrationError(f"{npz}: {n} marker positions but sizes {np.shape(sizes)} and valid "
                               f"{np.shape(valid)}", device="fingervision")
    shape = tuple(int(v) for v in values.get("frame_shape", (0, 0)))[:2]
    median_v = values.get("bg_median_v")
    return FingerVisionCalibration(
        baseline=MarkerBaseline(np.asarray(pos, float).reshape(-1, 2), np.asarray(sizes, float),
                                np.asarray(valid, bool)),
        bg_hist=np.asarray(bg, float) if np.size(bg) else None,
        bg_median_v=None if median_v is None else float(median_v),
        frame_shape=(shape[0], shape[1]) if len(shape) == 2 else (0, 0), path=js, version=version_of(js))


def load_gelsight_calibration(path: str | Path) -> GelSightCalibration:
    """A GelSight calibration (``.npz`` + ``.json``, stable name or a version)."""
    return GelSightCalibration.load(path)


@dataclass
class CameraCalibrations:
    """What is loaded for one camera: its sensor calibration, force map and substance model (or None)."""

    camera: str
    sensor: str
    calibration: Any = None  # FingerVisionCalibration | GelSightCalibration
    force_map: ForceMapModel | None = None
    substance: SubstanceModel | None = None
    files: dict[str, str] = field(default_factory=dict)

    def describe(self) -> dict[str, Any]:
        """Which file each consumer loaded (for outputs and recordings)."""
        return {"camera": self.camera, "sensor": self.sensor, **self.files}


def _first(*paths: Any) -> Path | None:
    for p in paths:
        if p is not None:
            return Path(p)
    return None


def _exists(p: Path) -> bool:
    return p.is_dir() or p.is_file() or p.with_suffix(".json").is_file()


def camera_calibrations(bench: Any = None, camera: str | None = None, *, sensor: str = "fingervision",
                        calibration: str | Path | None = None, force_map: str | Path | None = None,
                        substance_model: str | Path | None = None, defaults: bool = True,
                        load: tuple[str, ...] = ("calibration", "force_map")) -> CameraCalibrations:
    """Load what ``bench`` names for ``camera`` (default: its first camera of ``sensor``).

    Explicit paths win over the bench; without either, the sessions' default files
    (:data:`DEFAULT_FILES`) are used when they exist (``defaults``). A file the bench or the caller
    names must load (CalibrationError otherwise); a default that is absent is skipped. ``load`` says
    which of ``calibration``, ``force_map``, ``substance_model`` to load.
    """
    cfg = None
    if bench is not None:
        cams = bench.cameras
        if camera is None:
            camera = next((n for n, c in cams.items() if c.sensor == sensor), None)
        if camera is not None:
            if camera not in cams:
                raise ValueError(f"{bench.source}: no camera [{camera}] (cameras: {', '.join(cams) or 'none'})")
            cfg = cams[camera]
            sensor = cfg.sensor
    out = CameraCalibrations(camera=camera or "camera", sensor=sensor)
    named = {"calibration": _first(calibration, getattr(cfg, "calibration", None)),
             "force_map": _first(force_map, getattr(cfg, "force_map", None),
                                 getattr(bench, "force_map", None) if sensor == "fingervision" else None),
             "substance_model": _first(substance_model, getattr(cfg, "substance_model", None))}
    default_key = {"calibration": sensor}
    for key in load:
        path = named[key]
        if path is None and defaults:
            d = DEFAULT_FILES[default_key.get(key, key)]
            path = d if _exists(d) else None
        if path is None:
            continue
        if key == "calibration":
            out.calibration = (load_fingervision_calibration(path) if sensor == "fingervision"
                               else load_gelsight_calibration(path))
        elif key == "force_map":
            out.force_map = load_force_map(path)
        else:
            out.substance = load_substance_model(path)
        out.files[key] = str(path)
    return out


class CalibratedFingerVision:
    """A FingerVision camera as a ``TactileSensor``: frames → markers → force in newtons.

    ``camera`` is anything with ``read(timeout_s)`` returning a frame (``.image``, ``.t_host_s``)
    or an image. The processor starts from the stored baseline when one is loaded (otherwise it
    builds one from its first frames, as ``FingerVision`` does). ``mm_per_px`` turns the torque
    into N·mm. ``recorder`` (a :class:`~tactile_rig.rig.recording.Recorder`) gets every result on
    ``/perception/<name>`` with ``force_px``, ``torque_px2`` and, with a force map, ``force_n``,
    ``torque_nmm`` and ``force_map_n``.
    """

    def __init__(self, camera: Any, calibrations: CameraCalibrations, *, params: FingerVisionParams | None = None,
                 mm_per_px: float | None = None, recorder: Any = None, name: str | None = None) -> None:
        self.camera = camera
        self.calibrations = calibrations
        self.name = name or getattr(camera, "name", None) or calibrations.camera
        self.mm_per_px = mm_per_px
        self.recorder = recorder
        cal = calibrations.calibration
        self.fv = cal.processor(params) if isinstance(cal, FingerVisionCalibration) else FingerVision(
            params or FingerVisionParams())
        self.last: dict[str, Any] | None = None
        if recorder is not None:
            recorder.add_metadata(f"calibration.{self.name}", {k: v for k, v in calibrations.describe().items()})

    @property
    def calibrated(self) -> bool:
        """True when forces are in newtons (a force map is loaded)."""
        return self.calibrations.force_map is not None

    def process(self, image: np.ndarray, t_s: float | None = None) -> dict[str, Any]:
        """One frame → a JSON-able result: the FingerVision fields plus newtons when calibrated."""
        if self.last is None and isinstance(self.calibrations.calibration, FingerVisionCalibration):
            self.calibrations.calibration.check_frame(image)
        r = self.fv.process(image, t_s)
        out: dict[str, Any] = {"t_s": t_s, "calibrating": r.calibrating, "marker_count": r.n_markers,
                               "force_px": [float(v) for v in r.force_px],
                               "torque_px2": [float(v) for v in r.torque_px2], "contact": bool(r.contact),
                               "slip": bool(r.slip), "slip_magnitude_px": float(r.slip_magnitude_px),
                               "object_area_px": float(r.object_area_px),
                               "object_centroid_px": r.object_centroid_px,
                               "object_orientation_deg": r.object_orientation_deg}
        fm = self.calibrations.force_map
        if fm is not None and not r.calibrating:
            f_n, tq_npx, mag = fm.to_newtons(r.force_px, r.torque_px2)
            out["force_n"] = [float(v) for v in f_n]
            out["force_map_n"] = mag
            scale = self.mm_per_px if self.mm_per_px is not None else 1.0
            out["torque_nmm" if self.mm_per_px is not None else "torque_npx"] = [float(v * scale) for v in tq_npx]
        if self.recorder is not None:
            self.recorder.write_perception(self.name, out, t_s=t_s)
        self.last = out
        return out

    def read(self, timeout_s: float | None = None) -> TouchReading:
        """The newest frame as a TouchReading: newtons and N·mm with a force map, pixels without."""
        fr = self.camera.read(timeout_s=1.0 if timeout_s is None else timeout_s)
        if fr is None:
            raise DeviceTimeout(f"no frame within {timeout_s} s", device=self.name)
        image = getattr(fr, "image", fr)
        t = getattr(fr, "t_host_s", None)
        d = self.process(np.ascontiguousarray(image), None if t is None else float(t))
        force = d.get("force_n", d["force_px"])
        torque = d.get("torque_nmm", d.get("torque_npx", d["torque_px2"]))
        return TouchReading(t_s=float(t) if t is not None else float("nan"),
                            force_n=tuple(force),
                            torque_nmm=tuple(torque),
                            contact=d["contact"], slip=d["slip"],
                            slip_mm=d["slip_magnitude_px"] * (self.mm_per_px or 1.0),
                            object_area_px=d["object_area_px"], object_centroid_px=d["object_centroid_px"],
                            object_orientation_deg=d["object_orientation_deg"])


def describe_files(cal: CameraCalibrations) -> str:
    """One line naming what was loaded, for human-readable output."""
    if not cal.files:
        return "no calibration files loaded (forces in px)"
    return "; ".join(f"{k}: {v}" for k, v in cal.files.items())

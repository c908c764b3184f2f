"""Checked loaders for the project's own file formats (GelSight calibration, tactile map,
press folders, height maps, FingerVision configs, gripper calibrations).

Each one checks the file with :mod:`tactile_rig.rig.files` (size, dtype, shape, finiteness,
nesting) before the format's own reader sees it, and turns whatever that reader still raises into
a :class:`~tactile_rig.core.errors.BadFile` naming the file, so the command exits 2 with one line.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from tactile_rig.rig import files
from tactile_rig.core.errors import BadFile, CalibrationError, MissingFile
from tactile_rig.drivers.dynamixel.gripper import GripperCalibration
from tactile_rig.perception.fingervision import FingerVisionParams
from tactile_rig.perception.gelsight import GelSightCalibration, Reconstructor, TactileMap, load_presses
from tactile_rig.perception.gelsight.calibration import CALIBRATION_FILE
from tactile_rig.perception.gelsight.models import MODELS
from tactile_rig.perception.gelsight.tactile_map import MAP_FILE

__all__ = ["load_height_mm", "read_frame", "load_gelsight_calibration", "load_tactile_map", "load_press_folder",
           "load_config_mapping", "load_fingervision_params", "load_gripper_calibration", "check_settings", "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
MAX_PRESSES = 10000


def load_height_mm(path: str | Path) -> np.ndarray:
    """A 2-D height map (mm, ``.npy``, real and finite) as float32."""
    p = files.check_file(path, "height map", suffixes=(".npy",))
    arr = files.load_npy(p, "height map (mm)", ndim=2, finite=True)
    if min(arr.shape) < 8:
        raise BadFile(p, f"height map (mm) is only {arr.shape[0]}x{arr.shape[1]} px", "at least 8x8 px")
    return arr.astype(np.float32)


def read_frame(path: str | Path, what: str = "frame") -> np.ndarray:
    """A BGR frame, its header's size bounded before OpenCV decodes it."""
    return files.read_image(path, what)


def _calibration_paths(path: str | Path) -> tuple[Path, Path, Path]:
    base = Path(path)
    if base.suffix in (".npz", ".json"):
        base = base.with_suffix("")
    return base, base.with_suffix(".json"), base.with_suffix(".npz")


def load_gelsight_calibration(path: str | Path) -> GelSightCalibration:
    """A GelSight calibration (``.json`` + ``.npz``), both files checked before use and the model
    run once on its own background so a calibration of inconsistent shapes is refused here."""
    base, jpath, npath = _calibration_paths(path)
    if not jpath.exists() and not npath.exists():
        raise MissingFile(base, "GelSight calibration (.json + .npz)")
    meta = CALIBRATION_FILE.check(files.load_json(jpath, "GelSight calibration metadata"), jpath)
    if meta.get("model") not in MODELS:
        raise BadFile(jpath, f"GelSight calibration metadata has model={meta.get('model')!r}",
                      "one of " + ", ".join(sorted(MODELS)))
    for key in ("mm_per_px_x", "mm_per_px_y", "ball_radius_mm"):
        v = meta.get(key)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not 0 < float(v) < 1e3:
            raise BadFile(jpath, f"GelSight calibration metadata has {key}={v!r}", "a positive number of mm")
    arrays = files.load_npz(npath, "GelSight calibration arrays", required=("background",),
                            arrays={"background": {"kinds": "u", "ndim": 3, "shape": (None, None, 3)}},
                            default={"kinds": "biuf", "finite": True, "min_size": 1})
    bg = arrays["background"]
    files.check_image_dims(npath, "GelSight calibration background", bg.shape[1], bg.shape[0])
    if bg.dtype != np.uint8:
        raise BadFile(npath, f"GelSight calibration background has dtype {bg.dtype}", "uint8 BGR")
    with files.checked(npath, "GelSight calibration", "a calibration written by 'tactile-rig gelsight calibrate'"):
        try:
            cal = GelSightCalibration.from_saved(meta, arrays, str(jpath), str(npath))  # the files read once
        except CalibrationError as exc:  # the metadata is checked above: what is left is in the arrays
            msg = str(exc.args[0])
            problem = msg[len(f"{npath}: "):] if msg.startswith(f"{npath}: ") else msg
            raise BadFile(npath, problem, "the arrays of the model the metadata names") from None
        # A smoke run: a model whose arrays do not fit together fails here, naming the file.
        Reconstructor(cal).height_mm(cal.background)
    return cal


def load_tactile_map(path: str | Path, params: Any = None) -> TactileMap:
    """A tactile map (``.npz`` from ``gelsight map``), arrays and metadata checked before use."""
    p = files.check_file(path, "tactile map", suffixes=(".npz",))
    arrays = files.load_npz(p, "tactile map", required=("total", "count", "g_T_m", "meta"),
                            arrays={"meta": {"kinds": "U", "ndim": 0, "finite": False},
                                    "total": {"ndim": 2}, "count": {"ndim": 2},
                                    "g_T_m": {"ndim": 3, "shape": (None, 2, 3), "min_size": 0}})
    if arrays["total"].shape != arrays["count"].shape:
        raise BadFile(p, f"tactile map total {arrays['total'].shape} and count {arrays['count'].shape} differ",
                      "arrays of one shape")
    meta = MAP_FILE.check(files.loads_json(str(arrays["meta"]), p, "tactile map metadata"), p)
    for key, lo, hi in (("mm_per_px", 1e-6, 100.0), ("canvas_factor", 1.0, 100.0), ("accept_confidence", 0.0, 1.0)):
        v = meta.get(key)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not lo <= float(v) <= hi:
            raise BadFile(p, f"tactile map metadata has {key}={v!r}", f"a number in [{lo:g}, {hi:g}]")
    ts = meta.get("touch_shape")
    if ts is not None and not (isinstance(ts, list) and len(ts) == 2 and all(
            isinstance(v, int) and not isinstance(v, bool) and 8 <= v <= files.MAX_IMAGE_SIDE_PX for v in ts)):
        raise BadFile(p, f"tactile map metadata has touch_shape={ts!r}", "[rows, cols] in 8..16384 px, or null")
    with files.checked(p, "tactile map", "a map written by 'tactile-rig gelsight map'"):
        return TactileMap.load(p, params=params)


def load_press_folder(press_dir: str | Path) -> Any:
    """A ball-press folder (``background.png``, press images, ``labels.csv``): every image header and
    label checked before the press loader decodes anything."""
    d = Path(press_dir)
    if not d.exists():
        raise MissingFile(d, "press folder")
    if not d.is_dir():
        raise BadFile(d, "press folder is a file", "a folder with background.png and labels.csv")
    if (d / "presses").is_dir() and not (d / "labels.csv").exists():
        d = d / "presses"
    labels = files.check_file(d / "labels.csv", "press labels", max_bytes=files.MAX_TEXT_BYTES)
    bg = d / "background.png"
    w, h, _ = files.check_image_file(bg, "background frame")
    with files.checked(labels, "press labels", "CSV columns file, center_x_px, center_y_px, contact_radius_px"):
        rows = list(csv.DictReader(labels.read_text(encoding="utf-8").splitlines(), skipinitialspace=True))
    if len(rows) > MAX_PRESSES:
        raise BadFile(labels, f"press labels list {len(rows)} presses", f"at most {MAX_PRESSES}")
    for i, row in enumerate(rows, start=2):
        name = row.get("file")
        if not name or Path(name).is_absolute() or ".." in Path(name).parts:
            raise BadFile(labels, f"line {i}: file {name!r}", "an image name inside the press folder")
        for key in ("center_x_px", "center_y_px", "contact_radius_px"):
            try:
                v = float(row.get(key) or "")
            except ValueError:
                raise BadFile(labels, f"line {i}: {key}={row.get(key)!r}", "a number of pixels") from None
            if not np.isfinite(v) or not -1e5 < v < 1e5 or (key == "contact_radius_px" and v <= 0):
                raise BadFile(labels, f"line {i}: {key}={v!r}", "a finite pixel value (radius > 0)")
        fw, fh, _ = files.check_image_file(d / name, f"press frame {name}")
        if (fw, fh) != (w, h):
            raise BadFile(d / name, f"press frame is {fw}x{fh} px", f"the background's {w}x{h} px")
    with files.checked(d, "press folder", "background.png, press images and labels.csv"), files.quiet_opencv():
        try:
            return load_presses(d)
        except CalibrationError as exc:
            raise BadFile(d, str(exc).split(": ", 1)[-1], "background.png, press images and labels.csv") from None


MAX_SETTING = 1e6  # no FingerVision or registration setting is a million of its unit


def check_settings(data: Any, default: Any, path: str | Path, where: str = "") -> None:
    """Check a parsed settings mapping against a dataclass of defaults: each value of the default's
    type (an int for an int, a finite number for a float, a list of the same length), not negative
    where the default is not, and at most a million in size. Unknown keys are left to the class."""
    p = Path(path)
    if not dataclasses.is_dataclass(default) or not isinstance(data, Mapping):
        return
    for key, value in data.items():
        if not hasattr(default, key):
            continue
        d = getattr(default, key)
        name = f"{where}{key}"
        if dataclasses.is_dataclass(d):
            if not isinstance(value, Mapping):
                raise BadFile(p, f"[{name}] is {value!r}", f"a table of {type(d).__name__} settings")
            check_settings(value, d, p, f"{name}.")
            continue
        _check_setting(p, name, value, d)


def _check_setting(p: Path, name: str, value: Any, d: Any) -> None:
    if isinstance(d, bool) or d is None:
        if isinstance(d, bool) and not isinstance(value, bool):
            raise BadFile(p, f"{name} = {value!r}", "true or false")
        return
    if isinstance(d, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise BadFile(p, f"{name} = {value!r}", f"a number like {d!r}")
        if isinstance(d, int) and not isinstance(value, int):
            raise BadFile(p, f"{name} = {value!r}", f"a whole number like {d!r}")
        if not math.isfinite(value) or abs(value) > MAX_SETTING:
            raise BadFile(p, f"{name} = {value!r}", f"a finite number of magnitude at most {MAX_SETTING:g}")
        if d >= 0 and value < 0:
            raise BadFile(p, f"{name} = {value!r}", f"a number >= 0 (default {d!r})")
        return
    if isinstance(d, str):
        if not isinstance(value, str):
            raise BadFile(p, f"{name} = {value!r}", f"a string like {d!r}")
        return
    if isinstance(d, (tuple, list)):
        if not isinstance(value, (list, tuple)) or (len(d) and len(value) != len(d)):
            raise BadFile(p, f"{name} = {value!r}", f"a list of {len(d)} values like {list(d)!r}")
        for i, (v, dv) in enumerate(zip(value, d)):
            _check_setting(p, f"{name}[{i}]", v, dv)


def load_fingervision_params(path: str | Path | None, calib_frames: int | None = None,
                             init: str | None = None) -> FingerVisionParams:
    """FingerVisionParams from a TOML/JSON file (or the defaults), every value checked first; the
    command line's ``calib_frames`` and ``init`` override the file's."""
    data: dict[str, Any] = {}
    if path:
        data = load_config_mapping(path, "FingerVision config")
        check_settings(data, FingerVisionParams(), path)
    if calib_frames is not None:
        data = {**data, "n_calib_frames": calib_frames}
    if init is not None:
        data = {**data, "init": init}
    if not path:
        return FingerVisionParams.from_mapping(data)
    with files.checked(path, "FingerVision config",
                       "sections detector, tracker, force, proximity, lattice of FingerVisionParams"):
        return FingerVisionParams.from_mapping(data)


def load_gripper_calibration(path: str | Path) -> GripperCalibration:
    """A gripper calibration JSON (``closed_ticks``, ``open_ticks``, ``max_opening_m``, optionally
    under ``calibration``), each value checked against the type of its default."""
    data = files.load_json(path, "gripper calibration")
    data = data.get("calibration", data)
    if not isinstance(data, dict):
        raise BadFile(path, "gripper calibration's 'calibration' is not an object", "a JSON object")
    keys = {"closed_ticks", "open_ticks", "max_opening_m"}
    unknown, missing = sorted(set(data) - keys), sorted(keys - set(data))
    if missing:
        raise BadFile(path, f"gripper calibration lacks {', '.join(missing)}", "closed_ticks, open_ticks, max_opening_m")
    if unknown:
        raise BadFile(path, f"gripper calibration has unknown key(s) {unknown}", "closed_ticks, open_ticks, max_opening_m")
    check_settings(data, GripperCalibration(), path)
    with files.checked(path, "gripper calibration", "closed_ticks, open_ticks, max_opening_m"):
        try:
            return GripperCalibration(**data)
        except CalibrationError as exc:
            raise BadFile(path, f"gripper calibration {exc}", "distinct closed and open ticks, an opening > 0 m") from None


def load_config_mapping(path: str | Path, what: str = "config") -> dict[str, Any]:
    """A JSON or TOML file of settings as a mapping (bounded size and depth)."""
    p = Path(path)
    if p.suffix.lower() == ".json":
        return files.load_json(p, what)
    data, _ = files.load_toml(p, what)
    return data

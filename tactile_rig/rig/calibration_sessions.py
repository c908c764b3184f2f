"""Calibration sessions: collect the data on the rig, fit, and write a versioned calibration with its report.

Each session is guided on a terminal (it says what to do and waits for Enter) and scriptable
elsewhere (no prompt when stdin is not a TTY; every input has a command-line value). Every session
writes ``<out>.json`` (or, for GelSight, ``<out>.npz`` + ``<out>.json`` from
:meth:`GelSightCalibration.save`) and a report ``<out>.report.json`` + ``<out>.report.md``.

* **Scale** (:func:`scale_session`): tare the empty scale, put a known mass on it, calibrate
  (the factor is stored in the sketch's EEPROM and in the file), read it back as a check.
* **Gripper** (:func:`gripper_session`): find the closed and open stops at a low effort.
* **FingerVision** (:func:`fingervision_session`): marker rest positions (baseline) and the
  proximity-vision background histogram from no-contact frames.
* **GelSight** (:func:`gelsight_session`): a ball pressed into the gel is moved by the jig over a
  grid of positions; the no-contact frame is taken with the ball moved out of the field of view.
  Labels: the contact centre is the jig position in pixels plus the ball's offset at the jig's home
  (measured from the frames themselves, so a ball that is not centred on the bench is fine), and the
  contact radius is ``sqrt(R² − (R − d)²)`` for the press depth ``d``. Fit with
  :func:`~tactile_rig.perception.gelsight.calibration.calibrate_from_presses`; the report holds a
  k-fold held-out error (:func:`~tactile_rig.perception.gelsight.report.cross_validate`).

JSON calibration files share one envelope (:func:`write_calibration`): ``format``, ``version``,
``kind``, ``created``, ``device``, the values, and the report.

Files are versioned (:mod:`tactile_rig.rig.calibrations`): asked for ``calib/scale.json`` a session
writes ``calib/scale-vN.json`` (N one more than the newest on disk) and points the stable name at it;
``force=True`` rewrites the newest version instead. Every session also records what it measured to
``<stem>-vN.mcap`` (:class:`SessionRecording`: readings, frames, jig poses, commands, and the
calibration files as attachments) when the ``record`` extra (mcap) is installed.
"""

from __future__ import annotations

import csv
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence, TextIO

import cv2
import numpy as np

from tactile_rig.core.clock import Deadline, utc_now
from tactile_rig.core.errors import CalibrationError, DeviceTimeout, check_range
from tactile_rig.core.files import load_json
from tactile_rig.core.geometry import Pose
from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.devices.scale import STANDARD_GRAVITY_MPS2
from tactile_rig.perception.fingervision import (
    FingerVision,
    FingerVisionParams,
    detect_markers,
)
from tactile_rig.perception.gelsight.calibration import PressSet, calibrate_from_presses
from tactile_rig.perception.gelsight.report import cross_validate
from tactile_rig.rig.calibrations import CalibrationVersion, plan_version, publish
from tactile_rig.rig.recording import Recorder

__all__ = [
    "CALIBRATION_FORMAT",
    "CALIBRATION_VERSION",
    "SessionOutcome",
    "SessionRecording",
    "Guide",
    "write_calibration",
    "read_calibration",
    "BallPressPlan",
    "press_positions",
    "collect_ball_presses",
    "contact_centroid_px",
    "even_colour_direction",
    "gelsight_session",
    "scale_session",
    "gripper_session",
    "fingervision_session",
    "wait_for_load",
]

CALIBRATION_FORMAT = "tactile_rig.calibration"
CALIBRATION_VERSION = 1
# Files of one calibration version that get a stable link (those that exist).
LINKED_SUFFIXES = (".json", ".npz", ".report.json", ".report.md", ".mcap", "_presses")
JSON_SUFFIXES = (".json", ".report.json", ".report.md")


class SessionRecording:
    """The MCAP of what a calibration session measured, at ``path`` on the session's ``clock``.

    A no-op (``path`` None) when the optional ``mcap`` package is missing: a calibration must not
    fail for want of its recording. Topics are those of :mod:`tactile_rig.rig.recording`.
    """

    def __init__(self, path: str | Path | None, clock: Any, *, kind: str, bench: Any = None,
                 **meta: Any) -> None:
        self.rec: Recorder | None = None
        self.path: Path | None = None
        if path is None:
            return
        try:
            self.rec = Recorder(path, clock=clock)
        except ModuleNotFoundError:
            return
        self.path = Path(path)
        self.rec.add_metadata("session", {"kind": kind, **meta})
        if bench is not None:
            self.rec.add_bench(bench)

    def scale(self, reading: Any, **extra: Any) -> None:
        if self.rec is not None:
            grams = float(reading.grams)
            self.rec.write_scale(grams / 1000.0 * STANDARD_GRAVITY_MPS2, grams=grams, seq=reading.seq, **extra)

    def frame(self, camera: str, image: np.ndarray, **extra: Any) -> None:
        if self.rec is not None:
            self.rec.write_frame(camera, np.ascontiguousarray(image), compress="png")

    def perception(self, name: str, values: dict[str, Any]) -> None:
        if self.rec is not None:
            self.rec.write_perception(name, values)

    def jig(self, x_mm: float, y_mm: float, **extra: Any) -> None:
        if self.rec is not None:
            self.rec.write_jig_pose({"x_mm": float(x_mm), "y_mm": float(y_mm)}, **extra)

    def command(self, device: str, command: str, **args: Any) -> None:
        if self.rec is not None:
            self.rec.write_command(device, command, **args)

    def state(self, device: str, state: Any) -> None:
        if self.rec is not None:
            self.rec.write_state(device, state)

    def attach(self, name: str, *paths: str | Path | None, values: dict[str, Any] | None = None) -> None:
        """The calibration's files as attachments (every file: ``.json`` and ``.npz``)."""
        if self.rec is None:
            return
        files = [Path(p) for p in paths if p is not None and Path(p).is_file()]
        for p in files:
            media = "application/json" if p.suffix == ".json" else "application/octet-stream"
            self.rec.add_attachment(f"calibration/{name}/{p.name}", p.read_bytes(), media_type=media)
        self.rec.add_metadata(f"calibration.{name}", {"files": [str(p) for p in files], **(values or {})})

    def close(self) -> None:
        if self.rec is not None:
            self.rec.close()
            self.rec = None


def _session_version(out: str | Path, suffixes: Sequence[str], force: bool) -> CalibrationVersion:
    return plan_version(out, suffixes, force=force)


@dataclass
class SessionOutcome:
    """What a session wrote: the calibration file, its report (file and values)."""

    kind: str
    calibration_path: Path
    report_path: Path
    report: dict[str, Any]
    files: dict[str, Any] = field(default_factory=dict)  # paths, plus the version and links

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "calibration": str(self.calibration_path), "report": str(self.report_path),
                "values": self.report, "files": dict(self.files)}


class Guide:
    """Talks to the operator: on a terminal it prints steps and waits for Enter; otherwise it only logs.

    ``interactive=None`` decides from ``stdin.isatty()``. Messages go to ``stream`` (stderr), so a
    ``--json`` result on stdout stays clean.
    """

    def __init__(self, interactive: bool | None = None, *, stream: TextIO | None = None,
                 stdin: TextIO | None = None, quiet: bool = False) -> None:
        self.stdin = stdin if stdin is not None else sys.stdin
        if interactive is None:
            isatty = getattr(self.stdin, "isatty", None)
            interactive = bool(callable(isatty) and isatty())
        self.interactive = interactive
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet

    def say(self, text: str) -> None:
        if not self.quiet:
            self.stream.write(text + "\n")
            self.stream.flush()

    def step(self, text: str) -> None:
        """An operator action: prompt and wait on a terminal, just log it otherwise."""
        if self.interactive:
            self.stream.write(f"{text} — press Enter when done ")
            self.stream.flush()
            self.stdin.readline()
        else:
            self.say(f"[step] {text}")


_ENVELOPE = ("format", "version", "kind", "created", "device", "report")


def write_calibration(path: str | Path, kind: str, values: dict[str, Any], report: dict[str, Any], *,
                      device: str | None = None, force: bool = False,
                      version: CalibrationVersion | None = None) -> tuple[Path, Path]:
    """Write a JSON calibration and its report (``.report.json`` and ``.md``) as a new version of ``path``.

    ``path`` ``calib/scale.json`` writes ``calib/scale-vN.json`` and links ``calib/scale.json`` to it
    (see :mod:`tactile_rig.rig.calibrations`; ``force`` rewrites the newest version; ``version`` is
    one already chosen by the session). The file is flat: the envelope keys (``format``,
    ``version``, ``kind``, ``created``, ``device``), the values at the top level (so a driver's
    ``from_dict`` reads it as it is, e.g. ``GripperCalibration.from_dict``) and the ``report``.
    Returns (calibration path, report path) of the version written.
    """

    clash = sorted(set(values) & set(_ENVELOPE))
    if clash:
        raise ValueError(f"calibration values may not be named {', '.join(clash)} (envelope keys)")
    ver = version if version is not None else plan_version(path, JSON_SUFFIXES, force=force)
    p = ver.path(".json")
    p.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": CALIBRATION_FORMAT, "version": CALIBRATION_VERSION, "kind": kind, "created": utc_now(),
           "device": device, **to_jsonable(values), "report": to_jsonable(report)}
    p.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    rpath = p.with_name(p.stem + ".report.json")
    rpath.write_text(json.dumps(to_jsonable({"kind": kind, **report}), indent=2) + "\n", encoding="utf-8")
    _write_report_md(p.with_name(p.stem + ".report.md"), kind, p, values, report)
    publish(ver, LINKED_SUFFIXES)
    return p, rpath


def read_calibration(path: str | Path, kind: str) -> dict[str, Any]:
    """The values of a JSON calibration of ``kind``; raises CalibrationError naming the problem."""
    p = Path(path)
    try:
        doc = load_json(p, f"{kind} calibration", expect=None)
    except FileNotFoundError:
        raise CalibrationError(f"calibration file {p} does not exist; make it with: tactile-rig calibrate {kind}",
                               device=kind) from None
    except (OSError, ValueError) as exc:
        raise CalibrationError(f"{p} is not a readable calibration ({exc})", device=kind) from None
    if not isinstance(doc, dict) or doc.get("format") != CALIBRATION_FORMAT or doc.get("kind") != kind:
        got = (doc.get("format"), doc.get("kind")) if isinstance(doc, dict) else (type(doc).__name__, None)
        raise CalibrationError(f"{p} is not a {kind} calibration (format {got[0]!r}, kind {got[1]!r})", device=kind)
    if doc.get("version") != CALIBRATION_VERSION:
        raise CalibrationError(f"{p}: calibration version {doc.get('version')!r}, this code reads "
                               f"version {CALIBRATION_VERSION}", device=kind)
    return {k: v for k, v in doc.items() if k not in _ENVELOPE}


def _write_report_md(path: Path, kind: str, cal_path: Path, values: dict[str, Any], report: dict[str, Any]) -> None:
    lines = [f"# {kind} calibration", "", f"- file: `{cal_path.name}`", f"- created: {utc_now()}", ""]
    if values:
        lines += ["## Values", "", "| name | value |", "| --- | --- |"]
        lines += [f"| {k} | {_short(v)} |" for k, v in values.items()]
        lines.append("")
    lines += ["## Report", "", "| name | value |", "| --- | --- |"]
    lines += [f"| {k} | {_short(v)} |" for k, v in report.items() if not isinstance(v, list)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    text = json.dumps(v) if isinstance(v, (dict, list)) else str(v)
    return text if len(text) <= 80 else text[:77] + "..."


# -- GelSight ball presses --------------------------------------------------------------------
class PressRig(Protocol):
    """What the GelSight session needs: the jig (``move_to`` a :class:`Pose`) and a frame."""

    def move_to(self, pose: Any) -> None: ...

    def touch(self) -> np.ndarray: ...


@dataclass(frozen=True)
class BallPressPlan:
    """Where to press: a ``grid_x_mm`` x ``grid_y_mm`` grid (start, stop, count) of jig positions.

    ``background_mm`` is a jig position with the ball out of the field of view (the no-contact
    frame). ``press_depth_mm`` is how far the ball is pressed past first contact (the bench's z
    setting; the mock scene uses 0.6 mm) and ``ball_radius_mm`` its radius. ``method`` is the
    colour-to-gradient model ("lut", "poly" or "mlp"); ``background_frames`` no-contact frames are
    averaged into the background.
    """

    ball_radius_mm: float = 2.0
    press_depth_mm: float = 0.6
    grid_x_mm: tuple[float, float, int] = (-7.5, 7.5, 5)
    grid_y_mm: tuple[float, float, int] = (-5.0, 5.0, 4)
    background_mm: tuple[float, float] = (16.0, 0.0)
    method: str = "lut"
    folds: int = 4
    background_frames: int = 8

    def __post_init__(self) -> None:
        check_range("ball_radius_mm", float(self.ball_radius_mm), 0.1, 50.0, "mm")
        check_range("press_depth_mm", float(self.press_depth_mm), 0.01, float(self.ball_radius_mm), "mm")
        for name, g in (("grid_x_mm", self.grid_x_mm), ("grid_y_mm", self.grid_y_mm)):
            if len(g) != 3 or int(g[2]) < 1 or float(g[1]) < float(g[0]):
                raise ValueError(f"{name}={g!r} must be (start, stop, count) with start <= stop and count >= 1")
        if int(self.grid_x_mm[2]) * int(self.grid_y_mm[2]) < 3:
            raise ValueError(
                f"grid_x_mm count {int(self.grid_x_mm[2])} x grid_y_mm count {int(self.grid_y_mm[2])} gives "
                f"{int(self.grid_x_mm[2]) * int(self.grid_y_mm[2])} presses; a GelSight calibration needs at least 3 presses"
            )
        check_range("background_frames", float(self.background_frames), 1, 1000)
        if self.method not in ("lut", "poly", "mlp"):
            raise ValueError(f"method={self.method!r} must be 'lut', 'poly' or 'mlp'")

    @property
    def contact_radius_mm(self) -> float:
        r, d = float(self.ball_radius_mm), float(self.press_depth_mm)
        return math.sqrt(r * r - (r - d) ** 2)


def press_positions(plan: BallPressPlan) -> list[tuple[float, float]]:
    """The grid's jig positions (x, y) in mm, row by row."""
    xs = np.linspace(float(plan.grid_x_mm[0]), float(plan.grid_x_mm[1]), int(plan.grid_x_mm[2]))
    ys = np.linspace(float(plan.grid_y_mm[0]), float(plan.grid_y_mm[1]), int(plan.grid_y_mm[2]))
    return [(round(float(x), 6), round(float(y), 6)) for y in ys for x in xs]


def contact_centroid_px(frame_bgr: np.ndarray, background_bgr: np.ndarray, min_diff: float = 12.0,
                        direction_bgr: np.ndarray | None = None) -> tuple[float, float] | None:
    """Centre (x, y) px of the largest region that differs from the background, or None.

    Weighted by the colour difference: ``sum |Δ|`` over the channels, or ``|Δ · direction_bgr|``
    when a colour direction is given (see :func:`even_colour_direction`: with it the weights are
    symmetric about a ball's centre, so the centroid is the contact centre).
    """
    diff = frame_bgr.astype(np.float32) - background_bgr.astype(np.float32)
    d = cv2.GaussianBlur(np.abs(diff).sum(axis=2), (0, 0), 2.0)
    mask = (d > min_diff).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[k, cv2.CC_STAT_AREA] < 20:
        return None
    region = labels == k
    if direction_bgr is not None:
        # The region is found on all the colour change; the weights use only its even part.
        d = cv2.GaussianBlur(np.abs(diff @ np.asarray(direction_bgr, np.float32).reshape(3)), (0, 0), 2.0)
        region = cv2.dilate(region.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    w = np.where(region, d, 0.0)
    total = float(w.sum())
    if not total > 0:
        return None
    ys, xs = np.mgrid[0:d.shape[0], 0:d.shape[1]]
    return float((w * xs).sum() / total), float((w * ys).sum() / total)


def even_colour_direction(frames: Sequence[np.ndarray], background_bgr: np.ndarray,
                          centres_px: Sequence[Sequence[float]], radius_px: float) -> np.ndarray:
    """The colour direction (unit BGR vector) blind to the surface slopes' odd part.

    Under the LEDs a press changes the colour by ``gx·a + gy·b + (n_z − 1)·c``; ``gx, gy`` are odd
    about the contact centre and ``n_z − 1`` even. ``a`` and ``b`` are estimated as the colour
    changes' first moments along x and y around approximate centres; the direction ``a × b`` keeps
    only the even part, so a centroid weighted by it is not pulled toward the brighter LED.
    """
    bg = background_bgr.astype(np.float32)
    u = np.zeros(3)
    v = np.zeros(3)
    h, w = bg.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    for f, c in zip(frames, centres_px):
        dx, dy = xs - float(c[0]), ys - float(c[1])
        m = dx * dx + dy * dy < (1.5 * radius_px) ** 2
        d = (f.astype(np.float32) - bg)[m]
        u += (d * dx[m][:, None]).sum(axis=0)
        v += (d * dy[m][:, None]).sum(axis=0)
    n = np.cross(u, v)
    norm = float(np.linalg.norm(n))
    if not np.isfinite(norm) or norm == 0:
        return np.ones(3) / math.sqrt(3.0)
    return n / norm


def collect_ball_presses(rig: PressRig, plan: BallPressPlan, mm_per_px: float, out_dir: str | Path | None = None,
                         *, guide: Guide | None = None, recording: SessionRecording | None = None,
                         camera: str = "gelsight") -> Any:
    """Press the ball at every grid position; return a labelled PressSet (and write a ``presses/`` folder).

    The ball's offset from the sensor centre at the jig's home is the median over the presses of
    (measured contact centroid − commanded position); it is reported in ``PressSet.names``' folder
    ``labels.csv`` and returned as ``presses.offset_px``.
    """

    guide = guide or Guide(False, quiet=True)
    rec = recording or SessionRecording(None, None, kind="gelsight")
    check_range("mm_per_px", float(mm_per_px), 1e-4, 10.0, "mm/px")
    bx, by = plan.background_mm
    guide.say(f"moving the ball out of view ({bx:+.1f}, {by:+.1f}) mm for the no-contact frame")
    rec.command("jig", "move_to", x_mm=float(bx), y_mm=float(by), purpose="background")
    rig.move_to(Pose(float(bx), float(by)))
    rec.jig(bx, by, purpose="background")
    # The mean of several no-contact frames: the sensor noise and the lamp flicker of one frame would
    # otherwise be subtracted from every later frame as a false colour change.
    bg_frames = [rig.touch() for _ in range(int(plan.background_frames))]
    for f in bg_frames:
        rec.frame(camera, f)
    stack = np.stack(bg_frames).astype(np.float32)
    background = np.ascontiguousarray(np.clip(stack.mean(axis=0) + 0.5, 0, 255).astype(np.uint8))
    positions = press_positions(plan)
    frames: list[np.ndarray] = []
    guide.say(f"pressing at {len(positions)} jig positions")
    for k, (x, y) in enumerate(positions):
        rec.command("jig", "move_to", x_mm=x, y_mm=y, purpose="press", press=k)
        rig.move_to(Pose(x, y))
        rec.jig(x, y, purpose="press", press=k)
        frames.append(np.ascontiguousarray(rig.touch()))
        rec.frame(camera, frames[-1])
    rows, cols = background.shape[:2]
    centre = np.array([(cols - 1) / 2.0, (rows - 1) / 2.0])
    commanded_px = np.array([[x / mm_per_px, y / mm_per_px] for x, y in positions]) + centre
    radius_px = plan.contact_radius_mm / mm_per_px

    def measured_offset(direction: np.ndarray | None) -> np.ndarray:
        offsets = []
        for f, c in zip(frames, commanded_px):
            m = contact_centroid_px(f, background, direction_bgr=direction)
            if m is not None:
                offsets.append(np.array(m) - c)
        if len(offsets) < max(3, len(frames) // 2):
            raise CalibrationError(f"only {len(offsets)} of {len(frames)} presses show a contact: is the ball "
                                   "under the sensor and pressed?", device="gelsight.calibration")
        return np.median(np.array(offsets), axis=0)

    offset = measured_offset(None)
    for _ in range(2):  # the even colour direction needs centres; refine them with it
        offset = measured_offset(even_colour_direction(frames, background, commanded_px + offset, radius_px))
    centers = commanded_px + offset
    keep = [i for i, c in enumerate(centers)
            if radius_px <= c[0] <= cols - 1 - radius_px and radius_px <= c[1] <= rows - 1 - radius_px]
    if len(keep) < 3:
        raise CalibrationError(f"only {len(keep)} presses lie fully inside the {cols}x{rows} frame; "
                               "shrink the grid", device="gelsight.calibration")
    names = [f"press_{i:02d}.png" for i in range(len(keep))]
    presses = PressSet(background, [frames[i] for i in keep], centers[keep], np.full(len(keep), radius_px), names)
    presses.offset_px = (float(offset[0]), float(offset[1]))  # type: ignore[attr-defined]
    if out_dir is not None:
        d = Path(out_dir)
        d.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(d / "background.png"), background)
        with open(d / "labels.csv", "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["file", "center_x_px", "center_y_px", "contact_radius_px"])
            for name, f, c in zip(names, presses.frames, presses.centers_px):
                cv2.imwrite(str(d / name), f)
                w.writerow([name, round(float(c[0]), 2), round(float(c[1]), 2), round(radius_px, 2)])
    return presses


def gelsight_session(rig: PressRig, plan: BallPressPlan, mm_per_px: float, out: str | Path, *,
                     sensor: str = "gelsight", guide: Guide | None = None, force: bool = False,
                     bench: Any = None, clock: Any = None, camera: str = "gelsight") -> SessionOutcome:
    """Collect ball presses with the jig, fit the GelSight calibration, write it with its report.

    ``out`` is the calibration's stable base path: version N writes ``<out>-vN.npz`` + ``.json``,
    the presses to ``<out>-vN_presses/``, the report to ``<out>-vN.report.json`` / ``.md`` and the
    recording (jig poses and frames) to ``<out>-vN.mcap``; the stable names link to the newest.
    """

    guide = guide or Guide(False, quiet=True)
    ver = _session_version(out, (".npz", ".json", ".report.json", "_presses"), force)
    base = ver.stem
    guide.step(f"mount the {2 * plan.ball_radius_mm:g} mm ball on the jig and set the press depth to "
               f"{plan.press_depth_mm:g} mm")
    rec = SessionRecording(ver.path(".mcap"), clock if clock is not None else getattr(rig, "clock", None),
                           kind="gelsight", bench=bench, camera=camera)
    try:
        presses = collect_ball_presses(rig, plan, mm_per_px, base.parent / f"{base.name}_presses", guide=guide,
                                       recording=rec, camera=camera)
    except BaseException:
        rec.close()
        raise
    cal = calibrate_from_presses(presses, float(mm_per_px), float(plan.ball_radius_mm), plan.method, sensor=sensor)
    cal.extra.update({"session": "jig ball presses", "press_depth_mm": plan.press_depth_mm,
                      "ball_offset_px": list(presses.offset_px)})
    npz = cal.save(base)
    folds = max(2, min(int(plan.folds), len(presses.frames)))
    cv = cross_validate(presses, float(mm_per_px), float(plan.ball_radius_mm), plan.method, folds=folds)
    report = {"presses": len(presses.frames), "method": plan.method, "mm_per_px": float(mm_per_px),
              "ball_radius_mm": plan.ball_radius_mm, "press_depth_mm": plan.press_depth_mm,
              "contact_radius_px": round(plan.contact_radius_mm / float(mm_per_px), 3),
              "ball_offset_px": list(presses.offset_px),
              "heldout_protocol": cv.protocol, "heldout_mean_normal_deg": cv.mean_normal_deg,
              "heldout_mean_height_rms_mm": cv.mean_height_rms_mm, "colour_coverage": cv.colour_coverage,
              "per_press": [{"name": e.name, "normal_deg": e.normal_deg, "height_rms_mm": e.height_rms_mm}
                            for e in cv.presses]}
    rpath = base.with_name(base.name + ".report.json")

    rpath.write_text(json.dumps(to_jsonable({"kind": "gelsight", **report}), indent=2) + "\n", encoding="utf-8")
    _write_report_md(base.with_name(base.name + ".report.md"), "gelsight", npz, cal.metadata(), report)
    rec.attach("gelsight", base.with_suffix(".json"), npz)
    rec.close()
    report["recording"] = None if rec.path is None else str(rec.path)
    links = publish(ver, LINKED_SUFFIXES)
    guide.say(f"GelSight calibration: {len(presses.frames)} presses, held-out normal error "
              f"{cv.mean_normal_deg:.2f} deg, height RMS {cv.mean_height_rms_mm * 1000:.1f} um -> {npz}")
    return SessionOutcome("gelsight", base.with_suffix(".json"), rpath, report,
                          {"npz": str(npz), "json": str(base.with_suffix(".json")),
                           "presses": str(base.parent / f"{base.name}_presses"),
                           "recording": report["recording"], "version": ver.version,
                           "links": [str(p) for p in links]})


# -- scale: tare and known mass -----------------------------------------------------------------
def _grams(readings: Sequence[Any]) -> np.ndarray:
    return np.array([float(r.grams) for r in readings], dtype=np.float64)


def wait_for_load(scale: Any, empty_g: float, noise_g: float, *, timeout_s: float = 60.0, window: int = 8,
                  clock: Any = None) -> np.ndarray:
    """Wait until the scale reads a load that is clearly there (> 20 noise σ and > 1 g above the
    empty reading) and steady (σ of the last ``window`` readings < 3 noise σ + 0.05 g); return those
    readings in grams. For scripted sessions: whoever places the mass has ``timeout_s`` to do it."""

    dl = Deadline(clock or scale.clock, timeout_s)
    recent: list[float] = []
    while not dl.expired():
        recent.append(float(scale.read().grams))
        recent = recent[-window:]
        if len(recent) == window:
            a = np.array(recent)
            if abs(a.mean() - empty_g) > max(20 * noise_g, 1.0) and a.std() < 3 * noise_g + 0.05:
                return a
    raise DeviceTimeout(f"no steady load on the scale within {timeout_s:.3g} s (place the known mass)",
                        device="scale")


def scale_session(scale: Any, known_mass_g: float, out: str | Path, *, place_mass: Callable[[float], None] | None = None,
                  guide: Guide | None = None, samples: int = 20, wait_timeout_s: float = 60.0,
                  force: bool = False, bench: Any = None) -> SessionOutcome:
    """Tare the empty scale, calibrate it with ``known_mass_g``, verify, write the calibration and report.

    ``place_mass(grams)`` puts a mass on the scale (mocks: the world's load cell; 0 removes it);
    without it the operator does (a prompt on a terminal; otherwise the session waits up to
    ``wait_timeout_s`` for a steady load).
    """
    guide = guide or Guide(False, quiet=True)
    check_range("known_mass_g", float(known_mass_g), 1e-3, 1e6, "g")
    check_range("samples", float(samples), 3, 10000)
    ver = _session_version(out, JSON_SUFFIXES, force)
    rec = SessionRecording(ver.path(".mcap"), getattr(scale, "clock", None), kind="scale", bench=bench,
                           known_mass_g=float(known_mass_g))

    def read_many(phase: str) -> list[Any]:
        rs = scale.read_many(int(samples))
        for r in rs:
            rec.scale(r, phase=phase)
        return rs

    try:
        if place_mass is not None:
            place_mass(0.0)
        guide.step("empty the scale")
        rec.command("scale", "tare")
        scale.tare()
        scale.poll()  # readings queued before the tare was confirmed are not tared
        empty = _grams(read_many("empty"))
        noise_g = float(empty.std())
        if place_mass is not None:
            place_mass(float(known_mass_g))
            scale.poll()
            read_many("settling")  # the sketch's moving average settles on the new load
        elif guide.interactive:
            guide.step(f"place the {known_mass_g:g} g mass on the scale")
        else:
            guide.say(f"waiting up to {wait_timeout_s:g} s for the {known_mass_g:g} g mass")
            wait_for_load(scale, float(empty.mean()), noise_g, timeout_s=wait_timeout_s)
        rec.command("scale", "calibrate", known_mass_g=float(known_mass_g))
        factor = float(scale.calibrate(float(known_mass_g)))
        scale.poll()
        loaded = _grams(read_many("verify"))
    except BaseException:
        rec.close()
        raise
    error_g = float(loaded.mean() - known_mass_g)
    values = {"cal_factor_counts_per_g": factor, "known_mass_g": float(known_mass_g)}
    info = getattr(scale, "info", None)
    report = {"empty_mean_g": float(empty.mean()), "empty_noise_g": noise_g, "loaded_mean_g": float(loaded.mean()),
              "loaded_noise_g": float(loaded.std()), "verify_error_g": error_g,
              "verify_error_percent": 100.0 * error_g / float(known_mass_g), "samples": int(samples),
              "firmware": None if info is None else f"{info.firmware} {info.version}"}
    report["recording"] = None if rec.path is None else str(rec.path)
    cal, rpath = write_calibration(out, "scale", values, report, device=str(getattr(scale, "port", "scale")),
                                   version=ver)
    rec.attach("scale", cal, values=values)
    rec.close()
    guide.say(f"scale: factor {factor:.4g} counts/g; with the mass it reads {loaded.mean():.3f} g "
              f"({error_g:+.3f} g), empty noise {noise_g:.3f} g -> {cal}")
    if place_mass is not None:
        place_mass(0.0)
    return SessionOutcome("scale", cal, rpath, {**values, **report},
                          {"json": str(cal), "recording": report["recording"], "version": ver.version,
                           "latest": str(ver.link(".json"))})


# -- gripper: closed and open stops --------------------------------------------------------------
def gripper_session(gripper: Any, out: str | Path, *, effort: float = 0.2, max_opening_m: float | None = None,
                    closing_sign: int = -1, guide: Guide | None = None, force: bool = False,
                    bench: Any = None) -> SessionOutcome:
    """Find the gripper's closed and open stops at a low effort and write them (``GripperCalibration``
    fields at the top level, so ``tactile-rig gripper --calibration`` reads the file as it is); the
    recording holds the commands and the servo's state before and after."""
    guide = guide or Guide(False, quiet=True)
    ver = _session_version(out, JSON_SUFFIXES, force)
    guide.step("clear the fingers: the gripper will close and open fully")
    rec = SessionRecording(ver.path(".mcap"), getattr(gripper, "clock", None), kind="gripper", bench=bench)
    try:
        rec.state("gripper", _state_or_none(gripper))
        rec.command("gripper", "calibrate", effort=float(effort), closing_sign=int(closing_sign))
        cal = gripper.calibrate(effort=effort, max_opening_m=max_opening_m, closing_sign=closing_sign)
        rec.state("gripper", _state_or_none(gripper))
    except BaseException:
        rec.close()
        raise
    values = dict(cal.to_dict())
    span = int(values["open_ticks"]) - int(values["closed_ticks"])
    report: dict[str, Any] = {"span_ticks": span, "effort": float(effort), "closing_sign": int(closing_sign),
              "m_per_tick": float(values["max_opening_m"]) / abs(span) if span else None}
    report["recording"] = None if rec.path is None else str(rec.path)
    path, rpath = write_calibration(out, "gripper", values, report, device=str(getattr(gripper, "device", "gripper")),
                                    version=ver)
    rec.attach("gripper", path, values=values)
    rec.close()
    guide.say(f"gripper: closed {values['closed_ticks']} ticks, open {values['open_ticks']} ticks -> {path}")
    return SessionOutcome("gripper", path, rpath, {**values, **report},
                          {"json": str(path), "recording": report["recording"], "version": ver.version,
                           "latest": str(ver.link(".json"))})


def _state_or_none(device: Any) -> dict[str, Any]:
    """A device's state for the recording ({} when it cannot report one)."""
    try:
        return to_jsonable(device.state())
    except Exception:  # noqa: BLE001 - a state that cannot be read is simply not recorded
        return {}


# -- FingerVision: marker baseline and proximity-vision histograms --------------------------------
def fingervision_session(camera: Any, out: str | Path, *, frames: int = 10, guide: Guide | None = None,
                         params: Any = None, force: bool = False, bench: Any = None) -> SessionOutcome:
    """Average ``frames`` no-contact frames into the marker baseline (rest positions, sizes, valid
    flags) and the proximity-vision background histogram; write ``<out>-vN.npz`` (arrays),
    ``<out>-vN.json`` (with the report) and ``<out>-vN.mcap`` (the frames), linked from ``<out>.*``."""

    guide = guide or Guide(False, quiet=True)
    check_range("frames", float(frames), 1, 1000)
    ver = _session_version(out, (".npz", *JSON_SUFFIXES), force)
    name = str(getattr(camera, "name", "camera"))
    guide.step("nothing in contact with the skin and nothing behind it")
    rec = SessionRecording(ver.path(".mcap"), getattr(camera, "clock", None), kind="fingervision", bench=bench,
                           camera=name)
    imgs = []
    try:
        for _ in range(int(frames)):
            fr = camera.read(timeout_s=2.0)
            imgs.append(np.ascontiguousarray(getattr(fr, "image", fr)))
            rec.frame(name, imgs[-1])
    except BaseException:
        rec.close()
        raise
    fv = FingerVision(params or FingerVisionParams())
    base = fv.calibrate(imgs)
    n, n_valid = len(base), int(np.count_nonzero(base.valid))
    if n_valid < 3:
        rec.close()
        raise CalibrationError(f"only {n_valid} stable markers in {frames} frames: check focus and lighting",
                               device="fingervision.calibration")
    p = ver.stem
    p.parent.mkdir(parents=True, exist_ok=True)
    npz = p.with_name(p.name + ".npz")
    bg_hist = fv.proximity.bg_hist
    np.savez_compressed(npz, positions_px=base.positions_px, sizes_px=base.sizes_px, valid=base.valid,
                        bg_hist=np.zeros(0) if bg_hist is None else bg_hist)
    # Repeatability: how far each frame's detections sit from the baseline (nearest valid marker).

    jitter = []
    for img in imgs:
        det = detect_markers(img, fv.params.detector)
        pts = np.asarray(det.positions_px, float).reshape(-1, 2)
        if len(pts):
            d = np.linalg.norm(pts[:, None, :] - base.positions_px[base.valid][None, :, :], axis=2).min(axis=1)
            jitter.append(float(np.median(d)))
    values = {"arrays": npz.name, "frame_shape": list(imgs[0].shape[:2]), "markers": n, "valid_markers": n_valid,
              "bg_median_v": fv.proximity.bg_median_v}
    report: dict[str, Any] = {"frames": int(frames), "valid_fraction": n_valid / n if n else 0.0,
              "median_marker_jitter_px": float(np.median(jitter)) if jitter else None,
              "mean_marker_size_px": float(np.mean(base.sizes_px[base.valid])) if n_valid else None,
              "background_histogram_bins": int(0 if bg_hist is None else np.size(bg_hist))}
    for k, j in enumerate(jitter):
        rec.perception(name, {"frame": k, "median_marker_offset_px": j})
    report["recording"] = None if rec.path is None else str(rec.path)
    path, rpath = write_calibration(out, "fingervision", values, report, device=name, version=ver)
    rec.attach("fingervision", path, npz, values={"markers": n, "valid_markers": n_valid})
    rec.close()
    guide.say(f"FingerVision: {n_valid}/{n} stable markers -> {path}")
    return SessionOutcome("fingervision", path, rpath, {**values, **report},
                          {"npz": str(npz), "json": str(path), "recording": report["recording"],
                           "version": ver.version, "latest": str(ver.link(".json"))})

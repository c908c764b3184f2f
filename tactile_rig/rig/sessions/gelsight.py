"""The GelSight calibration session: a ball pressed into the gel by the jig over a grid, then fitted.

The no-contact frame is taken with the ball moved out of the field of view. Labels: the contact centre
is the jig position in pixels plus the ball's offset at the jig's home (measured from the frames
themselves, :func:`~tactile_rig.perception.gelsight.press_centres.contact_centroid_px`, so a ball that
is not centred on the bench is fine), and the contact radius is ``sqrt(R² − (R − d)²)`` for the press
depth ``d``. Fit with :func:`~tactile_rig.perception.gelsight.calibration.calibrate_from_presses`; the
report holds a k-fold held-out error (:func:`~tactile_rig.perception.gelsight.report.cross_validate`).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from tactile_rig.core.errors import CalibrationError, check_range
from tactile_rig.core.geometry import Pose
from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.perception.gelsight.calibration import PressSet, calibrate_from_presses
from tactile_rig.perception.gelsight.press_centres import contact_centroid_px, even_colour_direction
from tactile_rig.perception.gelsight.report import cross_validate
from tactile_rig.rig.calibrations import publish
from tactile_rig.rig.sessions.calibration_file import LINKED_SUFFIXES, SessionOutcome, session_version, write_report_md
from tactile_rig.rig.sessions.guide import Guide
from tactile_rig.rig.sessions.session_recording import SessionRecording

__all__ = ["BallPressPlan", "PressRig", "collect_ball_presses", "gelsight_session", "press_positions"]


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
                     bench: Any = None, clock: Any = None, camera: str = "gelsight",
                     live: Any = None) -> SessionOutcome:
    """Collect ball presses with the jig, fit the GelSight calibration, write it with its report.

    ``out`` is the calibration's stable base path: version N writes ``<out>-vN.npz`` + ``.json``,
    the presses to ``<out>-vN_presses/``, the report to ``<out>-vN.report.json`` / ``.md`` and the
    recording (jig poses and frames) to ``<out>-vN.mcap``; the stable names link to the newest.
    """

    guide = guide or Guide(False, quiet=True)
    ver = session_version(out, (".npz", ".json", ".report.json", "_presses"), force)
    base = ver.stem
    guide.step(f"mount the {2 * plan.ball_radius_mm:g} mm ball on the jig and set the press depth to "
               f"{plan.press_depth_mm:g} mm")
    rec = SessionRecording(ver.path(".mcap"), clock if clock is not None else getattr(rig, "clock", None),
                           kind="gelsight", bench=bench, live=live, camera=camera)
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
    write_report_md(base.with_name(base.name + ".report.md"), "gelsight", npz, cal.metadata(), report)
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

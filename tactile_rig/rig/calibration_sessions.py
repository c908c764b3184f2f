"""Calibration sessions: collect the data on the rig, fit, and write a versioned calibration with its report.

Each session is guided on a terminal (it says what to do and waits for Enter) and scriptable
elsewhere (no prompt when stdin is not a TTY; every input has a command-line value). Every session
writes ``<out>.json`` (or, for GelSight, ``<out>.npz`` + ``<out>.json`` from
:meth:`GelSightCalibration.save`) and a report ``<out>.report.json`` + ``<out>.report.md``.

* **GelSight** (:func:`gelsight_session`): a ball pressed into the gel is moved by the jig over a
  grid of positions; the no-contact frame is taken with the ball moved out of the field of view.
  Labels: the contact centre is the jig position in pixels plus the ball's offset at the jig's home
  (measured from the frames themselves, so a ball that is not centred on the bench is fine), and the
  contact radius is ``sqrt(R² − (R − d)²)`` for the press depth ``d``. Fit with
  :func:`~tactile_rig.perception.gelsight.calibration.calibrate_from_presses`; the report holds a
  k-fold held-out error (:func:`~tactile_rig.perception.gelsight.report.cross_validate`).

JSON calibration files share one envelope (:func:`write_calibration`): ``format``, ``version``,
``kind``, ``created``, ``device``, the values, and the report.
"""

from __future__ import annotations

import csv
import datetime as _dt
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence, TextIO

import cv2
import numpy as np

from tactile_rig.errors import CalibrationError, check_range

__all__ = [
    "CALIBRATION_FORMAT",
    "CALIBRATION_VERSION",
    "SessionOutcome",
    "Guide",
    "write_calibration",
    "read_calibration",
    "BallPressPlan",
    "press_positions",
    "collect_ball_presses",
    "contact_centroid_px",
    "gelsight_session",
]

CALIBRATION_FORMAT = "tactile_rig.calibration"
CALIBRATION_VERSION = 1


@dataclass
class SessionOutcome:
    """What a session wrote: the calibration file, its report (file and values)."""

    kind: str
    calibration_path: Path
    report_path: Path
    report: dict[str, Any]
    files: dict[str, str] = field(default_factory=dict)

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


def _utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def write_calibration(path: str | Path, kind: str, values: dict[str, Any], report: dict[str, Any], *,
                      device: str | None = None) -> tuple[Path, Path]:
    """Write a JSON calibration (``path``) and its report (``<stem>.report.json`` and ``.md``).

    Returns (calibration path, report path). The envelope carries ``format``, ``version`` and
    ``kind`` so a reader refuses a file of another kind or version (:func:`read_calibration`).
    """
    from tactile_rig.cli.common import to_jsonable

    p = Path(path)
    if p.suffix != ".json":
        p = p.with_suffix(".json")
    p.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": CALIBRATION_FORMAT, "version": CALIBRATION_VERSION, "kind": kind, "created": _utc_now(),
           "device": device, "values": to_jsonable(values), "report": to_jsonable(report)}
    p.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    rpath = p.with_name(p.stem + ".report.json")
    rpath.write_text(json.dumps(to_jsonable({"kind": kind, **report}), indent=2) + "\n", encoding="utf-8")
    _write_report_md(p.with_name(p.stem + ".report.md"), kind, p, values, report)
    return p, rpath


def read_calibration(path: str | Path, kind: str) -> dict[str, Any]:
    """The ``values`` of a JSON calibration of ``kind``; raises CalibrationError naming the problem."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CalibrationError(f"calibration file {p} does not exist; make it with: tactile-rig calibrate {kind}",
                               device=kind) from None
    except (OSError, json.JSONDecodeError) as exc:
        raise CalibrationError(f"{p} is not a readable calibration ({exc})", device=kind) from None
    if doc.get("format") != CALIBRATION_FORMAT or doc.get("kind") != kind:
        raise CalibrationError(f"{p} is not a {kind} calibration (format {doc.get('format')!r}, "
                               f"kind {doc.get('kind')!r})", device=kind)
    if doc.get("version") != CALIBRATION_VERSION:
        raise CalibrationError(f"{p}: calibration version {doc.get('version')!r}, this code reads "
                               f"version {CALIBRATION_VERSION}", device=kind)
    return dict(doc["values"])


def _write_report_md(path: Path, kind: str, cal_path: Path, values: dict[str, Any], report: dict[str, Any]) -> None:
    lines = [f"# {kind} calibration", "", f"- file: `{cal_path.name}`", f"- created: {_utc_now()}", ""]
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
    """What the GelSight session needs: the jig (``move_to`` a :class:`PlanarPose`) and a frame."""

    def move_to(self, pose: Any) -> None: ...

    def touch(self) -> np.ndarray: ...


@dataclass(frozen=True)
class BallPressPlan:
    """Where to press: a ``grid_x_mm`` x ``grid_y_mm`` grid (start, stop, count) of jig positions.

    ``background_mm`` is a jig position with the ball out of the field of view (the no-contact
    frame). ``press_depth_mm`` is how far the ball is pressed past first contact (the bench's z
    setting; the mock scene uses 0.6 mm) and ``ball_radius_mm`` its radius. ``method`` is the
    colour-to-gradient model ("lut", "poly" or "mlp").
    """

    ball_radius_mm: float = 2.0
    press_depth_mm: float = 0.6
    grid_x_mm: tuple[float, float, int] = (-7.5, 7.5, 5)
    grid_y_mm: tuple[float, float, int] = (-5.0, 5.0, 4)
    background_mm: tuple[float, float] = (16.0, 0.0)
    method: str = "lut"
    folds: int = 4

    def __post_init__(self) -> None:
        check_range("ball_radius_mm", float(self.ball_radius_mm), 0.1, 50.0, "mm")
        check_range("press_depth_mm", float(self.press_depth_mm), 0.01, float(self.ball_radius_mm), "mm")
        for name, g in (("grid_x_mm", self.grid_x_mm), ("grid_y_mm", self.grid_y_mm)):
            if len(g) != 3 or int(g[2]) < 1 or float(g[1]) < float(g[0]):
                raise ValueError(f"{name}={g!r} must be (start, stop, count) with start <= stop and count >= 1")
        if int(self.grid_x_mm[2]) * int(self.grid_y_mm[2]) < 3:
            raise ValueError("a GelSight calibration needs at least 3 presses (grid_x count x grid_y count)")
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


def contact_centroid_px(frame_bgr: np.ndarray, background_bgr: np.ndarray,
                        min_diff: float = 12.0) -> tuple[float, float] | None:
    """Centre (x, y) px of the largest region that differs from the background, or None.

    Weighted by the colour difference; the elastomer's blur is symmetric, so the centroid of a ball
    press is the contact centre.
    """
    d = np.abs(frame_bgr.astype(np.float32) - background_bgr.astype(np.float32)).sum(axis=2)
    d = cv2.GaussianBlur(d, (0, 0), 2.0)
    mask = (d > min_diff).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[k, cv2.CC_STAT_AREA] < 20:
        return None
    w = np.where(labels == k, d, 0.0)
    total = float(w.sum())
    ys, xs = np.mgrid[0:d.shape[0], 0:d.shape[1]]
    return float((w * xs).sum() / total), float((w * ys).sum() / total)


def collect_ball_presses(rig: PressRig, plan: BallPressPlan, mm_per_px: float, out_dir: str | Path | None = None,
                         *, guide: Guide | None = None, pose_type: Callable[..., Any] | None = None) -> Any:
    """Press the ball at every grid position; return a labelled PressSet (and write a ``presses/`` folder).

    The ball's offset from the sensor centre at the jig's home is the median over the presses of
    (measured contact centroid − commanded position); it is reported in ``PressSet.names``' folder
    ``labels.csv`` and returned as ``presses.offset_px``.
    """
    from tactile_rig.perception.gelsight.calibration import PressSet
    from tactile_rig.rig.jig_accuracy import PlanarPose

    make_pose = pose_type or PlanarPose
    guide = guide or Guide(False, quiet=True)
    check_range("mm_per_px", float(mm_per_px), 1e-4, 10.0, "mm/px")
    bx, by = plan.background_mm
    guide.say(f"moving the ball out of view ({bx:+.1f}, {by:+.1f}) mm for the no-contact frame")
    rig.move_to(make_pose(float(bx), float(by), 0.0))
    background = np.ascontiguousarray(rig.touch())
    positions = press_positions(plan)
    frames: list[np.ndarray] = []
    guide.say(f"pressing at {len(positions)} jig positions")
    for x, y in positions:
        rig.move_to(make_pose(x, y, 0.0))
        frames.append(np.ascontiguousarray(rig.touch()))
    rows, cols = background.shape[:2]
    centre = np.array([(cols - 1) / 2.0, (rows - 1) / 2.0])
    commanded_px = np.array([[x / mm_per_px, y / mm_per_px] for x, y in positions]) + centre
    offsets = []
    for f, c in zip(frames, commanded_px):
        m = contact_centroid_px(f, background)
        if m is not None:
            offsets.append(np.array(m) - c)
    if len(offsets) < max(3, len(frames) // 2):
        raise CalibrationError(f"only {len(offsets)} of {len(frames)} presses show a contact: is the ball under "
                               "the sensor and pressed?", device="gelsight.calibration")
    offset = np.median(np.array(offsets), axis=0)
    centers = commanded_px + offset
    radius_px = plan.contact_radius_mm / mm_per_px
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
                     sensor: str = "gelsight", guide: Guide | None = None) -> SessionOutcome:
    """Collect ball presses with the jig, fit the GelSight calibration, write it with its report.

    ``out`` is the calibration's base path (``out.npz`` + ``out.json``); the presses go to
    ``<out>_presses/`` and the report to ``<out>.report.json`` / ``.md``.
    """
    from tactile_rig.perception.gelsight.calibration import calibrate_from_presses
    from tactile_rig.perception.gelsight.report import cross_validate

    guide = guide or Guide(False, quiet=True)
    base = Path(out)
    if base.suffix in (".npz", ".json"):
        base = base.with_suffix("")
    guide.step(f"mount the {2 * plan.ball_radius_mm:g} mm ball on the jig and set the press depth to "
               f"{plan.press_depth_mm:g} mm")
    presses = collect_ball_presses(rig, plan, mm_per_px, base.parent / f"{base.name}_presses", guide=guide)
    cal = calibrate_from_presses(presses, float(mm_per_px), float(plan.ball_radius_mm), plan.method, sensor=sensor)
    cal.extra.update({"session": "jig ball presses", "press_depth_mm": plan.press_depth_mm,
                      "ball_offset_px": list(presses.offset_px)})  # type: ignore[attr-defined]
    npz = cal.save(base)
    folds = max(2, min(int(plan.folds), len(presses.frames)))
    cv = cross_validate(presses, float(mm_per_px), float(plan.ball_radius_mm), plan.method, folds=folds)
    report = {"presses": len(presses.frames), "method": plan.method, "mm_per_px": float(mm_per_px),
              "ball_radius_mm": plan.ball_radius_mm, "press_depth_mm": plan.press_depth_mm,
              "contact_radius_px": round(plan.contact_radius_mm / float(mm_per_px), 3),
              "ball_offset_px": list(presses.offset_px),  # type: ignore[attr-defined]
              "heldout_protocol": cv.protocol, "heldout_mean_normal_deg": cv.mean_normal_deg,
              "heldout_mean_height_rms_mm": cv.mean_height_rms_mm, "colour_coverage": cv.colour_coverage,
              "per_press": [{"name": e.name, "normal_deg": e.normal_deg, "height_rms_mm": e.height_rms_mm}
                            for e in cv.presses]}
    rpath = base.with_name(base.name + ".report.json")
    from tactile_rig.cli.common import to_jsonable

    rpath.write_text(json.dumps(to_jsonable({"kind": "gelsight", **report}), indent=2) + "\n", encoding="utf-8")
    _write_report_md(base.with_name(base.name + ".report.md"), "gelsight", npz, cal.metadata(), report)
    guide.say(f"GelSight calibration: {len(presses.frames)} presses, held-out normal error "
              f"{cv.mean_normal_deg:.2f} deg, height RMS {cv.mean_height_rms_mm * 1000:.1f} um -> {npz}")
    return SessionOutcome("gelsight", base.with_suffix(".json"), rpath, report,
                          {"npz": str(npz), "json": str(base.with_suffix(".json")),
                           "presses": str(base.parent / f"{base.name}_presses")})


def _first(values: Sequence[Any]) -> Any:
    return values[0] if values else None

"""Jig accuracy runs (Li et al. 2014, Fig. 7): how well does GelSight localization recover a jig move?

A run builds a tactile map of the object from a few touches, then steps the x-y-θ jig through
rotations (default −90..+90° in 10° steps) and shifts (−6..+6 mm in 1 mm steps), touches, localizes
the touch in the map, and compares the estimate with the truth: the stage pose of the simulated
world on mocks, the jig's commanded pose on a bench. The paper's bench figures are a rotation MAE of
1.15° (std 1.02) and a translation MAE of 0.14 mm (std 0.055).

Frames (all planar, mm and degrees, image axes: x right, y down, θ clockwise on screen):

* the *sensor* frame S: millimetres from the image centre;
* the *map* frame M: the sensor frame of the first map touch, taken at the jig's home pose;
* a stage pose ``(x_mm, y_mm, theta_deg)`` puts the object at ``p_s = R(θ) p_m + t`` in S, the
  convention of :func:`tactile_rig.sim.world.objects.view_in_sensor`.

A registration of a touch B onto the map returns the 2x3 matrix taking B's sensor points into the
map, ``p_m = R(−θ) (p_s − t)``; :func:`pose_from_touch_matrix` inverts it into the stage pose.

Resumability: every finished point is appended (and fsynced) to ``OUT/points.jsonl`` and the run's
configuration and fingerprint live in ``OUT/run.json``; a run started again on the same ``OUT`` with
the same configuration continues at the first unfinished point (the calibration and the tactile map
are reloaded from ``OUT`` so the points before and after the interruption share them).

The run sees the devices through :class:`JigRig` (:class:`DeviceJigRig` wraps a jig driver and a
camera driver; :func:`connect_mock_jig_rig` connects them to the mocks of the ``jig_accuracy``
scene) and perception through :class:`TouchLocalizer`. Driver and mock modules are imported only
inside the functions that connect them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Protocol, Sequence

import numpy as np

from tactile_rig.core.clock import utc_now
from tactile_rig.core.geometry import Pose, wrap_deg
from tactile_rig.core.errors import CalibrationError, RigError, RunConflict, check_range

__all__ = [
    "SWEEPS",
    "PAPER_FIGURES",
    "JigAccuracyConfig",
    "JigPoint",
    "Pose",
    "PointResult",
    "plan_points",
    "pose_from_touch_matrix",
    "touch_matrix_from_pose",
    "wrap_deg",
    "summarize",
    "RunStore",
    "RunConflict",
    "JigRig",
    "TouchLocalizer",
    "run_jig_accuracy",
    "RunOutcome",
    "format_table",
    "DeviceJigRig",
    "connect_mock_jig_rig",
    "connect_bench_jig_rig",
    "sim_camera_connector",
    "execute_jig_accuracy",
    "mock_gelsight_calibration",
    "calibration_digest",
    "write_report",
    "DEFAULT_REGISTRATION",
    "MOCK_SCENE",
    "MOCK_PRESS_SCENE",
]

SWEEPS = ("rotation", "translation", "both")
RUN_FORMAT = "tactile_rig.jig_accuracy.run"
RUN_FORMAT_VERSION = 1
# Li, Platt, Adelson 2014, Fig. 7 (real bench): the figures the table is compared with.
PAPER_FIGURES = {"rotation_mae_deg": 1.15, "rotation_std_deg": 1.02,
                 "translation_mae_mm": 0.14, "translation_std_mm": 0.055}


# -- configuration and plan -------------------------------------------------------------------
# Registration knobs of the run, measured on the mock (docs/jig_accuracy.md):
# * the dense polish's own uncertainty on this sensor (0.0634 mm/px, 0.6 mm gel blur, noise σ 1 grey
#   level + 0.5 flicker) is 0.1-0.4 px / 0.1-0.4°, above the perception default's 0.1 refusal bar,
#   while the actual errors stay well inside the targets: accept up to 0.5 px / 0.5°;
# * keypoints on maps resized to a 160 px short side (the default 120 is faster but costs accuracy
#   here: rotation MAE 0.27° → 0.37° on seed 0, 0.27° → 0.53° on seed 2).
DEFAULT_REGISTRATION: tuple[tuple[str, Any], ...] = (("detect_short_px", 160), ("max_sigma_px", 0.5),
                                                     ("max_sigma_rot_deg", 0.5))

@dataclass(frozen=True)
class JigAccuracyConfig:
    """What a run does; two runs with equal configs (and bench) can resume each other.

    ``rotations_deg`` and ``shifts_mm`` are (start, stop, step), stop included. ``shift_axis`` is the
    jig axis of the translation sweep (``x`` or ``y``). ``map_touches_mm`` are the (x, y) jig
    positions of the map touches (the first defines the map frame and should be (0, 0)); a touch
    joins the map only when its registration confidence exceeds ``map_min_confidence`` (Li 2014:
    0.98). A touch whose localization is refused, or has a confidence below
    ``retouch_below_confidence``, is repeated up to ``retouches`` times and the most confident
    localization is kept (0 disables re-touching confident ones; the summary counts extra touches).
    ``registration`` overrides :class:`~tactile_rig.perception.gelsight.registration.RegistrationParams`
    fields. ``feed_mm_per_min`` is the jig's feed rate (None: rapid moves, each axis at its own
    maximum rate); ``settle_s`` the pause after a move before touching.
    """

    sweep: str = "both"
    rotations_deg: tuple[float, float, float] = (-90.0, 90.0, 10.0)
    shifts_mm: tuple[float, float, float] = (-6.0, 6.0, 1.0)
    shift_axis: str = "x"
    map_touches_mm: tuple[tuple[float, float], ...] = ((0.0, 0.0), (0.0, -2.0), (0.0, 2.0))
    map_min_confidence: float = 0.98
    retouches: int = 2
    retouch_below_confidence: float = 0.99
    registration: tuple[tuple[str, Any], ...] = DEFAULT_REGISTRATION
    feed_mm_per_min: float | None = None
    settle_s: float = 0.1
    seed: int = 0

    def __post_init__(self) -> None:
        if self.sweep not in SWEEPS:
            raise ValueError(f"sweep={self.sweep!r} must be one of {', '.join(SWEEPS)}")
        if self.shift_axis not in ("x", "y"):
            raise ValueError(f"shift_axis={self.shift_axis!r} must be 'x' or 'y'")
        for name, rng in (("rotations_deg", self.rotations_deg), ("shifts_mm", self.shifts_mm)):
            if len(rng) != 3 or not all(math.isfinite(float(v)) for v in rng):
                raise ValueError(f"{name}={rng!r} must be three finite numbers (start, stop, step)")
            if float(rng[2]) <= 0 or float(rng[1]) < float(rng[0]):
                raise ValueError(f"{name}={rng!r}: need start <= stop and step > 0")
        if _count(*self.rotations_deg) > 1000 or _count(*self.shifts_mm) > 1000:
            raise ValueError(
                f"rotations_deg={self.rotations_deg!r} gives {_count(*self.rotations_deg)} points and shifts_mm="
                f"{self.shifts_mm!r} gives {_count(*self.shifts_mm)}: a sweep of more than 1000 points is a typo (check the step)"
            )
        check_range("rotation sweep start", float(self.rotations_deg[0]), -180.0, 180.0, "deg")
        check_range("rotation sweep stop", float(self.rotations_deg[1]), -180.0, 180.0, "deg")
        if not self.map_touches_mm:
            raise ValueError("map_touches_mm must hold at least one (x, y) touch position")
        check_range("map_min_confidence", float(self.map_min_confidence), 0.0, 1.0)
        check_range("retouches", float(self.retouches), 0, 20)
        check_range("retouch_below_confidence", float(self.retouch_below_confidence), 0.0, 1.0)
        if self.feed_mm_per_min is not None:
            check_range("feed_mm_per_min", float(self.feed_mm_per_min), 1.0, 100000.0, "mm/min")
        check_range("settle_s", float(self.settle_s), 0.0, 60.0, "s")

    # JSON round trip (tuples become lists in JSON).
    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["registration"] = dict(self.registration)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "JigAccuracyConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown jig accuracy setting(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        kw = dict(d)
        for key in ("rotations_deg", "shifts_mm"):
            if key in kw:
                kw[key] = tuple(float(v) for v in kw[key])
        if "map_touches_mm" in kw:
            kw["map_touches_mm"] = tuple((float(a), float(b)) for a, b in kw["map_touches_mm"])
        if "registration" in kw:
            kw["registration"] = tuple(sorted(dict(kw["registration"]).items()))
        return cls(**kw)

    def fingerprint(self) -> str:
        """Short hash of the configuration: a resumed run must have the same one."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _count(start: float, stop: float, step: float) -> int:
    return max(int(math.floor((float(stop) - float(start)) / float(step) + 1e-9)) + 1, 0)


def _inclusive_range(start: float, stop: float, step: float) -> list[float]:
    return [round(float(start) + i * float(step), 9) for i in range(_count(start, stop, step))]


@dataclass(frozen=True)
class JigPoint:
    """One commanded jig pose of a sweep; ``index`` is its place in the run (resume key)."""

    index: int
    sweep: str  # "rotation" or "translation"
    pose: Pose


def plan_points(cfg: JigAccuracyConfig) -> list[JigPoint]:
    """The commanded poses of a run, in order: the rotation sweep, then the translation sweep."""
    points: list[JigPoint] = []
    if cfg.sweep in ("rotation", "both"):
        for th in _inclusive_range(*cfg.rotations_deg):
            points.append(JigPoint(len(points), "rotation", Pose(0.0, 0.0, theta_deg=th)))
    if cfg.sweep in ("translation", "both"):
        for s in _inclusive_range(*cfg.shifts_mm):
            pose = Pose(s, 0.0, theta_deg=0.0) if cfg.shift_axis == "x" else Pose(0.0, s, theta_deg=0.0)
            points.append(JigPoint(len(points), "translation", pose))
    return points


# -- pose algebra -----------------------------------------------------------------------------
def touch_matrix_from_pose(pose: Pose) -> np.ndarray:
    """The 2x3 matrix (mm) taking a sensor point of a touch at stage ``pose`` into the map frame."""
    t = math.radians(pose.theta_deg)
    c, s = math.cos(t), math.sin(t)
    r_inv = np.array([[c, s], [-s, c]])  # R(−θ)
    tvec = np.array([pose.x_mm, pose.y_mm])
    return np.hstack([r_inv, (-r_inv @ tvec)[:, None]])


def pose_from_touch_matrix(matrix_mm: np.ndarray) -> Pose:
    """The stage pose whose touch maps into the map frame by ``matrix_mm`` (2x3, mm)."""
    m = np.asarray(matrix_mm, dtype=np.float64)
    if m.shape != (2, 3) or not np.all(np.isfinite(m)):
        raise ValueError(f"matrix_mm must be a finite 2x3 matrix, got shape {m.shape}")
    theta = -math.degrees(math.atan2(m[1, 0], m[0, 0]))  # M's rotation is R(−θ)
    t = math.radians(theta)
    c, s = math.cos(t), math.sin(t)
    r = np.array([[c, -s], [s, c]])  # R(θ)
    tvec = -r @ m[:, 2]
    return Pose(float(tvec[0]), float(tvec[1]), theta_deg=wrap_deg(theta))


# -- results ----------------------------------------------------------------------------------
@dataclass
class PointResult:
    """The outcome of one jig point (one line of ``points.jsonl``)."""

    index: int
    sweep: str
    commanded: Pose
    truth: Pose
    estimate: Pose | None
    ok: bool
    confidence: float
    method: str
    reason: str | None = None
    touches: int = 1
    rotation_error_deg: float | None = None
    translation_error_mm: float | None = None
    t_s: float = 0.0
    wall_s: float = 0.0

    @classmethod
    def make(cls, point: JigPoint, truth: Pose, estimate: Pose | None, **kw: Any) -> "PointResult":
        """Fill in the errors: rotation |Δθ| (wrapped) and translation |Δ(x, y)| of estimate vs truth."""
        r = cls(point.index, point.sweep, point.pose, truth, estimate, ok=estimate is not None, **kw)
        if estimate is not None:
            r.rotation_error_deg = abs(wrap_deg(estimate.theta_deg - truth.theta_deg))
            r.translation_error_mm = math.hypot(estimate.x_mm - truth.x_mm, estimate.y_mm - truth.y_mm)
        return r

    def to_json(self) -> dict[str, Any]:
        d = {"type": "point", "index": self.index, "sweep": self.sweep,
             "commanded": self.commanded.as_dict(), "truth": self.truth.as_dict(),
             "estimate": None if self.estimate is None else self.estimate.as_dict(),
             "ok": self.ok, "confidence": _finite(self.confidence), "method": self.method, "reason": self.reason,
             "touches": self.touches, "rotation_error_deg": self.rotation_error_deg,
             "translation_error_mm": self.translation_error_mm, "t_s": self.t_s, "wall_s": round(self.wall_s, 4)}
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "PointResult":
        return cls(index=int(d["index"]), sweep=str(d["sweep"]),
                   commanded=Pose.from_dict(d["commanded"]),  # type: ignore[arg-type]
                   truth=Pose.from_dict(d["truth"]),  # type: ignore[arg-type]
                   estimate=Pose.from_dict(d.get("estimate")), ok=bool(d["ok"]),
                   confidence=float(d["confidence"]) if d.get("confidence") is not None else float("nan"),
                   method=str(d.get("method", "")), reason=d.get("reason"), touches=int(d.get("touches", 1)),
                   rotation_error_deg=d.get("rotation_error_deg"),
                   translation_error_mm=d.get("translation_error_mm"),
                   t_s=float(d.get("t_s", 0.0)), wall_s=float(d.get("wall_s", 0.0)))


def _finite(v: float) -> float | None:
    return float(v) if v is not None and math.isfinite(float(v)) else None


def _mae_std(errors: Sequence[float]) -> tuple[float | None, float | None]:
    if not errors:
        return None, None
    a = np.abs(np.asarray(errors, dtype=np.float64))
    return float(a.mean()), float(a.std())


def summarize(results: Iterable[PointResult]) -> dict[str, Any]:
    """Li 2014 figures of a run: MAE and standard deviation of the absolute errors.

    Rotation figures come from the rotation sweep's points, translation figures from the
    translation sweep's (as in Fig. 7b/c); ``*_all`` figures pool every localized point. Refused
    points (no estimate) are counted in ``n_refused`` and left out of the errors. A figure is None
    when its sweep has no localized point.
    """
    res = sorted(results, key=lambda r: r.index)
    ok = [r for r in res if r.ok]
    rot = [r.rotation_error_deg for r in ok if r.sweep == "rotation" and r.rotation_error_deg is not None]
    tra = [r.translation_error_mm for r in ok if r.sweep == "translation" and r.translation_error_mm is not None]
    rot_mae, rot_std = _mae_std(rot)  # type: ignore[arg-type]
    tra_mae, tra_std = _mae_std(tra)  # type: ignore[arg-type]
    rot_all = _mae_std([r.rotation_error_deg for r in ok])  # type: ignore[misc]
    tra_all = _mae_std([r.translation_error_mm for r in ok])  # type: ignore[misc]
    return {"type": "summary", "n_points": len(res), "n_localized": len(ok), "n_refused": len(res) - len(ok),
            "rotation_points": sum(r.sweep == "rotation" for r in res),
            "translation_points": sum(r.sweep == "translation" for r in res),
            "rotation_mae_deg": rot_mae, "rotation_std_deg": rot_std,
            "translation_mae_mm": tra_mae, "translation_std_mm": tra_std,
            "rotation_max_deg": max(rot) if rot else None, "translation_max_mm": max(tra) if tra else None,
            "rotation_mae_all_deg": rot_all[0], "translation_mae_all_mm": tra_all[0],
            "extra_touches": sum(max(r.touches - 1, 0) for r in res),
            "paper": dict(PAPER_FIGURES)}


# -- persistence ------------------------------------------------------------------------------
class RunStore:
    """``OUT/run.json`` (config, fingerprint, status) and ``OUT/points.jsonl`` (one finished point a line)."""

    def __init__(self, out_dir: str | Path) -> None:
        self.out = Path(out_dir)
        self.run_path = self.out / "run.json"
        self.points_path = self.out / "points.jsonl"

    def read_meta(self) -> dict[str, Any] | None:
        if not self.run_path.exists():
            return None
        try:
            return json.loads(self.run_path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise RunConflict(f"{self.run_path} is unreadable ({exc}); use another --out or --overwrite") from None

    def write_meta(self, meta: dict[str, Any]) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        tmp = self.run_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")
        os.replace(tmp, self.run_path)  # atomic: a kill never leaves half a run.json

    def read_points(self) -> list[PointResult]:
        """Finished points; a torn last line (killed mid-write) is dropped from the file."""
        if not self.points_path.exists():
            return []
        raw = self.points_path.read_bytes()
        good: list[PointResult] = []
        keep = 0
        for line in raw.splitlines(keepends=True):
            if not line.endswith(b"\n"):
                break
            try:
                good.append(PointResult.from_json(json.loads(line)))
            except (ValueError, KeyError, TypeError):
                break
            keep += len(line)
        if keep != len(raw):
            with open(self.points_path, "r+b") as fh:
                fh.truncate(keep)
        return good

    def append_point(self, result: PointResult) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        line = json.dumps(result.to_json(), separators=(",", ":")) + "\n"
        with open(self.points_path, "a", encoding="utf-8") as fh:
            fh.write(line)
            fh.flush()
            os.fsync(fh.fileno())

    def reset(self) -> None:
        """Forget a previous run in OUT (its points, its state, its map and calibration)."""
        for p in (self.points_path, self.run_path, self.out / "summary.json", self.out / "map.npz"):
            if p.exists():
                p.unlink()

    def begin(self, cfg: JigAccuracyConfig, *, bench: dict[str, Any], resume: bool | None,
              overwrite: bool, calibration: dict[str, Any] | None = None) -> list[PointResult]:
        """Start or resume a run in OUT; return the points already finished.

        ``resume=None`` resumes automatically when OUT holds a partial run with the same config;
        ``True`` requires one; ``False`` refuses to touch an existing run unless ``overwrite``.
        ``calibration`` (path and digest) must match the one the run started with.
        """
        meta = None if overwrite else self.read_meta()
        if overwrite:
            self.reset()
        done: list[PointResult] = []
        if meta is not None:
            if meta.get("format") != RUN_FORMAT or meta.get("version") != RUN_FORMAT_VERSION:
                raise RunConflict(f"{self.run_path} is not a jig accuracy run of format version "
                                  f"{RUN_FORMAT_VERSION}; use another --out or --overwrite")
            if meta.get("fingerprint") != cfg.fingerprint() or meta.get("bench_kind") != bench.get("kind"):
                raise RunConflict(f"{self.out} holds a run with another configuration "
                                  f"(fingerprint {meta.get('fingerprint')} vs {cfg.fingerprint()}); "
                                  "resume it with the same options, or pass --overwrite or another --out")
            old_cal = (meta.get("calibration") or {}).get("sha256")
            if calibration is not None and old_cal is not None and old_cal != calibration.get("sha256"):
                raise RunConflict(f"{self.out} was started with another GelSight calibration "
                                  f"({meta['calibration'].get('path')}); resume it with that one, or pass "
                                  "--overwrite or another --out")
            if resume is False:
                raise RunConflict(f"{self.out} already holds a run (status {meta.get('status')!r}); "
                                  "pass --resume to continue it or --overwrite to start again")
            done = self.read_points()
        elif resume:
            raise RunConflict(f"--resume: {self.out} holds no run to resume")
        if meta is None:
            meta = {"format": RUN_FORMAT, "version": RUN_FORMAT_VERSION, "config": cfg.to_dict(),
                    "fingerprint": cfg.fingerprint(), "bench_kind": bench.get("kind"), "bench": bench,
                    "started": utc_now(), "points_planned": len(plan_points(cfg)), "attempts": 0,
                    "calibration": calibration}
        meta["attempts"] = int(meta.get("attempts", 0)) + 1
        meta["status"] = "complete" if len(done) >= meta["points_planned"] else "running"
        self.write_meta(meta)
        return done

    def finish(self, summary: dict[str, Any]) -> None:
        meta = self.read_meta() or {}
        meta["status"] = "complete"
        meta["finished"] = utc_now()
        self.write_meta(meta)
        (self.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")


# -- the devices and the perception, as the run sees them ---------------------------------------
class JigRig(Protocol):
    """What a jig accuracy run needs of the bench: move, touch, and (mocks) the truth."""

    def move_to(self, pose: Pose) -> None:
        """Move the jig to ``pose`` and return once it is idle there and settled."""
        ...

    def touch(self) -> np.ndarray:
        """A fresh GelSight frame (BGR uint8) of the object pressed at the current pose."""
        ...

    def truth(self, commanded: Pose) -> Pose:
        """The true pose: the world's stage pose on a mock, ``commanded`` on a bench."""
        ...

    def now_s(self) -> float:
        """The rig's clock (virtual time on mocks)."""
        ...

    def describe(self) -> dict[str, Any]:
        """JSON-able description (kind ``mock`` or ``bench``, devices, scene) for run.json."""
        ...


@dataclass
class Localization:
    """A touch localized in the map: the stage pose estimate (None: refused) and why."""

    pose: Pose | None
    confidence: float
    method: str
    reason: str | None = None
    raw: Any = None


class TouchLocalizer:
    """Frame → height map (calibrated GelSight model) → stage pose in the tactile map.

    The map is a :class:`~tactile_rig.perception.gelsight.tactile_map.TactileMap`: its frame is the
    first touch's sensor frame; later touches join it when their registration confidence exceeds
    ``min_map_confidence`` (the jig's commanded pose is passed as a hint for a dense check when the
    keypoints refuse).
    """

    def __init__(self, calibration: Any, registration: dict[str, Any] | None = None,
                 min_map_confidence: float = 0.98) -> None:
        from tactile_rig.perception.gelsight.pipeline import Reconstructor
        from tactile_rig.perception.gelsight.registration import RegistrationParams
        from tactile_rig.perception.gelsight.tactile_map import TactileMap

        self.calibration = calibration
        self.reconstructor = Reconstructor(calibration)
        self.params = RegistrationParams(**(registration or {}))
        self.min_map_confidence = float(min_map_confidence)
        mx, my = float(calibration.mm_per_px_x), float(calibration.mm_per_px_y)
        if abs(mx - my) > 1e-6 * max(mx, my):
            raise CalibrationError(f"the tactile map needs square pixels; the calibration has {mx} x {my} mm/px",
                                   device="jig_accuracy")
        self.map = TactileMap(mx, accept_confidence=self.min_map_confidence, params=self.params)

    def height_mm(self, frame_bgr: np.ndarray) -> np.ndarray:
        return self.reconstructor.height_mm(frame_bgr)

    @property
    def map_size(self) -> int:
        return len(self.map.poses)

    def add_to_map(self, height_mm: np.ndarray, hint: Pose | None = None) -> Localization:
        """Add a touch: the first defines the map frame; later ones join when localized with c above threshold."""
        first = self.map.empty
        rec = self.map.add_touch(height_mm, None if hint is None else touch_matrix_from_pose(hint))
        res = rec.result
        if first:
            return Localization(Pose(), 1.0, "root", None, res)
        if not rec.accepted:
            reason = res.reason or f"confidence {res.confidence:.3f} <= {self.min_map_confidence}"
            return Localization(None, float(res.confidence), res.method, reason, res)
        return Localization(pose_from_touch_matrix(res.matrix_mm), float(res.confidence), res.method, None, res)

    def localize(self, height_mm: np.ndarray) -> Localization:
        """The stage pose of a touch in the map frame (refused: ``pose`` None with a reason)."""
        if self.map.empty:
            raise CalibrationError("localize before any map touch", device="jig_accuracy")
        res = self.map.localize(height_mm)
        if not res.ok:
            return Localization(None, float(res.confidence), res.method, res.reason, res)
        return Localization(pose_from_touch_matrix(res.matrix_mm), float(res.confidence), res.method, None, res)

    def save_map(self, path: str | Path) -> None:
        self.map.save(path)

    def load_map(self, path: str | Path) -> None:
        from tactile_rig.perception.gelsight.tactile_map import TactileMap

        self.map = TactileMap.load(path, self.params)


# -- the run ----------------------------------------------------------------------------------
@dataclass
class RunOutcome:
    """What a run produced: every point (resumed ones included), the summary and the files."""

    results: list[PointResult]
    summary: dict[str, Any]
    out_dir: Path
    resumed_from: int = 0
    map_report: list[dict[str, Any]] = field(default_factory=list)
    files: dict[str, str] = field(default_factory=dict)


PointCallback = Callable[[PointResult, int, int], None]


def build_map(rig: JigRig, localizer: TouchLocalizer, cfg: JigAccuracyConfig) -> list[dict[str, Any]]:
    """Touch the object at the configured jig positions and grow the tactile map (Li 2014: c > 0.98).

    Returns one report row per touch (commanded pose, localized pose, confidence, accepted).
    Raises :class:`CalibrationError` when the first touch shows no contact texture.
    """
    rows: list[dict[str, Any]] = []
    for i, (x, y) in enumerate(cfg.map_touches_mm):
        pose = Pose(float(x), float(y), theta_deg=0.0)
        rig.move_to(pose)
        height = localizer.height_mm(rig.touch())
        if i == 0 and float(np.ptp(height)) < 1e-3:
            raise CalibrationError("the first map touch shows no contact (flat height map): is the object "
                                   "under the sensor and pressed?", device="jig_accuracy")
        loc = localizer.add_to_map(height, None if i == 0 else pose)
        rows.append({"commanded": pose.as_dict(), "truth": rig.truth(pose).as_dict(),
                     "estimate": None if loc.pose is None else loc.pose.as_dict(),
                     "confidence": _finite(loc.confidence), "accepted": loc.pose is not None,
                     "reason": loc.reason})
    return rows


def measure_point(rig: JigRig, localizer: TouchLocalizer, point: JigPoint, retouches: int,
                  retouch_below: float = 0.0) -> PointResult:
    """Move to one jig point, touch, localize, and score it.

    A touch that is refused, or localized with a confidence below ``retouch_below``, is repeated up
    to ``retouches`` times; the localization with the highest confidence is kept.
    """
    t_wall = time.perf_counter()
    rig.move_to(point.pose)
    truth = rig.truth(point.pose)
    loc = Localization(None, 0.0, "none", "not touched")
    touches = 0
    for touches in range(1, int(retouches) + 2):
        new = localizer.localize(localizer.height_mm(rig.touch()))
        if loc.pose is None or (new.pose is not None and new.confidence > loc.confidence):
            loc = new
        if loc.pose is not None and loc.confidence >= retouch_below:
            break
    return PointResult.make(point, truth, loc.pose, confidence=loc.confidence, method=loc.method,
                            reason=loc.reason, touches=touches, t_s=round(rig.now_s(), 6),
                            wall_s=time.perf_counter() - t_wall)


def run_jig_accuracy(rig: JigRig, localizer: TouchLocalizer, cfg: JigAccuracyConfig, out_dir: str | Path, *,
                     resume: bool | None = None, overwrite: bool = False,
                     on_point: PointCallback | None = None, recorder: Any = None,
                     stop_after: int | None = None, calibration: dict[str, Any] | None = None) -> RunOutcome:
    """Run (or resume) a jig accuracy run into ``out_dir``; see the module doc.

    ``on_point(result, done, total)`` is called after each point (resumed points included, first).
    ``recorder`` (optional) gets ``record_map(rows)`` once the map is built and ``record_point(result)``
    after each point.
    ``stop_after`` stops after that many new points (tests use it to simulate an interruption).
    """
    store = RunStore(out_dir)
    done = store.begin(cfg, bench=rig.describe(), resume=resume, overwrite=overwrite, calibration=calibration)
    plan = plan_points(cfg)
    by_index = {r.index: r for r in done if r.index < len(plan)}
    map_path = store.out / "map.npz"
    map_rows: list[dict[str, Any]] = []
    if by_index and map_path.exists():
        localizer.load_map(map_path)
        if (store.out / "map.json").exists():
            map_rows = json.loads((store.out / "map.json").read_text(encoding="utf-8"))
    else:
        map_rows = build_map(rig, localizer, cfg)
        localizer.save_map(map_path)
        (store.out / "map.json").write_text(json.dumps(map_rows, indent=2) + "\n", encoding="utf-8")
        if recorder is not None:
            recorder.record_map(map_rows)
    results = [by_index[i] for i in sorted(by_index)]
    for r in results:
        if on_point:
            on_point(r, r.index + 1, len(plan))
    new = 0
    for point in plan:
        if point.index in by_index:
            continue
        if stop_after is not None and new >= stop_after:
            break
        r = measure_point(rig, localizer, point, cfg.retouches, cfg.retouch_below_confidence)
        store.append_point(r)
        if recorder is not None:
            recorder.record_point(r)
        results.append(r)
        new += 1
        if on_point:
            on_point(r, point.index + 1, len(plan))
    summary = summarize(results)
    summary["config_fingerprint"] = cfg.fingerprint()
    summary["complete"] = len(results) == len(plan)
    if summary["complete"]:
        store.finish(summary)
    return RunOutcome(results=results, summary=summary, out_dir=store.out, resumed_from=len(by_index),
                      map_report=map_rows)


# -- the printed table ------------------------------------------------------------------------
def _f(v: float | None, fmt: str) -> str:
    return "—" if v is None or not math.isfinite(float(v)) else format(float(v), fmt)


def format_table(results: Sequence[PointResult], summary: dict[str, Any]) -> str:
    """The run as a text table (one row per point) and the Li 2014 comparison."""
    head = (f"{'#':>3} {'sweep':<11} {'cmd θ°':>7} {'cmd x':>6} {'cmd y':>6} | {'true θ°':>8} {'true x':>7} "
            f"{'true y':>7} | {'est θ°':>8} {'est x':>7} {'est y':>7} | {'err θ°':>6} {'err mm':>6} {'conf':>5}")
    lines = [head, "-" * len(head)]
    for r in sorted(results, key=lambda r: r.index):
        e = r.estimate
        lines.append(
            f"{r.index:>3} {r.sweep:<11} {r.commanded.theta_deg:>7.1f} {r.commanded.x_mm:>6.1f} "
            f"{r.commanded.y_mm:>6.1f} | {r.truth.theta_deg:>8.3f} {r.truth.x_mm:>7.3f} {r.truth.y_mm:>7.3f} | "
            f"{_f(e and e.theta_deg, '8.3f'):>8} {_f(e and e.x_mm, '7.3f'):>7} {_f(e and e.y_mm, '7.3f'):>7} | "
            f"{_f(r.rotation_error_deg, '6.3f'):>6} {_f(r.translation_error_mm, '6.3f'):>6} "
            f"{_f(r.confidence, '5.3f'):>5}" + ("" if r.ok else f"  refused: {r.reason}"))
    lines.append("")
    s, p = summary, PAPER_FIGURES
    lines.append(f"rotation sweep    ({s['rotation_points']:>2} points): MAE {_f(s['rotation_mae_deg'], '.3f')}° "
                 f"(std {_f(s['rotation_std_deg'], '.3f')}°)    Li 2014: {p['rotation_mae_deg']}° "
                 f"(std {p['rotation_std_deg']}°)")
    lines.append(f"translation sweep ({s['translation_points']:>2} points): MAE "
                 f"{_f(s['translation_mae_mm'], '.4f')} mm (std {_f(s['translation_std_mm'], '.4f')} mm)    "
                 f"Li 2014: {p['translation_mae_mm']} mm (std {p['translation_std_mm']} mm)")
    lines.append(f"localized {s['n_localized']}/{s['n_points']} points ({s['n_refused']} refused, "
                 f"{s.get('extra_touches', 0)} re-touches)")
    return "\n".join(lines)


# -- devices ----------------------------------------------------------------------------------
class DeviceJigRig:
    """A :class:`JigRig` over drivers: a GRBL ``Jig`` and a ``FingertipCamera`` on one clock.

    ``world`` (mocks only) supplies the truth: the stage model's pose after the world is advanced to
    now. Without a world the truth is the commanded pose (a bench). ``recorder`` (optional, a
    :class:`~tactile_rig.rig.recording.Recorder`) receives every move, pose and frame.
    """

    def __init__(self, jig: Any, camera: Any, clock: Any, *, world: Any = None, stage: str = "stage",
                 feed_mm_per_min: float | None = None, settle_s: float = 0.1, move_timeout_s: float = 120.0,
                 frame_timeout_s: float = 2.0, description: dict[str, Any] | None = None,
                 recorder: Any = None, camera_name: str = "gelsight") -> None:
        self.jig, self.camera, self.clock, self.world = jig, camera, clock, world
        self.stage_name = stage
        self.feed_mm_per_min = None if feed_mm_per_min is None else float(feed_mm_per_min)
        self.settle_s = float(settle_s)
        self.move_timeout_s = float(move_timeout_s)
        self.frame_timeout_s = float(frame_timeout_s)
        self.description = dict(description or {"kind": "mock" if world is not None else "bench"})
        self.recorder = recorder
        self.camera_name = camera_name

    def now_s(self) -> float:
        return float(self.clock.now_s())

    def move_to(self, pose: Pose) -> None:
        if self.recorder is not None:
            self.recorder.write_command("jig", "move_to", **pose.as_dict(), feed_mm_per_min=self.feed_mm_per_min)
        self.jig.move_to(pose.x_mm, pose.y_mm, pose.theta_deg, feed_mm_per_min=self.feed_mm_per_min)
        self.jig.wait_idle(timeout_s=self.move_timeout_s)
        self.clock.sleep(self.settle_s)
        if self.recorder is not None:
            extra = {}
            if self.world is not None:
                extra = {"true_" + k: v for k, v in self.truth(pose).as_dict().items()}
            self.recorder.write_jig_pose({**pose.as_dict(), "z_mm": 0.0}, **extra)

    def touch(self) -> np.ndarray:
        frame = self.camera.read(timeout_s=self.frame_timeout_s)
        image = getattr(frame, "image", frame)
        if self.recorder is not None:
            self.recorder.write_frame(self.camera_name, image, compress="png")
        return image

    def truth(self, commanded: Pose) -> Pose:
        if self.world is None:
            return commanded
        self.world.advance_to()
        st = self.world.require(self.stage_name, "the jig accuracy run")
        return Pose(float(st.x_mm), float(st.y_mm), theta_deg=float(st.theta_deg))

    def describe(self) -> dict[str, Any]:
        return dict(self.description)


def sim_camera_connector(sensor_model: str) -> Callable[[Any, Any], Any]:
    """A bench connector that renders a scene's sensor model through the simulated UVC camera."""

    def connect(cfg: Any, ctx: Any) -> Any:
        from tactile_rig.drivers.camera import CameraConfig, FingertipCamera
        from tactile_rig.mocks.camera import SimulatedCamera

        if ctx.world is None:
            raise RigError("a simulated GelSight camera needs a scene with a renderer", device=cfg.name)
        renderer = ctx.world.require(sensor_model, f"camera [{cfg.name}]")
        sim = SimulatedCamera(renderer, clock=ctx.clock, name=cfg.name, fourcc=cfg.fourcc,
                              width=cfg.width, height=cfg.height, fps=cfg.fps)
        cam = FingertipCamera(sim, CameraConfig(fourcc=cfg.fourcc, width=cfg.width, height=cfg.height,
                                                fps=cfg.fps), clock=ctx.clock, name=cfg.name)
        return cam.open()

    return connect


def connect_mock_jig_rig(*, scene: str = "jig_accuracy", seed: int = 0, start_s: float = 0.0,
                         sensor_model: str = "gelsight") -> Any:
    """Connect the jig and camera drivers of the built-in mock bench to ``scene`` (one VirtualClock).

    Returns the connected :class:`~tactile_rig.rig.bench.Rig` (its ``world`` holds the scene); the
    jig driver talks to the GRBL mock over ``rigsim://@mock.jig`` and the camera renders
    ``sensor_model`` at the stage's pose. ``start_s`` starts the clock later (a resumed run).
    """
    from tactile_rig.core.clock import VirtualClock
    from tactile_rig.rig.bench import Bench, connect_bench, load_bench, mock_bench_path

    base = load_bench(mock_bench_path(), check_files=False)
    missing = [d for d in ("jig", "camera") if d not in base.devices]
    if missing:
        raise RigError(f"the mock bench {base.source} lacks {', '.join(missing)}", device="jig_accuracy")
    bench = Bench(name=base.name, devices={k: base.devices[k] for k in ("jig", "camera")}, source=base.source,
                  path=base.path, text=base.text, scene=scene, seed=int(seed))
    return connect_bench(bench, connectors={"camera": sim_camera_connector(sensor_model)},
                         clock=VirtualClock(start_s))


def connect_bench_jig_rig(bench: Any, camera: str | None = None, *, start_s: float = 0.0) -> tuple[Any, str]:
    """Connect the jig and one GelSight camera of a bench; returns (Rig, camera name).

    A bench file made of mocks (every port ``rigsim://``) runs on its ``[bench] scene`` (default: the
    jig accuracy scene), with the simulated camera rendering the scene's ``gelsight`` model.
    """
    from tactile_rig.core.clock import VirtualClock
    from tactile_rig.rig.bench import Bench, connect_bench

    cams = [n for n, c in bench.cameras.items() if c.sensor == "gelsight"]
    name = camera or (cams[0] if cams else None)
    if name is None or name not in bench.devices:
        raise RigError(f"{bench.source}: a jig accuracy run needs a [camera] with sensor = \"gelsight\"",
                       device="jig_accuracy")
    sub = Bench(name=bench.name, devices={"jig": bench.device("jig"), name: bench.device(name)},
                source=bench.source, path=bench.path, text=bench.text, scene=bench.scene, seed=bench.seed)
    if not sub.is_mock:
        return connect_bench(sub), name
    sub.scene = sub.scene or MOCK_SCENE
    return connect_bench(sub, connectors={"camera": sim_camera_connector("gelsight")},
                         clock=VirtualClock(start_s)), name


# -- reports and recordings -------------------------------------------------------------------
def write_report(outcome: RunOutcome, localizer: TouchLocalizer | None = None) -> dict[str, str]:
    """Figures (estimated vs true as Li 2014 Fig. 7b/c, error histograms, the tactile map) and
    ``report.md`` in the run's folder. Needs matplotlib for the figures; without it only the page."""
    from tactile_rig.rig import reports

    out = outcome.out_dir
    files: dict[str, str] = {}
    res = sorted(outcome.results, key=lambda r: r.index)
    rot = [r for r in res if r.sweep == "rotation"]
    tra = [r for r in res if r.sweep == "translation"]
    nan = float("nan")
    figs: list[tuple[Path, str]] = []
    try:
        if rot:
            figs.append((reports.plot_estimated_vs_true(
                [r.truth.theta_deg for r in rot], [r.estimate.theta_deg if r.estimate else nan for r in rot],
                out / "rotation_est_vs_true.png", quantity="rotation", unit="deg",
                title="rotation (cf. Li 2014 Fig. 7b)"), "Rotation sweep: estimated vs true"))
            figs.append((reports.plot_error_histogram(
                [wrap_deg(r.estimate.theta_deg - r.truth.theta_deg) for r in rot if r.estimate],
                out / "rotation_error_hist.png", quantity="rotation error", unit="deg"),
                "Rotation error (estimate − truth)"))
        if tra:
            axis = "x_mm" if any(abs(r.commanded.x_mm) > 0 for r in tra) else "y_mm"
            figs.append((reports.plot_estimated_vs_true(
                [getattr(r.truth, axis) for r in tra], [getattr(r.estimate, axis) if r.estimate else nan for r in tra],
                out / "translation_est_vs_true.png", quantity=f"shift {axis[0]}", unit="mm",
                title="translation (cf. Li 2014 Fig. 7c)"), "Translation sweep: estimated vs true"))
            figs.append((reports.plot_error_histogram(
                [r.translation_error_mm for r in tra if r.translation_error_mm is not None],
                out / "translation_error_hist.png", quantity="translation error", unit="mm"),
                "Translation error: distance between estimate and truth"))
        if localizer is not None and not localizer.map.empty:
            cov = localizer.map.coverage
            rows, cols = np.nonzero(cov.any(axis=1))[0], np.nonzero(cov.any(axis=0))[0]
            crop = np.where(cov, localizer.map.height_mm, np.nan)[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
            figs.append((reports.plot_tactile_map(crop, out / "tactile_map.png", mm_per_px=localizer.map.mm_per_px,
                                                  title=f"tactile map ({localizer.map_size} touches)"),
                         "Tactile map (height, mm)"))
    except ModuleNotFoundError as exc:
        if exc.name != "matplotlib":
            raise
        files["figures"] = "skipped: matplotlib is not installed (pip install 'tactile-rig[report]')"
    s = outcome.summary
    page = reports.Report(out, "Jig accuracy run (Li 2014, Fig. 7)")
    page.text("Estimated vs true jig poses; truth is the simulated stage pose on mocks and the commanded "
              "jig pose on a bench. Errors: |Δθ| for the rotation sweep, |Δ(x, y)| for the translation "
              "sweep; MAE and standard deviation of the absolute errors; refused touches are counted, "
              "not scored.")
    page.numbers("Summary", {
        "rotation MAE (deg)": s["rotation_mae_deg"], "rotation std (deg)": s["rotation_std_deg"],
        "translation MAE (mm)": s["translation_mae_mm"], "translation std (mm)": s["translation_std_mm"],
        "Li 2014 rotation MAE / std (deg)": f"{PAPER_FIGURES['rotation_mae_deg']} / {PAPER_FIGURES['rotation_std_deg']}",
        "Li 2014 translation MAE / std (mm)":
            f"{PAPER_FIGURES['translation_mae_mm']} / {PAPER_FIGURES['translation_std_mm']}",
        "points localized": f"{s['n_localized']} / {s['n_points']}"})
    for path, caption in figs:
        page.figure(path, caption)
        files[path.stem] = str(path)
    page.table("Points", [{"#": r.index, "sweep": r.sweep, "true θ": r.truth.theta_deg, "true x": r.truth.x_mm,
                           "true y": r.truth.y_mm, "est θ": r.estimate.theta_deg if r.estimate else None,
                           "est x": r.estimate.x_mm if r.estimate else None,
                           "est y": r.estimate.y_mm if r.estimate else None,
                           "err θ": r.rotation_error_deg, "err mm": r.translation_error_mm,
                           "c": r.confidence, "refused": r.reason or ""} for r in res])
    files["report"] = str(page.write())
    return files


class RunRecorder:
    """Adapter from a :class:`~tactile_rig.rig.recording.Recorder` to the run's ``record_*`` calls."""

    def __init__(self, recorder: Any) -> None:
        self.recorder = recorder

    def record_map(self, rows: list[dict[str, Any]]) -> None:
        for i, row in enumerate(rows):
            self.recorder.write_perception("tactile_map_touch", {"touch": i, **row})
        self.recorder.flush()

    def record_point(self, result: PointResult) -> None:
        self.recorder.write_perception("jig_accuracy_point", result.to_json())
        self.recorder.flush()  # the point is in points.jsonl: make it readable in the MCAP too


def open_run_recording(out_dir: Path, clock: Any, *, resume: bool) -> Any:
    """``OUT/run.mcap`` (None without the ``mcap`` package). On a resumed run the messages of the
    interrupted attempt (readable up to its last flush) are copied into the new file first."""
    try:
        from tactile_rig.rig.recording import Recorder, iter_messages
    except ModuleNotFoundError:
        return None
    try:
        import mcap  # noqa: F401
    except ModuleNotFoundError:
        return None
    path = out_dir / "run.mcap"
    old: list[Any] = []
    if resume and path.exists():
        try:
            old = list(iter_messages(path))
        except Exception:  # noqa: BLE001 - an unreadable old recording is replaced, not fatal
            old = []
    rec = Recorder(path, clock=clock, background_flush=False)
    for m in old:
        rec.write(m.topic, m.data, t_s=m.t_s, schema=m.schema)
    rec.flush()
    return rec


# -- the whole run: calibration, devices, recording, report -------------------------------------
MOCK_SCENE = "jig_accuracy"
MOCK_PRESS_SCENE = "gelsight_ball_presses"


def prepare_jig(jig: Any, timeout_s: float = 120.0) -> None:
    """Bring a GRBL jig to Idle: home it when it is locked in Alarm (GRBL with homing enabled)."""
    status = getattr(jig, "status", None)
    state = ""
    if callable(status):
        st = status()
        state = str(getattr(st, "state", st) or "")
    if state.startswith("Alarm") and callable(getattr(jig, "home", None)):
        try:
            jig.home(timeout_s=timeout_s)
        except TypeError:  # a driver whose home() takes no timeout
            jig.home()


def mock_gelsight_calibration(out: Path, *, seed: int = 0, guide: Any = None) -> Path:
    """Run the GelSight calibration session on the mocks (ball scene) and return the calibration path."""
    from tactile_rig.rig.calibration_sessions import BallPressPlan, gelsight_session

    rig = connect_mock_jig_rig(scene=MOCK_PRESS_SCENE, seed=seed)
    try:
        prepare_jig(rig.jig)
        cam = rig.bench.devices["camera"]
        press_rig = DeviceJigRig(rig.jig, rig.devices["camera"], rig.clock, world=rig.world, settle_s=0.05)
        outcome = gelsight_session(press_rig, BallPressPlan(), float(cam.mm_per_px_x), out, guide=guide)
    finally:
        rig.close()
    return Path(outcome.files["json"])


def calibration_digest(path: str | Path) -> str:
    """SHA-256 (16 hex digits) of a GelSight calibration's files (``.json`` + ``.npz``)."""
    base = Path(path)
    if base.suffix in (".json", ".npz"):
        base = base.with_suffix("")
    h = hashlib.sha256()
    for suffix in (".json", ".npz"):
        p = base.with_suffix(suffix)
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def execute_jig_accuracy(cfg: JigAccuracyConfig, out_dir: str | Path, *, bench: Any = None,
                         calibration: str | Path | None = None, camera: str | None = None,
                         resume: bool | None = None, overwrite: bool = False, record: bool = True,
                         report: bool = True, on_point: PointCallback | None = None,
                         stop_after: int | None = None, guide: Any = None) -> RunOutcome:
    """A complete jig accuracy run on the mocks (``bench=None``) or on a bench (a loaded Bench).

    Calibration: ``calibration`` if given, else the one this run already stored in ``OUT/calibration``,
    else the bench camera's ``calibration`` file; on mocks a missing one is made by the GelSight
    calibration session on the ball scene. Writes ``OUT/points.jsonl``, ``run.json``, ``summary.json``,
    ``map.npz``, ``run.mcap`` (with mcap) and figures + ``report.md`` (with matplotlib).
    """
    from tactile_rig.perception.gelsight.calibration import GelSightCalibration

    out = Path(out_dir)
    store = RunStore(out)
    if overwrite:
        store.reset()
        for p in (out / "calibration").glob("gelsight*") if (out / "calibration").is_dir() else []:
            if p.is_file():
                p.unlink()
    cal_path: Path | None = Path(calibration) if calibration is not None else None
    meta = store.read_meta()
    started_with = Path((meta or {}).get("calibration", {}).get("path") or "") if meta else None
    stored_cal = out / "calibration" / "gelsight.json"
    if cal_path is None and started_with is not None and started_with.is_file():
        cal_path = started_with  # a resumed run keeps the calibration it started with
    if cal_path is None and stored_cal.exists():
        cal_path = stored_cal
    if cal_path is None and bench is not None:
        cams = [c for c in bench.cameras.values() if c.sensor == "gelsight" and (camera is None or c.name == camera)]
        if cams and cams[0].calibration is not None:
            cal_path = Path(cams[0].calibration)
        elif not bench.is_mock:
            raise CalibrationError(f"{bench.source}: no GelSight calibration; make one with: tactile-rig calibrate "
                                   f"gelsight --bench {bench.source} (or pass --calibration FILE)",
                                   device="jig_accuracy")
    if cal_path is None:
        cal_path = mock_gelsight_calibration(out / "calibration" / "gelsight", seed=cfg.seed, guide=guide)
    cal = GelSightCalibration.load(cal_path)
    cal_id = {"path": str(Path(cal_path).resolve().with_suffix(".json")), "sha256": calibration_digest(cal_path)}
    previous = store.read_points() if store.read_meta() is not None else []
    start_s = (max(r.t_s for r in previous) + 1.0) if previous else 0.0
    if bench is None:
        rig_handle = connect_mock_jig_rig(scene=MOCK_SCENE, seed=cfg.seed, start_s=start_s)
        cam_name = "camera"
        description = {"kind": "mock", "scene": MOCK_SCENE, "seed": cfg.seed,
                       "bench": rig_handle.bench.source}
    else:
        rig_handle, cam_name = connect_bench_jig_rig(bench, camera, start_s=start_s)
        description = {"kind": "mock" if bench.is_mock else "bench", "bench": bench.source, "name": bench.name}
        if bench.is_mock:
            description.update(scene=rig_handle.bench.scene, seed=bench.seed)
    recorder = None
    try:
        prepare_jig(rig_handle.jig)
        if record:
            recorder = open_run_recording(out, rig_handle.clock, resume=bool(previous))
            if recorder is not None:
                recorder.add_bench(rig_handle.bench)
                recorder.add_calibration("gelsight", path=cal_path)
                recorder.add_metadata("jig_accuracy", {"config": cfg.to_dict(), "fingerprint": cfg.fingerprint()})
        world = rig_handle.world if bench is None or bench.is_mock else None
        rig = DeviceJigRig(rig_handle.jig, rig_handle.devices[cam_name], rig_handle.clock, world=world,
                           feed_mm_per_min=cfg.feed_mm_per_min, settle_s=cfg.settle_s, description=description,
                           recorder=recorder, camera_name=cam_name)
        localizer = TouchLocalizer(cal, dict(cfg.registration), cfg.map_min_confidence)
        outcome = run_jig_accuracy(rig, localizer, cfg, out, resume=resume, overwrite=False, on_point=on_point,
                                   recorder=RunRecorder(recorder) if recorder is not None else None,
                                   stop_after=stop_after, calibration=cal_id)
        outcome.files.update({"points": str(store.points_path), "run": str(store.run_path),
                              "calibration": str(cal_path), "map": str(out / "map.npz")})
        if outcome.summary.get("complete"):
            outcome.files["summary"] = str(out / "summary.json")
        if recorder is not None:
            outcome.files["recording"] = str(recorder.path)
        elif record:
            outcome.files["recording"] = "skipped: the mcap package is not installed (pip install 'tactile-rig[record]')"
        if report and outcome.summary.get("complete"):
            outcome.files.update(write_report(outcome, localizer))
        return outcome
    finally:
        if recorder is not None:
            recorder.close()
        rig_handle.close()

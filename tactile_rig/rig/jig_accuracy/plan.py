"""What a jig accuracy run does: its configuration, its planned points, and the pose algebra between a
jig pose and the 2x3 transform a registration returns (frames in the package docstring)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactile_rig.core.errors import check_range
from tactile_rig.core.geometry import (
    Pose,
    invert_rigid,
    matrix_from_pose,
    rotation_2d,
    wrap_deg,
)

SWEEPS = ("rotation", "translation", "both")
# Li, Platt, Adelson 2014, Fig. 7 (real bench): the figures the table is compared with.
PAPER_FIGURES = {"rotation_mae_deg": 1.15, "rotation_std_deg": 1.02,
                 "translation_mae_mm": 0.14, "translation_std_mm": 0.055}


# The run registers with the perception defaults (RegistrationParams, the same values and flags as
# `tactile-rig gelsight register/map/localize`); ``registration`` overrides them explicitly, and the
# overrides are stored with the run.
DEFAULT_REGISTRATION: tuple[tuple[str, Any], ...] = ()

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
    """The 2x3 matrix (mm) taking a sensor point of a touch at stage ``pose`` into the map frame:
    the inverse of the stage's own transform, ``p_m = R(−θ) (p_s − t)``."""
    return invert_rigid(matrix_from_pose(pose, (2, 3)))


def pose_from_touch_matrix(matrix_mm: np.ndarray) -> Pose:
    """The stage pose whose touch maps into the map frame by ``matrix_mm`` (2x3, mm).

    Read as a rigid transform: θ from the rotation part, then ``t = −R(θ) m_t``, so a registration's
    slightly non-orthonormal estimate gives the nearest rigid pose."""
    m = np.asarray(matrix_mm, dtype=np.float64)
    if m.shape != (2, 3) or not np.all(np.isfinite(m)):
        raise ValueError(f"matrix_mm must be a finite 2x3 matrix, got shape {m.shape}")
    theta = -math.degrees(math.atan2(m[1, 0], m[0, 0]))  # M's rotation is R(−θ)
    tvec = -rotation_2d(theta) @ m[:, 2]
    return Pose(float(tvec[0]), float(tvec[1]), theta_deg=wrap_deg(theta))
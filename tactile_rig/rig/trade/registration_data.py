"""Independent re-touches for registration: Li's jig protocol, each touch rendered on its own.

The sensor is a GelSight Mini (the real no-contact frame of NormalFlow's unit, 240x320 at 0.0634
mm/px; see ``tactile_rig/sim/assets/PROVENANCE.md``), calibrated the way a lab would: ball presses
rendered on that background, fitted with the default calibration. A part is touched once at the
origin for the map (A) and then re-touched at every jig pose of the protocol (rotations -90..90 deg
in 10 deg steps x shifts along x): each re-touch has its **own** press depth, gel blur (elastomer
smoothing) and sensor noise, so B is never a resampled copy of A. The true B->A transform follows
from the poses in closed form (the mapping :func:`~tactile_rig.sim.world.objects.view_in_sensor`
samples with).

Scoring: a result is *right* when its rotation is within ``1 deg`` and its translation within
``0.1 mm`` of the truth, *wrong* when accepted outside that (a confident wrong answer), else
*refused*. Errors (MAE) are over the right answers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
import tempfile
from pathlib import Path

import numpy as np

from tactile_rig.perception.gelsight import (
    GelSightCalibration,
    Reconstructor,
    RegistrationParams,
    RegistrationResult,
    calibrate_from_presses,
    load_presses,
    register,
)
from tactile_rig.perception.gelsight.synthetic import tile
from tactile_rig.rig.trade.gelsight import presses_dir
from tactile_rig.sim.render import gelsight as render
from tactile_rig.sim.world import objects

MINI_MM_PER_PX = 0.0634
MINI_SHAPE = (240, 320)
ROTATIONS_DEG = tuple(float(r) for r in range(-90, 91, 10))
SHIFTS_MM = (-2.0, -1.0, 0.0, 1.0, 2.0)
RIGHT_ROT_DEG = 1.0
RIGHT_TRANS_MM = 0.1


@dataclass(frozen=True)
class Touch:
    """A rendered touch: its height map (mm, reconstructed from the frame), the frame and pose."""

    height_mm: np.ndarray
    frame_bgr: np.ndarray
    pose: tuple[float, float, float]  # x_mm, y_mm, theta_deg of the part in the sensor
    depth_mm: float
    blur_mm: float


@dataclass
class RetouchSet:
    """The map touch A and its re-touches B with the true B->A transform (2x3, px) of each."""

    part: str
    a: Touch
    touches: list[Touch] = field(default_factory=list)
    truth_px: list[np.ndarray] = field(default_factory=list)
    mm_per_px: float = MINI_MM_PER_PX


@lru_cache(maxsize=2)
def mini_calibration(seed: int = 0) -> GelSightCalibration:
    """The default calibration fitted on 20 ball presses rendered on the GelSight Mini background."""
    with tempfile.TemporaryDirectory() as tmp:
        render.render_ball_press_dataset(Path(tmp), n_presses=20, shape_px=MINI_SHAPE, mm_per_px=MINI_MM_PER_PX,
                                         background="gsmini", seed=seed)
        presses = load_presses(tmp)
    return calibrate_from_presses(presses, MINI_MM_PER_PX, 2.0)


def _sensor_to_object(obj: objects.HeightField, pose: tuple[float, float, float]) -> np.ndarray:
    # The affine map view_in_sensor samples with (sensor px -> object px), as a 3x3.
    m = objects.sensor_to_object_px(obj, MINI_SHAPE, MINI_MM_PER_PX, *pose)
    return np.vstack([m, [0.0, 0.0, 1.0]])


PARTS = {
    "plate": lambda: objects.plate_with_features(mm_per_px=0.05),
    "usb": lambda: objects.usb_connector_part(mm_per_px=0.05),
    # Plates of the same kind with their own seeded features: parts a plate map never saw.
    "other_plate_8": lambda: objects.plate_with_features(mm_per_px=0.05, seed=8),
    "other_plate_9": lambda: objects.plate_with_features(mm_per_px=0.05, seed=9),
    # Two more, held out: the search's thresholds were chosen without them.
    "other_plate_10": lambda: objects.plate_with_features(mm_per_px=0.05, seed=10),
    "other_plate_11": lambda: objects.plate_with_features(mm_per_px=0.05, seed=11),
}


def retouch_set(part: str = "plate", *, rotations_deg: tuple[float, ...] = ROTATIONS_DEG,
                shifts_mm: tuple[float, ...] = SHIFTS_MM, seed: int = 0,
                depth_mm: tuple[float, float] = (0.35, 0.7), blur_mm: tuple[float, float] = (0.5, 0.7),
                noise_scale: tuple[float, float] = (0.7, 1.5),
                calibration: GelSightCalibration | None = None) -> RetouchSet:
    """Render the map touch and one independent re-touch per (rotation, shift) of the protocol.

    depth_mm / blur_mm / noise_scale: ranges each re-touch draws its press depth, gel smoothing (mm)
    and sensor-noise multiplier from (the map touch uses their middles).
    """
    if part not in PARTS:
        raise ValueError(f"part must be one of {sorted(PARTS)}, got {part!r}")
    cal = calibration or mini_calibration()
    rec = Reconstructor(cal)
    obj = PARTS[part]()
    rng = np.random.default_rng(seed)

    def touch(pose: tuple[float, float, float], depth: float, blur: float, noise: float) -> Touch:
        r = render.GelSightRenderer(cal.background, MINI_MM_PER_PX, smoothing_mm=blur,
                                    noise_sigma=(render.TAXIM_NOISE_SIGMA[0] * noise, render.TAXIM_NOISE_SIGMA[1] * noise,
                                                 render.TAXIM_NOISE_SIGMA[2] * noise),
                                    flicker_sigma=0.5, seed=int(rng.integers(2**31)))
        frame, _ = r.render_object(obj, depth, *pose)
        return Touch(rec.height_mm(frame), frame, pose, depth, blur)

    mid = lambda lo_hi: 0.5 * (lo_hi[0] + lo_hi[1])  # noqa: E731
    pose_a = (0.0, 0.0, 0.0)
    out = RetouchSet(part, touch(pose_a, mid(depth_mm), mid(blur_mm), mid(noise_scale)))
    to_a = np.linalg.inv(_sensor_to_object(obj, pose_a))
    for rot in rotations_deg:
        for sh in shifts_mm:
            pose = (float(sh), 0.0, float(rot))
            out.touches.append(touch(pose, float(rng.uniform(*depth_mm)), float(rng.uniform(*blur_mm)),
                                     float(rng.uniform(*noise_scale))))
            out.truth_px.append((to_a @ _sensor_to_object(obj, pose))[:2])
    return out


def pose_error(matrix_px: np.ndarray, truth_px: np.ndarray, shape: tuple[int, int],
               mm_per_px: float) -> tuple[float, float]:
    """(rotation error deg, translation error mm) of a B->A ``matrix_px`` against the truth: the
    translation error is where B's centre lands in A, estimate against truth."""
    rot_t = math.degrees(math.atan2(truth_px[1, 0], truth_px[0, 0]))
    rot = math.degrees(math.atan2(matrix_px[1, 0], matrix_px[0, 0]))
    rot_err = abs((rot - rot_t + 180.0) % 360.0 - 180.0)
    c = np.array([(shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0])
    est = matrix_px[:, :2] @ c + matrix_px[:, 2]
    true = truth_px[:, :2] @ c + truth_px[:, 2]
    return rot_err, float(np.linalg.norm(est - true)) * mm_per_px


def is_right(rot_err_deg: float, trans_err_mm: float) -> bool:
    """Within RIGHT_ROT_DEG and RIGHT_TRANS_MM of the truth."""
    return rot_err_deg <= RIGHT_ROT_DEG and trans_err_mm <= RIGHT_TRANS_MM


@dataclass
class Score:
    """Right / wrong / refused counts and the errors of the right answers."""

    right: int = 0
    wrong: int = 0
    refused: int = 0
    rot_err_deg: list[float] = field(default_factory=list)
    trans_err_mm: list[float] = field(default_factory=list)
    reasons: dict[str, int] = field(default_factory=dict)

    @property
    def cases(self) -> int:
        return self.right + self.wrong + self.refused

    @property
    def rot_mae_deg(self) -> float:
        return float(np.mean(self.rot_err_deg)) if self.rot_err_deg else float("nan")

    @property
    def trans_mae_mm(self) -> float:
        return float(np.mean(self.trans_err_mm)) if self.trans_err_mm else float("nan")

    def add(self, res: RegistrationResult, truth_px: np.ndarray, shape: tuple[int, int], mm_per_px: float) -> None:
        if not res.ok or res.matrix_px is None:
            self.refused += 1
            self.reasons[str(res.reason)] = self.reasons.get(str(res.reason), 0) + 1
            return
        rot_err, trans_err = pose_error(res.matrix_px, truth_px, shape, mm_per_px)
        if is_right(rot_err, trans_err):
            self.right += 1
            self.rot_err_deg.append(rot_err)
            self.trans_err_mm.append(trans_err)
        else:
            self.wrong += 1

    def as_dict(self) -> dict:
        return {"cases": self.cases, "right": self.right, "wrong": self.wrong, "refused": self.refused,
                "rot_mae_deg": self.rot_mae_deg, "trans_mae_mm": self.trans_mae_mm,
                "rot_max_deg": max(self.rot_err_deg, default=float("nan")),
                "trans_max_mm": max(self.trans_err_mm, default=float("nan")), "reasons": dict(self.reasons)}


def score_pairs(data: RetouchSet, params: RegistrationParams | None = None,
                limit: int | None = None) -> Score:
    """Register every re-touch B onto the map touch A as a fresh pair and score it."""
    sc = Score()
    n = len(data.touches) if limit is None else min(limit, len(data.touches))
    for t, truth in list(zip(data.touches, data.truth_px))[:n]:
        res = register(data.a.height_mm, t.height_mm, data.mm_per_px, params)
        sc.add(res, truth, t.height_mm.shape, data.mm_per_px)
    return sc


# -- pairs that must be refused -------------------------------------------------------------------
TAXIM_MM_PER_PX = 0.1245


@lru_cache(maxsize=1)
def taxim_heights() -> tuple[np.ndarray, ...]:
    """Height maps (mm) of the 30 real Taxim ball presses, through a 32-bin LUT fitted on them all."""
    presses = load_presses(presses_dir())
    rec = Reconstructor(calibrate_from_presses(presses, TAXIM_MM_PER_PX, 2.0, "lut", bins=32))
    return tuple(rec.height_mm(f) for f in presses.frames)


def unrelated_tile_pairs(count: int, seed: int = 1,
                         heights: tuple[np.ndarray, ...] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` pairs of 240x320 maps with nothing to register: four real presses tiled 2x2 against
    four others (turned by 180 deg, flipped or as they are, at random). Domes that line up at some
    pose, the sensor's own gel texture in both: what a registration must refuse, never place."""
    hs = taxim_heights() if heights is None else heights
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        idx = rng.permutation(len(hs))[:8]
        a, b = tile([hs[i] for i in idx[:4]]), tile([hs[i] for i in idx[4:]])
        m = int(rng.integers(4))
        b = np.rot90(b, 2).copy() if m == 1 else (b[::-1].copy() if m == 2 else (b[:, ::-1].copy() if m == 3 else b))
        out.append((a, b))
    return out

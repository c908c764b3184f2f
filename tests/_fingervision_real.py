"""The real FingerVision demo frames and their hand labels: loading, scoring and tracking them.

Scored against the hand-labelled ``markers_gt.json``: 'unsure' markers and detections within 4 px of
the two listed smudges are don't-care; a detection within max(3 px, marker radius) of a true
marker is a hit; anything else (QR squares, print, debris, housing) is a false positive. Used by
``tests/perception/fingervision/test_real_frames.py`` and ``benchmarks/bench_fingervision.py``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from tactile_rig.perception.fingervision import FingerVision, FingerVisionParams

FOLDER = "fingervision_demo_gpl3"
SMUDGES_PX = np.array([[309.0, 16.0], [312.0, 213.0]])


@dataclass
class Score:
    tp: int
    fp: int
    n_true: int
    hit_ids: dict[int, int]
    """detection index -> ground-truth lattice id, for the hits."""
    errors_px: list[float]

    @property
    def precision(self) -> float:
        return self.tp / max(1, self.tp + self.fp)

    @property
    def recall(self) -> float:
        return self.tp / max(1, self.n_true)


def load_gt(folder: Path) -> dict[str, list[dict]]:
    return json.loads((folder / "markers_gt.json").read_text())["frames"]


def score(positions_px: np.ndarray, truth: list[dict]) -> Score:
    gp = np.array([[m["x"], m["y"]] for m in truth])
    gr = np.array([m["r"] for m in truth])
    unsure = np.array([m["unsure"] for m in truth])
    hit = np.zeros(len(truth), bool)
    tp = fp = 0
    ids: dict[int, int] = {}
    errs: list[float] = []
    for i, p in enumerate(np.asarray(positions_px).reshape(-1, 2)):
        d = np.hypot(*(gp - p).T)
        k = int(d.argmin())
        if d[k] <= max(3.0, gr[k]):
            if not unsure[k] and not hit[k]:
                tp += 1
                errs.append(float(d[k]))
            hit[k] = True
            ids[i] = int(truth[k]["id"])
        elif np.hypot(*(SMUDGES_PX - p).T).min() > 4.0:
            fp += 1
    return Score(tp, fp, int((~unsure).sum()), ids, errs)


def real_frames(folder: Path) -> list[tuple[str, np.ndarray]]:
    return [(p.name, cv2.imread(str(p))) for p in sorted((folder / "frames").glob("*.png"))]


def track_real(folder: Path, params: FingerVisionParams = FingerVisionParams()) -> dict[str, object]:
    """Baseline over all frames (markers barely move in this clip), then track them in order."""
    frames = real_frames(folder)
    fv = FingerVision(params)
    fv.calibrate([f for _, f in frames])
    return {name: fv.process(f) for name, f in frames}

"""Scoring marker tracking against labelled centres: precision, recall, centre error, id switches.

Per frame, predictions and true markers are matched one to one, closest pairs first, within a match
radius (px; a scalar or one per true marker, e.g. ``max(3 px, marker radius)``). A matched
prediction is a true positive, except on a don't-care marker (``unsure``), where it counts neither
way; an unmatched prediction is a false positive unless it lies within ``dont_care_radius_px`` of a
don't-care point; an unmatched true marker that is not don't-care is a false negative.

Over a sequence, an **id switch** is counted when a true marker is matched to a predicted id other
than the one it was last matched to (CLEAR-MOT's definition; a marker missed for a while and then
matched to its old id again is not a switch), and also when one predicted id moves from one true
marker to another.

Pure functions over arrays; units are pixels. Valid input: any number of predictions and true
markers (zero included); non-finite predicted positions never match and count as false positives.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["FrameScore", "SequenceScore", "match_frame", "score_sequence"]


class _Rates:
    """Precision and recall of a score's counts (true positives, false positives, false negatives)."""

    tp: int
    fp: int
    fn: int

    @property
    def precision(self) -> float:
        """tp / (tp + fp); 1.0 when nothing was predicted."""
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else 1.0

    @property
    def recall(self) -> float:
        """tp / (tp + fn); 1.0 when there was nothing to find."""
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else 1.0


@dataclass(frozen=True)
class FrameScore(_Rates):
    """One frame: counts, the matches (predicted index -> true index) and the matched centre errors."""

    tp: int
    fp: int
    fn: int
    matches: dict[int, int]
    errors_px: list[float] = field(default_factory=list)


@dataclass(frozen=True)
class SequenceScore(_Rates):
    """A sequence: summed counts, id switches, mean centre error (px) and the per-frame scores."""

    tp: int
    fp: int
    fn: int
    id_switches: int
    mean_error_px: float
    frames: list[FrameScore]

    def to_dict(self) -> dict[str, float | int]:
        return {"precision": self.precision, "recall": self.recall, "tp": self.tp, "fp": self.fp,
                "fn": self.fn, "id_switches": self.id_switches, "mean_error_px": self.mean_error_px,
                "frames": len(self.frames)}


def match_frame(
    predicted_px: np.ndarray,
    true_px: np.ndarray,
    radius_px: float | np.ndarray = 3.0,
    unsure: np.ndarray | None = None,
    dont_care_px: np.ndarray | None = None,
    dont_care_radius_px: float = 4.0,
) -> FrameScore:
    """Match one frame's predicted centres (N, 2) to the true centres (M, 2); see the module docstring."""
    pred = np.asarray(predicted_px, dtype=np.float64).reshape(-1, 2)
    true = np.asarray(true_px, dtype=np.float64).reshape(-1, 2)
    m = len(true)
    radius = np.broadcast_to(np.asarray(radius_px, dtype=np.float64), (m,)) if m else np.zeros(0)
    if np.any(~np.isfinite(radius)) or np.any(radius < 0):
        raise ValueError(f"match_frame: radius_px must be finite and >= 0, got {radius_px!r}")
    ignore = np.zeros(m, bool) if unsure is None else np.asarray(unsure, dtype=bool).reshape(m)
    matches: dict[int, int] = {}
    if len(pred) and m:
        d = np.hypot(pred[:, None, 0] - true[None, :, 0], pred[:, None, 1] - true[None, :, 1])
        d = np.where(np.isfinite(d), d, np.inf)
        ok = d <= radius[None, :]
        pi, ti = np.nonzero(ok)
        order = np.argsort(d[pi, ti], kind="stable")
        used_p: set[int] = set()
        used_t: set[int] = set()
        for k in order:
            a, b = int(pi[k]), int(ti[k])
            if a in used_p or b in used_t:
                continue
            used_p.add(a)
            used_t.add(b)
            matches[a] = b
    tp = sum(1 for b in matches.values() if not ignore[b])
    errors = [float(np.hypot(*(pred[a] - true[b]))) for a, b in matches.items() if not ignore[b]]
    fp = 0
    care = None if dont_care_px is None else np.asarray(dont_care_px, dtype=np.float64).reshape(-1, 2)
    for a in range(len(pred)):
        if a in matches:
            continue
        if care is not None and len(care) and np.isfinite(pred[a]).all():
            if np.hypot(*(care - pred[a]).T).min() <= dont_care_radius_px:
                continue
        fp += 1
    matched_true = set(matches.values())
    fn = sum(1 for b in range(m) if not ignore[b] and b not in matched_true)
    return FrameScore(tp, fp, fn, matches, errors)


def score_sequence(
    frames: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    radius_px: float | Sequence[np.ndarray] = 3.0,
    unsure: Sequence[np.ndarray] | None = None,
    dont_care_px: np.ndarray | None = None,
    dont_care_radius_px: float = 4.0,
) -> SequenceScore:
    """Score a sequence of ``(predicted_ids, predicted_px, true_ids, true_px)`` per frame.

    ``radius_px`` is one radius, or one array of per-marker radii per frame; ``unsure`` one boolean
    array per frame (don't-care markers). Ids are any integers; a predicted id that repeats within a
    frame is a caller error (ValueError).
    """
    scores: list[FrameScore] = []
    last_pred_for_true: dict[int, int] = {}
    last_true_for_pred: dict[int, int] = {}
    switches = 0
    errors: list[float] = []
    for k, (pid, ppx, tid, tpx) in enumerate(frames):
        pid = np.asarray(pid).reshape(-1)
        tid = np.asarray(tid).reshape(-1)
        if len(np.unique(pid)) != len(pid):
            raise ValueError(f"score_sequence: frame {k} repeats a predicted id")
        r: float | np.ndarray = float(radius_px) if isinstance(radius_px, (int, float)) else np.asarray(radius_px[k])
        u = None if unsure is None else unsure[k]
        s = match_frame(ppx, tpx, r, u, dont_care_px, dont_care_radius_px)
        ignore = np.zeros(len(tid), bool) if u is None else np.asarray(u, dtype=bool).reshape(-1)
        for a, b in s.matches.items():
            if ignore[b]:
                continue
            p_id, t_id = int(pid[a]), int(tid[b])
            if t_id in last_pred_for_true and last_pred_for_true[t_id] != p_id:
                switches += 1
            elif p_id in last_true_for_pred and last_true_for_pred[p_id] != t_id:
                switches += 1
            last_pred_for_true[t_id] = p_id
            last_true_for_pred[p_id] = t_id
        scores.append(s)
        errors += s.errors_px
    return SequenceScore(
        sum(s.tp for s in scores), sum(s.fp for s in scores), sum(s.fn for s in scores), switches,
        float(np.mean(errors)) if errors else 0.0, scores,
    )

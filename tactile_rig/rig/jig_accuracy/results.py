"""The outcome of each jig point and the Li 2014 figures of a run (MAE and std of absolute errors)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import numpy as np

from tactile_rig.core.geometry import Pose, wrap_deg
from tactile_rig.rig.jig_accuracy.plan import PAPER_FIGURES, JigPoint


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
    rot_mae, rot_std = _mae_std(rot)
    tra_mae, tra_std = _mae_std(tra)
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

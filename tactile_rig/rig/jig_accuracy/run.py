"""The run itself: build the tactile map, then measure every planned point (resuming after the last
finished one), scoring each against the truth."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from tactile_rig.core.errors import CalibrationError
from tactile_rig.rig.files import load_json
from tactile_rig.core.geometry import Pose
from tactile_rig.rig.jig_accuracy.localizer import (
    JigRig,
    TouchLocalization,
    TouchLocalizer,
)
from tactile_rig.rig.jig_accuracy.plan import JigAccuracyConfig, JigPoint, plan_points
from tactile_rig.rig.jig_accuracy.results import PointResult, _finite, summarize
from tactile_rig.rig.jig_accuracy.store import RunStore


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


def _begin_step(rig: JigRig, step: int) -> None:
    begin = getattr(rig, "begin_step", None)  # optional (JigRig): mocks reseed their noise per step
    if callable(begin):
        begin(step)


def build_map(rig: JigRig, localizer: TouchLocalizer, cfg: JigAccuracyConfig) -> list[dict[str, Any]]:
    """Touch the object at the configured jig positions and grow the tactile map (Li 2014: c > 0.98).

    Returns one report row per touch (commanded pose, localized pose, confidence, accepted).
    Raises :class:`CalibrationError` when the first touch shows no contact texture.
    """
    rows: list[dict[str, Any]] = []
    _begin_step(rig, 0)
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
    _begin_step(rig, point.index + 1)
    rig.move_to(point.pose)
    truth = rig.truth(point.pose)
    loc = TouchLocalization(None, 0.0, "none", "not touched")
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
            map_rows = load_json(store.out / "map.json", "map report", expect=list)
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
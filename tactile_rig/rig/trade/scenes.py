"""Trade topic ``scenes``: the model sensor against the rendered sensor, fidelity vs real-time factor.

A scene's ``[sensor]`` is either ``model`` (the perception result straight from the world models,
plus noise) or ``rendered`` (the renderer draws the camera frame and the real perception processor
reads it). The rendered path is the faithful one and the slow one. This topic runs the scenes that
have both wirings with each sensor kind at several sensing rates, on the same episode seeds, and
measures:

* speed: the real-time factor, simulated seconds per wall second over the setting's episodes;
* error: how far the arm's path departs from the scene's own setting (the rendered sensor at the
  scene's rate), RMS over the episode in mm, median over the episodes. The scene's own setting is
  the reference, so its error is 0 by construction; the other rows say what a cheaper sensor
  changes in what the controller does.

Beside them: the episode's judged figure (max lag, truth from the world), whether each episode is
judged the same as with the reference, and the worst departure.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import tomllib

from tactile_rig.rig.scene_runner import list_scenes, run_episode
from tactile_rig.rig.trade.table import TradeRow, TradeTable
from tactile_rig.sim.scenes import resolve_scene_path

TOPIC = "scenes"
SUMMARY = "model sensor vs rendered sensor (renderer + real processor): path fidelity vs real-time factor"

# Scenes that wire both sensor kinds, with the figure their property judges.
SCENES: dict[str, str] = {"following_proximity_rendered": "max_lag_mm"}
KINDS = ("rendered", "model")
RATES_HZ = (15.0, 30.0, 60.0)
EPISODES = {True: 2, False: 10}


def _path(report: Any) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, xy_mm) of the poses the controller read."""
    tr = report.result.trace
    t = np.asarray(tr.t_s, float)
    xy = np.column_stack([np.asarray(tr.channels["x_mm"], float), np.asarray(tr.channels["y_mm"], float)])
    return t, xy


def path_departure_mm(ref: tuple[np.ndarray, np.ndarray], other: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
    """(RMS, max) distance in mm between two arm paths, ``other`` interpolated at ``ref``'s times
    (inside the span both cover)."""
    t0, xy0 = ref
    t1, xy1 = other
    if t0.size == 0 or t1.size == 0:
        return math.nan, math.nan
    keep = (t0 >= t1[0]) & (t0 <= t1[-1])
    if not keep.any():
        return math.nan, math.nan
    t = t0[keep]
    d = np.hypot(np.interp(t, t1, xy1[:, 0]) - xy0[keep, 0], np.interp(t, t1, xy1[:, 1]) - xy0[keep, 1])
    return float(np.sqrt(np.mean(d * d))), float(d.max())


def _scene_sensor(scene: str) -> dict[str, Any]:
    raw = tomllib.loads(resolve_scene_path(scene).read_text(encoding="utf-8"))
    return dict(raw.get("sensor", {}))


def rendered_scenes() -> list[str]:
    """Built-in controller scenes whose ``[sensor]`` is the rendered kind."""
    return [s["name"] for s in list_scenes() if _scene_sensor(s["name"]).get("kind") == "rendered"]


def measure(*, quick: bool, seed: int) -> TradeTable:
    n = EPISODES[bool(quick)]
    seeds = [seed * 1000 + i for i in range(n)]
    rows: list[TradeRow] = []
    for scene, judged in SCENES.items():
        own = _scene_sensor(scene)
        own_kind, own_rate = str(own.get("kind", "model")), float(own.get("rate_hz", 30.0))
        # warm up both paths once (imports, OpenCV's first calls), so no setting pays for them
        for kind in KINDS:
            run_episode(scene, seeds[0], overrides={"sensor": {"kind": kind}})
        runs: dict[tuple[str, float], list[tuple[Any, float]]] = {}
        for kind in KINDS:
            for rate in RATES_HZ:
                out = []
                for s in seeds:
                    t0 = time.perf_counter()
                    rep = run_episode(scene, s, overrides={"sensor": {"kind": kind, "rate_hz": rate}})
                    out.append((rep, time.perf_counter() - t0))
                runs[(kind, rate)] = out
        ref = runs[(own_kind, own_rate)]
        for (kind, rate), out in runs.items():
            rms, worst, agree, dlag = [], [], 0, []
            for (rep, _w), (r0, _w0) in zip(out, ref):
                a, b = path_departure_mm(_path(r0), _path(rep))
                rms.append(a)
                worst.append(b)
                agree += rep.ok == r0.ok
                dlag.append(abs(rep.figures.get(judged, math.nan) - r0.figures.get(judged, math.nan)))
            sim = sum(r.sim_s for r, _ in out)
            wall = sum(w for _, w in out)
            is_ref = (kind, rate) == (own_kind, own_rate)
            rows.append(TradeRow(
                {"scene": scene, "sensor": kind, "rate_hz": rate}, sim / wall if wall > 0 else math.nan,
                float(np.median(rms)), is_default=is_ref,
                extra={"worst_departure_mm": float(np.max(worst)), f"median_{judged}": float(np.median(
                    [r.figures.get(judged, math.nan) for r, _ in out])),
                       f"median_abs_diff_{judged}": float(np.median(dlag)), "same_verdict": agree / n,
                       "ok_rate": sum(r.ok for r, _ in out) / n},
                note="the reference (the scene's own sensor)" if is_ref else ""))
    others = sorted(set(rendered_scenes()) - set(SCENES))
    table = TradeTable(
        TOPIC, "real_time_factor", "path_departure_rms_mm",
        f"{n} episodes per setting, the same seeds for every setting; departure of the arm's path from "
        "the run with the scene's own sensor (rendered, at its rate) on the same seed", rows,
        knobs={"sensor": "model (world → result + noise) or rendered (renderer + real processor)",
               "rate_hz": "sensing rate (Hz)", "scene": "built-in scene with both sensor wirings"},
        speed_tolerance=0.1)
    table.notes.append(
        "Real-time factors are wall-clock figures on a shared machine (the rendered rows are dominated by "
        "rendering and the FingerVision processor); departures are exact and repeat from the seed.")
    table.notes.append(
        "Only proximity following wires a rendered sensor today; the other controller scenes run the model "
        "sensor only (their [sensor] kind 'rendered' is refused with a one-line error)."
        + (f" Also rendered, not yet measured here: {', '.join(others)}." if others else ""))
    if not table.default_on_front():
        table.default_note = "the reference is the scene's own rendered sensor; a faster row matched it"
    else:
        table.default_note = ("the scene's own sensor is the reference (error 0 by construction): "
                              "the front shows what each cheaper sensor costs in fidelity")
    return table

"""Trade topic ``scenes``: how much of the world to model, fidelity against real-time factor.

Two kinds of fidelity knob, each studied per scene (``group_by = "scene"``: a row is only compared
with rows of its own scene, and each scene's own setting is its default):

* ``sensor``: ``model`` (the perception result straight from the world models, plus noise) or
  ``rendered`` (the renderer draws the camera frame and the real perception processor reads it), at
  several sensing rates, for the scenes that wire both (proximity following). Reference: the
  scene's own sensor (rendered, at its rate).
* ``arm_dt_ms``: the simulated arm's integration step, for scenes driven by the arm (collision stop,
  force following, insertion). Reference: the finest step (0.2 ms); the scenes ship 1 ms.

For each setting, on the same episode seeds:

* speed: the real-time factor, simulated seconds per wall second over the setting's episodes (the
  settings' episodes run interleaved, seed by seed, so the machine's load hits them alike);
* error: how far the arm's path departs from the reference setting's path on the same seed, RMS over
  the episode in mm (x, y and z where recorded), median over the episodes; the reference row is 0 by
  construction.

Beside them: the scene's judged figure (truth from the world), whether each episode is judged the
same as with the reference, and the worst departure.
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
SUMMARY = ("how much to model: model vs rendered sensor, and the simulated arm's integration step: "
           "path fidelity vs real-time factor, per scene")

# Scenes that wire both sensor kinds, with the figure their property judges.
SCENES: dict[str, str] = {"following_proximity_rendered": "max_lag_mm"}
KINDS = ("rendered", "model")
RATES_HZ = (15.0, 30.0, 60.0)
# Arm-driven scenes for the integration-step study, with their judged figure.
DT_SCENES: dict[str, str] = {"collision_stop": "overtravel_mm", "following_force": "max_lag_mm",
                             "insertion": "position_error_mm"}
DT_MS = (0.2, 1.0, 5.0, 10.0)
DT_REFERENCE_MS = 0.2
DEFAULT_DT_MS = 1.0  # SimArm's dt_s default: what every scene runs
EPISODES = {True: 2, False: 10}


def _path(report: Any) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, positions_mm) of the poses the controller read (x, y and z where the trace has z)."""
    tr = report.result.trace
    t = np.asarray(tr.t_s, float)
    cols = [np.asarray(tr.channels[c], float) for c in ("x_mm", "y_mm", "z_mm") if c in tr.channels]
    if not cols:  # an episode that ended before the controller read a pose
        return np.zeros(0), np.zeros((0, 3))
    xyz = np.column_stack(cols)
    keep = np.all(np.isfinite(xyz), axis=1)  # rows recorded without a pose (NaN-padded) are skipped
    return t[keep], xyz[keep]


def path_departure_mm(ref: tuple[np.ndarray, np.ndarray], other: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
    """(RMS, max) distance in mm between two paths, ``other`` interpolated at ``ref``'s times (inside
    the span both cover); positions are (n, 2) or (n, 3) arrays."""
    t0, p0 = ref
    t1, p1 = other
    if t0.size == 0 or t1.size == 0:
        return math.nan, math.nan
    keep = (t0 >= t1[0]) & (t0 <= t1[-1])
    if not keep.any():
        return math.nan, math.nan
    t = t0[keep]
    diff = np.column_stack([np.interp(t, t1, p1[:, k]) - p0[keep, k] for k in range(p0.shape[1])])
    d = np.sqrt(np.sum(diff * diff, axis=1))
    return float(np.sqrt(np.mean(d * d))), float(d.max())


def _scene_sensor(scene: str) -> dict[str, Any]:
    raw = tomllib.loads(resolve_scene_path(scene).read_text(encoding="utf-8"))
    return dict(raw.get("sensor", {}))


def rendered_scenes() -> list[str]:
    """Built-in controller scenes whose ``[sensor]`` is the rendered kind."""
    return [s["name"] for s in list_scenes() if _scene_sensor(s["name"]).get("kind") == "rendered"]


def _timed_runs(scene: str, seeds: list[int], settings: dict[tuple, dict[str, dict[str, Any]]]
                ) -> dict[tuple, list[tuple[Any, float]]]:
    """Every setting's episodes, interleaved: seed by seed, each setting in turn, so a load spike on
    the shared machine lands on all settings alike rather than on the one that happened to run then."""
    out: dict[tuple, list[tuple[Any, float]]] = {k: [] for k in settings}
    for sd in seeds:
        for key, overrides in settings.items():
            t0 = time.perf_counter()
            rep = run_episode(scene, sd, overrides=overrides)
            out[key].append((rep, time.perf_counter() - t0))
    return out


def _rows(scene: str, judged: str, runs: dict[tuple, list[tuple[Any, float]]], ref_key: tuple,
          default_key: tuple, setting: Any, n: int, ref_note: str) -> list[TradeRow]:
    ref = runs[ref_key]
    rows = []
    for key, out in runs.items():
        rms, worst, agree, dlag = [], [], 0, []
        for (rep, _w), (r0, _w0) in zip(out, ref):
            a, b = path_departure_mm(_path(r0), _path(rep))
            rms.append(a)
            worst.append(b)
            agree += rep.ok == r0.ok
            dlag.append(abs(rep.figures.get(judged, math.nan) - r0.figures.get(judged, math.nan)))
        sim = sum(r.sim_s for r, _ in out)
        wall = sum(w for _, w in out)
        notes = [ref_note] if key == ref_key else []
        if key == default_key and key != ref_key:
            notes.append("the scene's own setting")
        no_path = int(np.sum(~np.isfinite(rms)))
        if no_path:
            notes.append(f"{no_path}/{n} episodes without a pose to compare")
        finite_rms = [v for v in rms if math.isfinite(v)]
        rows.append(TradeRow(
            setting(key), sim / wall if wall > 0 else math.nan,
            float(np.median(finite_rms)) if finite_rms else math.nan,
            is_default=key == default_key,
            extra={"worst_departure_mm": float(np.nanmax(worst)) if finite_rms else math.nan,
                   "judged": float(np.median([r.figures.get(judged, math.nan) for r, _ in out])),
                   "judged_abs_diff": float(np.median(dlag)), "same_verdict": agree / n,
                   "ok_rate": sum(r.ok for r, _ in out) / n},
            note="; ".join([f"judged: median {judged}", *notes])))
    return rows


def measure(*, quick: bool, seed: int) -> TradeTable:
    n = EPISODES[bool(quick)]
    seeds = [seed * 1000 + i for i in range(n)]
    rows: list[TradeRow] = []
    for scene, judged in SCENES.items():
        own = _scene_sensor(scene)
        own_key = (str(own.get("kind", "model")), float(own.get("rate_hz", 30.0)))
        for kind in KINDS:  # warm up both paths once (imports, OpenCV's first calls)
            run_episode(scene, seeds[0], overrides={"sensor": {"kind": kind}})
        runs = _timed_runs(scene, seeds, {(kind, rate): {"sensor": {"kind": kind, "rate_hz": rate}}
                                          for kind in KINDS for rate in RATES_HZ})
        rows += _rows(scene, judged, runs, own_key, own_key,
                      lambda k, sc=scene: {"scene": sc, "sensor": k[0], "rate_hz": k[1], "arm_dt_ms": DEFAULT_DT_MS},
                      n, "the reference (the scene's own sensor)")
    for scene, judged in DT_SCENES.items():
        own = _scene_sensor(scene)
        run_episode(scene, seeds[0])  # warm-up
        runs = _timed_runs(scene, seeds, {(dt,): {"arm": {"dt_s": dt / 1000.0}} for dt in DT_MS})
        rows += _rows(scene, judged, runs, (DT_REFERENCE_MS,), (DEFAULT_DT_MS,),
                      lambda k, sc=scene, o=own: {"scene": sc, "sensor": str(o.get("kind", "model")),
                                                  "rate_hz": float(o.get("rate_hz", 30.0)), "arm_dt_ms": k[0]},
                      n, "the reference (finest arm step)")
    others = sorted(set(rendered_scenes()) - set(SCENES))
    table = TradeTable(
        TOPIC, "real_time_factor", "path_departure_rms_mm",
        f"{n} episodes per setting, the same seeds for every setting of a scene; departure of the arm's path "
        "from the scene's reference setting on the same seed (rendered sensor at the scene's rate; the "
        f"finest arm step, {DT_REFERENCE_MS} ms)", rows,
        knobs={"scene": "built-in scene (each scene is its own study: its own front and default)",
               "sensor": "model (world → result + noise) or rendered (renderer + real processor)",
               "rate_hz": "sensing rate (Hz)", "arm_dt_ms": "the simulated arm's integration step (ms)"},
        speed_tolerance=0.1, group_by="scene")
    table.notes.append(
        "Real-time factors are wall-clock figures on a shared machine (the rendered rows are dominated by "
        "rendering and the FingerVision processor); departures are exact and repeat from the seed. `judged` "
        "is the median of the scene's judged figure (named in the note), `judged_abs_diff` its median "
        "difference from the reference on the same seed.")
    table.notes.append(
        "Only proximity following wires a rendered sensor; the other controller scenes run the model "
        "sensor only (their [sensor] kind 'rendered' is refused with a one-line error)."
        + (f" Also rendered, not yet measured here: {', '.join(others)}." if others else ""))
    off = [rows[i] for i in table.default_indices if i not in set(table.front())]
    if off:
        table.default_note = ("off its scene's front: " + "; ".join(
            f"{r.setting['scene']} (a faster setting departs no more from the reference)" for r in off))
    else:
        table.default_note = ("each scene's own setting; where it is the reference its error is 0 by "
                              "construction and the front shows what each cheaper setting costs")
    return table

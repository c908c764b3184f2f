"""The substance session (thesis 3.4.2): stirring trials recorded, cut into windows, fitted, reported.

Stirring trials (marker force/torque time series) are recorded with a labelled trial start, read back
(:func:`stirring_trials_from_recording`), cut into windows of statistics
(:func:`~tactile_rig.perception.fingervision.substance.stirring_features`) and fitted
(:func:`~tactile_rig.perception.fingervision.substance.fit_substance`); accuracy is reported on held-out
TRIALS (never windows of a training trial). Versioned as the force map: ``OUT/substance-vN.*``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import CalibrationError
from tactile_rig.perception.fingervision.substance import STIR_FEATURES, fit_substance, stirring_features
from tactile_rig.rig.calibrations import plan_version, publish
from tactile_rig.rig.recording import Recorder, read_recording
from tactile_rig.rig.reports import Report, write_summary
from tactile_rig.sim.world.stirring import StirringScene

__all__ = ["record_stirring_session", "stirring_series_from_recording", "stirring_trials_from_recording",
           "substance_session"]


def record_stirring_session(path: str | Path, trials: Sequence[Any], *, camera: str = "fingervision",
                            gap_s: float = 1.0) -> Path:
    """Record stirring trials (``stirring.StirTrial``): a labelled trial start, then the marker series."""

    clock = VirtualClock()
    with Recorder(path, clock=clock) as rec:
        rec.add_metadata("session", {"kind": "substance", "camera": camera, "trials": len(trials)})
        for k, tr in enumerate(trials):
            t0 = clock.now_s()
            rec.write_command("session", "trial_start", t_s=t0, trial=k, label=tr.label)
            for t, row in zip(tr.t_s, tr.series):
                clock.advance_to(t0 + float(t))
                rec.write_perception(camera, {"trial": k, "force_px": [row[0], row[1], 0.0],
                                              "torque_px2": [0.0, 0.0, row[2]]}, t_s=clock.now_s())
            clock.advance(gap_s)
    return Path(path)


def stirring_trials_from_recording(path: str | Path, *, camera: str | None = None
                                   ) -> list[tuple[str, np.ndarray, float]]:
    """(label, series T × 3, rate_hz) per labelled trial of a recording."""

    rec = read_recording(path)
    labels = {int(m.data["trial"]): str(m.data["label"]) for m in rec.on("/command/session")
              if m.data.get("command") == "trial_start" and "label" in m.data}
    perc = sorted({m.topic for m in rec.messages if m.topic.startswith("/perception/")})
    topic = f"/perception/{camera}" if camera else (perc[0] if len(perc) == 1 else None)
    if topic is None or topic not in perc:
        raise CalibrationError(f"{path}: pick the camera's perception topic; found: {', '.join(perc) or '(none)'}",
                               device="substance")
    rows: dict[int, list[tuple[float, list[float]]]] = {}
    for m in rec.on(topic):
        k = m.data.get("trial")
        if k is None or int(k) not in labels:
            continue
        f, tq = m.data["force_px"], m.data["torque_px2"]
        rows.setdefault(int(k), []).append((m.t_s, [f[0], f[1], tq[2]]))
    out = []
    for k, samples in sorted(rows.items()):
        t = np.array([s[0] for s in samples])
        if t.size < 8:
            continue
        rate = (t.size - 1) / (t[-1] - t[0]) if t[-1] > t[0] else 30.0
        out.append((labels[k], np.array([s[1] for s in samples]), float(rate)))
    if not out:
        raise CalibrationError(f"{path}: no labelled stirring trials (trial_start with a label) found",
                               device="substance")
    return out


def substance_session(out_dir: str | Path, *, per_substance: int = 12, seed: int = 0,
                      recording: str | Path | None = None, test_fraction: float = 0.25, window_s: float = 2.0,
                      camera: str | None = None, figures: bool = True, force: bool = False,
                      collect: Any = None) -> dict[str, Any]:
    """Collect (mock, or live with ``collect(path) -> path``) or read stirring trials, fit the MLP on
    some trials, report held-out accuracy. Versioned as the force map: ``OUT/substance-vN.*``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if not 0 < test_fraction < 1:
        raise ValueError(f"test_fraction={test_fraction!r} must be in (0, 1)")
    ver = plan_version(out / "substance", (".npz", ".json"), force=force)
    if recording is None and collect is not None:
        recording = collect(ver.path(".mcap"))
    elif recording is None:

        recording = record_stirring_session(ver.path(".mcap"), StirringScene().trials(per_substance, seed=seed))
    trials = stirring_trials_from_recording(recording, camera=camera)
    rng = np.random.default_rng(seed)
    by_label: dict[str, list[int]] = {}
    for i, (lbl, _, _) in enumerate(trials):
        by_label.setdefault(lbl, []).append(i)
    test_idx: set[int] = set()
    for lbl, idx in by_label.items():  # stratified by trial: every substance is tested
        if len(idx) < 2:
            raise CalibrationError(f"substance {lbl!r} has {len(idx)} trial(s); need >= 2 (train and test)",
                                   device="substance")
        k = max(1, int(round(test_fraction * len(idx))))
        test_idx.update(rng.choice(idx, size=k, replace=False).tolist())

    def windows(sel: list[int]) -> tuple[np.ndarray, list[str]]:
        xs, ys = [], []
        for i in sel:
            lbl, series, rate = trials[i]
            f = stirring_features(series, rate, window_s=window_s)
            xs.append(f)
            ys += [lbl] * f.shape[0]
        return np.vstack(xs), ys

    train_sel = [i for i in range(len(trials)) if i not in test_idx]
    Xtr, ytr = windows(train_sel)
    Xte, yte = windows(sorted(test_idx))
    model = fit_substance(Xtr, ytr, seed=seed)
    pred = model.predict(Xte)
    acc = float(np.mean([p == t for p, t in zip(pred, yte)]))
    classes = model.classes
    confusion = [[int(sum(1 for p, t in zip(pred, yte) if t == a and p == b)) for b in classes] for a in classes]
    report = {"accuracy_holdout": acc, "classes": classes, "confusion": confusion,
              "n_train_trials": len(train_sel), "n_test_trials": len(test_idx), "n_train_windows": len(ytr),
              "n_test_windows": len(yte), "window_s": window_s, "recording": str(recording), "seed": seed}
    model.meta.update({k: report[k] for k in ("accuracy_holdout", "n_train_windows", "window_s")})
    npz, js = model.save(ver.stem)
    links = publish(ver, (".npz", ".json", ".mcap"))
    report["model"] = {"npz": str(npz), "json": str(js), "version": ver.version,
                       "latest": [str(p) for p in links]}
    if figures:

        write_summary(out, report, [{"true": t, "predicted": p} for t, p in zip(yte, pred)], name="substance_summary")
        rows = [{"true \\ predicted": a, **{b: confusion[i][j] for j, b in enumerate(classes)}}
                for i, a in enumerate(classes)]
        (Report(out, "Substance classifier (thesis 3.4.2)")
         .text(f"MLP (10, 10, 10), logistic units, lbfgs, on {len(STIR_FEATURES)} stirring statistics per "
               f"{window_s} s window; {len(train_sel)} training trials, {len(test_idx)} held-out trials.")
         .numbers("Held-out accuracy", {"accuracy": acc, "test windows": len(yte)})
         .table("Confusion (held-out windows)", rows)
         .write("substance.md"))
    return report



def stirring_series_from_recording(path: str | Path, *, camera: str | None = None
                                   ) -> list[dict[str, Any]]:
    """Every trial's marker series (T × 3: fx, fy, tz px) in a recording, labelled or not.

    Messages without a ``trial`` field form one series (trial None). Each item: ``trial``, ``label``
    (the trial start's label, or None), ``series``, ``rate_hz``.
    """
    rec = read_recording(path)
    labels = {int(m.data["trial"]): str(m.data["label"]) for m in rec.on("/command/session")
              if m.data.get("command") == "trial_start" and "label" in m.data and "trial" in m.data}
    perc = sorted({m.topic for m in rec.messages if m.topic.startswith("/perception/")})
    topic = f"/perception/{camera}" if camera else (perc[0] if len(perc) == 1 else None)
    if topic is None or topic not in perc:
        raise CalibrationError(f"{path}: pick the camera's perception topic with --camera; found: "
                               f"{', '.join(perc) or '(none)'}", device="substance")
    rows: dict[int | None, list[tuple[float, list[float]]]] = {}
    for m in rec.on(topic):
        f, tq = m.data.get("force_px"), m.data.get("torque_px2")
        if f is None or tq is None:
            continue
        k = m.data.get("trial")
        rows.setdefault(None if k is None else int(k), []).append((m.t_s, [f[0], f[1], tq[2]]))
    out = []
    for k, samples in sorted(rows.items(), key=lambda kv: -1 if kv[0] is None else kv[0]):
        t = np.array([s[0] for s in samples])
        rate = (t.size - 1) / (t[-1] - t[0]) if t.size > 1 and t[-1] > t[0] else 30.0
        out.append({"trial": k, "label": labels.get(k) if k is not None else None,
                    "series": np.array([s[1] for s in samples], float), "rate_hz": float(rate)})
    if not out:
        raise CalibrationError(f"{path}: no marker forces (force_px, torque_px2) on {topic}", device="substance")
    return out

"""The force-map session (thesis 3.4.1): press trials recorded, paired with the scale, fitted, reported.

A grasped stick is pressed on the scale through N trials of increasing force; each sample pairs one
fingertip's marker force/torque (6 features, px) with the scale's reading (N), shifted by the scale's
lag (:func:`scale_lag_s`). The fit is :func:`~tactile_rig.perception.fingervision.force_map.fit_force_map`
(RBF kernel ridge, λ = 0.02 as the thesis); one whole trial is held out and its MSE reported (the
thesis: 1.232). The session records to MCAP and learns from the recording, so the same fit runs on a
bench's recording (``--from-recording``), a live guided collection (``collect``,
:mod:`tactile_rig.rig.live_collection`) or the mock stick-press scene. The model is versioned
(:mod:`tactile_rig.rig.calibrations`: ``force_map-vN.*`` with ``force_map.*`` linking to the newest).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import CalibrationError
from tactile_rig.perception.fingervision.force_map import DEFAULT_GAMMA, ForceMapModel, fit_force_map
from tactile_rig.rig.calibrations import plan_version, publish
from tactile_rig.rig.recording import Recorder, read_recording
from tactile_rig.rig.reports import Report, plot_estimated_vs_true, plot_trace, write_summary
from tactile_rig.sim.world.stick_press import StickPressScene, increasing_peaks

__all__ = ["MAX_SCALE_LAG_S", "ForceTrialData", "fit_force_map_trials", "force_map_session",
           "force_trials_from_recording", "record_force_map_session", "scale_lag_s"]


@dataclass
class ForceTrialData:
    """One trial's aligned samples: features (T × 6, px) and the scale's force (T, N); ``scale_lag_s``
    is how late the scale's readings were taken to be (the pairing's shift)."""

    index: int
    features: np.ndarray
    force_n: np.ndarray
    t_s: np.ndarray
    scale_lag_s: float = 0.0


def record_force_map_session(path: str | Path, trials: Sequence[Any], *, camera: str = "fingervision",
                             bench: Any = None, gap_s: float = 1.0) -> Path:
    """Record press trials (``stick_press.PressTrial``) as a session would: perception + scale + commands."""

    clock = VirtualClock()
    with Recorder(path, clock=clock) as rec:
        if bench is not None:
            rec.add_bench(bench)
        rec.add_metadata("session", {"kind": "force-map", "camera": camera, "trials": len(trials)})
        for tr in trials:
            t0 = clock.now_s()
            rec.write_command("session", "trial_start", t_s=t0, trial=tr.index, peak_force_n=tr.peak_force_n)
            for t, f, scale in zip(tr.t_s, tr.features, tr.scale_n):
                clock.advance_to(t0 + float(t))
                ts = clock.now_s()
                rec.write_perception(camera, {"trial": tr.index, "force_px": f[:3], "torque_px2": f[3:]}, t_s=ts)
                rec.write_scale(float(scale), t_s=ts, trial=tr.index)
            clock.advance(gap_s)
    return Path(path)


MAX_SCALE_LAG_S = 0.2


def scale_lag_s(t_perc_s: np.ndarray, force_px: np.ndarray, t_scale_s: np.ndarray, f_scale_n: np.ndarray, *,
                max_lag_s: float = MAX_SCALE_LAG_S, step_s: float = 0.005) -> float:
    """How late the scale reports a force the markers show (s, 0 .. ``max_lag_s``): the lag that best
    correlates the scale's readings with the marker force's magnitude.

    The sketch averages its conversions and the host stamps a line when it arrives, so on a press
    that rises and falls the scale trails the camera by a frame or two; pairing the two at the same
    time stamp would teach the map a force that lags its own features."""
    mag = np.linalg.norm(np.asarray(force_px, float), axis=1)
    if mag.size < 8 or np.ptp(mag) == 0 or t_scale_s.size < 2:
        return 0.0
    best, best_c = 0.0, -np.inf
    for lag in np.arange(0.0, max_lag_s + step_s / 2, step_s):
        f = np.interp(t_perc_s + lag, t_scale_s, f_scale_n)
        if np.ptp(f) == 0:
            continue
        c = float(np.corrcoef(mag, f)[0, 1])
        if c > best_c + 1e-6:
            best, best_c = float(lag), c
    return best


def force_trials_from_recording(path: str | Path, *, camera: str | None = None, max_skew_s: float = 0.05,
                                lag_s: float | None = None) -> list[ForceTrialData]:
    """Pair each perception sample with the scale reading nearest in time to it plus the scale's lag
    (within ``max_skew_s``); ``lag_s`` None estimates the lag (:func:`scale_lag_s`).

    Trials come from the ``trial`` field of the messages (or the ``/command/session`` trial starts).
    """

    rec = read_recording(path)
    perc_topics = sorted({m.topic for m in rec.messages if m.topic.startswith("/perception/")})
    topic = f"/perception/{camera}" if camera else (perc_topics[0] if len(perc_topics) == 1 else None)
    if topic is None or topic not in perc_topics:
        raise CalibrationError(f"{path}: pick the camera's perception topic; found: "
                               f"{', '.join(perc_topics) or '(none)'}", device="force-map")
    scale = rec.on("/scale/force")
    if not scale:
        raise CalibrationError(f"{path}: no /scale/force readings recorded", device="force-map")
    t_scale = np.array([m.t_s for m in scale])
    f_scale = np.array([float(m.data["force_n"]) for m in scale])
    starts = sorted((m.t_s, int(m.data.get("trial", 0))) for m in rec.on("/command/session")
                    if m.data.get("command") == "trial_start")
    by_trial: dict[int, tuple[list, list, list]] = {}
    order = np.argsort(t_scale)
    t_sorted, f_sorted = t_scale[order], f_scale[order]
    # a live session also records the fingertip at rest, probing and released: only presses train
    samples = [m for m in rec.on(topic) if "force_px" in m.data and "torque_px2" in m.data
               and m.data.get("phase", "press") == "press"]
    if lag_s is None:
        lag_s = scale_lag_s(np.array([m.t_s for m in samples]), np.array([m.data["force_px"] for m in samples]),
                            t_sorted, f_sorted)
    for m in samples:
        d = m.data
        trial = d.get("trial")
        if trial is None:
            trial = max((k for ts, k in starts if ts <= m.t_s), default=0)
        t = m.t_s + lag_s
        j = int(np.searchsorted(t_sorted, t))
        cands = [i for i in (j - 1, j) if 0 <= i < t_sorted.size]
        i = min(cands, key=lambda i: abs(t_sorted[i] - t))
        if abs(t_sorted[i] - t) > max_skew_s:
            continue
        feats, forces, times = by_trial.setdefault(int(trial), ([], [], []))
        feats.append(list(d["force_px"]) + list(d["torque_px2"]))
        forces.append(f_sorted[i])
        times.append(m.t_s)
    if not by_trial:
        raise CalibrationError(f"{path}: no perception sample on {topic} has a scale reading within "
                               f"{max_skew_s} s", device="force-map")
    return [ForceTrialData(k, np.asarray(v[0], float), np.asarray(v[1], float), np.asarray(v[2], float),
                           float(lag_s)) for k, v in sorted(by_trial.items())]


def fit_force_map_trials(trials: Sequence[ForceTrialData], *, holdout: int | None = None, alpha: float = 0.02,
                         gamma: float | None = DEFAULT_GAMMA) -> tuple[ForceMapModel, dict[str, Any]]:
    """Fit on every trial but ``holdout`` (default: the middle one) and report the held-out MSE (N²)."""
    if len(trials) < 2:
        raise CalibrationError(f"force map needs >= 2 trials (one held out), got {len(trials)}", device="force-map")
    idx = [t.index for t in trials]
    h = idx[len(idx) // 2] if holdout is None else holdout
    if h not in idx:
        raise ValueError(f"holdout trial {h} is not among the recorded trials {idx}")
    train = [t for t in trials if t.index != h]
    test = next(t for t in trials if t.index == h)
    model = fit_force_map(np.vstack([t.features for t in train]), np.concatenate([t.force_n for t in train]),
                          alpha=alpha, gamma=gamma)
    pred = model.predict(test.features)
    err = pred - test.force_n
    report = {"holdout_trial": h, "n_train": int(model.x_fit.shape[0]), "n_test": int(err.size),
              "mse_holdout_n2": float(np.mean(err**2)), "rmse_holdout_n": float(np.sqrt(np.mean(err**2))),
              "mae_holdout_n": float(np.mean(np.abs(err))), "alpha": model.alpha, "gamma": model.gamma,
              "trials": idx}
    model.meta.update(report)
    return model, report


def force_map_session(out_dir: str | Path, *, n_trials: int = 10, max_force_n: float = 20.0, seed: int = 0,
                      recording: str | Path | None = None, holdout: int | None = None, alpha: float = 0.02,
                      gamma: float | None = DEFAULT_GAMMA, camera: str | None = None, bench: Any = None,
                      figures: bool = True, force: bool = False, collect: Any = None) -> dict[str, Any]:
    """The whole session: collect (mock, or live with ``collect``) or read (``recording``) trials, fit,
    save, report.

    The model is versioned (:mod:`tactile_rig.rig.calibrations`): ``OUT/force_map-vN.npz`` + ``.json``
    with ``OUT/force_map.npz`` / ``.json`` linking to the newest; ``force`` rewrites the newest.
    On mocks the trials come from :class:`~tactile_rig.sim.world.stick_press.StickPressScene` and are
    recorded to ``OUT/force_map-vN.mcap`` first; ``collect(path) -> path`` records a live session
    there instead (:mod:`tactile_rig.rig.live_collection`); the fit always reads a recording.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ver = plan_version(out / "force_map", (".npz", ".json"), force=force)
    scene = None
    if recording is None and collect is not None:
        recording = collect(ver.path(".mcap"))
        camera = camera or "fingervision"
    elif recording is None:

        scene = StickPressScene()
        trials_sim = scene.trials(increasing_peaks(n_trials, max_force_n), seed=seed)
        recording = record_force_map_session(ver.path(".mcap"), trials_sim, bench=bench)
        camera = camera or "fingervision"
    trials = force_trials_from_recording(recording, camera=camera)
    model, report = fit_force_map_trials(trials, holdout=holdout, alpha=alpha, gamma=gamma)
    report["source"] = ("mock stick-press scene" if scene is not None
                        else "live collection" if collect is not None else str(recording))
    report["recording"] = str(recording)
    report["scale_lag_s"] = trials[0].scale_lag_s
    test = next(t for t in trials if t.index == report["holdout_trial"])
    pred = model.predict(test.features)
    if scene is not None:
        noise = scene.force_noise_n(test.force_n)
        report["scene_noise_rms_n"] = float(np.sqrt(np.mean(noise**2)))
        report["scene"] = {"marker_noise_px": scene.marker_noise_px, "scale_noise_n": scene.scale_noise_n,
                           "gain_sd": scene.gain_sd, "seed": seed}
    npz, js = model.save(ver.stem)
    links = publish(ver, (".npz", ".json", ".mcap"))
    report["model"] = {"npz": str(npz), "json": str(js), "version": ver.version,
                       "latest": [str(p) for p in links]}
    if figures:

        f1 = plot_estimated_vs_true(test.force_n, pred, out / "force_map_holdout.png", quantity="force", unit="N",
                                    true_label="scale force", est_label="force map estimate",
                                    title=f"held-out trial {report['holdout_trial']}: MSE "
                                          f"{report['mse_holdout_n2']:.3g} N²")
        f2 = plot_trace({"t_s": test.t_s - test.t_s[0], "scale_n": test.force_n, "predicted_n": pred,
                         "shear_fy_px": test.features[:, 1]}, out / "force_map_trace.png",
                        channels=[("scale_n", "predicted_n"), "shear_fy_px"],
                        title="held-out trial: scale vs force map", units={"scale_n": "N", "shear_fy_px": "px"})
        write_summary(out, report, [{"t_s": float(t), "scale_n": float(s), "predicted_n": float(p)}
                                    for t, s, p in zip(test.t_s, test.force_n, pred)], name="force_map_summary")
        (Report(out, "Force map (thesis 3.4.1)")
         .text(f"Kernel ridge regression (RBF, λ = {model.alpha}, γ = {model.gamma:.4g}) on robust-scaled marker "
               f"features, trained on {len(trials) - 1} trials ({report['n_train']} samples), tested on held-out "
               f"trial {report['holdout_trial']}. The thesis reports an MSE of 1.232.")
         .numbers("Held-out trial", {k: report[k] for k in ("mse_holdout_n2", "rmse_holdout_n", "mae_holdout_n")}
                  | ({"scene_noise_rms_n": report["scene_noise_rms_n"]} if scene is not None else {}))
         .figure(f1, "predicted vs scale force, held-out trial")
         .figure(f2, "held-out trial over time")
         .write("force_map.md"))
    return report

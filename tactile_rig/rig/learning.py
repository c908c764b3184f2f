"""Learning sessions: the force map (thesis 3.4.1) and the substance classifier (thesis 3.4.2).

**Force map.** A grasped stick is pressed on the scale through N trials of increasing force; each
sample pairs one fingertip's marker force/torque (6 features, px) with the scale's reading (N).
Features are robust-scaled (median and IQR, as sklearn's ``RobustScaler``) and a kernel ridge
regression with an RBF kernel (``alpha`` = λ = 0.02 as the thesis) maps them to newtons. One whole
trial is held out and its MSE reported (the thesis: 1.232). The model is saved WITHOUT pickle: an
``.npz`` (dual coefficients, the scaled training inputs, the scaler's centre and scale, gamma) and
a ``.json`` of metadata; :class:`ForceMapModel` predicts with numpy only.

**Substance classifier.** Stirring trials (marker force/torque time series) are cut into windows;
each window becomes statistics whose distribution depends on the substance's viscosity
(:func:`stirring_features`); an ``MLPClassifier(hidden_layer_sizes=(10, 10, 10),
activation='logistic', solver='lbfgs')`` learns the substance; accuracy is reported on held-out
TRIALS (never windows of a training trial). Saved the same way; :class:`SubstanceModel` predicts
with numpy only.

Both sessions record to MCAP and learn from the recording, so the same fit runs on a bench's
recording (``--from-recording``) or a live guided collection (``collect``,
:mod:`tactile_rig.rig.live_collection`) as on the mocks. Models are versioned
(:mod:`tactile_rig.rig.calibrations`: ``force_map-vN.*`` with ``force_map.*`` linking to the newest).
The consumers load them with :func:`load_force_map` (``ForceMapModel.to_newtons``: a fingertip's
marker force in N) and :func:`load_substance_model` (:func:`predict_substance`). scikit-learn is
the optional extra ``learn``; it is needed to fit, never to predict.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence, TypeVar

import numpy as np

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import CalibrationError
from tactile_rig.rig.files import checked, load_json, load_npz
from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.calibrations import plan_version, publish
from tactile_rig.rig.recording import Recorder, read_recording
from tactile_rig.rig.reports import (
    Report,
    plot_estimated_vs_true,
    plot_trace,
    write_summary,
)
from tactile_rig.sim.world.stick_press import StickPressScene, increasing_peaks
from tactile_rig.sim.world.stirring import StirringScene

FORCE_MAP_FORMAT = "tactile-rig/force-map"
SUBSTANCE_FORMAT = "tactile-rig/substance-classifier"
FORMAT_VERSION = 1
# RBF width on robust-scaled features. The thesis gives λ only; 0.05 (a kernel wider than sklearn's
# 1/n_features = 0.17) generalises better across trials whose grasp squeeze differs.
DEFAULT_GAMMA = 0.05
FORCE_FEATURES = ("fx_px", "fy_px", "fz_px", "tx_px2", "ty_px2", "tz_px2")
STIR_FEATURES = ("fy_mean", "fy_std", "fy_p2p", "fy_roughness", "fy_hf_frac", "fx_std", "tz_mean", "tz_std")


def _sklearn() -> None:
    try:
        import sklearn  # noqa: F401
    except ModuleNotFoundError as exc:  # pragma: no cover - depends on the install
        raise ModuleNotFoundError("fitting needs scikit-learn: pip install 'tactile-rig[learn]'",
                                  name=exc.name) from exc


def _one_blas_thread() -> Any:
    """Small dense problems run 10-30x slower when BLAS threads fight over a busy machine."""
    from threadpoolctl import threadpool_limits  # a dependency of scikit-learn

    return threadpool_limits(limits=1, user_api="blas")


def _paths(path: str | Path) -> tuple[Path, Path]:
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".npz", ".json") else p
    return stem.with_suffix(".npz"), stem.with_suffix(".json")


def _check_features(X: np.ndarray, n_features: int, who: str) -> np.ndarray:
    x = np.asarray(X, float)
    if x.ndim == 1:
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] != n_features:
        raise ValueError(f"{who}: expected an (n, {n_features}) feature array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{who}: features contain NaN or infinity")
    return x


# -- force map --------------------------------------------------------------------------------
@dataclass
class ForceMapModel:
    """Marker features (px) → force (N) by RBF kernel ridge regression; numpy-only prediction."""

    center: np.ndarray
    scale: np.ndarray
    x_fit: np.ndarray  # scaled training inputs (n_train × n_features)
    dual_coef: np.ndarray  # (n_train,)
    gamma: float
    alpha: float
    feature_names: tuple[str, ...] = FORCE_FEATURES
    meta: dict[str, Any] = field(default_factory=dict)

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Force in newtons for each row of ``X`` (n × n_features, in the features' own units)."""
        x = (_check_features(X, len(self.feature_names), "force map") - self.center) / self.scale
        out = np.empty(x.shape[0])
        for i in range(0, x.shape[0], 2048):  # bounded memory for long recordings
            xb = x[i:i + 2048]
            d2 = (np.sum(xb**2, 1)[:, None] + np.sum(self.x_fit**2, 1)[None, :] - 2.0 * xb @ self.x_fit.T)
            out[i:i + 2048] = np.exp(-self.gamma * np.maximum(d2, 0.0)) @ self.dual_coef
        return out

    def to_newtons(self, force_px: Sequence[float] | np.ndarray, torque_px2: Sequence[float] | np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, float]:
        """One fingertip's marker force (px) and torque (px²) → (force N (3,), torque N·px (3,), |F| N).

        The map was fitted on the force the scale measured, so it gives the magnitude ``|F|``
        (clamped at 0 N); the direction is the marker force's. Force and torque are scaled by the
        same ``|F| / |force_px|`` (zero when the markers do not move); multiply the torque by the
        camera's mm/px for N·mm.
        """
        f = np.asarray(force_px, float).reshape(3)
        tq = np.asarray(torque_px2, float).reshape(3)
        magnitude = max(0.0, float(self.predict(np.concatenate([f, tq])[None, :])[0]))
        norm = float(np.linalg.norm(f))
        k = magnitude / norm if norm > 1e-9 else 0.0
        return f * k, tq * k, magnitude

    def save(self, path: str | Path) -> tuple[Path, Path]:
        """Write ``<stem>.npz`` (arrays) and ``<stem>.json`` (metadata); no pickle anywhere."""
        npz, js = _paths(path)
        npz.parent.mkdir(parents=True, exist_ok=True)
        np.savez(npz, center=self.center, scale=self.scale, x_fit=self.x_fit, dual_coef=self.dual_coef,
                 gamma=np.float64(self.gamma), alpha=np.float64(self.alpha))
        meta = {"format": FORCE_MAP_FORMAT, "version": FORMAT_VERSION, "kernel": "rbf", "gamma": self.gamma,
                "alpha": self.alpha, "features": list(self.feature_names), "n_train": int(self.x_fit.shape[0]),
                "arrays": npz.name, **self.meta}

        js.write_text(json.dumps(to_jsonable(meta), indent=1) + "\n", encoding="utf-8")
        return npz, js

    @classmethod
    def load(cls, path: str | Path) -> "ForceMapModel":
        npz, js = _paths(path)
        meta = _load_meta(js, FORCE_MAP_FORMAT)
        if not npz.is_file():
            raise CalibrationError(f"force map arrays {npz} are missing (the .json is there); "
                                   "re-run: tactile-rig calibrate force-map", device="force-map")
        with checked(npz, "force map", "a model written by 'tactile-rig calibrate force-map'"):
            z = load_npz(npz, "force map arrays")
            model = cls(center=z["center"], scale=z["scale"], x_fit=z["x_fit"], dual_coef=z["dual_coef"],
                        gamma=float(z["gamma"]), alpha=float(z["alpha"]),
                        feature_names=tuple(meta.get("features", FORCE_FEATURES)))
        model.meta = {k: v for k, v in meta.items() if k not in ("format", "version", "arrays")}
        return model


def _model_path(path: str | Path, name: str) -> Path:
    """A model named by its .json, .npz, stem, or the session's output folder (``<folder>/<name>``)."""
    p = Path(path)
    return p / name if p.is_dir() else p


def model_json_path(path: str | Path, name: str) -> Path:
    """The ``.json`` of a model named by a bench (its folder, stem, ``.json`` or ``.npz``); ``name`` is
    the file name inside a session folder (``force_map``, ``substance``)."""
    return _paths(_model_path(path, name))[1]


def load_force_map(path: str | Path) -> ForceMapModel:
    """The force map a bench names (``calib/force_map``, ``.../force_map.json`` or ``.npz``; the
    stable name reads the newest version). Raises CalibrationError naming the file and the command."""
    return _load_model(ForceMapModel, path, "force_map", "force-map")


def load_substance_model(path: str | Path) -> SubstanceModel:
    """The substance classifier a bench names (folder, ``.json``, ``.npz`` or stem)."""
    return _load_model(SubstanceModel, path, "substance", "substance")


_Model = TypeVar("_Model", "ForceMapModel", "SubstanceModel")


def _load_model(cls: type[_Model], path: str | Path, name: str, command: str) -> _Model:
    """``cls.load`` of what ``path`` names, the error naming the command that makes the file."""
    p = _model_path(path, name)
    try:
        model = cls.load(p)
    except CalibrationError as exc:
        raise CalibrationError(f"{exc}; make it with: tactile-rig calibrate {command}", device=command) from None
    model.meta.setdefault("path", str(_paths(p)[1]))
    return model


def _load_meta(js: Path, fmt: str) -> dict[str, Any]:
    if not js.is_file():
        raise CalibrationError(f"model file {js} does not exist", device=fmt)
    try:
        meta = load_json(js, "model file")
    except ValueError as exc:
        raise CalibrationError(f"model file {js} is not valid JSON: {exc}", device=fmt) from None
    if meta.get("format") != fmt:
        raise CalibrationError(f"{js} is a {meta.get('format')!r} file, expected {fmt!r}", device=fmt)
    if meta.get("version") != FORMAT_VERSION:
        raise CalibrationError(f"{js} has format version {meta.get('version')!r}; this tactile-rig reads "
                               f"version {FORMAT_VERSION}", device=fmt)
    return meta


def fit_force_map(X: np.ndarray, y: np.ndarray, *, alpha: float = 0.02, gamma: float | None = DEFAULT_GAMMA
                  ) -> ForceMapModel:
    """Fit robust scaling + RBF kernel ridge (sklearn); ``gamma=None`` means 1 / n_features (sklearn's)."""
    _sklearn()
    from sklearn.kernel_ridge import KernelRidge
    from sklearn.preprocessing import RobustScaler

    x = _check_features(X, len(FORCE_FEATURES), "force map training")
    yy = np.asarray(y, float).ravel()
    if yy.shape[0] != x.shape[0] or not np.all(np.isfinite(yy)):
        raise ValueError(f"force map training: {yy.shape[0]} finite forces needed for {x.shape[0]} samples")
    if not alpha > 0:
        raise ValueError(f"alpha={alpha!r} must be > 0 (the ridge penalty λ)")
    g = 1.0 / x.shape[1] if gamma is None else float(gamma)
    if not g > 0:
        raise ValueError(f"gamma={gamma!r} must be > 0")
    scaler = RobustScaler().fit(x)
    xs = scaler.transform(x)
    with warnings.catch_warnings(), _one_blas_thread():
        warnings.simplefilter("ignore")  # an ill-conditioned kernel is handled by the ridge term
        krr = KernelRidge(alpha=alpha, kernel="rbf", gamma=g).fit(xs, yy)
    return ForceMapModel(center=np.asarray(scaler.center_, float), scale=np.asarray(scaler.scale_, float),
                         x_fit=np.asarray(xs, float), dual_coef=np.asarray(krr.dual_coef_, float).ravel(),
                         gamma=g, alpha=float(alpha))


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


# -- substance classifier ---------------------------------------------------------------------
def stirring_features(series: np.ndarray, rate_hz: float, *, window_s: float = 2.0,
                      hop_s: float | None = None) -> np.ndarray:
    """Cut a stirring series (T × 3: fx, fy, tz in px) into windows → statistics (n × 8, :data:`STIR_FEATURES`).

    fy mean, std, peak-to-peak, roughness (mean |Δ|), the fraction of its variance above 3 Hz
    (sloshing), fx std, tz mean and std. Windows shorter than ``window_s`` at the end are dropped.
    """
    s = np.asarray(series, float)
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"stirring series must be T × 3 (fx, fy, tz), got shape {s.shape}")
    if not rate_hz > 0:
        raise ValueError(f"rate_hz={rate_hz!r} must be > 0")
    n = int(round(window_s * rate_hz))
    hop = int(round((hop_s or window_s) * rate_hz))
    if n < 4 or hop < 1:
        raise ValueError(f"window_s={window_s} at {rate_hz} Hz gives {n} samples; need >= 4")
    rows = []
    for a in range(0, s.shape[0] - n + 1, hop):
        w = np.nan_to_num(s[a:a + n])
        fx, fy, tz = w[:, 0], w[:, 1], w[:, 2]
        fyc = fy - fy.mean()
        spec = np.abs(np.fft.rfft(fyc)) ** 2
        freqs = np.fft.rfftfreq(n, 1.0 / rate_hz)
        total = spec.sum()
        hf = float(spec[freqs > 3.0].sum() / total) if total > 0 else 0.0
        rows.append([fy.mean(), fy.std(), np.ptp(fy), np.abs(np.diff(fy)).mean(), hf, fx.std(), tz.mean(), tz.std()])
    return np.asarray(rows, float).reshape(-1, len(STIR_FEATURES))


@dataclass
class SubstanceModel:
    """Stirring features → substance, an MLP with logistic units; numpy-only prediction."""

    center: np.ndarray
    scale: np.ndarray
    weights: list[np.ndarray]
    biases: list[np.ndarray]
    classes: list[str]
    out_activation: str  # "softmax" (3+ classes) or "logistic" (2 classes), as sklearn's MLP
    feature_names: tuple[str, ...] = STIR_FEATURES
    meta: dict[str, Any] = field(default_factory=dict)

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        a = (_check_features(X, len(self.feature_names), "substance classifier") - self.center) / self.scale
        for W, b in zip(self.weights[:-1], self.biases[:-1]):
            a = 1.0 / (1.0 + np.exp(-np.clip(a @ W + b, -500, 500)))
        z = a @ self.weights[-1] + self.biases[-1]
        if self.out_activation == "logistic":
            p = 1.0 / (1.0 + np.exp(-np.clip(z[:, 0], -500, 500)))
            return np.column_stack([1 - p, p])
        z = z - z.max(axis=1, keepdims=True)
        e = np.exp(z)
        return e / e.sum(axis=1, keepdims=True)

    def predict(self, X: np.ndarray) -> list[str]:
        return [self.classes[i] for i in np.argmax(self.predict_proba(X), axis=1)]

    def save(self, path: str | Path) -> tuple[Path, Path]:
        npz, js = _paths(path)
        npz.parent.mkdir(parents=True, exist_ok=True)
        arrays: dict[str, Any] = {"center": self.center, "scale": self.scale}
        for i, (W, b) in enumerate(zip(self.weights, self.biases)):
            arrays[f"W{i}"] = W
            arrays[f"b{i}"] = b
        np.savez(npz, **arrays)
        meta = {"format": SUBSTANCE_FORMAT, "version": FORMAT_VERSION, "classes": self.classes,
                "layers": len(self.weights), "activation": "logistic", "out_activation": self.out_activation,
                "features": list(self.feature_names), "arrays": npz.name, **self.meta}

        js.write_text(json.dumps(to_jsonable(meta), indent=1) + "\n", encoding="utf-8")
        return npz, js

    @classmethod
    def load(cls, path: str | Path) -> "SubstanceModel":
        npz, js = _paths(path)
        meta = _load_meta(js, SUBSTANCE_FORMAT)
        if not npz.is_file():
            raise CalibrationError(f"substance model arrays {npz} are missing (the .json is there)",
                                   device="substance")
        with checked(npz, "substance model", "a model written by 'tactile-rig calibrate substance'"):
            z = load_npz(npz, "substance model arrays")
            n = int(meta["layers"])
            model = cls(center=z["center"], scale=z["scale"], weights=[z[f"W{i}"] for i in range(n)],
                        biases=[z[f"b{i}"] for i in range(n)], classes=list(meta["classes"]),
                        out_activation=str(meta["out_activation"]),
                        feature_names=tuple(meta.get("features", STIR_FEATURES)))
        model.meta = {k: v for k, v in meta.items()
                      if k not in ("format", "version", "arrays", "classes", "layers", "out_activation")}
        return model


def fit_substance(X: np.ndarray, labels: Sequence[str], *, seed: int = 0,
                  hidden_layer_sizes: tuple[int, ...] = (10, 10, 10), max_iter: int = 2000) -> SubstanceModel:
    """Robust scaling + ``MLPClassifier(hidden_layer_sizes, activation='logistic', solver='lbfgs')``."""
    _sklearn()
    from sklearn.neural_network import MLPClassifier
    from sklearn.preprocessing import RobustScaler

    x = _check_features(X, len(STIR_FEATURES), "substance training")
    y = np.asarray(list(labels))
    if y.shape[0] != x.shape[0]:
        raise ValueError(f"substance training: {y.shape[0]} labels for {x.shape[0]} windows")
    if len(set(y.tolist())) < 2:
        raise CalibrationError("substance training needs at least two substances", device="substance")
    scaler = RobustScaler().fit(x)
    mlp = MLPClassifier(hidden_layer_sizes=hidden_layer_sizes, activation="logistic", solver="lbfgs",
                        max_iter=max_iter, random_state=seed)
    with warnings.catch_warnings(), _one_blas_thread():
        warnings.simplefilter("ignore")  # lbfgs stopping at max_iter is reported by the held-out accuracy
        mlp.fit(scaler.transform(x), y)
    return SubstanceModel(center=np.asarray(scaler.center_, float), scale=np.asarray(scaler.scale_, float),
                          weights=[np.asarray(w, float) for w in mlp.coefs_],
                          biases=[np.asarray(b, float) for b in mlp.intercepts_],
                          classes=[str(c) for c in mlp.classes_], out_activation=str(mlp.out_activation_))


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


def predict_substance(model: SubstanceModel, series: np.ndarray, rate_hz: float, *,
                      window_s: float | None = None) -> dict[str, Any]:
    """Classify a stirring series (T × 3: fx, fy, tz in px) window by window, then by majority.

    ``window_s`` defaults to the window the model was trained on. Returns the per-window labels and
    probabilities, the majority ``substance`` and its share of the windows (``agreement``).
    """
    w = float(window_s if window_s is not None else model.meta.get("window_s", 2.0))
    X = stirring_features(series, rate_hz, window_s=w)
    if X.shape[0] == 0:
        raise ValueError(f"the series has {np.asarray(series).shape[0]} samples at {rate_hz:.3g} Hz: shorter "
                         f"than one {w:g} s window")
    proba = model.predict_proba(X)
    labels = [model.classes[i] for i in np.argmax(proba, axis=1)]
    counts = {c: labels.count(c) for c in model.classes}
    best = max(model.classes, key=lambda c: (counts[c], float(proba[:, model.classes.index(c)].mean())))
    return {"substance": best, "agreement": counts[best] / len(labels), "windows": len(labels),
            "window_s": w, "counts": counts, "per_window": labels,
            "mean_probability": {c: float(proba[:, i].mean()) for i, c in enumerate(model.classes)}}


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

"""Substance classifier (thesis 3.4.2): what a stirred container holds, from its marker force series.

A stirring series (T × 3: fx, fy, tz in px) is cut into windows and each window becomes statistics
whose distribution depends on the substance's viscosity (:func:`stirring_features`,
:data:`STIR_FEATURES`); an MLP with logistic units (scikit-learn's ``MLPClassifier(activation=
'logistic', solver='lbfgs')``, fitted by :func:`fit_substance` with the ``learn`` extra) maps them to
a substance. :class:`SubstanceModel` predicts with numpy alone; :func:`predict_substance` classifies
a whole series by the majority of its windows. Saved as the force map is (:mod:`.force_map`), with
the envelope :data:`SUBSTANCE_FILE`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from tactile_rig.core.envelope import FileFormat
from tactile_rig.core.errors import CalibrationError
from tactile_rig.perception.fingervision.learned import (
    SavedModel,
    check_features,
    checked_envelope,
    feature_names,
    one_blas_thread,
    require_sklearn,
    saved_array,
)

__all__ = ["STIR_FEATURES", "SUBSTANCE_FILE", "SubstanceModel", "fit_substance", "predict_substance",
           "stirring_features"]

SUBSTANCE_FILE = FileFormat("substance_classifier", 1, "substance classifier")
STIR_FEATURES = ("fy_mean", "fy_std", "fy_p2p", "fy_roughness", "fy_hf_frac", "fx_std", "tz_mean", "tz_std")
_MAX_LAYERS = 64  # weight matrices a saved classifier may declare


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
class SubstanceModel(SavedModel):
    """Stirring features → substance, an MLP with logistic units; numpy-only prediction."""

    FILE = SUBSTANCE_FILE
    DEVICE = "substance"

    center: np.ndarray
    scale: np.ndarray
    weights: list[np.ndarray]
    biases: list[np.ndarray]
    classes: list[str]
    out_activation: str  # "softmax" (3+ classes) or "logistic" (2 classes), as sklearn's MLP
    feature_names: tuple[str, ...] = STIR_FEATURES
    meta: dict[str, Any] = field(default_factory=dict)

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Each class's probability (n × classes) for each row of stirring features ``X``."""
        a = (check_features(X, len(self.feature_names), "substance classifier") - self.center) / self.scale
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
        """The most probable substance for each row of ``X``."""
        return [self.classes[i] for i in np.argmax(self.predict_proba(X), axis=1)]

    def to_arrays(self) -> dict[str, Any]:
        """What ``<stem>.npz`` holds: the scaler and each layer's ``W<i>`` and ``b<i>``."""
        arrays: dict[str, Any] = {"center": self.center, "scale": self.scale}
        for i, (W, b) in enumerate(zip(self.weights, self.biases)):
            arrays[f"W{i}"] = W
            arrays[f"b{i}"] = b
        return arrays

    def metadata(self, arrays_name: str) -> dict[str, Any]:
        """What ``<stem>.json`` holds: the envelope, classes, layers and features, then :attr:`meta`."""
        return {**SUBSTANCE_FILE.header(), "classes": self.classes, "layers": len(self.weights),
                "activation": "logistic", "out_activation": self.out_activation,
                "features": list(self.feature_names), "arrays": arrays_name, **self.meta}

    @classmethod
    def from_saved(cls, meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray],
                   source: str = "substance classifier") -> "SubstanceModel":
        """A model from its metadata (envelope, classes, layers checked) and arrays, each layer's shape
        checked against the one before it and the classes; CalibrationError naming ``source`` otherwise."""
        meta = checked_envelope(SUBSTANCE_FILE, meta, source, "substance")
        classes, layers, out = meta.get("classes"), meta.get("layers"), meta.get("out_activation")
        if not (isinstance(classes, list) and len(classes) >= 2 and all(isinstance(c, str) for c in classes)):
            raise CalibrationError(f"{source}: 'classes' is {classes!r}; two or more names are needed",
                                   device="substance")
        if isinstance(layers, bool) or not isinstance(layers, int) or not 1 <= layers <= _MAX_LAYERS:
            raise CalibrationError(f"{source}: 'layers' is {layers!r}; 1-{_MAX_LAYERS} are needed", device="substance")
        if out not in ("softmax", "logistic") or (out == "logistic") != (len(classes) == 2):
            raise CalibrationError(f"{source}: 'out_activation' is {out!r} for {len(classes)} classes; "
                                   "'logistic' for two, 'softmax' for more", device="substance")
        names = feature_names(meta, STIR_FEATURES, source, "substance")
        width = len(names)
        weights, biases = [], []
        for i in range(layers):
            last = i == layers - 1
            W = saved_array(arrays, f"W{i}", (width, (1 if out == "logistic" else len(classes)) if last else None),
                            source, "substance")
            width = W.shape[1]
            weights.append(W)
            biases.append(saved_array(arrays, f"b{i}", (width,), source, "substance"))
        model = cls(center=saved_array(arrays, "center", (len(names),), source, "substance"),
                    scale=saved_array(arrays, "scale", (len(names),), source, "substance"), weights=weights,
                    biases=biases, classes=list(classes), out_activation=str(out), feature_names=names)
        model.meta = {k: v for k, v in meta.items()
                      if k not in ("format", "version", "arrays", "classes", "layers", "out_activation")}
        return model


def fit_substance(X: np.ndarray, labels: Sequence[str], *, seed: int = 0,
                  hidden_layer_sizes: tuple[int, ...] = (10, 10, 10), max_iter: int = 2000) -> SubstanceModel:
    """Robust scaling + ``MLPClassifier(hidden_layer_sizes, activation='logistic', solver='lbfgs')``
    (scikit-learn, the ``learn`` extra) on stirring features ``X`` (n × 8) and their substances."""
    require_sklearn()
    from sklearn.neural_network import MLPClassifier  # the learn extra: only fitting imports it
    from sklearn.preprocessing import RobustScaler

    x = check_features(X, len(STIR_FEATURES), "substance training")
    y = np.asarray(list(labels))
    if y.shape[0] != x.shape[0]:
        raise ValueError(f"substance training: {y.shape[0]} labels for {x.shape[0]} windows")
    if len(set(y.tolist())) < 2:
        raise CalibrationError("substance training needs at least two substances", device="substance")
    scaler = RobustScaler().fit(x)
    mlp = MLPClassifier(hidden_layer_sizes=hidden_layer_sizes, activation="logistic", solver="lbfgs",
                        max_iter=max_iter, random_state=seed)
    with warnings.catch_warnings(), one_blas_thread():
        warnings.simplefilter("ignore")  # lbfgs stopping at max_iter is reported by the held-out accuracy
        mlp.fit(scaler.transform(x), y)
    return SubstanceModel(center=np.asarray(scaler.center_, float), scale=np.asarray(scaler.scale_, float),
                          weights=[np.asarray(w, float) for w in mlp.coefs_],
                          biases=[np.asarray(b, float) for b in mlp.intercepts_],
                          classes=[str(c) for c in mlp.classes_], out_activation=str(mlp.out_activation_))


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

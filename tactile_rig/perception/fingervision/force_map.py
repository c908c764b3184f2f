"""Force map (thesis 3.4.1): a fingertip's marker force/torque (px) -> the force it presses with (N).

Six marker features (:data:`FORCE_FEATURES`) are robust-scaled (median and IQR, as scikit-learn's
``RobustScaler``) and an RBF kernel ridge regression maps them to newtons. :class:`ForceMapModel`
predicts with numpy alone; :func:`fit_force_map` fits with scikit-learn (the ``learn`` extra, imported
only when fitting: importing perception, loading a map and predicting never need it).

The model saves without pickle: ``<stem>.npz`` (the scaled training inputs, dual coefficients, the
scaler's centre and scale, gamma and alpha) and ``<stem>.json`` (the envelope
:data:`FORCE_MAP_FILE` and metadata). :meth:`ForceMapModel.load` reads both as they are; a bench
loads through :func:`tactile_rig.rig.learning.load_force_map`, which bounds and checks the files
first. Either way :meth:`ForceMapModel.from_saved` refuses arrays whose shapes disagree.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from tactile_rig.core.envelope import FileFormat
from tactile_rig.perception.fingervision.learned import (
    SavedModel,
    check_features,
    checked_envelope,
    feature_names,
    one_blas_thread,
    require_sklearn,
    saved_array,
)

__all__ = ["DEFAULT_GAMMA", "FORCE_FEATURES", "FORCE_MAP_FILE", "ForceMapModel", "fit_force_map"]

FORCE_MAP_FILE = FileFormat("force_map", 1, "force map model")
# RBF width on robust-scaled features. The thesis gives λ only; 0.05 (a kernel wider than sklearn's
# 1/n_features = 0.17) generalises better across trials whose grasp squeeze differs.
DEFAULT_GAMMA = 0.05
FORCE_FEATURES = ("fx_px", "fy_px", "fz_px", "tx_px2", "ty_px2", "tz_px2")
_PREDICT_BLOCK = 2048  # rows per kernel block: bounded memory for long recordings


@dataclass
class ForceMapModel(SavedModel):
    """Marker features (px) -> force (N) by RBF kernel ridge regression; numpy-only prediction."""

    FILE = FORCE_MAP_FILE
    DEVICE = "force-map"

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
        x = (check_features(X, len(self.feature_names), "force map") - self.center) / self.scale
        out = np.empty(x.shape[0])
        for i in range(0, x.shape[0], _PREDICT_BLOCK):
            xb = x[i:i + _PREDICT_BLOCK]
            d2 = (np.sum(xb**2, 1)[:, None] + np.sum(self.x_fit**2, 1)[None, :] - 2.0 * xb @ self.x_fit.T)
            out[i:i + _PREDICT_BLOCK] = np.exp(-self.gamma * np.maximum(d2, 0.0)) @ self.dual_coef
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

    def to_arrays(self) -> dict[str, Any]:
        """What ``<stem>.npz`` holds."""
        return {"center": self.center, "scale": self.scale, "x_fit": self.x_fit, "dual_coef": self.dual_coef,
                "gamma": np.float64(self.gamma), "alpha": np.float64(self.alpha)}

    def metadata(self, arrays_name: str) -> dict[str, Any]:
        """What ``<stem>.json`` holds: the envelope, the kernel and the features, then :attr:`meta`."""
        return {**FORCE_MAP_FILE.header(), "kernel": "rbf", "gamma": self.gamma, "alpha": self.alpha,
                "features": list(self.feature_names), "n_train": int(self.x_fit.shape[0]), "arrays": arrays_name,
                **self.meta}

    @classmethod
    def from_saved(cls, meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray],
                   source: str = "force map") -> "ForceMapModel":
        """A model from its metadata (envelope checked) and arrays, each shape checked against the
        features and the training size; CalibrationError naming ``source`` otherwise."""
        meta = checked_envelope(FORCE_MAP_FILE, meta, source, "force-map")
        names = feature_names(meta, FORCE_FEATURES, source, "force-map")
        k = len(names)
        x_fit = saved_array(arrays, "x_fit", (None, k), source, "force-map")
        n = x_fit.shape[0]
        model = cls(center=saved_array(arrays, "center", (k,), source, "force-map"),
                    scale=saved_array(arrays, "scale", (k,), source, "force-map"), x_fit=x_fit,
                    dual_coef=saved_array(arrays, "dual_coef", (n,), source, "force-map"),
                    gamma=float(saved_array(arrays, "gamma", (), source, "force-map")),
                    alpha=float(saved_array(arrays, "alpha", (), source, "force-map")), feature_names=names)
        model.meta = {k: v for k, v in meta.items() if k not in ("format", "version", "arrays")}
        return model


def fit_force_map(X: np.ndarray, y: np.ndarray, *, alpha: float = 0.02, gamma: float | None = DEFAULT_GAMMA
                  ) -> ForceMapModel:
    """Fit robust scaling + RBF kernel ridge (scikit-learn) on features ``X`` (n × 6, px) and forces
    ``y`` (N); ``alpha`` is the ridge penalty λ, ``gamma=None`` means 1 / n_features (sklearn's)."""
    require_sklearn()
    from sklearn.kernel_ridge import KernelRidge  # the learn extra: only fitting imports it
    from sklearn.preprocessing import RobustScaler

    x = check_features(X, len(FORCE_FEATURES), "force map training")
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
    with warnings.catch_warnings(), one_blas_thread():
        warnings.simplefilter("ignore")  # an ill-conditioned kernel is handled by the ridge term
        krr = KernelRidge(alpha=alpha, kernel="rbf", gamma=g).fit(xs, yy)
    return ForceMapModel(center=np.asarray(scaler.center_, float), scale=np.asarray(scaler.scale_, float),
                         x_fit=np.asarray(xs, float), dual_coef=np.asarray(krr.dual_coef_, float).ravel(),
                         gamma=g, alpha=float(alpha))

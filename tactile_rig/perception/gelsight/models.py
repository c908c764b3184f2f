"""Colour(+position) -> slope models: the paper's lookup table, a polynomial and a tiny numpy MLP.

Every model maps features ``(N, 5)`` = (dB, dG, dR, u, v) to slopes ``(N, 2)`` = (gx, gy), where dB/dG/dR
are the frame minus background in 0..255 units divided by 255 and u, v the pixel position normalised to
-1..1. Models store their parameters as plain float arrays so that they save without pickle; each
``from_arrays`` refuses arrays that are missing, of another shape than the model's declared sizes, or
not finite, with a :class:`~tactile_rig.core.errors.CalibrationError` naming the array (as saved in a
calibration's ``.npz``: ``model_<name>``).
"""

from __future__ import annotations

import itertools
from typing import Any, Mapping

import numpy as np

from tactile_rig.core.errors import CalibrationError

COLOUR_SCALE = 255.0
MLP_MAX_LAYERS = 16    # hidden layers a saved MLP may declare
MLP_MAX_WIDTH = 4096   # units a saved MLP's hidden layer may declare


def _model_array(arrays: Mapping[str, np.ndarray], key: str, shape: tuple[int | None, ...], sizes: str) -> np.ndarray:
    """``arrays[key]``: present, real, finite and of ``shape`` (None: any length on that axis), which
    ``sizes`` (the model's declared sizes) explains; else CalibrationError naming ``model_<key>``."""
    if key not in arrays:
        raise CalibrationError(f"the model array model_{key} is missing ({sizes})", device="gelsight.calibration")
    a = np.asarray(arrays[key])
    want = "(" + ", ".join("N" if n is None else str(n) for n in shape) + ("," if len(shape) == 1 else "") + ")"
    if a.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, a.shape)):
        raise CalibrationError(f"the model array model_{key} has shape {a.shape}; {sizes} need {want}",
                               device="gelsight.calibration")
    if a.dtype.kind not in "biuf":
        raise CalibrationError(f"the model array model_{key} has dtype {a.dtype}; a real numeric array is needed",
                               device="gelsight.calibration")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise CalibrationError(f"the model array model_{key} holds NaN or infinity", device="gelsight.calibration")
    return a


def _declared(make: Any, *args: Any) -> Any:
    """A model built from saved hyper-parameters; a value outside its range is a CalibrationError."""
    try:
        return make(*args)
    except (ValueError, OverflowError) as exc:
        raise CalibrationError(f"the model's saved hyper-parameters are invalid ({exc})",
                               device="gelsight.calibration") from None


class LutModel:
    """Li 2014 lookup table: colour difference binned per channel, mean slope per bin (position-blind).

    bins: bins per channel; colour_range: the difference range (0..255 units) covered, symmetric about 0.
    Empty bins take the value of the nearest filled bin.
    """

    kind = "lut"

    def __init__(self, bins: int = 32, colour_range: float = 128.0) -> None:
        if bins < 2 or bins > 256:
            raise ValueError(f"bins must be in 2..256, got {bins}")
        if not colour_range > 0:
            raise ValueError(f"colour_range must be > 0, got {colour_range}")
        self.bins = int(bins)
        self.colour_range = float(colour_range)
        self.table = np.zeros((self.bins,) * 3 + (2,), np.float32)
        self.filled = np.zeros((self.bins,) * 3, bool)

    def bin_index(self, diff: np.ndarray) -> np.ndarray:
        """Integer bin per channel of colour differences in 0..255 units (any shape, last axis 3)."""
        scale = self.bins / (2.0 * self.colour_range)
        idx = np.floor((diff + self.colour_range) * scale).astype(np.int32)
        return np.clip(idx, 0, self.bins - 1)

    def fit(self, feats: np.ndarray, slopes: np.ndarray) -> "LutModel":
        from scipy import ndimage

        idx = self.bin_index(feats[:, :3] * COLOUR_SCALE)
        flat = np.ravel_multi_index((idx[:, 0], idx[:, 1], idx[:, 2]), (self.bins,) * 3)
        n = self.bins ** 3
        count = np.bincount(flat, minlength=n).astype(np.float64)
        table = np.zeros((n, 2))
        for c in range(2):
            table[:, c] = np.bincount(flat, weights=slopes[:, c], minlength=n)
        filled = count > 0
        table[filled] /= count[filled, None]
        self.filled = filled.reshape((self.bins,) * 3)
        table = table.reshape((self.bins,) * 3 + (2,))
        if filled.any() and not filled.all():
            _, near = ndimage.distance_transform_edt(~self.filled, return_indices=True)
            table = table[near[0], near[1], near[2]]
        self.table = table.astype(np.float32)
        return self

    def predict(self, feats: np.ndarray) -> np.ndarray:
        idx = self.bin_index(feats[:, :3] * COLOUR_SCALE)
        return self.table[idx[:, 0], idx[:, 1], idx[:, 2]]

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"table": self.table, "filled": self.filled,
                "hyper": np.array([self.bins, self.colour_range], np.float64)}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> "LutModel":
        """The table saved by :meth:`to_arrays`, its shape checked against its bins."""
        bins, rng = _model_array(arrays, "hyper", (2,), "a lookup table's (bins, colour range)")
        m = _declared(cls, int(bins), float(rng))
        sizes = f"a lookup table of {m.bins} bins a channel"
        m.table = _model_array(arrays, "table", (m.bins,) * 3 + (2,), sizes).astype(np.float32)
        m.filled = _model_array(arrays, "filled", (m.bins,) * 3, sizes).astype(bool)
        return m


def _exponents(degree: int, n_vars: int) -> np.ndarray:
    rows = [e for e in itertools.product(range(degree + 1), repeat=n_vars) if sum(e) <= degree]
    rows.sort(key=lambda e: (sum(e), e))
    return np.array(rows, np.int64)


class PolyModel:
    """Least-squares polynomial of total degree ``degree`` in colour (and pixel position if position).

    ridge: Tikhonov weight relative to the mean diagonal of the normal matrix.
    """

    kind = "poly"

    def __init__(self, degree: int = 3, position: bool = True, ridge: float = 1e-6) -> None:
        if degree < 1 or degree > 6:
            raise ValueError(f"degree must be in 1..6, got {degree}")
        self.degree = int(degree)
        self.position = bool(position)
        self.ridge = float(ridge)
        self.exps = _exponents(self.degree, 5 if self.position else 3)
        self.coef = np.zeros((len(self.exps), 2), np.float64)

    def _design(self, feats: np.ndarray) -> np.ndarray:
        x = feats[:, : self.exps.shape[1]].astype(np.float64)
        powers = [x[:, [j]] ** np.arange(self.degree + 1)[None, :] for j in range(x.shape[1])]
        out = np.ones((len(x), len(self.exps)))
        for j in range(x.shape[1]):
            out *= powers[j][:, self.exps[:, j]]
        return out

    def fit(self, feats: np.ndarray, slopes: np.ndarray) -> "PolyModel":
        a = self._design(feats)
        ata = a.T @ a
        lam = self.ridge * np.trace(ata) / len(ata)
        self.coef = np.linalg.solve(ata + lam * np.eye(len(ata)), a.T @ slopes)
        return self

    def predict(self, feats: np.ndarray) -> np.ndarray:
        return (self._design(feats) @ self.coef).astype(np.float32)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"coef": self.coef, "hyper": np.array([self.degree, float(self.position), self.ridge])}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> "PolyModel":
        """The coefficients saved by :meth:`to_arrays`, their shape checked against the degree."""
        deg, pos, ridge = _model_array(arrays, "hyper", (3,), "a polynomial's (degree, position, ridge)")
        m = _declared(cls, int(deg), bool(pos), float(ridge))
        sizes = f"a degree-{m.degree} polynomial of {m.exps.shape[1]} variables ({len(m.exps)} terms)"
        m.coef = _model_array(arrays, "coef", (len(m.exps), 2), sizes).astype(np.float64)
        return m


class MlpModel:
    """Tiny MLP (5 -> hidden... -> 2, tanh) on colour + position, trained with Adam in numpy (float32).

    The output is the slope angle (atan of the slope, radians) so that steep rims stay bounded;
    predict returns slopes. epochs: passes over the data in minibatches of ``batch``; the learning
    rate follows a cosine decay from ``lr``.
    """

    kind = "mlp"

    def __init__(self, hidden: tuple[int, ...] = (32, 32), epochs: int = 60, batch: int = 512,
                 lr: float = 3e-3, seed: int = 0) -> None:
        if not hidden or min(hidden) < 1:
            raise ValueError(f"hidden must be a non-empty tuple of positive sizes, got {hidden}")
        if epochs < 1 or batch < 1:
            raise ValueError(f"epochs and batch must be >= 1, got {epochs}, {batch}")
        self.hidden = tuple(int(h) for h in hidden)
        self.epochs, self.batch, self.lr, self.seed = int(epochs), int(batch), float(lr), int(seed)
        sizes = (5,) + self.hidden + (2,)
        rng = np.random.default_rng(self.seed)
        self.weights = [rng.normal(0, np.sqrt(1.0 / a), (a, b)).astype(np.float32)
                        for a, b in zip(sizes[:-1], sizes[1:])]
        self.biases = [np.zeros(b, np.float32) for b in sizes[1:]]
        self.in_scale = np.array([4.0, 4.0, 4.0, 1.0, 1.0], np.float32)

    def _forward(self, x: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        acts = [x]
        h = x
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = h @ w + b
            if i < len(self.weights) - 1:
                h = np.tanh(h)
            acts.append(h)
        return h, acts

    def fit(self, feats: np.ndarray, slopes: np.ndarray) -> "MlpModel":
        # Multi-threaded BLAS on 512x32 products is slower than one thread (and oversubscribes).
        try:
            from threadpoolctl import threadpool_limits
        except ImportError:  # optional: without it the fit is just slower on busy machines
            return self._fit(feats, slopes)
        with threadpool_limits(1):
            return self._fit(feats, slopes)

    def _fit(self, feats: np.ndarray, slopes: np.ndarray) -> "MlpModel":
        x_all = (feats * self.in_scale).astype(np.float32)
        y_all = np.arctan(slopes).astype(np.float32)
        rng = np.random.default_rng(self.seed)
        params = self.weights + self.biases
        m = [np.zeros_like(p) for p in params]
        v = [np.zeros_like(p) for p in params]
        b1, b2, eps, t = 0.9, 0.999, 1e-8, 0
        n = len(x_all)
        steps = max(1, self.epochs * -(-n // self.batch))
        nw = len(self.weights)
        for _ in range(self.epochs):
            order = rng.permutation(n)
            for start in range(0, n, self.batch):
                sel = order[start:start + self.batch]
                out, acts = self._forward(x_all[sel])
                grad = (2.0 / len(sel)) * (out - y_all[sel])
                grads: list[np.ndarray] = [None] * (2 * nw)  # type: ignore[list-item]
                for i in range(nw - 1, -1, -1):
                    grads[i] = acts[i].T @ grad
                    grads[nw + i] = grad.sum(axis=0)
                    if i > 0:
                        grad = (grad @ self.weights[i].T) * (1.0 - acts[i] ** 2)
                t += 1
                lr = self.lr * 0.5 * (1 + np.cos(np.pi * min(t, steps) / steps))  # cosine decay
                c1, c2 = 1 - b1 ** t, 1 - b2 ** t
                for j, g in enumerate(grads):
                    m[j] *= b1
                    m[j] += (1 - b1) * g
                    v[j] *= b2
                    v[j] += (1 - b2) * g * g
                    params[j] -= (lr / c1) * m[j] / (np.sqrt(v[j] / c2) + eps)
        return self

    def predict(self, feats: np.ndarray) -> np.ndarray:
        out, _ = self._forward((feats * self.in_scale).astype(np.float32))
        return np.tan(np.clip(out, -1.5, 1.5)).astype(np.float32)

    def to_arrays(self) -> dict[str, np.ndarray]:
        d: dict[str, np.ndarray] = {"hyper": np.array([self.epochs, self.batch, self.lr, self.seed]),
                                    "hidden": np.array(self.hidden, np.int64)}
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            d[f"w{i}"], d[f"b{i}"] = w, b
        return d

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> "MlpModel":
        """The weights saved by :meth:`to_arrays`, each shape checked against the declared layer sizes."""
        epochs, batch, lr, seed = _model_array(arrays, "hyper", (4,), "an MLP's (epochs, batch, rate, seed)")
        hidden = _model_array(arrays, "hidden", (None,), "an MLP's hidden layer sizes")
        if not 1 <= hidden.size <= MLP_MAX_LAYERS or hidden.min() < 1 or hidden.max() > MLP_MAX_WIDTH:
            # Checked before the model is built: its constructor allocates every layer.
            raise CalibrationError(f"the model array model_hidden is {hidden.tolist()}; an MLP of 1-{MLP_MAX_LAYERS} "
                                   f"hidden layers of 1-{MLP_MAX_WIDTH} units is needed", device="gelsight.calibration")
        m = _declared(cls, tuple(int(h) for h in hidden), int(epochs), int(batch), float(lr), int(seed))
        layers = (5,) + m.hidden + (2,)
        sizes = f"the layer sizes {list(layers)}"
        m.weights = [_model_array(arrays, f"w{i}", (a, b), sizes).astype(np.float32)
                     for i, (a, b) in enumerate(zip(layers[:-1], layers[1:]))]
        m.biases = [_model_array(arrays, f"b{i}", (b,), sizes).astype(np.float32) for i, b in enumerate(layers[1:])]
        return m


MODELS: dict[str, Any] = {"lut": LutModel, "poly": PolyModel, "mlp": MlpModel}  # name -> model class (fit, from_arrays)

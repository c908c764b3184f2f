"""Colour(+position) -> slope models: the paper's lookup table, a polynomial and a tiny numpy MLP.

Every model maps features ``(N, 5)`` = (dB, dG, dR, u, v) to slopes ``(N, 2)`` = (gx, gy), where dB/dG/dR
are the frame minus background in 0..255 units divided by 255 and u, v the pixel position normalised to
-1..1. Models store their parameters as plain float arrays so that they save without pickle.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

COLOUR_SCALE = 255.0


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
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> "LutModel":
        bins, rng = arrays["hyper"]
        m = cls(int(bins), float(rng))
        m.table = arrays["table"].astype(np.float32)
        m.filled = arrays["filled"].astype(bool)
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
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> "PolyModel":
        deg, pos, ridge = arrays["hyper"]
        m = cls(int(deg), bool(pos), float(ridge))
        m.coef = arrays["coef"].astype(np.float64)
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
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> "MlpModel":
        epochs, batch, lr, seed = arrays["hyper"]
        m = cls(tuple(int(h) for h in arrays["hidden"]), int(epochs), int(batch), float(lr), int(seed))
        n = len(m.weights)
        m.weights = [arrays[f"w{i}"].astype(np.float32) for i in range(n)]
        m.biases = [arrays[f"b{i}"].astype(np.float32) for i in range(n)]
        return m


MODELS: dict[str, Any] = {"lut": LutModel, "poly": PolyModel, "mlp": MlpModel}  # name -> model class (fit, from_arrays)

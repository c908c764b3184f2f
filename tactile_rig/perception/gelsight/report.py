"""Calibration report: height and normal error on held-out ball presses, colour-space coverage."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactile_rig.perception.gelsight.calibration import (
    FitOptions,
    PressSet,
    calibrate_from_presses,
    clamp_radius_px,
    sphere_cap,
)
from tactile_rig.perception.gelsight.integration import IntegrationParams
from tactile_rig.perception.gelsight.models import LutModel
from tactile_rig.perception.gelsight.pipeline import ContactParams, Reconstructor


@dataclass
class PressError:
    """Error of one press: mean normal angle (deg) inside ``normal_fraction`` of the contact radius,
    height RMS (mm) inside the contact circle after the best constant offset."""

    name: str
    normal_deg: float
    height_rms_mm: float


@dataclass
class CalibrationReport:
    """Held-out errors per press, their means, and the fraction of occupied colour bins."""

    presses: list[PressError] = field(default_factory=list)
    mean_normal_deg: float = float("nan")
    mean_height_rms_mm: float = float("nan")
    colour_coverage: float = float("nan")
    protocol: str = ""


def press_error(height_mm: np.ndarray, center_px: tuple[float, float], radius_px: float,
                ball_radius_mm: float, mm_per_px: float, normal_fraction: float = 0.8) -> tuple[float, float]:
    """(mean normal angle error deg inside normal_fraction*a, height RMS mm inside a after offset)."""
    z_true, gx_t, gy_t, inside = sphere_cap(height_mm.shape, center_px, radius_px, ball_radius_mm, mm_per_px)
    gy, gx = np.gradient(height_mm.astype(np.float64), mm_per_px)
    n_est = np.stack([-gx, -gy, np.ones_like(gx)], -1)
    n_true = np.stack([-gx_t, -gy_t, np.ones_like(gx)], -1)
    n_est /= np.linalg.norm(n_est, axis=-1, keepdims=True)
    n_true /= np.linalg.norm(n_true, axis=-1, keepdims=True)
    _, _, _, core = sphere_cap(height_mm.shape, center_px, radius_px * normal_fraction, ball_radius_mm, mm_per_px)
    cosang = np.clip(np.sum(n_est * n_true, -1), -1.0, 1.0)
    normal_deg = float(np.degrees(np.arccos(cosang[core])).mean())
    d = height_mm[inside] - z_true[inside]
    height_rms = float(np.sqrt(np.mean((d - d.mean()) ** 2)))
    return normal_deg, height_rms


def colour_coverage(presses: PressSet, bins: int = 16, colour_range: float = 128.0) -> float:
    """Fraction of colour-difference bins (bins^3 over +-colour_range) seen in the presses' contacts.

    Only bins inside the convex span actually reachable matter, so this is a relative figure: compare
    calibrations, do not expect 1.0.
    """
    lut = LutModel(bins, colour_range)
    seen = np.zeros(bins ** 3, bool)
    bg = presses.background.astype(np.float32)
    for f in presses.frames:
        idx = lut.bin_index((f.astype(np.float32) - bg).reshape(-1, 3))
        seen[np.ravel_multi_index((idx[:, 0], idx[:, 1], idx[:, 2]), (bins,) * 3)] = True
    return float(seen.mean())


def cross_validate(presses: PressSet, mm_per_px: float, ball_radius_mm: float, method: str = "mlp",
                   folds: int = 5, integration: IntegrationParams | None = None,
                   contact: ContactParams | None = None, fit: FitOptions = FitOptions(),
                   bake_bins: int | None = 32, **hyper: Any) -> CalibrationReport:
    """k-fold held-out errors: press i is in test fold i % folds; fit on the rest, measure on it."""
    n = len(presses.frames)
    if folds < 2 or folds > n:
        raise ValueError(f"folds must be in 2..{n}, got {folds}")
    errors: list[PressError] = [None] * n  # type: ignore[list-item]
    for k in range(folds):
        test = [i for i in range(n) if i % folds == k]
        train = [i for i in range(n) if i % folds != k]
        cal = calibrate_from_presses(presses.subset(train), mm_per_px, ball_radius_mm, method,
                                     fit=fit, bake_bins=bake_bins, **hyper)
        rec = Reconstructor(cal, integration, contact)
        for i in test:
            z = rec.height_mm(presses.frames[i])
            a = clamp_radius_px(presses.radii_px[i], ball_radius_mm, mm_per_px, fit.max_radius_fraction)
            nd, hr = press_error(z, tuple(presses.centers_px[i]), a, ball_radius_mm, mm_per_px)
            errors[i] = PressError(presses.names[i], nd, hr)
    return CalibrationReport(errors, float(np.mean([e.normal_deg for e in errors])),
                             float(np.mean([e.height_rms_mm for e in errors])), colour_coverage(presses),
                             f"{folds}-fold (press i tests in fold i mod {folds}), method={method}")

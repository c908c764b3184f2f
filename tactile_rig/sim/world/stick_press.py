"""A small world model of the force-map session: a grasped stick pressed on the load cell.

Only what the session needs is modelled (thesis 3.4.1). The gripper holds a stick upright between
two FingerVision fingertips and pushes it down on the scale; the scale's reaction ``F`` (N) goes up
the stick into the fingertips as shear, half per finger. What one fingertip's marker-force
estimator reports (:func:`tactile_rig.perception.fingervision.force.estimate_force_torque`, pixels):

- shear along the stick, ``fy = g_k · D_sat · tanh(F / (2 F_sat))``: linear for light presses,
  saturating as the skin's markers reach their travel; ``g_k`` is the trial's gain (where the stick
  sits in the grasp, skin temperature), drawn per trial around 1;
- cross-talk ``fx = fy · sin(a)`` from the camera's fixed misalignment ``a`` to the stick axis;
- normal ``fz = s_k + c_z · F``: the grasp squeeze ``s_k`` (per trial) plus a little bulging under load;
- torque ``tz = r · fy`` with ``r`` the fixed offset of the grasp from the image centre (px);
  ``tx``, ``ty`` are noise only.

Stated noise (std, per sample): marker centroid noise ``marker_noise_px`` on fx, fy, fz (after
averaging ~100 markers); ``torque_noise_px2`` on the torques; the scale's HX711 noise
``scale_noise_n`` on its readings. Per-trial variation: the shear gain ``gain_sd`` (relative) and
the squeeze ``squeeze_sd_px``; the rig's geometry (``misalign_deg``, ``lever_px``) is fixed. :meth:`StickPressScene.force_noise_n` is the resulting noise
floor in newtons at a force: what no map from these features can beat on a new trial.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FEATURES = ("fx_px", "fy_px", "fz_px", "tx_px2", "ty_px2", "tz_px2")


@dataclass(frozen=True)
class PressTrial:
    """One press: time, true force, scale readings (N) and marker features (T × 6, :data:`FEATURES`)."""

    index: int
    peak_force_n: float
    t_s: np.ndarray
    force_true_n: np.ndarray
    scale_n: np.ndarray
    features: np.ndarray


@dataclass(frozen=True)
class StickPressScene:
    """Parameters of the stick-press world (units in the names; see the module doc for the physics)."""

    shear_sat_px: float = 6.0
    force_sat_n: float = 10.0
    normal_per_n_px: float = 0.02
    marker_noise_px: float = 0.03
    torque_noise_px2: float = 0.05
    scale_noise_n: float = 0.02
    gain_sd: float = 0.02
    misalign_deg: float = 3.0
    lever_px: float = 5.0
    squeeze_mean_px: float = 1.0
    squeeze_sd_px: float = 0.05
    rate_hz: float = 20.0
    ramp_s: float = 1.0
    hold_s: float = 0.5

    def shear_px(self, force_n: np.ndarray | float, gain: float = 1.0) -> np.ndarray:
        """Noise-free shear of one fingertip (px) at total stick force ``force_n``."""
        return gain * self.shear_sat_px * np.tanh(np.asarray(force_n, float) / (2 * self.force_sat_n))

    def profile(self, peak_force_n: float) -> tuple[np.ndarray, np.ndarray]:
        """Time (s) and true force (N) of one press: ramp up, hold, ramp down."""
        dt = 1.0 / self.rate_hz
        t = np.arange(0.0, 2 * self.ramp_s + self.hold_s + dt / 2, dt)
        up = np.clip(t / self.ramp_s, 0, 1)
        down = np.clip((2 * self.ramp_s + self.hold_s - t) / self.ramp_s, 0, 1)
        return t, peak_force_n * np.minimum(up, down)

    def trial(self, index: int, peak_force_n: float, rng: np.random.Generator) -> PressTrial:
        """Simulate one press with this trial's own variation and noise."""
        if not (peak_force_n >= 0 and np.isfinite(peak_force_n)):
            raise ValueError(f"peak_force_n={peak_force_n!r} must be a finite force >= 0 N")
        t, f = self.profile(peak_force_n)
        gain = 1.0 + self.gain_sd * rng.standard_normal()
        squeeze = self.squeeze_mean_px + self.squeeze_sd_px * rng.standard_normal()
        n = t.size
        fy = self.shear_px(f, gain)
        fx = fy * np.sin(np.deg2rad(self.misalign_deg))
        fz = squeeze + self.normal_per_n_px * f
        feats = np.column_stack([
            fx + self.marker_noise_px * rng.standard_normal(n),
            fy + self.marker_noise_px * rng.standard_normal(n),
            fz + self.marker_noise_px * rng.standard_normal(n),
            self.torque_noise_px2 * rng.standard_normal(n),
            self.torque_noise_px2 * rng.standard_normal(n),
            self.lever_px * fy + self.torque_noise_px2 * rng.standard_normal(n),
        ])
        scale = f + self.scale_noise_n * rng.standard_normal(n)
        return PressTrial(index, float(peak_force_n), t, f, scale, feats)

    def trials(self, peaks_n: list[float] | np.ndarray, seed: int = 0, *, first_index: int = 0) -> list[PressTrial]:
        """Several presses, one per peak force, from one seed."""
        rng = np.random.default_rng(seed)
        return [self.trial(first_index + i, float(p), rng) for i, p in enumerate(peaks_n)]

    def force_noise_n(self, force_n: np.ndarray | float) -> np.ndarray:
        """The noise floor (std, N) of any force estimate from these features on a new trial.

        Shear noise and the trial's unknown gain, mapped to force through the local slope of the
        saturating shear, plus the scale's own noise (the estimate is compared with the scale).
        """
        f = np.asarray(force_n, float)
        u = f / (2 * self.force_sat_n)
        slope = self.shear_sat_px / (2 * self.force_sat_n) * (1 - np.tanh(u) ** 2)  # px per N
        shear = self.shear_px(f)
        shear_var = self.marker_noise_px**2 + (self.gain_sd * shear) ** 2
        return np.sqrt(self.scale_noise_n**2 + shear_var / slope**2)


def increasing_peaks(n_trials: int, max_force_n: float, min_force_n: float | None = None) -> np.ndarray:
    """``n_trials`` peak forces rising evenly to ``max_force_n`` (the session's press schedule)."""
    if n_trials < 2:
        raise ValueError(f"n_trials={n_trials!r} must be >= 2 (one trial is held out)")
    if not max_force_n > 0:
        raise ValueError(f"max_force_n={max_force_n!r} must be > 0 N")
    lo = max_force_n / n_trials if min_force_n is None else min_force_n
    return np.linspace(lo, max_force_n, n_trials)

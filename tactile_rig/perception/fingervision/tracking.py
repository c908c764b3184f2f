"""Marker identities across frames: gated windowed re-detection plus an optional per-marker Kalman filter.

Each marker of the baseline keeps its id for ever. Every frame, each marker is re-measured inside a
small window around its predicted position by thresholded moments of the contrast map (cheap, and
sub-pixel), then accepted only if it passes the reference's gates: peak contrast, position jump
(``max_jump_px``, VPMax), size jump (``max_size_jump_px``, VSMax), and no other marker measured at the
same place (two windows converging on one dot during a crossing). A marker that fails
``n_reset`` frames in a row is reset to its baseline rest position and re-detected there (the
window is larger while it is lost).

The Kalman filter (the thesis's, not in the reference code) is constant-velocity per marker on state
``(x, vx, y, vy, s)``: the thesis writes it as ``(x0, x, y0, y, s)`` with the previous position in
place of the velocity, the same model. Defaults ``dt_s = 1/15``, measurement noise 0.1, process noise
0.01 (identity covariances, pixel units). It is vectorised over markers, the covariance is updated in
Joseph form and symmetrised so it stays symmetric positive definite, and a marker that is missed is
held still (velocity zeroed, no prediction) so it never drifts while it is lost.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactile_rig.perception.fingervision.markers import MarkerBaseline, refine_centroids

__all__ = ["TrackerParams", "KalmanBank", "TrackState", "MarkerTracker"]


@dataclass(frozen=True)
class TrackerParams:
    """Tracking knobs (pixels, frames, seconds)."""

    window_half_px: int = 6
    """Half size of the measurement window around the predicted position."""
    lost_window_half_px: int = 8
    """Half size of the re-detection window around the rest position of a lost marker."""
    rel_threshold: float = 0.5
    """Fraction of the window's peak contrast below which pixels do not count in the centroid."""
    disc_margin_px: float | None = 1.0
    """After the first centroid pass only a disc of the marker's radius + this counts (print next to a
    marker cannot pull it); None: the half-maximum disc of the window, however wide."""
    min_peak_contrast: float = 0.3
    """A window whose peak contrast is lower holds no marker (contrast map units, 0..1)."""
    max_jump_px: float = 5.0
    """Largest accepted position change in one frame (the reference's VPMax)."""
    max_size_jump_px: float = 2.0
    """Largest accepted diameter change in one frame (the reference's VSMax, on a noisier size)."""
    min_separation_px: float = 3.0
    """Two markers measured closer than this are both rejected this frame (ambiguous)."""
    n_reset: int = 3
    """Consecutive misses after which a marker is reset to its rest position (NReset)."""
    n_confirm: int = 2
    """A lost marker is re-acquired after this many consecutive frames of a dot near its rest position..."""
    confirm_motion_px: float = 1.0
    """...that moved less than this between those frames (a passing dot is not a returning marker)."""
    use_kalman: bool = True
    dt_s: float = 1.0 / 15.0
    """Kalman time step used when the frames carry no timestamps."""
    max_dt_s: float = 1.0
    """A longer gap between timestamps counts as this long (the velocity is stale after a pause)."""
    measurement_noise: float = 0.1
    process_noise: float = 0.01


def _sel(which: np.ndarray) -> np.ndarray | slice:
    """A boolean selection, or a plain slice when it selects everything (views, not copies: faster)."""
    return slice(None) if which.all() else which


class KalmanBank:
    """Constant-velocity Kalman filters for N markers at once, state ``(x, vx, y, vy, s)``.

    With identity noise covariances and x, y always measured together, the x and y blocks of the
    covariance are equal and independent of the size block, so the 5x5 covariance of each marker is
    stored as one symmetric 2x2 axis block ``(p00, p01, p11)`` plus a size variance ``ps``: the same
    filter in closed form, elementwise over markers (no batched matrix algebra per frame).

    Valid input: noises > 0 (``ValueError`` otherwise), time steps >= 0 s; the covariance stays
    symmetric positive definite and finite (10^5-step and extreme-step property tests).
    """

    def __init__(
        self, positions_px: np.ndarray, sizes_px: np.ndarray, measurement_noise: float = 0.1,
        process_noise: float = 0.01,
    ) -> None:
        if not (measurement_noise > 0 and process_noise > 0):
            raise ValueError(
                f"KalmanBank: noises must be > 0, got measurement {measurement_noise}, process {process_noise}"
            )
        pos = np.asarray(positions_px, dtype=np.float64).reshape(-1, 2)
        n = pos.shape[0]
        self.r = float(measurement_noise)
        self.q = float(process_noise)
        self.pos = pos.copy()
        self.vel = np.zeros((n, 2))
        self.size = np.asarray(sizes_px, dtype=np.float64).reshape(n).copy()
        self.p00 = np.full(n, self.r)
        self.p01 = np.zeros(n)
        self.p11 = np.full(n, self.r)
        self.ps = np.full(n, self.r)

    def reset(self, which: np.ndarray, positions_px: np.ndarray, sizes_px: np.ndarray) -> None:
        """Re-initialise the markers selected by the boolean mask ``which`` at rest (zero velocity)."""
        self.pos[which] = positions_px[which]
        self.vel[which] = 0.0
        self.size[which] = sizes_px[which]
        self.p00[which] = self.r
        self.p01[which] = 0.0
        self.p11[which] = self.r
        self.ps[which] = self.r

    def snapshot(self) -> tuple[np.ndarray, ...]:
        return (self.pos.copy(), self.vel.copy(), self.size.copy())

    def predict(self, dt_s: float, which: np.ndarray) -> None:
        """Advance the selected markers by ``dt_s`` seconds (constant velocity)."""
        if not np.any(which):
            return
        sel = _sel(which)
        q = self.q
        self.pos[sel] += self.vel[sel] * dt_s
        # all new values are computed before any is stored: with a slice the inputs are views
        p00, p01, p11 = self.p00[sel], self.p01[sel], self.p11[sel]
        n00 = p00 + 2.0 * dt_s * p01 + dt_s * dt_s * p11 + q
        n01 = p01 + dt_s * p11
        n11 = p11 + q
        self.p00[sel], self.p01[sel], self.p11[sel] = n00, n01, n11
        self.ps[sel] += q

    def update(self, z: np.ndarray, which: np.ndarray) -> None:
        """Fuse measurements ``z`` (N, 3) = (x, y, size) for the selected markers (Joseph form)."""
        if not np.any(which):
            return
        sel = _sel(which)
        r = self.r
        p00, p01, p11 = self.p00[sel], self.p01[sel], self.p11[sel]
        k0 = p00 / (p00 + r)
        k1 = p01 / (p00 + r)
        innov = z[sel, :2] - self.pos[sel]
        self.pos[sel] += k0[:, None] * innov
        self.vel[sel] += k1[:, None] * innov
        a = 1.0 - k0
        # P+ = A P A^T + r K K^T with A = I - K H, H = [1, 0]: stays symmetric positive definite
        n00 = a * a * p00 + r * k0 * k0
        n01 = a * (p01 - k1 * p00) + r * k0 * k1
        n11 = k1 * k1 * p00 - 2.0 * k1 * p01 + p11 + r * k1 * k1
        self.p00[sel], self.p01[sel], self.p11[sel] = n00, n01, n11
        ps = self.ps[sel]
        ks = ps / (ps + r)
        self.size[sel] += ks * (z[sel, 2] - self.size[sel])
        self.ps[sel] = (1.0 - ks) ** 2 * ps + r * ks * ks

    def hold(self, which: np.ndarray, previous: tuple[np.ndarray, ...]) -> None:
        """A missed marker stays where it was before the prediction, with zero velocity (no drift)."""
        pos, _vel, size = previous
        self.pos[which] = pos[which]
        self.vel[which] = 0.0
        self.size[which] = size[which]

    def append(self, positions_px: np.ndarray, sizes_px: np.ndarray) -> None:
        """Add markers at rest (zero velocity, initial covariance) after the existing ones."""
        pos = np.asarray(positions_px, dtype=np.float64).reshape(-1, 2)
        n = len(pos)
        self.pos = np.vstack([self.pos, pos])
        self.vel = np.vstack([self.vel, np.zeros((n, 2))])
        self.size = np.concatenate([self.size, np.asarray(sizes_px, dtype=np.float64).reshape(n)])
        self.p00 = np.concatenate([self.p00, np.full(n, self.r)])
        self.p01 = np.concatenate([self.p01, np.zeros(n)])
        self.p11 = np.concatenate([self.p11, np.full(n, self.r)])
        self.ps = np.concatenate([self.ps, np.full(n, self.r)])

    def covariance(self, i: int) -> np.ndarray:
        """The full 5x5 covariance of marker ``i`` in state order (x, vx, y, vy, s)."""
        blk = np.array([[self.p00[i], self.p01[i]], [self.p01[i], self.p11[i]]])
        P = np.zeros((5, 5))
        P[0:2, 0:2] = blk
        P[2:4, 2:4] = blk
        P[4, 4] = self.ps[i]
        return P

    @property
    def positions_px(self) -> np.ndarray:
        return self.pos.copy()

    @property
    def sizes_px(self) -> np.ndarray:
        return self.size.copy()


@dataclass(frozen=True)
class TrackState:
    """Markers of one frame, in baseline order. ``valid``: baseline-valid and not lost."""

    ids: np.ndarray
    positions_px: np.ndarray
    sizes_px: np.ndarray
    valid: np.ndarray
    found: np.ndarray
    """Measured in this frame (passed every gate)."""
    misses: np.ndarray


class MarkerTracker:
    """Track the markers of a :class:`MarkerBaseline` through a sequence of contrast maps."""

    def __init__(self, baseline: MarkerBaseline, params: TrackerParams = TrackerParams()) -> None:
        if params.n_reset < 1:
            raise ValueError(f"TrackerParams.n_reset: expected >= 1, got {params.n_reset}")
        if not (0 < params.dt_s <= params.max_dt_s < float("inf")):
            raise ValueError(f"TrackerParams.dt_s, max_dt_s: expected 0 < dt_s <= max_dt_s < inf s, got "
                             f"{params.dt_s}, {params.max_dt_s}")
        self.params = params
        self.baseline = baseline
        n = len(baseline)
        self.ids = np.arange(n)
        self.positions_px = baseline.positions_px.astype(np.float64).copy().reshape(n, 2)
        self.sizes_px = baseline.sizes_px.astype(np.float64).copy().reshape(n)
        self.misses = np.zeros(n, dtype=np.int64)
        self.lost = np.zeros(n, dtype=bool)
        self._confirm = np.zeros(n, dtype=np.int64)
        self._confirm_pos = np.zeros((n, 2))
        self.kalman = (
            KalmanBank(self.positions_px, self.sizes_px, params.measurement_noise, params.process_noise)
            if params.use_kalman
            else None
        )
        self._last_t_s: float | None = None

    def add_markers(self, positions_px: np.ndarray, sizes_px: np.ndarray) -> np.ndarray:
        """Add markers (rest positions and diameters, px) with new ids after the existing ones; returns
        the new ids. The existing ids, positions and filter states do not change."""
        pos = np.asarray(positions_px, dtype=np.float64).reshape(-1, 2)
        size = np.asarray(sizes_px, dtype=np.float64).reshape(len(pos))
        n0, n = len(self.ids), len(pos)
        b = self.baseline
        self.baseline = MarkerBaseline(np.vstack([b.positions_px.reshape(-1, 2), pos]),
                                       np.concatenate([b.sizes_px, size]),
                                       np.concatenate([np.asarray(b.valid, bool), np.ones(n, bool)]))
        self.ids = np.arange(n0 + n)
        self.positions_px = np.vstack([self.positions_px, pos])
        self.sizes_px = np.concatenate([self.sizes_px, size])
        self.misses = np.concatenate([self.misses, np.zeros(n, np.int64)])
        self.lost = np.concatenate([self.lost, np.zeros(n, bool)])
        self._confirm = np.concatenate([self._confirm, np.zeros(n, np.int64)])
        self._confirm_pos = np.vstack([self._confirm_pos, np.zeros((n, 2))])
        if self.kalman is not None:
            self.kalman.append(pos, size)
        return self.ids[n0:].copy()

    def update(self, contrast: np.ndarray, t_s: float | None = None) -> TrackState:
        """Measure every marker in ``contrast`` (see :func:`markers.contrast_map`); returns the new state.

        Valid input: a contrast map (H x W, values 0..1; NaN reads as no contrast) and a finite ``t_s``
        (s) or None; a time step is at most ``max_dt_s``. Positions stay finite and inside the frame.
        """
        contrast = np.nan_to_num(np.asarray(contrast, dtype=np.float32), nan=0.0, posinf=1.0, neginf=0.0)
        p = self.params
        n = len(self.ids)
        dt_s = p.dt_s
        if t_s is not None:
            if not np.isfinite(t_s):
                raise ValueError(f"MarkerTracker.update: t_s must be a finite time in s, got {t_s!r}")
            if self._last_t_s is not None and t_s > self._last_t_s:
                dt_s = min(t_s - self._last_t_s, p.max_dt_s)
            self._last_t_s = t_s
        if n == 0:
            empty = np.zeros(0)
            return TrackState(self.ids, np.zeros((0, 2)), empty, empty.astype(bool), empty.astype(bool), self.misses)
        active = ~self.lost
        if self.kalman is not None:
            previous = self.kalman.snapshot()
            self.kalman.predict(dt_s, active)
            predicted = self.kalman.positions_px
            predicted[self.lost] = self.positions_px[self.lost]
        else:
            predicted = self.positions_px.copy()

        meas = np.zeros((n, 2))
        size = np.zeros(n)
        peak = np.zeros(n)
        for half, sel in ((p.window_half_px, active), (p.lost_window_half_px, self.lost)):
            if np.any(sel):
                meas[sel], size[sel], peak[sel] = refine_centroids(
                    contrast, predicted[sel], half, p.rel_threshold,
                    max_radius_px=None if p.disc_margin_px is None else self.sizes_px[sel] / 2 + p.disc_margin_px,
                )
        h, w = contrast.shape[:2]
        ref_pos = np.where(self.lost[:, None], self.baseline.positions_px, predicted)
        ok = (peak >= p.min_peak_contrast) & np.isfinite(meas).all(axis=1)
        ok &= (meas[:, 0] >= -0.5) & (meas[:, 0] <= w - 0.5) & (meas[:, 1] >= -0.5) & (meas[:, 1] <= h - 0.5)
        jump_limit = np.where(self.lost, p.lost_window_half_px, p.max_jump_px)
        ok &= np.hypot(*(meas - ref_pos).T) <= jump_limit
        ok &= np.abs(size - self.sizes_px) <= p.max_size_jump_px + np.where(self.lost, p.max_size_jump_px, 0.0)
        if n > 1 and np.count_nonzero(ok) > 1:
            idx = np.flatnonzero(ok)
            m = meas[idx]
            d = np.hypot(m[:, None, 0] - m[None, :, 0], m[:, None, 1] - m[None, :, 1])
            np.fill_diagonal(d, np.inf)
            ok[idx[(d < p.min_separation_px).any(axis=1)]] = False

        # a lost marker comes back only on a dot that stays put for n_confirm frames
        seen = ok & self.lost
        still = np.hypot(*(meas - self._confirm_pos).T) <= p.confirm_motion_px
        self._confirm = np.where(seen, np.where(still & (self._confirm > 0), self._confirm + 1, 1), 0)
        self._confirm_pos = np.where(seen[:, None], meas, self._confirm_pos)
        ok &= ~self.lost | (self._confirm >= p.n_confirm)

        if self.kalman is not None:
            z = np.column_stack([meas, size])
            revived = ok & self.lost
            self.kalman.reset(revived, meas, size)
            self.kalman.update(z, ok & ~revived)
            self.kalman.hold(~ok, previous)
            self.positions_px[ok] = self.kalman.positions_px[ok]
            self.sizes_px[ok] = self.kalman.sizes_px[ok]
        else:
            self.positions_px[ok] = meas[ok]
            self.sizes_px[ok] = size[ok]
        self.misses = np.where(ok, 0, self.misses + 1)
        self.lost &= ~ok
        newly_lost = (self.misses >= p.n_reset) & ~self.lost
        if np.any(newly_lost):
            self.lost |= newly_lost
            self.positions_px[newly_lost] = self.baseline.positions_px[newly_lost]
            self.sizes_px[newly_lost] = self.baseline.sizes_px[newly_lost]
            if self.kalman is not None:
                self.kalman.reset(newly_lost, self.positions_px, self.sizes_px)
        valid = self.baseline.valid.astype(bool) & ~self.lost
        return TrackState(
            self.ids.copy(), self.positions_px.copy(), self.sizes_px.copy(), valid, ok.copy(), self.misses.copy()
        )

"""Marker identities across frames: gated windowed re-detection plus an optional per-marker Kalman filter.

Each marker of the baseline keeps its id for ever. Every frame, each marker is re-measured inside a
small window around its last measured position (its rest position while the skin is known to be
still, ``at_rest``) by thresholded moments of the contrast map (cheap, and sub-pixel), then accepted only if it passes the reference's gates: peak contrast, position jump
(``max_jump_px``, VPMax), size jump (``max_size_jump_px``, VSMax), and no other marker measured at
the same place. Two tracked markers measured on one dot (a crossing) can no longer be told apart:
both are lost at once. A marker that fails ``n_reset`` frames in a row is lost too. A lost marker is
reset to its baseline rest position and re-detected there in a larger window; it comes back only on
a dot that lies wholly inside that window (a dot entering or leaving it is clipped, and a clipped
dot's centroid creeps by less than the dot moves), that is nearer to its rest position than to any
live marker (a live marker passing over the rest position stays the live marker's, and is not
dropped for it), and that stays put for ``n_confirm`` frames.

The Kalman filter (the thesis's, not in the reference code) smooths what is reported; the windows
and gates follow the measurements as in the reference, so the filter can neither drop a marker the
plain path keeps nor steer a window off its marker. It is constant-velocity per marker on state
``(x, vx, y, vy, s)`` (the thesis writes ``(x0, x, y0, y, s)`` with the previous position in place of
the velocity: the same model), with noises in the sensor's units: the centre's measurement noise in
px, and the process noise as a random acceleration in px/frame² (the discrete white-noise
acceleration model: each frame the velocity changes by a random ``a`` and the position by ``a/2``).
A measurement whose normalised innovation squared (NIS, against the prediction and its covariance)
falls outside the ``innovation_gate_p`` ellipse means the marker has left the constant-velocity
model (a contact, a release or a slip starts or stops): that marker's filter restarts at the
measurement, with the velocity of the displacement since its last measurement (two-point
initialisation). So the filter smooths rest and steady motion and never lags a measurement by more
than its gate. It is vectorised over markers, its covariance is updated in Joseph form so it stays
symmetric positive definite, and a marker that is missed is held where it was (velocity zeroed, its
covariance growing) so it never drifts on a stale velocity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from tactile_rig.perception.fingervision.markers import MarkerBaseline, refine_centroids

__all__ = ["TrackerParams", "KalmanBank", "TrackState", "MarkerTracker"]


@dataclass(frozen=True)
class TrackerParams:
    """Tracking knobs (pixels, frames, seconds)."""

    window_half_px: int = 6
    """Half size of the measurement window around the last measured position."""
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
    """Two tracked markers measured closer than this are both lost at once (a crossing: their ids can
    no longer be told apart); a lost marker measured this close to another marker is rejected alone."""
    n_reset: int = 3
    """Consecutive misses after which a marker is reset to its rest position (NReset)."""
    n_confirm: int = 2
    """A lost marker is re-acquired after this many consecutive frames of a whole dot near its rest
    position..."""
    confirm_motion_px: float = 1.0
    """...that moved less than this between those frames (a passing dot is not a returning marker)."""
    use_kalman: bool = True
    dt_s: float = 1.0 / 15.0
    """The frame period: the Kalman time step when the frames carry no timestamps, and the frame that
    the per-frame noises below refer to."""
    max_dt_s: float = 1.0
    """A longer gap between timestamps counts as this long (the velocity is stale after a pause)."""
    measurement_noise_px: float = 0.1
    """Standard deviation of a measured centre, px: the scatter of a marker's centre over the ten real
    demo frames is 0.08 px (median over markers; mean 0.11, skin motion included), ten times that of
    rendered frames with sensor noise and flicker."""
    accel_noise_px_per_frame2: float = 0.05
    """Standard deviation of a marker's change of velocity in one frame, px/frame², between changes
    of motion: a shear or a slip building up to 1 px/frame over 20 frames (1.3 s at 15 frames/s).
    Faster changes (a contact's onset, a release, stick-slip) leave the innovation gate and restart
    the marker's filter; smaller values smooth more and lag a gentle change more, up to the gate."""
    size_measurement_noise_px: float = 0.32
    """Standard deviation of a measured diameter, px (the thesis's R = 0.1 px²)."""
    size_noise_px_per_frame: float = 0.1
    """Standard deviation of a diameter's change in one frame, px (the thesis's Q = 0.01 px²)."""
    innovation_gate_p: float = 0.99
    """A measurement whose innovation lies outside the ellipse holding this probability of the
    prediction (chi-square, 2 degrees of freedom) restarts the marker's filter; 1: never."""

    def gate_nis(self) -> float:
        """The normalised innovation squared at the edge of the gate: ``-2 ln(1 - p)`` (chi-square, 2 dof)."""
        return math.inf if self.innovation_gate_p >= 1.0 else -2.0 * math.log1p(-self.innovation_gate_p)


def _sel(which: np.ndarray) -> np.ndarray | slice:
    """A boolean selection, or a plain slice when it selects everything (views, not copies: faster)."""
    return slice(None) if which.all() else which


class KalmanBank:
    """Constant-velocity Kalman filters for N markers at once, state ``(x, vx, y, vy, s)`` (px, px/s).

    Process model: discrete white-noise acceleration (the velocity changes by ``a dt`` and the position
    by ``a dt²/2`` in a step of ``dt`` s, ``a`` white with standard deviation ``accel_noise_px_per_frame2``
    per frame of ``frame_s``); the diameter is a random walk. Both axes share the same noises and are
    always measured together, so the x and y blocks of the covariance are equal and independent of
    the size block: the 5x5 covariance of each marker is stored as one symmetric 2x2 axis block
    ``(p00, p01, p11)`` plus a size variance ``ps``, the same filter in closed form, elementwise over
    markers (no batched matrix algebra per frame).

    Valid input: noises and ``frame_s`` finite and > 0 (``ValueError`` otherwise), time steps >= 0 s;
    the covariance stays symmetric positive definite and finite (10^5-step and extreme-step property
    tests).
    """

    def __init__(
        self, positions_px: np.ndarray, sizes_px: np.ndarray, measurement_noise_px: float = 0.1,
        accel_noise_px_per_frame2: float = 0.05, size_measurement_noise_px: float = 0.32,
        size_noise_px_per_frame: float = 0.1, frame_s: float = 1.0 / 15.0,
    ) -> None:
        noises = {"measurement_noise_px": measurement_noise_px, "accel_noise_px_per_frame2": accel_noise_px_per_frame2,
                  "size_measurement_noise_px": size_measurement_noise_px,
                  "size_noise_px_per_frame": size_noise_px_per_frame, "frame_s": frame_s}
        bad = {k: v for k, v in noises.items() if not (math.isfinite(v) and v > 0)}
        if bad:
            raise ValueError(f"KalmanBank: noises and frame_s must be finite and > 0, got {bad}")
        pos = np.asarray(positions_px, dtype=np.float64).reshape(-1, 2)
        n = pos.shape[0]
        self.r = float(measurement_noise_px) ** 2
        accel_px_s2 = float(accel_noise_px_per_frame2) / frame_s**2
        self.qa = accel_px_s2**2
        """Acceleration variance, px²/s⁴."""
        self.v0 = (accel_px_s2 * frame_s) ** 2
        """Velocity variance of a marker (re)started at rest: one frame of acceleration, (px/s)²."""
        self.rs = float(size_measurement_noise_px) ** 2
        self.qs = float(size_noise_px_per_frame) ** 2 / frame_s
        """Diameter random-walk variance per second, px²/s."""
        self.pos = pos.copy()
        self.vel = np.zeros((n, 2))
        """Velocities, px/s."""
        self.size = np.asarray(sizes_px, dtype=np.float64).reshape(n).copy()
        self.p00 = np.full(n, self.r)
        self.p01 = np.zeros(n)
        self.p11 = np.full(n, self.v0)
        self.ps = np.full(n, self.rs)
        self.anchor = pos.copy()
        """Position after the last fused measurement (where a restart measures the displacement from)."""
        self.age_s = np.zeros(n)
        """Time since the last fused measurement, s."""

    def reset(self, which: np.ndarray, positions_px: np.ndarray, sizes_px: np.ndarray) -> None:
        """Re-initialise the markers selected by the boolean mask ``which`` at rest (zero velocity)."""
        self.pos[which] = positions_px[which]
        self.vel[which] = 0.0
        self.size[which] = sizes_px[which]
        self.p00[which] = self.r
        self.p01[which] = 0.0
        self.p11[which] = self.v0
        self.ps[which] = self.rs
        self.anchor[which] = positions_px[which]
        self.age_s[which] = 0.0

    def predict(self, dt_s: float, which: np.ndarray, move: bool = True) -> None:
        """Advance the selected markers by ``dt_s`` seconds (constant velocity). With ``move=False``
        they stay where they are with zero velocity while their covariance grows as in a prediction:
        a missed marker is held, it never drifts on a stale velocity."""
        if not np.any(which):
            return
        sel = _sel(which)
        dt = float(dt_s)
        q00, q01, q11 = self.qa * dt**4 / 4.0, self.qa * dt**3 / 2.0, self.qa * dt * dt
        if move:
            self.pos[sel] += self.vel[sel] * dt
        # all new values are computed before any is stored: with a slice the inputs are views
        p00, p01, p11 = self.p00[sel], self.p01[sel], self.p11[sel]
        n00 = p00 + 2.0 * dt * p01 + dt * dt * p11 + q00
        n01 = p01 + dt * p11 + q01
        n11 = p11 + q11
        self.p00[sel], self.p01[sel], self.p11[sel] = n00, n01, n11
        self.ps[sel] += self.qs * dt
        self.age_s[sel] += dt
        if not move:
            self.vel[sel] = 0.0

    def update(self, z: np.ndarray, which: np.ndarray, gate_nis: float = math.inf) -> np.ndarray:
        """Fuse measurements ``z`` (N, 3) = (x, y, size) for the selected markers (Joseph form).

        A selected marker whose normalised innovation squared exceeds ``gate_nis`` restarts instead:
        its position is the measurement, its velocity the displacement since its last fused measurement
        over the time since, with the two-point covariance. Returns the mask of restarted markers."""
        z = np.asarray(z, dtype=np.float64)
        r = self.r
        innov = z[:, :2] - self.pos
        s_px2 = self.p00 + r
        restart = which & ((innov[:, 0] ** 2 + innov[:, 1] ** 2) > gate_nis * s_px2)
        fuse = which & ~restart
        if fuse.any():
            sel = _sel(fuse)
            p00, p01, p11 = self.p00[sel], self.p01[sel], self.p11[sel]
            k0 = p00 / s_px2[sel]
            k1 = p01 / s_px2[sel]
            dz = innov[sel]
            self.pos[sel] += k0[:, None] * dz
            self.vel[sel] += k1[:, None] * dz
            a = 1.0 - k0
            # P+ = A P A^T + r K K^T with A = I - K H, H = [1, 0]: stays symmetric positive definite
            n00 = a * a * p00 + r * k0 * k0
            n01 = a * (p01 - k1 * p00) + r * k0 * k1
            n11 = k1 * k1 * p00 - 2.0 * k1 * p01 + p11 + r * k1 * k1
            self.p00[sel], self.p01[sel], self.p11[sel] = n00, n01, n11
        if restart.any():
            self._restart(restart, z[:, :2])
        if which.any():
            sel = _sel(which)
            ps = self.ps[sel]
            ks = ps / (ps + self.rs)
            self.size[sel] += ks * (z[sel, 2] - self.size[sel])
            self.ps[sel] = (1.0 - ks) ** 2 * ps + self.rs * ks * ks
            self.anchor[sel] = self.pos[sel]
            self.age_s[sel] = 0.0
        return restart

    def _restart(self, which: np.ndarray, z: np.ndarray) -> None:
        """Two-point initialisation: x = z, v = (z - anchor) / age, P = [[r, r/age], [r/age, 2r/age²]]
        (the anchor is a filtered position, no noisier than a measurement). With no time elapsed the
        velocity and its variance are kept."""
        r = self.r
        age = self.age_s[which]
        timed = age > 0.0
        safe = np.where(timed, age, 1.0)
        self.vel[which] = np.where(timed[:, None], (z[which] - self.anchor[which]) / safe[:, None], self.vel[which])
        self.pos[which] = z[which]
        self.p00[which] = r
        self.p01[which] = np.where(timed, r / safe, 0.0)
        self.p11[which] = np.where(timed, 2.0 * r / safe**2, self.p11[which])

    def append(self, positions_px: np.ndarray, sizes_px: np.ndarray) -> None:
        """Add markers at rest (zero velocity, initial covariance) after the existing ones."""
        pos = np.asarray(positions_px, dtype=np.float64).reshape(-1, 2)
        n = len(pos)
        self.pos = np.vstack([self.pos, pos])
        self.vel = np.vstack([self.vel, np.zeros((n, 2))])
        self.size = np.concatenate([self.size, np.asarray(sizes_px, dtype=np.float64).reshape(n)])
        self.p00 = np.concatenate([self.p00, np.full(n, self.r)])
        self.p01 = np.concatenate([self.p01, np.zeros(n)])
        self.p11 = np.concatenate([self.p11, np.full(n, self.v0)])
        self.ps = np.concatenate([self.ps, np.full(n, self.rs)])
        self.anchor = np.vstack([self.anchor, pos])
        self.age_s = np.concatenate([self.age_s, np.zeros(n)])

    def covariance(self, i: int) -> np.ndarray:
        """The full 5x5 covariance of marker ``i`` in state order (x, vx, y, vy, s); px and px/s."""
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


def _whole_in_window(contrast: np.ndarray, centres_px: np.ndarray, meas_px: np.ndarray, peak: np.ndarray,
                     radius_px: np.ndarray, half: int, rel_threshold: float) -> np.ndarray:
    """Whether the dot measured at ``meas_px`` lies wholly inside the window of half size ``half``
    around each rounded centre: the connected region above ``rel_threshold`` x peak that holds the
    dot's pixels (within its radius of the measured centre) does not reach the window's edge. The
    image's own edge is not the window's: outside the frame reads as no contrast."""
    h, w = contrast.shape[:2]
    side = 2 * half + 1
    offs = np.arange(side) - half
    out = np.zeros(len(centres_px), bool)
    for k, (c, m, pk, rad) in enumerate(zip(centres_px, meas_px, peak, radius_px)):
        cx, cy = int(np.clip(np.rint(c[0]), 0, w - 1)), int(np.clip(np.rint(c[1]), 0, h - 1))
        win = np.zeros((side, side), np.float32)
        x0, x1, y0, y1 = max(0, cx - half), min(w, cx + half + 1), max(0, cy - half), min(h, cy + half + 1)
        win[y0 - cy + half:y1 - cy + half, x0 - cx + half:x1 - cx + half] = contrast[y0:y1, x0:x1]
        mask = (win >= rel_threshold * pk).astype(np.uint8)
        n_lab, labels = cv2.connectedComponents(mask, connectivity=8)
        near = ((offs[None, :] + cx - m[0]) ** 2 + (offs[:, None] + cy - m[1]) ** 2) <= rad**2
        dot = np.unique(labels[near & (mask > 0)])
        if pk <= 0 or n_lab < 2 or dot.size == 0:
            continue
        edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
        out[k] = not np.isin(dot, edge[edge > 0]).any()
    return out


class MarkerTracker:
    """Track the markers of a :class:`MarkerBaseline` through a sequence of contrast maps."""

    def __init__(self, baseline: MarkerBaseline, params: TrackerParams = TrackerParams()) -> None:
        if params.n_reset < 1:
            raise ValueError(f"TrackerParams.n_reset: expected >= 1, got {params.n_reset}")
        if not (0 < params.dt_s <= params.max_dt_s < float("inf")):
            raise ValueError(f"TrackerParams.dt_s, max_dt_s: expected 0 < dt_s <= max_dt_s < inf s, got "
                             f"{params.dt_s}, {params.max_dt_s}")
        if not (0.0 < params.innovation_gate_p <= 1.0):
            raise ValueError(f"TrackerParams.innovation_gate_p: expected a probability in (0, 1], got "
                             f"{params.innovation_gate_p}")
        self.params = params
        self.baseline = baseline
        n = len(baseline)
        self.ids = np.arange(n)
        self.positions_px = baseline.positions_px.astype(np.float64).copy().reshape(n, 2)
        self.sizes_px = baseline.sizes_px.astype(np.float64).copy().reshape(n)
        self._meas_px = self.positions_px.copy()
        """Last accepted measurement of each marker (its rest position while lost): windows centre here."""
        self._meas_size_px = self.sizes_px.copy()
        self.misses = np.zeros(n, dtype=np.int64)
        self.lost = np.zeros(n, dtype=bool)
        self._confirm = np.zeros(n, dtype=np.int64)
        self._confirm_pos = np.zeros((n, 2))
        self._gate_nis = params.gate_nis()
        self.kalman = (
            KalmanBank(self.positions_px, self.sizes_px, params.measurement_noise_px,
                       params.accel_noise_px_per_frame2, params.size_measurement_noise_px,
                       params.size_noise_px_per_frame, params.dt_s)
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
        self._meas_px = np.vstack([self._meas_px, pos])
        self._meas_size_px = np.concatenate([self._meas_size_px, size])
        self.misses = np.concatenate([self.misses, np.zeros(n, np.int64)])
        self.lost = np.concatenate([self.lost, np.zeros(n, bool)])
        self._confirm = np.concatenate([self._confirm, np.zeros(n, np.int64)])
        self._confirm_pos = np.vstack([self._confirm_pos, np.zeros((n, 2))])
        if self.kalman is not None:
            self.kalman.append(pos, size)
        return self.ids[n0:].copy()

    def update(self, contrast: np.ndarray, t_s: float | None = None, at_rest: bool = False) -> TrackState:
        """Measure every marker in ``contrast`` (see :func:`markers.contrast_map`); returns the new state.

        ``at_rest``: the skin is known to be still (no contact, e.g. the frames that refine the rest
        positions): every tracked marker is measured around its rest position rather than its last
        measured one, so print beside a marker cannot drag its window a little further every frame.

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
        # windows and gates follow the measurements, as in the reference; the filter only smooths
        # what is reported, so it can neither lose a marker nor steer a window off it
        centres = self.baseline.positions_px.astype(np.float64).reshape(n, 2) if at_rest else np.where(
            self.lost[:, None], self.baseline.positions_px, self._meas_px)
        meas = np.zeros((n, 2))
        size = np.zeros(n)
        peak = np.zeros(n)
        max_r = None if p.disc_margin_px is None else self._meas_size_px / 2 + p.disc_margin_px
        for half, sel in ((p.window_half_px, active), (p.lost_window_half_px, self.lost)):
            if np.any(sel):
                meas[sel], size[sel], peak[sel] = refine_centroids(
                    contrast, centres[sel], half, p.rel_threshold, max_radius_px=None if max_r is None else max_r[sel],
                )
        h, w = contrast.shape[:2]
        ok = (peak >= p.min_peak_contrast) & np.isfinite(meas).all(axis=1)
        ok &= (meas[:, 0] >= -0.5) & (meas[:, 0] <= w - 0.5) & (meas[:, 1] >= -0.5) & (meas[:, 1] <= h - 0.5)
        jump_limit = np.where(self.lost, p.lost_window_half_px, p.max_jump_px)
        ok &= np.hypot(*(meas - centres).T) <= jump_limit
        ok &= np.abs(size - self._meas_size_px) <= p.max_size_jump_px + np.where(self.lost, p.max_size_jump_px, 0.0)
        if np.any(ok & self.lost):
            ok &= self._reacquirable(contrast, meas, peak, centres, ok)
        collided = np.zeros(n, bool)
        if n > 1 and np.count_nonzero(ok) > 1:
            idx = np.flatnonzero(ok)
            m = meas[idx]
            lost = self.lost[idx]
            d = np.hypot(m[:, None, 0] - m[None, :, 0], m[:, None, 1] - m[None, :, 1])
            np.fill_diagonal(d, np.inf)
            close = d < p.min_separation_px
            # two tracked markers on one dot can no longer be told apart: both are lost now (held
            # where they met, either could take the other's dot as they part); a lost marker yields
            collided[idx[~lost & (close & ~lost[None, :]).any(axis=1)]] = True
            ok[idx[lost & close.any(axis=1)]] = False
            ok &= ~collided

        # a lost marker comes back only on a dot that stays put for n_confirm frames
        seen = ok & self.lost
        still = np.hypot(*(meas - self._confirm_pos).T) <= p.confirm_motion_px
        self._confirm = np.where(seen, np.where(still & (self._confirm > 0), self._confirm + 1, 1), 0)
        self._confirm_pos = np.where(seen[:, None], meas, self._confirm_pos)
        ok &= ~self.lost | (self._confirm >= p.n_confirm)

        if self.kalman is not None:
            revived = ok & self.lost
            fused = ok & ~revived
            self.kalman.predict(dt_s, fused)
            self.kalman.predict(dt_s, active & ~ok, move=False)
            if revived.any():
                self.kalman.reset(revived, meas, size)
            self.kalman.update(np.column_stack([meas, size]), fused, self._gate_nis)
            self.positions_px[ok] = self.kalman.pos[ok]
            self.sizes_px[ok] = self.kalman.size[ok]
        else:
            self.positions_px[ok] = meas[ok]
            self.sizes_px[ok] = size[ok]
        self._meas_px[ok] = meas[ok]
        self._meas_size_px[ok] = size[ok]
        self.misses = np.where(ok, 0, self.misses + 1)
        self.lost &= ~ok
        newly_lost = ((self.misses >= p.n_reset) | collided) & ~self.lost
        if np.any(newly_lost):
            self.lost |= newly_lost
            self.positions_px[newly_lost] = self.baseline.positions_px[newly_lost]
            self.sizes_px[newly_lost] = self.baseline.sizes_px[newly_lost]
            self._meas_px[newly_lost] = self.positions_px[newly_lost]
            self._meas_size_px[newly_lost] = self.sizes_px[newly_lost]
            if self.kalman is not None:
                self.kalman.reset(newly_lost, self.positions_px, self.sizes_px)
        valid = self.baseline.valid.astype(bool) & ~self.lost
        return TrackState(
            self.ids.copy(), self.positions_px.copy(), self.sizes_px.copy(), valid, ok.copy(), self.misses.copy()
        )

    def _reacquirable(self, contrast: np.ndarray, meas: np.ndarray, peak: np.ndarray, centres: np.ndarray,
                      ok: np.ndarray) -> np.ndarray:
        """False for a lost marker whose candidate dot is clipped by its re-detection window (a dot
        entering or leaving it, whose centroid moves by less than the dot) or lies nearer to a live
        marker's window centre than to the lost marker's rest position (that marker's dot)."""
        p = self.params
        keep = np.ones(len(ok), bool)
        cand = np.flatnonzero(ok & self.lost)
        rest = self.baseline.positions_px[cand]
        radius = self.baseline.sizes_px[cand] / 2 + (1.0 if p.disc_margin_px is None else p.disc_margin_px)
        keep[cand] = _whole_in_window(contrast, rest, meas[cand], peak[cand], radius, p.lost_window_half_px,
                                      p.rel_threshold)
        live = centres[~self.lost]
        if len(live):
            m = meas[cand]
            d_live = np.hypot(m[:, None, 0] - live[None, :, 0], m[:, None, 1] - live[None, :, 1]).min(axis=1)
            keep[cand] &= np.hypot(*(m - rest).T) < d_live
        return keep

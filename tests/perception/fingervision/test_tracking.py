"""FingerVision tracking: identities, gates, reset, re-acquisition, Kalman filter."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from tactile_rig.perception.fingervision import (
    KalmanBank,
    MarkerBaseline,
    MarkerTracker,
    TrackerParams,
    contrast_map,
)
from tests._fingervision_synth import lattice, render


def _baseline(points: np.ndarray, size: float = 8.0) -> MarkerBaseline:
    return MarkerBaseline(points.copy(), np.full(len(points), size), np.ones(len(points), bool))


def _contrast(points: np.ndarray | None, seed: int = 0, gain: float = 1.0) -> np.ndarray:
    return contrast_map(render(points, seed=seed, gain=gain))[2]


PLAIN_TOL_PX = 0.3  # the windowed centroid on rendered frames (sensor noise, flicker)


def _gate_radius_px(p: TrackerParams) -> float:
    """Radius of the innovation gate of a still marker's filter in steady state, px: a reported
    position never lags its measurement by more (beyond it the filter restarts at the measurement)."""
    kb = KalmanBank(np.zeros((1, 2)), np.full(1, 8.0), p.measurement_noise_px, p.accel_noise_px_per_frame2,
                    p.size_measurement_noise_px, p.size_noise_px_per_frame, p.dt_s)
    one = np.ones(1, bool)
    for _ in range(200):
        kb.predict(p.dt_s, one)
        s_px2 = kb.p00[0] + kb.r
        kb.update(np.array([[0.0, 0.0, 8.0]]), one)
    return float(np.sqrt(p.gate_nis() * s_px2))


@pytest.mark.parametrize("use_kalman", [False, True])
def test_identities_follow_moving_markers(use_kalman: bool) -> None:
    rest = lattice()
    tracker = MarkerTracker(_baseline(rest), TrackerParams(use_kalman=use_kalman))
    v = np.array([0.7, -0.4])
    for k in range(1, 16):
        truth = rest + v * k
        state = tracker.update(_contrast(truth, seed=k))
        assert state.found.all() and state.valid.all()
        err = np.hypot(*(state.positions_px - truth).T)
        # each id stays on its own marker (markers are 45+ px apart); the filter lags its measurement
        # by at most its innovation gate
        assert err.max() <= PLAIN_TOL_PX + (_gate_radius_px(tracker.params) if use_kalman else 0.0)
    assert np.array_equal(state.ids, np.arange(len(rest)))


def test_a_missing_marker_is_held_then_reset_then_reacquired() -> None:
    rest = lattice()
    p = TrackerParams(n_reset=3, use_kalman=True)
    tracker = MarkerTracker(_baseline(rest), p)
    shifted = rest + [1.0, 0.5]
    for k in range(4):
        tracker.update(_contrast(shifted, seed=k))
    held = tracker.positions_px[5].copy()
    gone = np.delete(shifted, 5, axis=0)
    for k in range(p.n_reset - 1):
        st_ = tracker.update(_contrast(gone, seed=10 + k))
        assert not st_.found[5] and st_.valid[5]
        assert np.array_equal(st_.positions_px[5], held), "a missed marker must not drift"
    st_ = tracker.update(_contrast(gone, seed=20))
    assert not st_.valid[5]
    assert np.allclose(st_.positions_px[5], rest[5])
    assert st_.valid[np.arange(len(rest)) != 5].all()
    st_ = tracker.update(_contrast(shifted, seed=21))
    assert not st_.valid[5], "re-acquisition needs a confirming second frame"
    st_ = tracker.update(_contrast(shifted, seed=22))
    assert st_.found[5] and st_.valid[5]
    assert np.hypot(*(st_.positions_px[5] - shifted[5])) <= 0.3


def test_all_markers_lost_on_a_black_frame() -> None:
    rest = lattice()
    p = TrackerParams(n_reset=2)
    tracker = MarkerTracker(_baseline(rest), p)
    black = contrast_map(np.zeros((240, 320, 3), np.uint8))[2]
    for _ in range(p.n_reset):
        st_ = tracker.update(black)
    assert not st_.found.any() and not st_.valid.any()
    assert np.all(np.isfinite(st_.positions_px))


def test_a_jump_beyond_the_gate_is_rejected() -> None:
    rest = lattice()
    tracker = MarkerTracker(_baseline(rest), TrackerParams(max_jump_px=2.0, window_half_px=6, use_kalman=False))
    st_ = tracker.update(_contrast(rest + [3.5, 0.0]))
    assert not st_.found.any()
    assert np.allclose(st_.positions_px, rest)


def test_no_markers_at_all() -> None:
    empty = MarkerBaseline(np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool))
    st_ = MarkerTracker(empty).update(_contrast(None))
    assert st_.positions_px.shape == (0, 2) and st_.valid.shape == (0,)


MARKER_R_PX = 4.0  # the synthetic maker's default disc radius


def _pair_run(gap_y_px: float, speed_px: float, frames: int, params: TrackerParams):
    """Markers a (left) and b (right, ``gap_y_px`` lower) moving towards each other along x at
    ``speed_px`` a frame; yields (frame, truth (2, 2) px, state) for every frame."""
    a0, b0 = np.array([130.3, 120.2]), np.array([190.6, 120.2 + gap_y_px])
    tracker = MarkerTracker(_baseline(np.array([a0, b0])), params)
    for k in range(1, frames + 1):
        truth = np.array([a0 + [speed_px * k, 0.0], b0 - [speed_px * k, 0.0]])
        yield k, truth, tracker.update(_contrast(truth, seed=k))


@pytest.mark.parametrize("use_kalman", [False, True])
def test_markers_passing_inside_each_others_window_keep_their_identities(use_kalman: bool) -> None:
    """Two markers on rows 9 px apart pass each other at 1.5 px a frame. At the closest approach each
    one's disc reaches into the other's measurement window, yet both are measured in every frame, each
    id stays on its own marker, and the ids end in the markers' swapped left-right order."""
    p = TrackerParams(use_kalman=use_kalman)
    # an id within half the closest approach of its own marker is nearer to it than to the other; the
    # filter adds at most its innovation gate
    tol_px = 1.0 + (_gate_radius_px(p) if use_kalman else 0.0)
    closest_px = np.inf
    for k, truth, st_ in _pair_run(9.0, 1.5, 80, p):
        closest_px = min(closest_px, float(np.hypot(*(truth[0] - truth[1]))))
        assert st_.found.all() and st_.valid.all(), f"frame {k}: a visible marker was dropped: {st_.found}"
        err = np.hypot(*(st_.positions_px - truth).T)
        assert err.max() <= tol_px, f"frame {k}: ids off their markers by {err} px"
    assert closest_px - MARKER_R_PX < p.window_half_px, "the markers must come within each other's window"
    assert 2 * tol_px < closest_px
    assert truth[0, 0] > truth[1, 0] and st_.positions_px[0, 0] > st_.positions_px[1, 0]


@pytest.mark.parametrize("speed_px", [1.5, 2.0, 3.0])
@pytest.mark.parametrize("use_kalman", [False, True])
def test_markers_that_run_through_each_other_are_dropped_not_swapped(use_kalman: bool, speed_px: float) -> None:
    """Two markers on one row run through each other and on across the other's rest position. While
    they approach, more than two windows apart, both are measured; where they overlap they cannot be
    told apart and are dropped; but no id is ever found on the other marker, at the overlap (3 px a
    frame: they part before ``n_reset`` misses) or later, when each passes the other's rest position
    (1.5 px a frame: the re-detection window clips the entering dot, whose centroid creeps by less
    than ``confirm_motion_px`` a frame)."""
    p = TrackerParams(use_kalman=use_kalman)
    apart_px = 2 * (p.window_half_px + MARKER_R_PX)
    for k, truth, st_ in _pair_run(0.0, speed_px, int(120 / speed_px), p):
        approaching = truth[0, 0] < truth[1, 0]
        if approaching and np.hypot(*(truth[0] - truth[1])) >= apart_px:
            assert st_.found.all(), f"frame {k}: a marker {apart_px} px from the other was dropped"
        err = np.hypot(*(st_.positions_px - truth).T)
        for i in np.flatnonzero(st_.found):
            assert err[i] <= 3.5, f"frame {k}: id {i} found {err[i]:.1f} px off its marker (on the other?)"
        assert np.all(np.isfinite(st_.positions_px))


def test_a_lost_marker_is_not_reacquired_on_a_dot_its_window_clips() -> None:
    """A still dot straddling the edge of a lost marker's re-detection window is never taken for it
    (only part of it is seen); once the dot is wholly inside, it is re-acquired after n_confirm frames."""
    rest = lattice()
    p = TrackerParams(use_kalman=False)
    tracker = MarkerTracker(_baseline(rest), p)
    gone = np.delete(rest, 7, axis=0)
    for k in range(p.n_reset):
        st_ = tracker.update(_contrast(gone, seed=k))
    assert not st_.valid[7]
    straddling = rest.copy()
    straddling[7] += [p.lost_window_half_px + 1.0, 0.0]  # its disc (radius 4 px) crosses the window's edge
    for k in range(8):
        st_ = tracker.update(_contrast(straddling, seed=10 + k))
        assert not st_.found[7] and not st_.valid[7], f"frame {k}: re-acquired on a clipped dot"
        assert st_.found[np.arange(len(rest)) != 7].all()
    inside = rest + [1.0, -0.5]
    for k in range(p.n_confirm):
        st_ = tracker.update(_contrast(inside, seed=20 + k))
    assert st_.found[7] and st_.valid[7]
    assert np.hypot(*(st_.positions_px[7] - inside[7])) <= PLAIN_TOL_PX


@pytest.mark.parametrize("use_kalman", [False, True])
def test_a_live_marker_crossing_a_lost_markers_rest_position_stays_live(use_kalman: bool) -> None:
    """A tracked marker creeping (slower than ``confirm_motion_px`` a frame, so it looks still) across
    the rest position of a lost one keeps its id and is measured in every frame; the lost id is not
    re-acquired on it."""
    p = TrackerParams(use_kalman=use_kalman)
    a0, b0 = np.array([130.3, 120.2]), np.array([160.6, 121.0])
    tracker = MarkerTracker(_baseline(np.array([a0, b0])), p)
    for k in range(p.n_reset):
        st_ = tracker.update(_contrast(b0[None], seed=k))
    assert not st_.valid[0] and st_.valid[1]
    speed_px = 0.6
    for k in range(1, int(60 / speed_px)):
        b = b0 - [speed_px * k, 0.0]
        st_ = tracker.update(_contrast(b[None], seed=10 + k))
        assert not st_.found[0] and not st_.valid[0], f"frame {k}: the lost id was re-acquired on the other marker"
        assert st_.found[1], f"frame {k}: the live marker was dropped at {b}"
        assert np.hypot(*(st_.positions_px[1] - b)) <= PLAIN_TOL_PX + (_gate_radius_px(p) if use_kalman else 0.0)


def test_at_rest_a_marker_beside_larger_print_is_measured_around_its_rest_position() -> None:
    """While the skin is known to be still (``at_rest``, the refinement frames), a dark dot larger than
    a marker 9 px beside it biases its measurement by one frame's pull at most: the window stays on
    the rest position instead of following the pull further every frame."""
    rest = np.array([[160.3, 120.2]])
    print_dot = rest[0] + [9.0, 0.7]
    frame_pts = np.vstack([rest, print_dot])
    tracker = MarkerTracker(_baseline(rest), TrackerParams(use_kalman=False))
    for k in range(30):
        contrast = contrast_map(render(frame_pts, marker_r_px=np.array([4.0, 5.0]), seed=k))[2]
        st_ = tracker.update(contrast, at_rest=True)
        assert st_.found[0] and np.hypot(*(st_.positions_px[0] - rest[0])) <= 1.0, f"frame {k}: {st_.positions_px[0]}"


def _steady_run(speed_px: float, angle_deg: float, seed: int, params: TrackerParams, frames: int = 16):
    """A 3 x 3 patch of markers (50 x 40 px pitch) starting from rest at ``speed_px`` a frame in one
    direction; yields (frame, truth, state) for every frame."""
    rest = lattice(nx=3, ny=3, x0=110.0, y0=80.0, dx=50.0, dy=40.0, jitter_seed=seed)
    u = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    tracker = MarkerTracker(_baseline(rest), params)
    for k in range(1, frames + 1):
        truth = rest + u * speed_px * k
        yield k, truth, tracker.update(_contrast(truth, seed=100 * seed + k))


# the plain path's reach with the default gates (max_jump_px 5, 13 px window, 8 px dots): checked on
# every example below, so the Kalman path is held to exactly what the plain path follows
FOLLOWED_PX_PER_FRAME = 4.5


@settings(deadline=None, max_examples=20)
@given(speed_px=st.floats(0.05, FOLLOWED_PX_PER_FRAME), angle_deg=st.floats(0.0, 360.0), seed=st.integers(0, 99))
@example(speed_px=2.0, angle_deg=0.0, seed=0)
@example(speed_px=FOLLOWED_PX_PER_FRAME, angle_deg=45.0, seed=1)
def test_the_kalman_path_keeps_every_steady_speed_the_plain_path_keeps(speed_px: float, angle_deg: float,
                                                                       seed: int) -> None:
    """Markers that start from rest at a steady speed, up to what the plain path follows, are measured
    in every frame by both paths; the filtered positions stay within the innovation gate of the
    plain path's error (a change of motion restarts the filter instead of making it lag)."""
    for use_kalman in (False, True):
        p = TrackerParams(use_kalman=use_kalman)
        tol_px = PLAIN_TOL_PX + (_gate_radius_px(p) if use_kalman else 0.0)
        for k, truth, st_ in _steady_run(speed_px, angle_deg, seed, p):
            assert st_.found.all() and st_.valid.all(), f"kalman={use_kalman}, frame {k}: dropped {~st_.found}"
            err = np.hypot(*(st_.positions_px - truth).T)
            assert err.max() <= tol_px, f"kalman={use_kalman}, frame {k}: {err.max():.2f} px off"


def test_kalman_reduces_jitter_under_flicker() -> None:
    rest = lattice()
    series = {}
    for use_kalman in (False, True):
        tracker = MarkerTracker(_baseline(rest), TrackerParams(use_kalman=use_kalman))
        means = []
        for k in range(30):
            gain = 1.0 + 0.25 * (k % 2) - 0.1 * (k % 3)
            st_ = tracker.update(_contrast(rest, seed=k % 7, gain=gain))
            means.append((st_.positions_px - rest).mean(axis=0))
        series[use_kalman] = np.array(means[5:])
    jitter = {k: float(np.linalg.norm(v.std(axis=0))) for k, v in series.items()}
    assert jitter[True] < jitter[False]


def test_bad_tracker_parameters() -> None:
    base = _baseline(lattice())
    with pytest.raises(ValueError, match="n_reset"):
        MarkerTracker(base, dataclasses.replace(TrackerParams(), n_reset=0))
    with pytest.raises(ValueError, match="dt_s"):
        MarkerTracker(base, dataclasses.replace(TrackerParams(), dt_s=0.0))
    with pytest.raises(ValueError, match="innovation_gate_p"):
        MarkerTracker(base, dataclasses.replace(TrackerParams(), innovation_gate_p=0.0))
    with pytest.raises(ValueError, match="measurement_noise_px"):
        KalmanBank(np.zeros((1, 2)), np.zeros(1), measurement_noise_px=0.0)
    with pytest.raises(ValueError, match="accel_noise_px_per_frame2"):
        KalmanBank(np.zeros((1, 2)), np.zeros(1), accel_noise_px_per_frame2=float("nan"))
    with pytest.raises(ValueError, match="frame_s"):
        KalmanBank(np.zeros((1, 2)), np.zeros(1), frame_s=-1.0)


@settings(deadline=None, max_examples=30)
@given(
    steps=st.lists(
        st.tuples(
            st.floats(1e-4, 2.0),
            st.lists(st.booleans(), min_size=4, max_size=4),
            st.floats(-1e4, 1e4),
        ),
        min_size=1,
        max_size=40,
    ),
    sigma_z=st.floats(1e-2, 3.0),
    accel=st.floats(1e-3, 10.0),
    gate_nis=st.sampled_from([1.0, 9.21, np.inf]),
)
def test_kalman_covariance_stays_symmetric_positive_definite(steps, sigma_z: float, accel: float,
                                                             gate_nis: float) -> None:
    kb = KalmanBank(np.zeros((4, 2)), np.full(4, 8.0), measurement_noise_px=sigma_z, accel_noise_px_per_frame2=accel)
    for dt, upd, z in steps:
        which = np.ones(4, bool)
        kb.predict(dt, which)
        kb.update(np.full((4, 3), z), np.array(upd), gate_nis)
        for i in range(4):
            P = kb.covariance(i)
            assert np.allclose(P, P.T)
            assert np.linalg.eigvalsh(P).min() > 0
    assert np.all(np.isfinite(kb.pos)) and np.all(np.isfinite(kb.vel))


@settings(deadline=None, max_examples=50)
@given(
    moves=st.lists(st.tuples(st.floats(-20.0, 20.0), st.floats(-20.0, 20.0), st.booleans()), min_size=1, max_size=30),
    dt_s=st.sampled_from([1 / 60, 1 / 15, 0.2]),
)
def test_a_filtered_position_never_leaves_the_innovation_gate(moves, dt_s: float) -> None:
    """Whatever the motion (jumps, stops, reversals, missed frames), a fused position lies within the
    gate of its measurement, and a restart puts the filter on the measurement with the velocity of the
    displacement since the last fused one."""
    p = TrackerParams()
    gate = p.gate_nis()
    kb = KalmanBank(np.zeros((1, 2)), np.full(1, 8.0), frame_s=p.dt_s)
    one = np.ones(1, bool)
    z = np.zeros((1, 3)) + [0.0, 0.0, 8.0]
    for dx, dy, measured in moves:
        z = z + [dx, dy, 0.0]
        anchor, age = kb.anchor.copy(), kb.age_s.copy() + dt_s
        kb.predict(dt_s, one)
        if not measured:
            continue
        s_px2 = kb.p00[0] + kb.r
        restarted = kb.update(z, one, gate)
        assert np.hypot(*(kb.pos[0] - z[0, :2])) <= np.sqrt(gate * s_px2) + 1e-9
        if restarted[0]:
            assert np.allclose(kb.pos[0], z[0, :2])
            assert np.allclose(kb.vel[0], (z[0, :2] - anchor[0]) / age[0])


def test_kalman_follows_constant_velocity_without_lag_eventually() -> None:
    kb = KalmanBank(np.zeros((1, 2)), np.full(1, 8.0))
    dt = 1 / 15
    for k in range(1, 200):
        kb.predict(dt, np.ones(1, bool))
        kb.update(np.array([[3.0 * k * dt, -1.5 * k * dt, 8.0]]), np.ones(1, bool))
    assert np.allclose(kb.vel[0], [3.0, -1.5], atol=0.05)
    assert np.allclose(kb.pos[0], [3.0 * 199 * dt, -1.5 * 199 * dt], atol=0.05)


def test_kalman_all_markers_equals_subset_path() -> None:
    """Selecting every marker (fast slice path) gives the same filter as a boolean subset."""
    rng = np.random.default_rng(3)
    a = KalmanBank(np.zeros((3, 2)), np.full(3, 8.0))
    b = KalmanBank(np.zeros((4, 2)), np.full(4, 8.0))
    sub = np.array([True, True, True, False])
    for _ in range(10):
        z = rng.normal(0, 2, (4, 3))
        a.predict(0.07, np.ones(3, bool))
        b.predict(0.07, sub)
        a.update(z[:3], np.ones(3, bool))
        b.update(z, sub)
    assert np.allclose(a.pos, b.pos[:3]) and np.allclose(a.vel, b.vel[:3])
    for i in range(3):
        assert np.allclose(a.covariance(i), b.covariance(i))

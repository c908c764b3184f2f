"""FingerVision at the extremes: every entry point returns a bounded result or raises a typed error.

Flat, black, white, saturated, NaN/inf, one-pixel and huge frames; wrong dtypes and shapes; empty
object masks; calibration on frames without markers; 10^5-step Kalman runs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tactile_rig.cli import main
from tactile_rig.core.errors import CalibrationError, InvalidFrame, MarkersNotFound
from tactile_rig.perception.fingervision import (
    FingerVision,
    FingerVisionParams,
    KalmanBank,
    MarkerBaseline,
    MarkerTracker,
    ProximityVision,
    contrast_map,
    detect_markers,
    detect_markers_reference,
    object_moments,
)
from tests._fingervision_synth import lattice, render

REST = lattice()
W, H = 320, 240
FLATS = {"black": 0, "grey": 128, "white": 255}


def _bounded(r, w: int = W, h: int = H) -> None:
    """A result inside physical bounds: finite, markers inside the frame, force within the frame's size."""
    assert np.isfinite(r.marker_positions_px).all() and np.isfinite(r.marker_sizes_px).all()
    if len(r.marker_positions_px):
        assert (r.marker_positions_px >= -0.5).all() and (r.marker_positions_px[:, 0] <= w - 0.5).all()
        assert (r.marker_positions_px[:, 1] <= h - 0.5).all()
    diag = math.hypot(w, h)
    assert np.isfinite(r.force_px).all() and np.abs(r.force_px).max() <= diag
    assert np.isfinite(r.torque_px2).all() and np.abs(r.torque_px2).max() <= diag * diag
    assert math.isfinite(r.slip_magnitude_px) and 0 <= r.slip_magnitude_px <= diag
    assert 0 <= r.object_area_px <= w * h


def _tracking() -> FingerVision:
    fv = FingerVision(FingerVisionParams(n_calib_frames=2))
    for k in range(2):
        fv.process(render(REST, seed=k))
    assert fv.tracker is not None and fv._refine_left == 0
    return fv


@pytest.mark.parametrize("init", ["lattice", "frames"])
@pytest.mark.parametrize("level", sorted(FLATS.values()))
def test_calibrating_on_flat_frames_is_a_typed_error(init: str, level: int) -> None:
    fv = FingerVision(FingerVisionParams(init=init, n_calib_frames=3))
    with pytest.raises(MarkersNotFound, match="no markers") as exc:
        fv.calibrate([np.full((H, W, 3), level, np.uint8)] * 3)
    assert isinstance(exc.value, CalibrationError) and isinstance(exc.value, ValueError)


@pytest.mark.parametrize("level", sorted(FLATS.values()))
def test_cli_on_flat_frames_exits_2_with_one_line(tmp_path, capsys, level: int) -> None:
    import cv2

    for i in range(4):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), np.full((H, W, 3), level, np.uint8))
    assert main(["fingervision", "track", str(tmp_path), "--calib-frames", "3", "--no-calibration"]) == 2
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if "error" in ln]
    assert len(err) == 1 and "no marker lattice" in err[0]
    # fewer frames than n_calib_frames
    assert main(["fingervision", "track", str(tmp_path), "--no-calibration", "--json"]) == 2


def test_cli_bad_options_exit_2(tmp_path, capsys) -> None:
    import cv2

    cv2.imwrite(str(tmp_path / "a.png"), render(REST))
    for bad in (["--fps", "0"], ["--fps", "inf"], ["--limit", "0"], ["--calib-frames", "0"],
                ["--object-rect", "0", "0", "0", "5"]):
        try:  # bounds checked by argparse exit 2 as argparse does; the rest return 2 from the handler
            code = main(["fingervision", "track", str(tmp_path), "--no-calibration", *bad])
        except SystemExit as exc:
            code = exc.code
        assert code == 2, bad
    capsys.readouterr()
    cv2.imwrite(str(tmp_path / "b.png"), render(REST, size_wh=(160, 120)))
    assert main(["fingervision", "track", str(tmp_path), "--no-calibration"]) == 2  # frames of two sizes
    assert "differs from the first frame" in capsys.readouterr().err


@pytest.mark.parametrize("frame", [
    np.zeros((1, 1, 3), np.uint8), np.zeros((8, 300, 3), np.uint8), np.zeros((0, 5, 3), np.uint8),
    np.zeros((20, 20, 4), np.uint8), np.zeros((20, 20, 3), bool), np.zeros((20, 20, 3), complex),
    "not a frame",
], ids=["one-pixel", "thin", "empty", "4-channel", "bool", "complex", "str"])
def test_frames_outside_the_valid_input_are_typed_errors(frame) -> None:
    with pytest.raises(InvalidFrame):
        FingerVision().process(frame)


@pytest.mark.parametrize("name", ["black", "grey", "white", "nan", "inf", "-inf", "noise"])
def test_extreme_frames_while_tracking_give_bounded_results(name: str) -> None:
    fv = _tracking()
    if name in FLATS:
        frame = np.full((H, W, 3), FLATS[name], np.uint8)
    elif name == "noise":
        frame = np.random.default_rng(0).integers(0, 256, (H, W, 3)).astype(np.uint8)
    else:
        frame = np.full((H, W, 3), float(name), np.float64)
    for _ in range(fv.params.tracker.n_reset + 1):
        r = fv.process(frame)
        _bounded(r)
    assert r.n_markers == 0 and not r.marker_valid.any() and not r.contact
    # and it recovers: the markers come back on real frames with their ids
    for k in range(3):
        r = fv.process(render(REST, seed=30 + k))
    assert r.marker_valid.all() and np.array_equal(r.marker_ids, np.arange(len(REST)))


def test_a_huge_frame_is_processed() -> None:
    big = np.kron(render(REST), np.ones((4, 4, 1), np.uint8))  # 1280 x 960, markers 4x larger
    fv = FingerVision(FingerVisionParams(n_calib_frames=1))
    r = fv.process(big)
    _bounded(r, 1280, 960)
    r = fv.process(np.full_like(big, 255))
    _bounded(r, 1280, 960)


@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 48), st.integers(1, 48), st.sampled_from([1, 3])),
                  elements=st.floats(allow_nan=True, allow_infinity=True, width=32)),
       st.sampled_from(["uint8", "int16", "float32", "float64"]))
def test_detectors_take_any_frame(frame: np.ndarray, dtype: str) -> None:
    if dtype in ("uint8", "int16"):
        info = np.iinfo(dtype)
        frame = np.clip(np.nan_to_num(frame), info.min, info.max).astype(dtype)
    else:
        frame = frame.astype(dtype)
    value, bg, contrast = contrast_map(frame)
    assert np.isfinite(contrast).all() and (contrast >= 0).all() and (contrast <= 1).all()
    for det in (detect_markers(frame), detect_markers_reference(frame)):
        assert np.isfinite(det.positions_px).all() and len(det.positions_px) == len(det.sizes_px)


@given(hnp.arrays(np.float64, (6, 8, 3), elements=st.one_of(
    st.sampled_from([np.nan, np.inf, -np.inf, -1e9, 0.0, 255.0, 1e9]), st.floats(0, 255))))
def test_processor_takes_any_frame_after_calibration(small: np.ndarray) -> None:
    fv = _tracking()
    frame = np.kron(small, np.ones((40, 40, 1)))  # 240 x 320 blocks of extreme values
    _bounded(fv.process(frame))


def test_empty_object_masks_are_refused_and_empty_moments_are_no_object() -> None:
    pv = ProximityVision()
    frame = render(REST)
    with pytest.raises(ValueError, match="select no pixel"):
        pv.learn_object(frame, mask=np.zeros((H, W), np.uint8))
    with pytest.raises(ValueError, match="select no pixel"):
        pv.learn_object(frame, rects=[(400, 400, 10, 10)])
    m = object_moments(np.zeros((10, 10), np.uint8))
    assert m.area_px == 0 and m.centroid_px is None and m.orientation_deg is None
    r = pv.process(frame)  # nothing learnt: no object, no slip
    assert r.moments.area_px == 0 and not r.slip
    with pytest.raises(InvalidFrame):
        pv.process(np.zeros((3, 3, 3), np.uint8))


def test_kalman_1e5_steps_stays_finite_and_converges() -> None:
    rng = np.random.default_rng(0)
    n = 30
    truth = rng.uniform(0, 300, (n, 2))
    kb = KalmanBank(truth, np.full(n, 8.0), 0.1, 0.01)
    all_ = np.ones(n, bool)
    half = np.arange(n) % 2 == 0
    dts = rng.choice([1e-3, 1 / 15, 1.0], 100_000)
    for k in range(100_000):
        if k % 1000 == 0:  # noise drawn in blocks: the loop is the filter, not the generator
            noise = rng.normal(0, 0.3, (1000, n, 3))
        kb.predict(float(dts[k]), all_)
        z = np.column_stack([truth, np.full(n, 8.0)]) + noise[k % 1000]
        kb.update(z, all_ if k % 7 else half)  # some frames measure half the markers only
    assert np.isfinite(kb.pos).all() and np.isfinite(kb.vel).all()
    assert np.abs(kb.positions_px - truth).max() < 2.0
    for i in range(n):
        P = kb.covariance(i)
        assert np.allclose(P, P.T) and np.linalg.eigvalsh(P).min() > 0 and np.linalg.eigvalsh(P).max() < 10


@given(st.lists(st.tuples(st.floats(1e-6, 1e3), st.floats(-1e6, 1e6), st.booleans()), min_size=1, max_size=60))
def test_kalman_any_time_steps_and_measurements_stay_finite(steps) -> None:
    kb = KalmanBank(np.zeros((3, 2)), np.full(3, 8.0))
    sel = np.ones(3, bool)
    for dt, zval, measured in steps:
        kb.predict(dt, sel)
        if measured:
            kb.update(np.full((3, 3), zval), sel)
    assert np.isfinite(kb.pos).all() and np.isfinite(kb.p00).all() and (kb.p00 > 0).all()


def test_tracker_timestamps_are_checked_and_gaps_bounded() -> None:
    base = MarkerBaseline(REST.copy(), np.full(len(REST), 8.0), np.ones(len(REST), bool))
    tr = MarkerTracker(base)
    c = contrast_map(render(REST))[2]
    tr.update(c, 0.0)
    st_ = tr.update(c, 1e9)  # an enormous gap counts as max_dt_s
    assert st_.found.all() and np.isfinite(st_.positions_px).all()
    with pytest.raises(ValueError, match="t_s"):
        tr.update(c, float("nan"))
    st_ = tr.update(np.full_like(c, np.nan))
    assert not st_.found.any() and np.isfinite(st_.positions_px).all()


def test_calibration_session_on_black_frames_is_a_typed_error(tmp_path) -> None:
    """The rig's calibration session (``tactile-rig calibrate fingervision``) on a camera seeing black."""
    from tactile_rig.rig.calibration_sessions import fingervision_session

    class Black:
        def read(self, timeout_s: float = 1.0) -> np.ndarray:
            return np.zeros((H, W, 3), np.uint8)

    with pytest.raises(MarkersNotFound):
        fingervision_session(Black(), tmp_path / "fv", frames=3)
    written = {p.suffix for p in tmp_path.iterdir()}
    assert not written & {".json", ".npz"}, "no calibration is written (the session's recording may stay)"

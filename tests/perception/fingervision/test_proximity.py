"""FingerVision proximity vision: histograms, back-projection, moments, orientation, slip."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_rig.perception.fingervision import ProximityParams, ProximityVision, estimate_shift, object_moments
from tests._fingervision_synth import Ellipse, angle_err, ellipse_mask, lattice, render

MARKERS = lattice()


@pytest.fixture(scope="module")
def trained() -> ProximityVision:
    pv = ProximityVision()
    pv.set_background([render(MARKERS, seed=s) for s in range(3)])
    obj = Ellipse(170, 120, 60, 30, 25)
    pv.learn_object(render(MARKERS, obj=obj, seed=9), mask=ellipse_mask(obj))
    return pv


def test_empty_mask_is_no_object_not_nan() -> None:
    m = object_moments(np.zeros((60, 80), np.uint8))
    assert m.area_px == 0.0 and m.centroid_px is None and m.orientation_deg is None


def test_round_object_has_undefined_orientation() -> None:
    m = object_moments(ellipse_mask(Ellipse(150.5, 100.25, 30, 30, 0)))
    assert m.orientation_deg is None
    assert m.centroid_px == pytest.approx((150.5, 100.25), abs=0.1)
    assert m.area_px == pytest.approx(math.pi * 900, rel=0.02)


@pytest.mark.parametrize("angle", [89.5, 90.0, 90.5, -89.5, 0.0, 179.0])
def test_orientation_wraps_at_plus_minus_90(angle: float) -> None:
    m = object_moments(ellipse_mask(Ellipse(160, 120, 70, 20, angle)))
    assert m.orientation_deg is not None and -90.0 < m.orientation_deg <= 90.0
    assert angle_err(m.orientation_deg, angle) < 0.5


@settings(deadline=None, max_examples=25)
@given(angle=st.floats(80.0, 100.0), sign=st.sampled_from([1.0, -1.0]))
def test_orientation_wrap_by_hypothesis(angle: float, sign: float) -> None:
    m = object_moments(ellipse_mask(Ellipse(160, 120, 70, 20, sign * angle)))
    assert m.orientation_deg is not None and -90.0 < m.orientation_deg <= 90.0
    assert angle_err(m.orientation_deg, sign * angle) < 0.5


@settings(deadline=None, max_examples=40)
@given(seed=st.integers(0, 2**31 - 1), density=st.sampled_from([0.0, 0.001, 0.05, 0.5, 1.0]),
       scale=st.sampled_from([1.0, 2.0, 4.0]))
def test_moments_of_arbitrary_masks_are_finite(seed: int, density: float, scale: float) -> None:
    mask = (np.random.default_rng(seed).random((30, 40)) < density).astype(np.uint8) * 255
    m = object_moments(mask, scale)
    if not mask.any():
        assert m.area_px == 0 and m.centroid_px is None and m.orientation_deg is None
    else:
        assert m.area_px == pytest.approx(np.count_nonzero(mask) * scale * scale)
        assert all(math.isfinite(v) for v in m.centroid_px)
        assert m.orientation_deg is None or -90.0 < m.orientation_deg <= 90.0


def test_histogram_update_rule(trained: ProximityVision) -> None:
    p = trained.params
    before = trained.obj_hist.copy()
    obj = Ellipse(170, 120, 60, 30, 25)
    frame = render(MARKERS, obj=obj, seed=10)
    mask = ellipse_mask(obj)
    pv = ProximityVision(p)
    pv.bg_hist = trained.bg_hist
    pv.obj_hist = before.copy()
    pv.learn_object(frame, mask=mask)
    h_def = pv._hist(pv._small_hsv(frame), cv2.resize(mask, (160, 120), interpolation=cv2.INTER_NEAREST))
    expected = np.minimum(255.0, before + p.f_gain * np.maximum(0.0, h_def - p.f_bg * trained.bg_hist))
    assert np.allclose(pv.obj_hist, expected)
    assert pv.obj_hist.max() <= 255.0
    # background colours never enter the object model
    assert np.all(pv.obj_hist[trained.bg_hist >= 255.0 / p.f_bg] == before[trained.bg_hist >= 255.0 / p.f_bg])


def test_learning_from_rectangles_and_bad_input() -> None:
    pv = ProximityVision()
    frame = render(MARKERS, obj=Ellipse(170, 120, 60, 30, 25))
    pv.learn_object(frame, rects=[(150, 110, 40, 20)])
    assert pv.obj_hist is not None and pv.obj_hist.max() > 0
    with pytest.raises(ValueError, match="mask or rectangles"):
        pv.learn_object(frame)
    with pytest.raises(ValueError, match="mask shape"):
        pv.learn_object(frame, mask=np.ones((10, 10), np.uint8))


def test_no_object_model_and_no_object_in_view(trained: ProximityVision) -> None:
    r = ProximityVision().process(render(MARKERS))
    assert r.moments.area_px == 0 and r.moments.centroid_px is None and not r.slip
    r = trained.process(render(MARKERS, seed=3))
    assert r.moments.area_px == 0 and r.moments.orientation_deg is None


@settings(deadline=None, max_examples=12)
@given(angle=st.floats(0.0, 180.0), cx=st.floats(120.0, 200.0))
def test_orientation_within_2_deg_over_0_180(trained: ProximityVision, angle: float, cx: float) -> None:
    e = Ellipse(cx, 118.0, 55, 22, angle)
    r = trained.process(render(MARKERS, obj=e, seed=int(angle) % 5))
    m = r.moments
    assert m.orientation_deg is not None
    assert angle_err(m.orientation_deg, angle) <= 2.0
    assert m.centroid_px == pytest.approx((cx, 118.0), abs=1.5)
    assert m.area_px == pytest.approx(math.pi * 55 * 22, rel=0.15)


def test_round_object_through_the_pipeline(trained: ProximityVision) -> None:
    r = trained.process(render(MARKERS, obj=Ellipse(160, 120, 35, 35, 0), seed=2))
    assert r.moments.area_px > 0 and r.moments.orientation_deg is None


@pytest.mark.parametrize("direction_deg", [30.0, 200.0])
def test_slip_detected_within_one_frame_and_never_while_still(direction_deg: float) -> None:
    pv = ProximityVision()
    pv.set_background([render(MARKERS, seed=s) for s in range(3)])
    e0 = Ellipse(150, 120, 50, 28, 10)
    pv.learn_object(render(MARKERS, obj=e0, seed=3), mask=ellipse_mask(e0))
    u = np.array([math.cos(math.radians(direction_deg)), math.sin(math.radians(direction_deg))])
    start, speed = 10, 1.0
    reports = []
    for k in range(16):
        off = u * speed * max(0, k - start + 1)  # first moved frame: k == start
        e = Ellipse(e0.cx + off[0], e0.cy + off[1], e0.a, e0.b, e0.angle_deg)
        gain = 1.0 + 0.12 * math.sin(1.7 * k)  # light flicker
        r = pv.process(render(MARKERS, obj=e, obj_texture_offset_px=tuple(off), seed=k, gain=gain), MARKERS)
        reports.append(r)
    assert not any(r.slip for r in reports[:start]), [round(r.slip_magnitude_px, 2) for r in reports[:start]]
    first = next(k for k, r in enumerate(reports) if r.slip)
    assert start <= first <= start + 1
    for r in reports[start + 1:]:
        assert r.slip
        assert r.slip_magnitude_px == pytest.approx(speed, abs=0.3)
        assert angle_err(2 * r.slip_direction_deg, 2 * direction_deg) / 2 <= 10.0 or abs(
            (r.slip_direction_deg - direction_deg + 180) % 360 - 180) <= 10.0


def test_estimate_shift_refuses_flat_or_tiny_regions() -> None:
    flat = np.full((30, 40), 100, np.uint8)
    assert estimate_shift(flat, flat, np.ones_like(flat)) is None
    noise = np.random.default_rng(0).integers(0, 255, (30, 40)).astype(np.uint8)
    assert estimate_shift(noise, noise, np.zeros_like(noise)) is None
    assert estimate_shift(np.zeros_like(noise), noise, np.ones_like(noise)) is None


@settings(deadline=None, max_examples=20)
@given(level=st.sampled_from([0, 1, 128, 254, 255]), learn=st.booleans())
def test_black_or_saturated_frames_never_nan(level: int, learn: bool) -> None:
    pv = ProximityVision(ProximityParams(min_object_area_px=0.0))
    frame = np.full((240, 320, 3), level, np.uint8)
    if learn:
        pv.learn_object(frame, rects=[(0, 0, 320, 240)])
    for _ in range(2):
        r = pv.process(frame)
        assert math.isfinite(r.moments.area_px) and math.isfinite(r.slip_magnitude_px)
        assert not r.slip

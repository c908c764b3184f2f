"""Where a ball press touches a GelSight frame: the contact centroid, unbiased by the lighting."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.perception.gelsight.press_centres import contact_centroid_px, even_colour_direction


@given(st.floats(30, 290), st.floats(30, 210), st.integers(6, 20))
def test_contact_centroid_finds_a_blurred_disc(cx, cy, r):
    bg = np.full((240, 320, 3), 120, np.uint8)
    frame = bg.copy()
    cv2.circle(frame, (int(round(cx * 16)), int(round(cy * 16))), r * 16, (160, 90, 150), -1, cv2.LINE_AA, 4)
    frame = cv2.GaussianBlur(frame, (0, 0), 3.0)
    got = contact_centroid_px(frame, bg)
    assert got is not None
    assert abs(got[0] - cx) < 0.6 and abs(got[1] - cy) < 0.6


def test_contact_centroid_of_no_contact_is_none():
    bg = np.full((60, 80, 3), 100, np.uint8)
    assert contact_centroid_px(bg, bg) is None
    # saturated: the whole frame is one region, centred on the image
    assert contact_centroid_px(np.full_like(bg, 255), np.zeros_like(bg)) == pytest.approx((39.5, 29.5), abs=1e-3)


def test_even_colour_direction_ignores_the_odd_slope_colours():
    """A press whose colour change is c·even(r) + a·gx + b·gy: the direction is ⟂ a and b."""
    a, b, c = np.array([40.0, -10.0, 5.0]), np.array([-5.0, 30.0, 20.0]), np.array([10.0, 10.0, -30.0])
    h, w = 80, 100
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    bg = np.full((h, w, 3), 120.0, np.float32)
    frames, centres = [], [(40.0, 35.0), (60.5, 44.0)]
    for cx, cy in centres:
        dx, dy = (xs - cx) / 10.0, (ys - cy) / 10.0
        r2 = dx * dx + dy * dy
        inside = np.clip(1.0 - r2, 0.0, None)
        gx, gy, even = -dx * inside, -dy * inside, r2 * inside
        frames.append(np.clip(bg + gx[..., None] * a + gy[..., None] * b + even[..., None] * c, 0, 255).astype(np.uint8))
    d = even_colour_direction(frames, bg.astype(np.uint8), centres, 10.0)
    assert abs(np.linalg.norm(d) - 1.0) < 1e-9
    assert abs(d @ a) / np.linalg.norm(a) < 0.05 and abs(d @ b) / np.linalg.norm(b) < 0.05
    for f, (cx, cy) in zip(frames, centres):
        got = contact_centroid_px(f, bg.astype(np.uint8), direction_bgr=d)
        assert got is not None and abs(got[0] - cx) < 0.3 and abs(got[1] - cy) < 0.3
    flat = even_colour_direction([bg.astype(np.uint8)], bg.astype(np.uint8), [(50.0, 40.0)], 10.0)
    assert np.all(np.isfinite(flat)) and abs(np.linalg.norm(flat) - 1.0) < 1e-9

"""FingerVision perception on frames of the simulated gel (tactile_rig.sim.render.fingervision).

Same parameters as on the real frames. Skipped if the renderer is not importable.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_rig.perception.fingervision import FingerVision, detect_markers

import tactile_rig.sim.render.fingervision as render_mod  # noqa: E402  (a broken import must fail, not skip)


@pytest.fixture(scope="module")
def renderer():
    return render_mod.FingerVisionRenderer(seed=1)


def test_rendered_markers_found_within_0_3_px(renderer) -> None:
    img, truth = renderer.render(light_gain=0.8)
    det = detect_markers(img)
    gt = np.asarray(truth["markers_px"])
    r = np.asarray(truth["marker_radius_px"])
    d = np.hypot(det.positions_px[:, None, 0] - gt[None, :, 0], det.positions_px[:, None, 1] - gt[None, :, 1])
    # every detection is on a marker (a dot cut by the image border has a biased centroid: within r)
    assert np.all(d.min(axis=1) <= np.maximum(1.0, r[d.argmin(axis=1)])), "a detection away from every marker"
    # markers whose disc lies inside the image and is at least 5 px wide
    clear = (gt[:, 0] - r >= 1) & (gt[:, 0] + r <= 318) & (gt[:, 1] - r >= 1) & (gt[:, 1] + r <= 238) & (r >= 2.5)
    assert clear.sum() >= 15
    assert np.all(d.min(axis=0)[clear] <= 0.3)


@pytest.mark.parametrize("angle_deg", [60.0, -150.0])
def test_rendered_shear_direction_and_object_orientation(renderer, angle_deg: float) -> None:
    fv = FingerVision()
    fv.calibrate([renderer.render()[0] for _ in range(4)])
    obj = render_mod.FvObject((170.0, 120.0), (60.0, 25.0), 35.0 + angle_deg)
    img, truth = renderer.render(object=obj)
    mask = np.zeros(img.shape[:2], np.uint8)
    render_mod.FingerVisionRenderer._draw_object(mask, obj)
    fv.learn_object(img, mask=mask)
    u = np.array([math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))])
    for k in range(1, 9):
        shift = np.tile(u * 0.3 * k, (len(renderer.rest_px), 1))
        img, truth = renderer.render(markers_shift_px=shift, object=obj, light_gain=1.0 + 0.1 * (-1) ** k)
        r = fv.process(img)
    got = math.degrees(math.atan2(r.force_px[1], r.force_px[0]))
    assert abs((got - angle_deg + 180) % 360 - 180) <= 5.0
    err = abs((r.object_orientation_deg - truth["object_orientation_deg"] + 90) % 180 - 90)
    assert err <= 2.0

"""The same pipeline, same default parameters, on frames from the simulated gel (tactile_rig.sim.world).

Skips when the renderer is not available. Rendered touches are independent renders (own sensor
noise), so registration here is a harder, more realistic test than re-sampling one height map.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_rig.perception.gelsight import (
    Reconstructor, calibrate_from_presses, clamp_radius_px, load_presses, press_error, register)

from tactile_rig.sim.render import gelsight as render  # noqa: E402  (a broken import must fail, not skip)
from tactile_rig.sim.world import objects  # noqa: E402

MM = 0.1245
SHAPE = (120, 160)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rendered_presses")
    render.render_ball_press_dataset(folder, n_presses=20, seed=1)
    presses = load_presses(folder)
    cal = calibrate_from_presses(presses.subset(range(15)), MM, 2.0)  # defaults, as for the real presses
    return presses, Reconstructor(cal)


def test_calibration_holds_out_on_rendered_presses(rendered) -> None:
    presses, rec = rendered
    errs = []
    for i in range(15, 20):
        z = rec.height_mm(presses.frames[i])
        a = clamp_radius_px(presses.radii_px[i], 2.0, MM)
        errs.append(press_error(z, tuple(presses.centers_px[i]), a, 2.0, MM))
    normal_deg, rms_mm = np.mean(errs, axis=0)
    assert normal_deg <= 9.0 and rms_mm <= 0.14


def _sensor_to_object(obj, pose) -> np.ndarray:
    # Mirrors view_in_sensor's sampling map (sensor px -> object px) to get the true relative pose.
    x, y, th = pose
    t = math.radians(th)
    c, s = math.cos(t), math.sin(t)
    k = MM / obj.mm_per_px
    orows, ocols = obj.height_mm.shape
    px0 = -(SHAPE[1] - 1) / 2 * MM - x
    py0 = -(SHAPE[0] - 1) / 2 * MM - y
    return np.array([[c * k, s * k, (c * px0 + s * py0) / obj.mm_per_px + (ocols - 1) / 2],
                     [-s * k, c * k, (-s * px0 + c * py0) / obj.mm_per_px + (orows - 1) / 2], [0, 0, 1]])


@pytest.mark.parametrize("pose_b", [(1.0, 0.5, 10.0), (-2.0, 1.0, -30.0), (0.5, 0.5, -90.0), (0.0, 0.0, 180.0)])
def test_rendered_touches_of_a_textured_part_register(rendered, pose_b) -> None:
    _, rec = rendered
    renderer = render.GelSightRenderer("taxim", MM, shape_px=SHAPE, seed=3)
    obj = objects.plate_with_features(mm_per_px=0.05)
    pose_a = (0.0, 0.0, 0.0)
    za = rec.height_mm(renderer.render_object(obj, 0.5, *pose_a)[0])
    zb = rec.height_mm(renderer.render_object(obj, 0.5, *pose_b)[0])
    res = register(za, zb, MM)
    assert res.ok, res.reason
    m = (np.linalg.inv(_sensor_to_object(obj, pose_a)) @ _sensor_to_object(obj, pose_b))[:2]
    c = np.array([(SHAPE[1] - 1) / 2, (SHAPE[0] - 1) / 2])
    true_rot = math.degrees(math.atan2(m[1, 0], m[0, 0]))
    true_t = (m[:, :2] @ c + m[:, 2] - c) * MM
    assert abs((res.rotation_deg - true_rot + 180) % 360 - 180) <= 0.5
    assert np.linalg.norm(res.translation_mm - true_t) <= 0.06

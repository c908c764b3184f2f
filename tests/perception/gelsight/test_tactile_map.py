"""Tactile map: mosaic touches of a real-texture surface, localize new touches, save/load."""

from __future__ import annotations

import numpy as np
import pytest

from tactile_rig.perception.gelsight import Reconstructor, TactileMap, calibrate_from_presses, load_presses
from tactile_rig.perception.gelsight.synthetic import tile, touch_at
from tests._data import test_data

MM_PER_PX = 0.1245
SHAPE = (120, 160)
ROOT = (160.0, 120.0)


@pytest.fixture(scope="module")
def surface():
    presses = load_presses(test_data("taxim_gelsight_ball") / "presses")
    rec = Reconstructor(calibrate_from_presses(presses, MM_PER_PX, 2.0, "lut", bins=32))
    hs = [rec.height_mm(presses.frames[i]) for i in (0, 5, 11, 22)]
    return tile(hs)


def _truth_mm(center_px) -> np.ndarray:
    return (np.array(center_px) - ROOT) * MM_PER_PX


@pytest.fixture(scope="module")
def built(surface):
    tmap = TactileMap(MM_PER_PX)
    records = [tmap.add_touch(touch_at(surface, 0, ROOT, SHAPE))]
    for rot, c in [(10, (130, 110)), (-20, (190, 130)), (35, (150, 100)), (60, (110, 90))]:
        records.append(tmap.add_touch(touch_at(surface, rot, c, SHAPE)))
    return tmap, records


def test_root_touch_defines_the_map_frame(built) -> None:
    tmap, records = built
    root = records[0]
    assert root.accepted and root.result.method == "root"
    np.testing.assert_allclose(root.g_T_m, np.hstack([np.eye(2), np.zeros((2, 1))]), atol=1e-9)


def test_accepted_touches_are_placed_where_they_belong(built) -> None:
    tmap, records = built
    cases = [(10, (130, 110)), (-20, (190, 130)), (35, (150, 100)), (60, (110, 90))]
    accepted = 0
    for rec, (rot, c) in zip(records[1:], cases):
        if not rec.accepted:
            assert rec.result.confidence <= tmap.accept_confidence or not rec.result.ok
            continue
        accepted += 1
        assert rec.result.confidence > 0.98
        assert abs(rec.result.rotation_deg - rot) < 0.2
        np.testing.assert_allclose(rec.result.translation_mm, _truth_mm(c), atol=0.03)
        # g_T_m is the inverse of the touch's placement in the map.
        back = rec.g_T_m @ np.append(rec.result.translation_mm, 1.0)
        np.testing.assert_allclose(back, 0.0, atol=1e-9)
    assert accepted >= 3
    assert tmap.coverage.sum() > SHAPE[0] * SHAPE[1] * 1.5  # the map grew past the root


def test_overlaps_are_averaged_not_summed(built, surface) -> None:
    tmap, _ = built
    z = tmap.height_mm
    assert z.max() < float(surface.max()) * 1.05
    assert (tmap.count > 1).any()


@pytest.mark.parametrize("rot, center", [(50, (170, 125)), (-80, (140, 110)), (170, (180, 135))])
def test_localize_new_touches(built, surface, rot, center) -> None:
    tmap, _ = built
    res = tmap.localize(touch_at(surface, rot, center, SHAPE))
    assert res.ok, res.reason
    err = (res.rotation_deg - rot + 180) % 360 - 180
    assert abs(err) < 0.2
    np.testing.assert_allclose(res.translation_mm, _truth_mm(center), atol=0.03)


def test_a_touch_off_the_map_is_refused(built) -> None:
    tmap, _ = built
    rng = np.random.default_rng(0)
    res = tmap.localize(rng.normal(0, 0.05, SHAPE).astype(np.float32))
    assert not res.ok and res.matrix_mm is None


def test_save_load_keeps_map_and_poses(tmp_path, built, surface) -> None:
    tmap, _ = built
    path = tmap.save(tmp_path / "map.npz")
    loaded = TactileMap.load(path)
    np.testing.assert_allclose(loaded.height_mm, tmap.height_mm)
    assert len(loaded.poses) == len(tmap.poses)
    res = loaded.localize(touch_at(surface, 50, (170, 125), SHAPE))
    assert res.ok and abs(res.rotation_deg - 50) < 0.2


def test_pose_hint_places_a_touch_keypoints_cannot(surface) -> None:
    tmap = TactileMap(MM_PER_PX, accept_confidence=0.98)
    tmap.add_touch(touch_at(surface, 0, ROOT, SHAPE))
    touch = touch_at(surface, 0, (170, 125), SHAPE)
    hint = np.hstack([np.eye(2), _truth_mm((170.6, 124.5))[:, None]])  # 0.1 mm off
    # Force registration to refuse: demand more inliers than any touch yields, no dense search.
    tmap.params = type(tmap.params)(min_inliers=10_000, dense_fallback=False)
    rec = tmap.add_touch(touch, pose_hint=hint)
    assert rec.accepted and rec.result.method == "hint"
    np.testing.assert_allclose(rec.result.translation_mm, _truth_mm((170, 125)), atol=0.03)


def test_empty_map_and_bad_arguments() -> None:
    tmap = TactileMap(MM_PER_PX)
    with pytest.raises(ValueError, match="empty"):
        tmap.localize(np.zeros(SHAPE, np.float32))
    with pytest.raises(ValueError, match="mm_per_px"):
        TactileMap(-1.0)

"""FingerVision renderer: blob statistics against the real frames, physics, extremes, scene use."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tactile_rig.sim import World
from tactile_rig.sim.render.fingervision import FingerVisionRenderer, FvObject, contact_shear_field
from tests._data import require_shared


def _detector() -> cv2.SimpleBlobDetector:
    """One detector setting for real and rendered frames: the reference FingerVision parameters."""
    p = cv2.SimpleBlobDetector_Params()
    p.minThreshold, p.maxThreshold, p.thresholdStep = 5, 200, 10
    p.filterByColor, p.blobColor = True, 0
    p.filterByArea, p.minArea, p.maxArea = True, 10, 150
    p.filterByCircularity, p.minCircularity = True, 0.10
    p.filterByConvexity, p.minConvexity = True, 0.87
    p.filterByInertia, p.minInertiaRatio = True, 0.01
    p.minDistBetweenBlobs = 10
    return cv2.SimpleBlobDetector_create(p)


DETECTOR = _detector()


def blobs(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centres N x 2, diameters N) after the reference HSV pre-threshold (V <= 42 is marker ink)."""
    dark = cv2.inRange(cv2.cvtColor(img, cv2.COLOR_BGR2HSV), (0, 0, 0), (180, 255, 42))
    kps = DETECTOR.detect(255 - dark)
    return np.array([k.pt for k in kps]).reshape(-1, 2), np.array([k.size for k in kps])


def test_blob_count_and_sizes_match_the_real_frames():
    frames = sorted((require_shared("fingervision_demo_gpl3") / "frames").glob("*.png"))
    assert len(frames) >= 5
    real = [blobs(cv2.imread(str(f)))[1] for f in frames]
    rendered = [blobs(FingerVisionRenderer(seed=s).render()[0])[1] for s in range(6)]
    real_counts = [len(s) for s in real]
    ren_counts = [len(s) for s in rendered]
    assert min(real_counts) <= np.median(ren_counts) <= max(real_counts)
    assert min(ren_counts) >= min(real_counts) - 3
    q = [10, 25, 50, 75, 90]
    q_real = np.percentile(np.concatenate(real), q)
    q_ren = np.percentile(np.concatenate(rendered), q)
    assert np.all(np.abs(q_real - q_ren) <= 1.0), (q_real, q_ren)  # diameters in px


def test_truth_markers_are_what_a_detector_finds():
    r = FingerVisionRenderer(seed=2)
    img, truth = r.render()
    det, _ = blobs(img)
    d = np.hypot(*(det[:, None, :] - truth["markers_px"][None, :, :]).transpose(2, 0, 1))
    assert np.all(d.min(axis=1) < 1.5)  # no detection away from a true marker
    assert (d.min(axis=0) < 1.5).sum() >= 0.8 * len(truth["markers_px"])


def test_shift_moves_the_markers():
    r = FingerVisionRenderer(seed=0, noise_sigma=0.0)
    shift = np.tile([3.0, -2.0], (len(r.rest_px), 1))
    img0, t0 = r.render()
    img1, t1 = r.render(markers_shift_px=shift)
    assert np.allclose(t1["markers_px"] - t0["markers_px"], shift)
    p0, _ = blobs(img0)
    p1, _ = blobs(img1)
    central = p0[(np.abs(p0[:, 0] - 160) < 100) & (np.abs(p0[:, 1] - 120) < 80)]
    moved = [p1[np.argmin(np.hypot(*(p1 - (p + [3, -2])).T))] - p for p in central]
    assert np.allclose(np.median(moved, axis=0), [3.0, -2.0], atol=0.3)


def test_contact_shear_field_translation_and_twist():
    pts = np.array([[100.0, 100.0], [110.0, 100.0], [100.0, 400.0]])
    d = contact_shear_field(pts, (100.0, 100.0), shift_px=(2.0, 0.0), radius_px=50.0)
    assert np.allclose(d[0], [2.0, 0.0]) and np.linalg.norm(d[2]) < 1e-6
    tw = contact_shear_field(pts, (100.0, 100.0), twist_deg=10.0, radius_px=1e4)
    assert np.allclose(tw[0], 0) and tw[1, 1] > 0 and abs(tw[1, 0]) < 0.2  # +x point turns towards +y
    with pytest.raises(ValueError, match="radius_px"):
        contact_shear_field(pts, (0, 0), radius_px=0.0)


def test_normal_load_grows_the_blobs():
    r = FingerVisionRenderer(seed=0)

    def ink_px(img: np.ndarray) -> int:
        return int(np.count_nonzero(cv2.inRange(cv2.cvtColor(img, cv2.COLOR_BGR2HSV), (0, 0, 0), (180, 255, 42))))

    a0, a1 = ink_px(r.render(normal_load=0.0)[0]), ink_px(r.render(normal_load=1.0)[0])
    assert a1 > 1.4 * a0  # radius x1.35 at full load -> ink area x1.8
    p0, s0 = blobs(r.render(normal_load=0.0)[0])
    p1, s1 = blobs(r.render(normal_load=0.4)[0])
    ratio = [s1[np.argmin(np.hypot(*(p1 - p).T))] / s for p, s in zip(p0, s0)]
    assert np.median(ratio) > 1.08  # the same markers, seen bigger (radius x1.14)
    assert np.allclose(r.render(normal_load=5.0)[1]["marker_radius_px"], r.render(normal_load=1.0)[1]["marker_radius_px"])


@pytest.mark.parametrize("angle_deg", [0.0, 30.0, -60.0])
def test_object_truth_matches_what_is_seen(angle_deg):
    r = FingerVisionRenderer(seed=0, noise_sigma=0.0)
    bg, _ = r.render()
    obj = FvObject((170.0, 110.0), (70.0, 25.0), angle_deg, colour_bgr=(30, 30, 220), blur_px=1.0)
    img, truth = r.render(object=obj)
    seen = (np.abs(img.astype(int) - bg).sum(axis=2) > 60).astype(np.uint8)
    m = cv2.moments(seen, binaryImage=True)
    cx, cy = m["m10"] / m["m00"], m["m01"] / m["m00"]
    assert math.hypot(cx - truth["object_centroid_px"][0], cy - truth["object_centroid_px"][1]) < 3.0
    assert truth["object_centroid_px"] == pytest.approx((170.0, 110.0), abs=1.0)
    assert truth["object_orientation_deg"] == pytest.approx(angle_deg, abs=2.0)


def test_light_gain_extremes_clip_like_a_sensor():
    r = FingerVisionRenderer(seed=0, noise_sigma=0.0)
    dark, _ = r.render(light_gain=0.0)
    assert dark.max() == 0
    bright, _ = r.render(light_gain=20.0)
    assert bright.max() == 255 and (bright == 255).mean() > 0.5  # saturated, not wrapped around
    with pytest.raises(ValueError, match="light_gain"):
        r.render(light_gain=float("nan"))
    with pytest.raises(ValueError, match="markers_shift_px"):
        r.render(markers_shift_px=np.zeros((3, 2)))


@given(
    st.floats(-1e9, 1e9),
    st.floats(0, 1e3),
    hnp.arrays(np.float64, 2, elements=st.floats(allow_nan=True, allow_infinity=True)),
    st.tuples(st.floats(-1e7, 1e7), st.floats(-1e7, 1e7), st.floats(0, 1e7), st.floats(0, 1e7), st.floats(-1e4, 1e4)),
)
def test_any_input_gives_a_valid_frame(load, gain, shift, obj):
    r = FingerVisionRenderer((24, 32), seed=0)
    fv = FvObject((obj[0], obj[1]), (obj[2], obj[3]), obj[4])
    img, truth = r.render(markers_shift_px=np.tile(shift, (len(r.rest_px), 1)), normal_load=load, object=fv,
                          light_gain=gain)
    assert img.dtype == np.uint8 and img.shape == (24, 32, 3)
    assert np.all(np.isfinite(truth["markers_px"])) and np.all(np.isfinite(truth["marker_radius_px"]))


class _Contact:
    def __init__(self) -> None:
        self.normal_force_n, self.shear_x_n, self.shear_y_n, self.torque_nmm = 0.0, 0.0, 0.0, 0.0

    def advance_to(self, t_s: float) -> None:
        pass


def test_renderer_model_reads_contact_from_the_world():
    world = World(seed=3)
    contact = world.add("contact", _Contact())
    world.build("object", "primitive_object", primitive="box", width_mm=8.0, length_mm=4.0, height_mm=3.0,
                theta_deg=20.0, colour_bgr=[20, 200, 20])
    fv = world.build("fv", "fingervision_renderer", mm_per_px=0.1)
    fv.render_now()
    rest = fv.last_truth["markers_px"]
    assert fv.last_truth["object_orientation_deg"] == pytest.approx(20.0, abs=2.0)
    contact.normal_force_n, contact.shear_x_n = 5.0, 1.0
    fv.render_now()
    moved = fv.last_truth["markers_px"] - rest
    centre = np.hypot(rest[:, 0] - 159.5, rest[:, 1] - 119.5) < 60
    assert np.all(moved[centre, 0] > 2.0) and np.all(np.abs(moved[centre, 1]) < 0.5)
    assert np.all(fv.last_truth["marker_radius_px"] > fv.renderer.radius_px)

"""GelSight renderer: realism against the real Taxim presses, numerics at the extremes, scene use."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tactile_rig.sim import World
from tactile_rig.sim.render.gelsight import (
    TAXIM_LIGHTING,
    GelSightRenderer,
    LightingModel,
    ball_press_height_mm,
    fit_lighting,
    lighting_from_leds,
    load_background,
    read_labels,
    render_ball_press_dataset,
)
from tactile_rig.sim.world.objects import (
    HeightField,
    box,
    cone,
    plate_with_features,
    pressed_indentation_mm,
    usb_connector_part,
    view_in_sensor,
)
from tests._data import TESTS_DATA, require_shared

MM_PER_PX = 0.1245


def taxim_presses() -> Path:
    local = TESTS_DATA / "taxim_gelsight_ball" / "presses"
    return local if local.is_dir() else require_shared("taxim_gelsight_ball") / "presses"


def disc_stats(img: np.ndarray, bg: np.ndarray, row: dict) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel mean and std of (frame − background) inside the labelled disc grown by 4 px."""
    yy, xx = np.mgrid[0:bg.shape[0], 0:bg.shape[1]]
    m = (xx - row["center_x_px"]) ** 2 + (yy - row["center_y_px"]) ** 2 <= (row["contact_radius_px"] + 4) ** 2
    d = img.astype(np.float32)[m] - bg.astype(np.float32)[m]
    return np.r_[d.mean(0), d.std(0)], d


def test_rendered_ball_presses_have_real_colour_statistics():
    presses = taxim_presses()
    bg = cv2.imread(str(presses / "background.png"))
    r = GelSightRenderer(bg, MM_PER_PX, seed=3)
    real, rendered, corr = [], [], []
    for row in read_labels(presses)[15:]:  # held out: TAXIM_LIGHTING was fitted on 00-14
        img = cv2.imread(str(presses / row["file"]))
        h = ball_press_height_mm(r.shape_px, MM_PER_PX, (row["center_x_px"], row["center_y_px"]), 2.0,
                                 row["contact_radius_px"])
        s_real, d_real = disc_stats(img, bg, row)
        s_ren, d_ren = disc_stats(r.render(h), bg, row)
        real.append(s_real)
        rendered.append(s_ren)
        corr.append([np.corrcoef(d_real[:, c], d_ren[:, c])[0, 1] for c in range(3)])
    real, rendered = np.array(real), np.array(rendered)
    lo, hi = real.min(0), real.max(0)
    # Every rendered press's disc mean and std (B, G, R) lies within the spread of the real presses.
    assert np.all(rendered >= lo - 1e-6) and np.all(rendered <= hi + 1e-6), (rendered, lo, hi)
    # And the pattern matches pixel by pixel, not only on average.
    assert np.median(np.array(corr), axis=0).min() > 0.8


def test_noise_level_matches_the_real_sensor():
    presses = taxim_presses()
    bg = cv2.imread(str(presses / "background.png")).astype(np.float32)
    yy, xx = np.mgrid[0:bg.shape[0], 0:bg.shape[1]]

    def hp_std(diff: np.ndarray, row: dict) -> np.ndarray:
        far = (xx - row["center_x_px"]) ** 2 + (yy - row["center_y_px"]) ** 2 > 40**2
        return (diff - cv2.GaussianBlur(diff, (0, 0), 2.0))[far].std(axis=0)

    r = GelSightRenderer("taxim", MM_PER_PX, seed=4)
    real, ren = [], []
    for row in read_labels(presses)[:10]:
        real.append(hp_std(cv2.imread(str(presses / row["file"])).astype(np.float32) - bg, row))
        ren.append(hp_std(r.render(None).astype(np.float32) - r.render(None).astype(np.float32), row))
    ratio = np.median(ren, axis=0) / np.median(real, axis=0)  # frame-to-frame noise, per channel
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio


def test_default_lighting_is_what_the_fit_gives():
    presses = taxim_presses()
    fitted = fit_lighting(presses, files=[f"press_{i:02d}.png" for i in range(15)])
    assert np.allclose(fitted.matrix, TAXIM_LIGHTING.matrix, atol=0.05)


def test_no_contact_is_the_background_plus_noise():
    r = GelSightRenderer("taxim", MM_PER_PX, noise_sigma=1.0, seed=0)
    for h in (None, np.zeros(r.shape_px, np.float32)):
        d = r.render(h).astype(np.float32) - r.background_bgr
        assert abs(d.mean()) < 0.2 and 0.7 < d.std() < 1.3


def test_noise_free_no_contact_equals_background_exactly():
    r = GelSightRenderer("taxim", MM_PER_PX, noise_sigma=0.0)
    assert np.array_equal(r.render(None), r.background_bgr)


def test_contact_beyond_the_gel_range_is_clipped():
    r = GelSightRenderer("taxim", MM_PER_PX, noise_sigma=0.0)
    deep = ball_press_height_mm(r.shape_px, MM_PER_PX, (80, 60), 2.0, 15.9)  # ~1.8 mm deep
    assert deep.max() > 1.5
    s = r.gel_surface_mm(deep)
    assert s.max() <= r.max_protrusion_mm + 1e-6
    assert np.array_equal(r.render(deep), r.render(np.minimum(deep, r.max_protrusion_mm)))


def test_object_larger_than_the_view():
    r = GelSightRenderer("gsmini", 0.0634, noise_sigma=0.0)
    flat = box(60.0, 60.0, 2.0, mm_per_px=0.2)
    frame, ind = r.render_object(flat, 0.5)
    assert np.allclose(ind, 0.5)  # a uniform press: no gradients, so no colour change
    assert np.array_equal(frame, r.background_bgr)
    part = usb_connector_part()
    assert part.size_mm[0] > r.shape_px[1] * r.mm_per_px and part.size_mm[1] > r.shape_px[0] * r.mm_per_px
    frame, ind = r.render_object(part, 0.5)
    changed = np.abs(frame.astype(int) - r.background_bgr).max(axis=2) > 8
    assert 0.02 < changed.mean() < 0.9


@given(hnp.arrays(np.float32, (12, 16), elements=st.floats(allow_nan=True, allow_infinity=True, width=32)))
def test_any_height_field_gives_a_valid_frame(h):
    bg = np.full((12, 16, 3), 128, np.uint8)
    r = GelSightRenderer(bg, MM_PER_PX, noise_sigma=1.0, seed=0)
    s = r.gel_surface_mm(h)
    assert np.all(np.isfinite(s)) and s.min() >= 0 and s.max() <= r.max_protrusion_mm + 1e-6
    assert np.all(np.isfinite(r.shading_bgr(s)))
    f = r.render(h)
    assert f.dtype == np.uint8 and f.shape == (12, 16, 3)


def test_grazing_normals_saturate_as_a_sensor_clips():
    bg = np.full((40, 40, 3), 128, np.uint8)
    strong = LightingModel(TAXIM_LIGHTING.matrix * 20)
    r = GelSightRenderer(bg, 0.05, lighting=strong, smoothing_mm=0.0, noise_sigma=0.0)
    c = cone(0.8, 5.0, mm_per_px=0.05)  # flanks at ~80°
    frame, _ = r.render_object(c, 1.0)
    expected = np.clip(bg + r.shading_bgr(r.gel_surface_mm(_)) + 0.5, 0, 255)
    assert frame.min() == 0 and frame.max() == 255  # clipped, not wrapped around
    assert np.array_equal(frame, expected.astype(np.uint8))


@pytest.mark.parametrize("shape_px, mm_per_px", [((240, 320), 0.0634), ((250, 333), 0.05)])
def test_coarse_grid_shading_matches_full_resolution(shape_px, mm_per_px):
    r = GelSightRenderer("gsmini", mm_per_px, shape_px=shape_px, noise_sigma=0.0)
    part = usb_connector_part(0.05)
    h = pressed_indentation_mm(view_in_sensor(part, shape_px, mm_per_px, 1.0, -0.5, 20.0), 0.5, part.max_height_mm)
    exact = cv2.GaussianBlur(np.minimum(h, 1.0), (0, 0), 0.6 / mm_per_px, borderType=cv2.BORDER_REPLICATE)
    assert np.abs(r.gel_surface_mm(h) - exact).max() < 0.01 * exact.max()
    full, quick = r.shading_bgr(exact), r.shading_for(h)
    assert np.abs(full).max() > 20  # there is something to compare
    assert np.abs(full - quick).max() < 2.0 and np.abs(full - quick).mean() < 0.2  # grey levels


def test_elastomer_smooths_sharp_edges():
    r_sharp = GelSightRenderer("taxim", MM_PER_PX, smoothing_mm=0.0, noise_sigma=0.0)
    r_soft = GelSightRenderer("taxim", MM_PER_PX, smoothing_mm=0.6, noise_sigma=0.0)
    h = np.zeros(r_sharp.shape_px, np.float32)
    h[40:80, 60:100] = 0.5
    g_sharp = np.abs(np.diff(r_sharp.gel_surface_mm(h), axis=1)).max()
    g_soft = np.abs(np.diff(r_soft.gel_surface_mm(h), axis=1)).max()
    assert g_soft < 0.25 * g_sharp


def test_leds_build_a_lighting_model():
    # A red LED on the right lights slopes that face right (surface falling to the right: gx < 0).
    m = lighting_from_leds([(0.0, 30.0, (0.0, 0.0, 100.0))])
    d = m.shade(np.array([[-0.5]], np.float32), np.array([[0.0]], np.float32))[0, 0]
    assert d[2] > 20 and abs(d[0]) < 1e-6 and abs(d[1]) < 1e-6


def test_pose_convention():
    h = np.zeros((81, 81), np.float32)
    h[40, 60] = 1.0  # a bump 20 px = 2 mm along the object's +x axis
    obj = HeightField(h, 0.1)
    v0 = view_in_sensor(obj, (81, 81), 0.1)
    assert np.unravel_index(v0.argmax(), v0.shape) == (40, 60)
    v_shift = view_in_sensor(obj, (81, 81), 0.1, x_mm=1.0, y_mm=-0.5)
    assert np.unravel_index(v_shift.argmax(), v_shift.shape) == (35, 70)
    v_rot = view_in_sensor(obj, (81, 81), 0.1, theta_deg=90.0)  # clockwise on screen: +x goes to +y (down)
    assert np.unravel_index(v_rot.argmax(), v_rot.shape) == (60, 40)


def test_pressed_indentation_uses_the_whole_objects_top():
    view = np.array([[0.0, 1.0], [2.0, 1.5]], np.float32)
    assert np.allclose(pressed_indentation_mm(view, 0.5), [[0, 0], [0.5, 0]])
    assert np.allclose(pressed_indentation_mm(view, 0.5, top_height_mm=3.0), 0)
    assert np.allclose(pressed_indentation_mm(view, -1.0), 0)
    assert np.allclose(pressed_indentation_mm(view, float("nan")), 0)


def test_textured_parts_are_asymmetric():
    for part in (usb_connector_part(0.1), plate_with_features(mm_per_px=0.1)):
        h = part.height_mm
        assert h.min() == 0 and h.max() >= 2.0
        for rot in (np.rot90(h, 2), h[::-1], h[:, ::-1]):
            assert np.abs(rot - h).mean() > 0.05


def test_ball_press_dataset_format(tmp_path):
    labels = render_ball_press_dataset(tmp_path / "presses", n_presses=4, seed=1)
    files = sorted(p.name for p in (tmp_path / "presses").iterdir())
    assert files == ["background.png", "labels.csv", "press_00.png", "press_01.png", "press_02.png", "press_03.png"]
    with open(tmp_path / "presses" / "labels.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["file", "center_x_px", "center_y_px", "contact_radius_px"] and len(rows) == 5
    bg = cv2.imread(str(tmp_path / "presses" / "background.png")).astype(np.float32)
    for row in read_labels(tmp_path / "presses"):
        img = cv2.imread(str(tmp_path / "presses" / row["file"])).astype(np.float32)
        assert img.shape == (120, 160, 3)
        yy, xx = np.mgrid[0:120, 0:160]
        r2 = (xx - row["center_x_px"]) ** 2 + (yy - row["center_y_px"]) ** 2
        diff = np.abs(img - bg).sum(2)
        assert diff[r2 <= row["contact_radius_px"] ** 2].mean() > 4 * diff[r2 > (row["contact_radius_px"] + 12) ** 2].mean()
    lab = labels[0]
    a_mm = np.sqrt(2.0**2 - (2.0 - lab["press_depth_mm"]) ** 2)
    assert lab["contact_radius_px"] == pytest.approx(a_mm / MM_PER_PX, abs=0.01)


def test_ball_press_dataset_any_size_and_scale(tmp_path):
    labels = render_ball_press_dataset(tmp_path, n_presses=2, shape_px=(240, 320), mm_per_px=0.0634,
                                       background="gsmini", ball_radius_mm=3.0, seed=2)
    assert cv2.imread(str(tmp_path / "press_01.png")).shape == (240, 320, 3)
    assert all(lab["contact_radius_px"] > 20 for lab in labels)
    with pytest.raises(ValueError, match="press_depth_mm"):
        render_ball_press_dataset(tmp_path, n_presses=1, press_depth_mm=(0.5, 1.5))


def test_background_lookup_and_errors():
    assert load_background("gsmini").shape == (240, 320, 3)
    assert load_background("taxim", (480, 640)).shape == (480, 640, 3)
    with pytest.raises(FileNotFoundError, match="known names"):
        load_background("nope")
    with pytest.raises(ValueError, match="height_mm has shape"):
        GelSightRenderer("taxim", MM_PER_PX).render(np.zeros((10, 10)))
    with pytest.raises(ValueError, match="mm_per_px"):
        GelSightRenderer("taxim", 0.0)


class _Stage:
    """The attributes a stage model exposes after advance_to."""

    def __init__(self) -> None:
        self.x_mm, self.y_mm, self.theta_deg = 0.0, 0.0, 0.0

    def advance_to(self, t_s: float) -> None:
        pass


def test_renderer_model_follows_the_stage():
    world = World(seed=1)
    world.build("object", "height_field_object", shape="usb_connector", mm_per_px=0.1, press_depth_mm=0.5)
    stage = world.add("stage", _Stage())
    cam = world.build("gelsight", "gelsight_renderer", background="gsmini", noise_sigma=0.0)
    cam.render_now()
    ind0 = cam.last_truth["indentation_mm"]
    stage.x_mm, stage.theta_deg = 0.0634 * 10, 0.0
    cam.render_now()
    ind1 = cam.last_truth["indentation_mm"]
    assert np.allclose(ind1[:, 30:-30], ind0[:, 20:-40], atol=1e-3)  # shifted 10 px to the right
    stage.theta_deg = 45.0
    frame = cam.render_now()
    assert cam.last_truth["theta_deg"] == 45.0 and frame.shape == (240, 320, 3)


def test_renderer_model_without_object_renders_background():
    world = World()
    cam = world.build("gelsight", "gelsight_renderer", noise_sigma=0.0)
    assert np.array_equal(cam.render_now(), load_background("taxim"))


def test_scene_file_builds_objects_and_renderer(tmp_path):
    from tactile_rig.sim.scenes import load_scene

    path = tmp_path / "touch.toml"
    path.write_text(
        '[scene]\nname = "touch"\n\n'
        '[models.object]\ntype = "primitive_object"\nprimitive = "sphere"\nradius_mm = 2.0\npress_depth_mm = 0.6\n\n'
        '[models.gelsight]\ntype = "gelsight_renderer"\nbackground = "taxim"\n'
    )
    sc = load_scene(path)
    frame = sc.world.get("gelsight").render_now()
    d = np.abs(frame.astype(int) - load_background("taxim")).sum(2)
    assert d[50:70, 70:90].mean() > 5 * d[:15, :15].mean()

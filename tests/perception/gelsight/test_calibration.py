"""Calibration from the real Taxim ball presses: held-out accuracy, persistence, bad frames."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_rig.core.errors import CalibrationError, SaturatedFrame
from tactile_rig.perception.gelsight import (
    ContactParams, GelSightCalibration, IntegrationParams, Reconstructor, calibrate_from_presses, clamp_radius_px,
    cross_validate, load_presses, marker_mask, press_error)
from tests._data import test_data

MM_PER_PX = 0.1245
BALL_MM = 2.0
TRAIN = list(range(0, 30, 3)) + list(range(1, 30, 3))  # 20 presses
TEST = list(range(2, 30, 3))  # 10 held-out presses


@pytest.fixture(scope="module")
def presses():
    return load_presses(test_data("taxim_gelsight_ball") / "presses")


@pytest.fixture(scope="module")
def lut_cal(presses):
    return calibrate_from_presses(presses.subset(TRAIN), MM_PER_PX, BALL_MM, "lut", bins=32)


@pytest.fixture(scope="module")
def mlp_cal(presses):
    return calibrate_from_presses(presses.subset(TRAIN), MM_PER_PX, BALL_MM, "mlp")


def _held_out(cal, presses, solver="dct"):
    rec = Reconstructor(cal, IntegrationParams(solver=solver))
    normals, rms = [], []
    for i in TEST:
        z = rec.height_mm(presses.frames[i])
        a = clamp_radius_px(presses.radii_px[i], BALL_MM, MM_PER_PX)
        n, h = press_error(z, tuple(presses.centers_px[i]), a, BALL_MM, MM_PER_PX)
        normals.append(n)
        rms.append(h)
    return float(np.mean(normals)), float(np.mean(rms))


def test_loads_the_press_folder(presses) -> None:
    assert len(presses.frames) == 30
    assert presses.background.shape == (120, 160, 3)
    assert presses.radii_px.max() == 17


def test_label_radius_is_clamped_below_the_ball() -> None:
    # 17 px * 0.1245 mm = 2.12 mm > the 2.0 mm ball: clamped to 0.95 R.
    assert clamp_radius_px(17, BALL_MM, MM_PER_PX) == pytest.approx(0.95 * 2.0 / MM_PER_PX)
    assert clamp_radius_px(10, BALL_MM, MM_PER_PX) == 10


def test_position_aware_model_beats_targets_on_held_out_presses(presses, mlp_cal) -> None:
    normal_deg, rms_mm = _held_out(mlp_cal, presses)
    # One fixed split here (the docs give the 5-fold figures): 7-9 deg, 0.14-0.155 mm.
    assert normal_deg <= 9.0
    assert rms_mm <= 0.16


def test_lut_baseline_is_sane_but_worse(presses, lut_cal, mlp_cal) -> None:
    lut_deg, lut_rms = _held_out(lut_cal, presses)
    mlp_deg, _ = _held_out(mlp_cal, presses)
    assert lut_deg < 14.0 and lut_rms < 0.25
    assert mlp_deg < lut_deg


def test_background_frame_reads_flat(lut_cal, mlp_cal) -> None:
    for cal in (lut_cal, mlp_cal):
        gx, gy = cal.gradients(cal.background)
        assert np.abs(gx).max() < 1e-6 and np.abs(gy).max() < 1e-6
        z = Reconstructor(cal).height_mm(cal.background)
        assert np.all(np.isfinite(z)) and np.abs(z).max() < 1e-6


@pytest.mark.parametrize("value", [0, 255])
def test_saturated_frames_are_refused(mlp_cal, value: int) -> None:
    # An all-black (lights off, lens covered) or all-white frame would read as -7..+8 mm heights: refused.
    frame = np.full_like(mlp_cal.background, value)
    with pytest.raises(SaturatedFrame) as err:
        Reconstructor(mlp_cal).height_mm(frame)
    assert err.value.value > 0.9 and err.value.limit == 0.2
    with pytest.raises(SaturatedFrame):
        mlp_cal.gradients(frame)


@settings(deadline=None, max_examples=15)
@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), st.integers(0, 2**31 - 1))
def test_colours_outside_the_calibrated_range_stay_finite(lut_cal, b, g, r, seed) -> None:
    rng = np.random.default_rng(seed)
    frame = lut_cal.background.copy()
    y, x = rng.integers(0, 100), rng.integers(0, 140)
    frame[y:y + 20, x:x + 20] = (b, g, r)
    gx, gy = lut_cal.gradients(frame)
    assert np.all(np.isfinite(gx)) and np.all(np.isfinite(gy))
    # Out-of-range colours take the edge bins: the slopes stay within what the table holds.
    assert np.abs(gx).max() <= np.abs(lut_cal._table).max() * 2 + 1e-6


@pytest.mark.parametrize(
    "frame, msg",
    [
        (np.zeros((120, 161, 3), np.uint8), "120x160"),
        (np.zeros((120, 160, 3), np.float32), "uint8"),
        (np.zeros((120, 160), np.uint8), "HxWx3"),
        ([[0]], "numpy array"),
    ],
)
def test_wrong_frames_raise_value_error(lut_cal, frame, msg) -> None:
    with pytest.raises(ValueError, match=msg):
        lut_cal.gradients(frame)


@pytest.mark.parametrize("method", ["lut", "mlp"])
def test_save_load_roundtrip_gives_identical_slopes(tmp_path, presses, lut_cal, mlp_cal, method) -> None:
    cal = lut_cal if method == "lut" else mlp_cal
    path = cal.save(tmp_path / "cal")
    meta = json.loads((tmp_path / "cal.json").read_text())
    assert meta["version"] == 1 and meta["mm_per_px_x"] == MM_PER_PX and meta["ball_radius_mm"] == BALL_MM
    assert meta["model"] == method and "date" in meta and "sensor" in meta
    loaded = GelSightCalibration.load(path)
    frame = presses.frames[TEST[0]]
    for a, b in zip(cal.gradients(frame), loaded.gradients(frame)):
        np.testing.assert_allclose(a, b, atol=1e-6)
    # npz holds no pickled objects.
    with np.load(path, allow_pickle=False) as d:
        assert all(d[k].dtype != object for k in d.files)


def test_load_rejects_other_versions(tmp_path, lut_cal) -> None:
    lut_cal.save(tmp_path / "cal")
    meta = json.loads((tmp_path / "cal.json").read_text())
    meta["version"] = 99
    (tmp_path / "cal.json").write_text(json.dumps(meta))
    with pytest.raises(CalibrationError, match="version"):
        GelSightCalibration.load(tmp_path / "cal")
    with pytest.raises(CalibrationError, match="needs both"):
        GelSightCalibration.load(tmp_path / "missing")


def test_poly_model_and_unbaked_evaluation_agree_roughly(presses) -> None:
    sub = presses.subset(TRAIN[:8])
    baked = calibrate_from_presses(sub, MM_PER_PX, BALL_MM, "poly", degree=2, bake_bins=32, bake_cells=(2, 2))
    exact = calibrate_from_presses(sub, MM_PER_PX, BALL_MM, "poly", degree=2, bake_bins=None)
    frame = presses.frames[TEST[1]]
    gb, ge = baked.gradients(frame), exact.gradients(frame)
    # Baking quantises colour to 8-level bins: close, not equal.
    assert np.mean(np.abs(gb[0] - ge[0])) < 0.05


def test_cross_validation_report_covers_every_press(presses) -> None:
    rep = cross_validate(presses, MM_PER_PX, BALL_MM, "lut", folds=3, bins=16)
    assert len(rep.presses) == 30 and all(np.isfinite(p.normal_deg) for p in rep.presses)
    assert 0.0 < rep.colour_coverage < 1.0
    assert "3-fold" in rep.protocol


def test_contact_mask_threshold_keeps_background_flat(presses, lut_cal) -> None:
    rec = Reconstructor(lut_cal, contact=ContactParams(colour_threshold=1000.0))
    assert np.abs(rec.height_mm(presses.frames[0])).max() == 0.0


def test_marker_mask_finds_dark_dots() -> None:
    img = np.full((60, 80, 3), 150, np.uint8)
    for x in range(10, 80, 15):
        cv2.circle(img, (x, 30), 3, (20, 20, 20), -1)
    m = marker_mask(img)
    assert m[30, 10] and m[30, 70] and not m[5, 5]
    assert 5 <= cv2.connectedComponents(m.astype(np.uint8))[0] - 1 <= 6


def test_bad_calibration_inputs(tmp_path, presses) -> None:
    with pytest.raises(CalibrationError, match="labels.csv"):
        calibrate_from_presses(tmp_path, MM_PER_PX, BALL_MM)
    with pytest.raises(ValueError, match="ball_radius_mm"):
        calibrate_from_presses(presses, MM_PER_PX, -1.0)
    with pytest.raises(ValueError, match="method"):
        calibrate_from_presses(presses, MM_PER_PX, BALL_MM, "svm")


def test_saved_baked_table_is_loaded_not_rebaked(tmp_path, mlp_cal, presses, monkeypatch) -> None:
    mlp_cal.save(tmp_path / "c")
    with np.load(tmp_path / "c.npz", allow_pickle=False) as data:
        assert "baked_table" in data.files

    def no_predict(self, feats):
        raise AssertionError("the model was evaluated while loading a baked calibration")

    # Baking an MLP costs about a second per load; the saved table is read instead.
    monkeypatch.setattr(type(mlp_cal.model), "predict", no_predict)
    back = GelSightCalibration.load(tmp_path / "c")
    for frame in presses.frames[:3]:
        for g_saved, g_fit in zip(back.gradients(frame), mlp_cal.gradients(frame)):
            np.testing.assert_array_equal(g_saved, g_fit)


def _saved_arrays(model: str) -> tuple[dict, dict[str, np.ndarray]]:
    base = test_data("file_formats") / f"gelsight_calibration_{model}"
    with np.load(base.with_suffix(".npz"), allow_pickle=False) as z:
        return json.loads(base.with_suffix(".json").read_text()), {k: z[k] for k in z.files}


# Each model array with a shape its model does not declare (the MLP is 5-4-2, the table 8 bins).
WRONG_SHAPES = [("mlp", "model_w0", np.zeros((4, 5), np.float32)), ("mlp", "model_w0", np.zeros((5, 4, 1), np.float32)),
                ("mlp", "model_w1", np.zeros((4, 3), np.float32)), ("mlp", "model_b0", np.zeros(5, np.float32)),
                ("mlp", "model_b1", np.zeros((1, 2), np.float32)), ("mlp", "model_hidden", np.array([[4]])),
                ("mlp", "model_hyper", np.zeros(3)), ("lut", "model_table", np.zeros((8, 8, 8, 3), np.float32)),
                ("lut", "model_filled", np.ones((8, 8, 7), bool)), ("lut", "model_hyper", np.array([8.0]))]


@pytest.mark.parametrize(("model", "key", "value"), WRONG_SHAPES)
def test_a_model_array_of_the_wrong_shape_is_refused_naming_it(model: str, key: str, value: np.ndarray) -> None:
    """A calibration whose baked table is fine but whose model arrays do not fit the model's declared
    sizes is refused at load, not kept to fail (or answer wrongly) once the model is evaluated."""
    meta, arrays = _saved_arrays(model)
    good = GelSightCalibration.from_saved(meta, arrays, "cal.json", "cal.npz")  # the file as written loads
    assert good.model.kind == model
    with pytest.raises(CalibrationError, match=rf"cal\.npz: the model array {key} (has shape|is)"):
        GelSightCalibration.from_saved(meta, {**arrays, key: value}, "cal.json", "cal.npz")


@pytest.mark.parametrize(("model", "key"), [("mlp", "model_w0"), ("mlp", "model_b1"), ("lut", "model_table")])
def test_a_model_array_missing_or_not_finite_is_refused_naming_it(model: str, key: str) -> None:
    meta, arrays = _saved_arrays(model)
    with pytest.raises(CalibrationError, match=rf"cal\.npz: the model array {key} is missing"):
        GelSightCalibration.from_saved(meta, {k: v for k, v in arrays.items() if k != key}, "cal.json", "cal.npz")
    nan = arrays[key].astype(np.float32).copy()
    nan.flat[0] = np.nan
    with pytest.raises(CalibrationError, match=rf"cal\.npz: the model array {key} holds NaN"):
        GelSightCalibration.from_saved(meta, {**arrays, key: nan}, "cal.json", "cal.npz")


def test_a_saved_mlp_declaring_absurd_layers_is_refused_before_it_is_built() -> None:
    meta, arrays = _saved_arrays("mlp")
    with pytest.raises(CalibrationError, match=r"model_hidden is \[1000000000\]"):
        GelSightCalibration.from_saved(meta, {**arrays, "model_hidden": np.array([10**9])}, "cal.json", "cal.npz")

"""GelSight entry points at the extremes: a bounded result or a typed error naming the reason.

Flat, black, white, saturated, NaN/inf, one-pixel and huge inputs, +-180 deg and squashed (det R -> 0)
maps, through the calibration lookup, the integration, the reconstruction, the registration, the
tactile map and the CLI.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tactile_rig.cli import main
from tactile_rig.core.errors import (
    DegenerateTransform,
    GradientOutOfRange,
    HeightOutOfRange,
    NoContact,
    PerceptionError,
    SaturatedFrame,
)
from tactile_rig.perception.gelsight import (
    ContactParams,
    HeightMapper,
    Reconstructor,
    TactileMap,
    height_map_mm,
    register,
)
from tactile_rig.perception.gelsight.registration import DEGENERATE, NO_CONTACT, REASONS
from tactile_rig.perception.gelsight.synthetic import jig_move, tile
from tests._data import extreme_frame, taxim_calibration, taxim_presses, test_data

MM = 0.1245
PRESSES = test_data("taxim_gelsight_ball") / "presses"


@pytest.fixture(scope="module")
def presses():
    return taxim_presses()


@pytest.fixture(scope="module")
def rec():
    return Reconstructor(taxim_calibration("lut", 32))


@pytest.fixture(scope="module")
def textured(presses, rec):
    return tile([rec.height_mm(presses.frames[i]) for i in (0, 5, 11, 22)])


# -- reconstruction ------------------------------------------------------------------------------

@pytest.mark.parametrize("value", [0, 255])
def test_black_and_white_frames_are_saturated_not_heights(rec, value) -> None:
    frame = np.full_like(rec.calibration.background, value)
    with pytest.raises(SaturatedFrame, match="clipped") as err:
        rec.height_mm(frame)
    assert err.value.value > 0.99 and err.value.device == "gelsight.calibration"


def test_lights_off_frame_is_out_of_the_calibrated_range(rec) -> None:
    # Dark but not clipped: every colour far below the background's.
    frame = np.full_like(rec.calibration.background, 12)
    with pytest.raises((GradientOutOfRange, HeightOutOfRange)):
        rec.height_mm(frame)


def test_flat_frame_reads_zero(rec) -> None:
    z = rec.height_mm(rec.calibration.background.copy())
    assert np.all(z == 0.0)


def test_one_pixel_and_wrong_size_frames_are_value_errors(rec) -> None:
    with pytest.raises(ValueError, match="120x160"):
        rec.height_mm(np.zeros((1, 1, 3), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        rec.height_mm(np.full((120, 160, 3), np.nan, np.float32))


@settings(deadline=None, max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(["patch", "noise", "constant", "gain"]), st.integers(0, 255), st.integers(0, 2**31 - 1))
def test_any_frame_gives_a_bounded_height_or_a_typed_error(rec, kind, value, seed) -> None:
    rng = np.random.default_rng(seed)
    bg = rec.calibration.background
    frame = extreme_frame(bg, kind, value, rng)
    try:
        z = rec.height_mm(frame)
    except PerceptionError as exc:
        assert isinstance(exc, (SaturatedFrame, GradientOutOfRange, HeightOutOfRange))
        assert exc.value is not None and exc.limit is not None and exc.value > exc.limit
        return
    assert z.shape == bg.shape[:2] and np.isfinite(z).all()
    assert float(z.max() - z.min()) <= ContactParams().max_height_range_mm


def test_bad_contact_params_name_the_knob() -> None:
    with pytest.raises(ValueError, match="max_saturated_fraction"):
        ContactParams(max_saturated_fraction=1.5)
    with pytest.raises(ValueError, match="max_height_range_mm"):
        ContactParams(max_height_range_mm=0.0)


# -- integration ---------------------------------------------------------------------------------

@pytest.mark.parametrize("solver", ["dst", "dct", "fc"])
def test_huge_gradients_are_refused_not_integrated(solver) -> None:
    g = np.full((240, 320), 1e6, np.float32)
    with pytest.raises(GradientOutOfRange, match="max_slope") as err:
        height_map_mm(g, g, 0.0634, method=solver)
    assert err.value.value == pytest.approx(1e6) and err.value.limit == 20.0


@settings(deadline=None, max_examples=30)
@given(arrays(np.float32, (9, 11), elements=st.floats(-20, 20, width=32) | st.sampled_from(
    [np.nan, np.inf, -np.inf])), st.sampled_from(["dst", "dct", "fc"]), st.sampled_from([1, 2]))
def test_slopes_within_range_give_finite_bounded_heights(g, solver, downsample) -> None:
    z = HeightMapper(g.shape, MM, solver=solver, downsample=downsample).height_mm(g, g[::-1].copy())
    assert np.isfinite(z).all()
    assert np.abs(z).max() <= 20.0 * MM * (9 + 11) + 1e-3


def test_one_pixel_gradients_are_value_errors() -> None:
    with pytest.raises(ValueError, match="3x3"):
        height_map_mm(np.zeros((1, 1)), np.zeros((1, 1)), MM)


# -- registration --------------------------------------------------------------------------------

@pytest.mark.parametrize("fill", [0.0, 0.3, np.nan, np.inf])
def test_flat_or_unknown_maps_are_no_contact(textured, fill) -> None:
    flat = np.full((120, 160), fill, np.float32)
    res = register(textured, flat, MM)
    assert not res.ok and res.reason == NO_CONTACT and res.matrix_mm is None
    assert isinstance(res.error(), NoContact) and "no_contact" in str(res.error())


@pytest.mark.parametrize("peak", [1e3, 1e30])
def test_huge_heights_are_refused(textured, peak) -> None:
    z = textured.astype(np.float64) * (peak / 2.0)
    with pytest.raises(HeightOutOfRange) as err:
        register(textured, z, MM)
    assert err.value.limit == 50.0


def test_one_pixel_map_is_a_value_error(textured) -> None:
    with pytest.raises(ValueError, match="16x16"):
        register(textured, np.zeros((1, 1), np.float32), MM)


@pytest.mark.parametrize("rotation_deg", [180.0, -180.0, 179.0, -179.0])
def test_half_turns_register_with_the_wrapped_angle(textured, rotation_deg) -> None:
    b, truth = jig_move(textured, rotation_deg, (1.0, -1.0), MM)
    res = register(textured, b, MM)
    assert res.ok, res.reason
    true_rot = np.degrees(np.arctan2(truth[1, 0], truth[0, 0]))
    assert abs((res.rotation_deg - true_rot + 180.0) % 360.0 - 180.0) <= 0.2
    assert -180.0 < res.rotation_deg <= 180.0


def _squash(z: np.ndarray, s: float, angle_deg: float) -> np.ndarray:
    h, w = z.shape
    c = ((w - 1) / 2.0, (h - 1) / 2.0)
    rot = np.vstack([cv2.getRotationMatrix2D(c, angle_deg, 1.0), [0, 0, 1]])
    sq = np.array([[1.0, 0, 0], [0, s, (1 - s) * c[1]], [0, 0, 1]])
    return cv2.warpAffine(z, (sq @ rot)[:2], (w, h))


@pytest.mark.parametrize("s", [0.4, 0.2, 0.1, 0.03])
@pytest.mark.parametrize("angle_deg", [0.0, 30.0])
def test_squashed_map_is_a_degenerate_transform(textured, s, angle_deg) -> None:
    res = register(textured, _squash(textured, s, angle_deg), MM)
    assert not res.ok and res.reason == DEGENERATE, res.reason
    err = res.error()
    assert isinstance(err, DegenerateTransform) and "det R" in str(err)


def test_every_reason_is_explained() -> None:
    assert {NO_CONTACT, DEGENERATE, "insufficient_texture", "no_consensus", "low_confidence",
            "dense_check_failed"} <= set(REASONS)


@settings(deadline=None, max_examples=25, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.floats(-180, 180), st.floats(-8, 8), st.floats(-8, 8), st.sampled_from(["ok", "noise", "nan", "scaled"]))
def test_any_pair_is_right_or_refused(textured, rot, dx, dy, kind) -> None:
    b, truth = jig_move(textured, rot, (dx, dy), MM)
    rng = np.random.default_rng(int(abs(rot * 1000)) % 2**31)
    if kind == "noise":
        b = b + rng.normal(0, 0.01, b.shape).astype(np.float32)
    elif kind == "nan":
        b = b.copy()
        b[rng.random(b.shape) < 0.01] = np.nan
    elif kind == "scaled":
        b = b * 3.0
    res = register(textured, b, MM)
    if not res.ok:
        assert res.reason in REASONS and res.matrix_mm is None
        return
    assert np.isfinite(res.matrix_mm).all()
    true_rot = np.degrees(np.arctan2(truth[1, 0], truth[0, 0]))
    assert abs((res.rotation_deg - true_rot + 180.0) % 360.0 - 180.0) <= 1.0
    assert np.linalg.norm(res.translation_mm - truth[:, 2]) <= 0.1


# -- tactile map ---------------------------------------------------------------------------------

def test_map_refuses_flat_and_squashed_touches_with_their_reason(textured) -> None:
    tmap = TactileMap(MM)
    tmap.add_touch(textured)
    flat = tmap.add_touch(np.zeros_like(textured))
    assert not flat.accepted and flat.result.reason == NO_CONTACT
    squashed = tmap.localize(_squash(textured, 0.1, 0.0))
    assert not squashed.ok and squashed.reason == DEGENERATE
    assert len(tmap.poses) == 1


# -- CLI -----------------------------------------------------------------------------------------

def _last_json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_cli_map_and_localize_exit_1_when_they_refuse(tmp_path, capsys, textured) -> None:
    a, flat = tmp_path / "a.npy", tmp_path / "flat.npy"
    np.save(a, textured)
    np.save(flat, np.zeros_like(textured))
    mp = tmp_path / "m.npz"
    assert main(["gelsight", "map", str(a), str(flat), "--mm-per-px", str(MM), "-o", str(mp), "--json"]) == 1
    out = _last_json(capsys)
    assert out["rejected"] == 1 and out["touches"][1]["reason"] == NO_CONTACT and mp.exists()
    sq = tmp_path / "sq.npy"
    np.save(sq, _squash(textured, 0.1, 0.0))
    assert main(["gelsight", "localize", str(mp), str(sq), "--json"]) == 1
    assert _last_json(capsys)["reason"] == DEGENERATE
    assert main(["gelsight", "localize", str(mp), str(a), "--json"]) == 0


def test_cli_threshold_flags_reach_the_registration(tmp_path, capsys, textured) -> None:
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    np.save(a, textured)
    np.save(b, np.nan_to_num(jig_move(textured, 20, (1.0, 0.5), MM)[0]))  # the CLI loader takes finite heights
    base = ["gelsight", "register", str(a), str(b), "--mm-per-px", str(MM), "--json"]
    assert main(base) == 0
    capsys.readouterr()
    # A correlation bar no real pair can pass turns the same pair into a refusal.
    assert main(base + ["--min-ncc", "1.0", "--no-dense-fallback"]) == 1
    assert _last_json(capsys)["reason"] == "dense_check_failed"
    assert main(base + ["--min-inliers", "100000", "--no-dense-fallback"]) == 1


@pytest.mark.parametrize("sub", ["register", "map", "localize"])
def test_cli_documents_every_threshold(capsys, sub) -> None:
    with pytest.raises(SystemExit):
        main(["gelsight", sub, "--help"])
    text = capsys.readouterr().out
    for flag in ("--ransac-iters", "--inlier-px", "--min-inliers", "--min-confidence", "--min-ncc",
                 "--min-overlap", "--max-sigma-rot-deg", "--max-sigma-px", "--detect-short-px",
                 "--orb-features", "--min-rotation-pinning", "--search-max-sigma-px", "--no-dense-fallback"):
        assert flag in text, flag


def test_cli_height_of_a_black_frame_is_exit_2_one_line(tmp_path, capsys) -> None:
    cal = tmp_path / "cal"
    assert main(["gelsight", "calibrate", str(PRESSES), "--mm-per-px", str(MM), "--ball-radius-mm", "2.0",
                 "--method", "lut", "-o", str(cal)]) == 0
    black = tmp_path / "black.png"
    cv2.imwrite(str(black), np.zeros((120, 160, 3), np.uint8))
    capsys.readouterr()
    assert main(["gelsight", "height", str(cal), str(black), "-o", str(tmp_path / "z.npy")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "clipped" in err
    assert not (tmp_path / "z.npy").exists()

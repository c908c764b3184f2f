"""The FingerVision processor end to end on synthetic frames, and the CLI."""

from __future__ import annotations

import dataclasses
import json
import math

import cv2
import numpy as np
import pytest

from tactile_rig.cli import main
from tactile_rig.perception.fingervision import FingerVision, FingerVisionParams, FingerVisionResult, TrackerParams
from tests._fingervision_synth import Ellipse, angle_err, ellipse_mask, lattice, render

REST = lattice()


def _calibrated(params: FingerVisionParams = FingerVisionParams()) -> FingerVision:
    fv = FingerVision(params)
    for k in range(params.n_calib_frames):
        r = fv.process(render(REST, seed=k))
        assert r.calibrating and np.all(r.force_px == 0)
    assert fv.baseline is not None and fv.baseline.valid.all() and len(fv.baseline) == len(REST)
    return fv


@pytest.mark.parametrize("angle_deg", [0.0, 75.0, 160.0, -100.0])
def test_shear_direction_within_5_deg(angle_deg: float) -> None:
    fv = _calibrated()
    u = np.array([math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))])
    for k in range(1, 9):
        r = fv.process(render(REST + u * 0.25 * k, seed=20 + k, gain=1.0 + 0.1 * (-1) ** k))
    assert not r.calibrating and r.n_markers == len(REST)
    got = math.degrees(math.atan2(r.force_px[1], r.force_px[0]))
    assert abs((got - angle_deg + 180) % 360 - 180) <= 5.0
    assert r.contact  # 2 px of shear
    assert isinstance(r, FingerVisionResult) and r.force_px.shape == (3,) and r.torque_px2.shape == (3,)
    assert set(r.timings_ms) >= {"contrast", "track", "force", "proximity", "total"}


def test_object_orientation_and_slip_through_the_processor() -> None:
    fv = _calibrated()
    e0 = Ellipse(160, 120, 55, 25, 120.0)
    fv.learn_object(render(REST, obj=e0, seed=40), mask=ellipse_mask(e0))
    reports = []
    for k in range(8):
        off = (0.0, 0.0) if k < 4 else (1.0 * (k - 3), 0.0)
        e = Ellipse(e0.cx + off[0], e0.cy, e0.a, e0.b, e0.angle_deg)
        reports.append(fv.process(render(REST, obj=e, obj_texture_offset_px=off, seed=41 + k), t_s=k / 15))
    assert all(r.object_orientation_deg is not None and angle_err(r.object_orientation_deg, 120.0) <= 2.0
               for r in reports)
    assert [r.slip for r in reports] == [False] * 4 + [True] * 4
    assert abs(reports[-1].slip_direction_deg) <= 10.0
    assert reports[-1].slip_magnitude == reports[-1].slip_magnitude_px == pytest.approx(1.0, abs=0.3)


@pytest.mark.parametrize("level", [0, 255])
def test_black_or_saturated_frame_loses_markers_without_nan(level: int) -> None:
    fv = _calibrated()
    p = fv.params.tracker
    for _ in range(p.n_reset):
        r = fv.process(np.full((240, 320, 3), level, np.uint8))
    assert r.n_markers == 0 and not r.marker_valid.any()
    assert np.all(r.force_px == 0) and np.all(r.torque_px2 == 0) and not r.contact
    assert r.object_area_px == 0 and r.object_centroid_px is None and not r.slip


def test_calibrate_explicitly_and_frame_shape_checks() -> None:
    fv = FingerVision(FingerVisionParams(n_calib_frames=3))
    base = fv.calibrate([render(REST, seed=s) for s in range(3)])
    assert len(base) == len(REST)
    r = fv.process(render(REST, seed=9))
    assert not r.calibrating and r.n_markers == len(REST)
    assert not r.contact and np.linalg.norm(r.force_px) < 0.1  # nothing moved
    with pytest.raises(ValueError, match="frame shape"):
        fv.process(np.zeros((120, 160, 3), np.uint8))
    with pytest.raises(ValueError, match="at least one frame"):
        fv.calibrate([])


def test_params_from_mapping() -> None:
    p = FingerVisionParams.from_mapping({"n_calib_frames": 4, "tracker": {"use_kalman": False, "n_reset": 5}})
    assert p.n_calib_frames == 4 and p.tracker == dataclasses.replace(TrackerParams(), use_kalman=False, n_reset=5)
    with pytest.raises(ValueError, match="unknown key 'bogus'"):
        FingerVisionParams.from_mapping({"bogus": 1})
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['nope'\] in \[tracker\]"):
        FingerVisionParams.from_mapping({"tracker": {"nope": 1}})


# -- CLI ---------------------------------------------------------------------------------------------

def _write_frames(folder, n: int = 6) -> None:
    folder.mkdir()
    for k in range(n):
        shift = [0.0, 0.0] if k < 3 else [1.0, 0.0]
        cv2.imwrite(str(folder / f"f{k:03d}.png"), render(REST + shift, seed=k))


def test_cli_track_folder_json(tmp_path, capsys) -> None:
    _write_frames(tmp_path / "frames")
    cfg = tmp_path / "fv.toml"
    cfg.write_text("n_calib_frames = 3\n[tracker]\nuse_kalman = false\n")
    assert main(["fingervision", "track", str(tmp_path / "frames"), "--config", str(cfg), "--json"]) == 0
    lines = [json.loads(s) for s in capsys.readouterr().out.splitlines()]
    assert len(lines) == 6
    assert [d["calibrating"] for d in lines] == [True] * 3 + [False] * 3
    last = lines[-1]
    assert last["marker_count"] == len(REST) and len(last["markers"]) == len(REST)
    assert last["force_px"][0] == pytest.approx(1.0, abs=0.1) and abs(last["force_px"][1]) < 0.1
    assert {"area_px", "centroid_px", "orientation_deg"} <= set(last["object"])
    assert last["slip"] is False


def test_cli_glob_video_and_errors(tmp_path, capsys) -> None:
    _write_frames(tmp_path / "frames", 4)
    cfg = tmp_path / "fv.json"
    cfg.write_text(json.dumps({"n_calib_frames": 2}))
    assert main(["fingervision", "track", str(tmp_path / "frames" / "*.png"), "--config", str(cfg), "--json"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 4
    video = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 15, (320, 240))
    for k in range(4):
        vw.write(render(REST, seed=k))
    vw.release()
    assert main(["fingervision", "track", str(video), "--calib-frames", "2", "--fps", "15"]) == 0
    out = [ln for ln in capsys.readouterr().out.splitlines() if not ln.startswith("calibration:")]
    assert len(out) == 4 and "markers" in out[-1]
    assert main(["fingervision", "track", str(tmp_path / "nothing_here")]) == 2
    bad = tmp_path / "bad.toml"
    bad.write_text("[tracker]\nwindow = 3\n")
    assert main(["fingervision", "track", str(tmp_path / "frames"), "--config", str(bad)]) == 2
    assert "window" in capsys.readouterr().err


def test_cli_init_flag_selects_lattice_ids_or_ids_after_the_baseline_frames(tmp_path, capsys) -> None:
    for k in range(4):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), render(REST, seed=k))
    assert main(["fingervision", "track", str(tmp_path), "--calib-frames", "2", "--no-calibration", "--json"]) == 0
    lattice_ = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert all(d["marker_count"] == len(REST) and all(m["id"] >= 0 for m in d["markers"]) for d in lattice_)
    assert main(["fingervision", "track", str(tmp_path), "--calib-frames", "2", "--init", "frames", "--no-calibration",
                 "--json"]) == 0
    frames_ = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [all(m["id"] < 0 for m in d["markers"]) for d in frames_] == [True, True, False, False]
    with pytest.raises(SystemExit) as exc:  # argparse's usage error
        main(["fingervision", "track", str(tmp_path), "--init", "grid"])
    assert exc.value.code == 2

"""Calibration sessions on the mocks: GelSight ball presses with the jig, scale, gripper, FingerVision."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from tactile_rig.core.errors import CalibrationError, DeviceTimeout
from tactile_rig.rig.calibration_sessions import (
    BallPressPlan,
    Guide,
    collect_ball_presses,
    press_positions,
    read_calibration,
    wait_for_load,
    write_calibration,
)
from tactile_rig.rig.jig_accuracy import DeviceJigRig, connect_mock_jig_rig, prepare_jig
from tactile_rig.sim.scenes import GELSIGHT_BALL_PRESS_SCENE


def test_press_grid_and_plan_validation():
    pts = press_positions(BallPressPlan(grid_x_mm=(-1, 1, 3), grid_y_mm=(0, 2, 2)))
    assert pts == [(-1.0, 0.0), (0.0, 0.0), (1.0, 0.0), (-1.0, 2.0), (0.0, 2.0), (1.0, 2.0)]
    assert BallPressPlan(ball_radius_mm=2.0, press_depth_mm=0.6).contact_radius_mm == pytest.approx(1.4283, abs=1e-4)
    with pytest.raises(ValueError, match="press_depth_mm"):
        BallPressPlan(press_depth_mm=3.0)
    with pytest.raises(ValueError, match="at least 3 presses"):
        BallPressPlan(grid_x_mm=(0, 0, 1), grid_y_mm=(0, 0, 2))
    with pytest.raises(ValueError, match="method"):
        BallPressPlan(method="svm")


def test_calibration_file_envelope(tmp_path):
    path, rpath = write_calibration(tmp_path / "scale", "scale", {"cal_factor_counts_per_g": 700.5},
                                    {"verify_error_g": 0.01}, device="scale@x")
    assert path.suffix == ".json" and rpath.exists() and (tmp_path / "scale.report.md").exists()
    assert read_calibration(path, "scale") == {"cal_factor_counts_per_g": 700.5}
    with pytest.raises(CalibrationError, match="not a gripper calibration"):
        read_calibration(path, "gripper")
    doc = json.loads(path.read_text())
    doc["version"] = 99
    path.write_text(json.dumps(doc))
    with pytest.raises(CalibrationError, match="version 99"):
        read_calibration(path, "scale")
    path.write_text("{not json")
    with pytest.raises(CalibrationError, match="not a readable"):
        read_calibration(path, "scale")
    with pytest.raises(CalibrationError, match="does not exist.*calibrate scale"):
        read_calibration(tmp_path / "missing.json", "scale")
    with pytest.raises(ValueError, match="envelope"):
        write_calibration(tmp_path / "bad", "scale", {"version": 2}, {})


class _NoStdin:
    def isatty(self) -> bool:
        return False

    def readline(self) -> str:  # a scripted session must never wait for input
        raise AssertionError("read stdin")


def test_guide_prompts_only_on_a_terminal():
    err = io.StringIO()
    g = Guide(None, stream=err, stdin=_NoStdin())
    assert not g.interactive
    g.step("place the mass")
    assert "[step] place the mass" in err.getvalue()
    tty_in = io.StringIO("\n")
    g2 = Guide(True, stream=io.StringIO(), stdin=tty_in)
    g2.step("press it")
    assert tty_in.tell() == 1  # the Enter was consumed


# -- GelSight on the mock jig ------------------------------------------------------------------
def test_ball_presses_with_the_jig_measure_an_offset_ball(tmp_path):
    """A ball that is not centred on the jig (as on a real bench) is found from the frames."""
    rig = connect_mock_jig_rig(scene=GELSIGHT_BALL_PRESS_SCENE, seed=1)
    try:
        prepare_jig(rig.jig)
        ball = rig.world.require("object")
        ball.x_mm, ball.y_mm = 1.0, -0.5
        press_rig = DeviceJigRig(rig.jig, rig.devices["camera"], rig.clock, world=rig.world, settle_s=0.05)
        plan = BallPressPlan(grid_x_mm=(-4, 4, 3), grid_y_mm=(-3, 3, 2))
        presses = collect_ball_presses(press_rig, plan, 0.0634, tmp_path / "presses")
    finally:
        rig.close()
    assert presses.offset_px == pytest.approx((1.0 / 0.0634, -0.5 / 0.0634), abs=0.5)
    assert len(presses.frames) == 6
    labels = (tmp_path / "presses" / "labels.csv").read_text().splitlines()
    assert labels[0] == "file,center_x_px,center_y_px,contact_radius_px" and len(labels) == 7
    # The labelled centre of the first press is the jig position plus the ball's offset.
    x0, y0 = press_positions(plan)[0]
    assert presses.centers_px[0][0] == pytest.approx(159.5 + (x0 + 1.0) / 0.0634, abs=0.5)
    assert presses.centers_px[0][1] == pytest.approx(119.5 + (y0 - 0.5) / 0.0634, abs=0.5)
    from tactile_rig.perception.gelsight.calibration import load_presses

    again = load_presses(tmp_path / "presses")
    assert len(again.frames) == 6 and np.array_equal(again.frames[0], presses.frames[0])


def test_presses_without_contact_are_refused():
    rig = connect_mock_jig_rig(scene=GELSIGHT_BALL_PRESS_SCENE, seed=0)
    try:
        prepare_jig(rig.jig)
        rig.world.require("object").press_depth_mm = 0.0  # the ball never touches the gel
        press_rig = DeviceJigRig(rig.jig, rig.devices["camera"], rig.clock, world=rig.world, settle_s=0.05)
        with pytest.raises(CalibrationError, match="show a contact"):
            collect_ball_presses(press_rig, BallPressPlan(grid_x_mm=(-2, 2, 2), grid_y_mm=(-2, 2, 2)), 0.0634)
    finally:
        rig.close()


def test_gelsight_session_cli_writes_a_versioned_calibration_and_report(tmp_path, capsys):
    from tactile_rig.cli import main
    from tactile_rig.perception.gelsight.calibration import FORMAT_VERSION, GelSightCalibration

    out = tmp_path / "gelsight"
    assert main(["calibrate", "gelsight", "--mock", "--out", str(out), "--grid-x", "-6", "6", "4",
                 "--grid-y", "-4", "4", "3", "--json"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["kind"] == "gelsight" and res["values"]["presses"] == 12
    meta = json.loads((tmp_path / "gelsight.json").read_text())
    assert meta["version"] == FORMAT_VERSION and meta["extra"]["session"] == "jig ball presses"
    cal = GelSightCalibration.load(out)
    assert cal.shape == (240, 320)
    # Held-out presses reconstruct close to the true sphere caps.
    assert res["values"]["heldout_mean_normal_deg"] < 10.0
    assert res["values"]["heldout_mean_height_rms_mm"] < 0.08
    assert abs(res["values"]["ball_offset_px"][0]) < 0.5 and abs(res["values"]["ball_offset_px"][1]) < 0.5
    assert (tmp_path / "gelsight.report.md").exists() and (tmp_path / "gelsight_presses" / "labels.csv").exists()
    from tactile_rig.rig.recording import read_recording

    rec = read_recording(res["files"]["recording"])
    assert len([m for m in rec.on("/jig/pose") if m.data["purpose"] == "press"]) == 12
    assert {"calibration/gelsight/gelsight-v1.json", "calibration/gelsight/gelsight-v1.npz"} <= set(rec.attachments)


# -- scale, gripper, FingerVision through the CLI ---------------------------------------------------
def test_scale_session_on_the_mock(tmp_path, capsys):
    from tactile_rig.cli import main

    out = tmp_path / "scale.json"
    assert main(["calibrate", "scale", "--mock", "--known-mass-g", "200", "--out", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    values = read_calibration(out, "scale")
    assert values["known_mass_g"] == 200.0
    # the mock bench's load cell has the sketch's default factor: the session must find it, not any factor
    from tactile_rig.devices.scale import DEFAULT_CAL_FACTOR

    assert values["cal_factor_counts_per_g"] == pytest.approx(DEFAULT_CAL_FACTOR, rel=0.005)
    assert abs(res["values"]["verify_error_g"]) < 0.5
    assert res["values"]["empty_noise_g"] < 1.0


def test_scale_without_a_mass_times_out():
    from tactile_rig.core.clock import VirtualClock
    from tactile_rig.rig.bench import Bench, connect_bench, load_bench, mock_bench_path

    base = load_bench(mock_bench_path(), check_files=False)
    rig = connect_bench(Bench("mock", {"scale": base.devices["scale"]}, source=base.source), clock=VirtualClock())
    try:
        rig.scale.tare()
        with pytest.raises(DeviceTimeout, match="place the known mass"):
            wait_for_load(rig.scale, 0.0, 0.01, timeout_s=1.0)
    finally:
        rig.close()


def test_gripper_session_file_is_read_by_the_gripper_driver(tmp_path, capsys):
    from tactile_rig.cli import main
    from tactile_rig.drivers.dynamixel.gripper import GripperCalibration

    out = tmp_path / "gripper.json"
    assert main(["calibrate", "gripper", "--mock", "--out", str(out), "--max-opening-m", "0.08"]) == 0
    assert "closed" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    cal = GripperCalibration.from_dict(doc)
    assert cal.open_ticks - cal.closed_ticks > 500 and cal.max_opening_m == 0.08
    assert doc["report"]["span_ticks"] == cal.open_ticks - cal.closed_ticks


def test_fingervision_session_on_the_mock(tmp_path, capsys):
    from tactile_rig.cli import main

    out = tmp_path / "fv"
    assert main(["calibrate", "fingervision", "--mock", "--frames", "4", "--out", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["values"]["valid_markers"] >= 10
    assert res["values"]["median_marker_jitter_px"] < 0.5
    with np.load(tmp_path / "fv.npz") as d:
        assert d["positions_px"].shape == (res["values"]["markers"], 2) and d["bg_hist"].size > 0
    assert read_calibration(tmp_path / "fv.json", "fingervision")["frame_shape"] == [240, 320]


# -- every session records what it measured, and never overwrites a calibration ------------------
def test_scale_session_records_its_readings_and_adds_a_version(tmp_path, capsys):
    from tactile_rig.cli import main
    from tactile_rig.rig.recording import read_recording

    out = tmp_path / "scale.json"
    for _ in range(2):
        assert main(["calibrate", "scale", "--mock", "--known-mass-g", "100", "--out", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["calibration"].endswith("scale-v2.json") and (tmp_path / "scale-v1.json").is_file()
    rec = read_recording(res["files"]["recording"])
    phases = {m.data["phase"] for m in rec.on("/scale/force")}
    assert phases == {"empty", "settling", "verify"}
    verify = [m.data["grams"] for m in rec.on("/scale/force") if m.data["phase"] == "verify"]
    assert abs(np.mean(verify) - 100.0) < 0.5  # the recording holds the readings the check was made on
    assert [m.data["command"] for m in rec.on("/command/scale")] == ["tare", "calibrate"]
    assert "calibration/scale/scale-v2.json" in rec.attachments and "bench.toml" in rec.attachments


def test_fingervision_session_records_frames_and_attaches_json_and_npz(tmp_path, capsys):
    from tactile_rig.cli import main
    from tactile_rig.rig.recording import read_recording

    assert main(["calibrate", "fingervision", "--mock", "--frames", "3", "--out", str(tmp_path / "fv"),
                 "--json"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    rec = read_recording(res["files"]["recording"])
    frames = [m for m in rec.messages if m.topic.endswith("compressed")]
    assert len(frames) == 3 and frames[0].image().shape == (240, 320, 3)
    assert {"calibration/fingervision/fv-v1.json", "calibration/fingervision/fv-v1.npz"} <= set(rec.attachments)

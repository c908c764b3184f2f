"""Calibrations are used: the bench names them per camera and every consumer loads them by default."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

import mcap  # noqa: F401  (extras installed by .[all,test]: absent = fail, not skip)
import sklearn  # noqa: F401

from tactile_rig.core.errors import BenchError, CalibrationError
from tactile_rig.core.types import TouchReading
from tactile_rig.rig.bench import load_bench
from tactile_rig.rig.calibration_sessions import fingervision_session
from tactile_rig.rig.camera_calibrations import (
    CalibratedFingerVision,
    camera_calibrations,
    load_fingervision_calibration,
)
from tactile_rig.rig.learning import fit_force_map, load_force_map, load_substance_model
from tactile_rig.sim.render.fingervision import FingerVisionRenderer, contact_shear_field


class _RenderedCamera:
    """A camera that returns rendered FingerVision frames: at rest, or pressed (``load`` 0..1 of
    10 N, with a shear of 4 px per unit load)."""

    name = "left"

    def __init__(self) -> None:
        self.renderer = FingerVisionRenderer((240, 320), seed=3)
        self.load = 0.0
        self.t_s = 0.0

    def frame(self) -> np.ndarray:
        field = None
        if self.load > 0:
            field = lambda p: contact_shear_field(p, (159.5, 119.5), shift_px=(0.0, 4.0 * self.load),  # noqa: E731
                                                  radius_px=110)
        return self.renderer.render(field, normal_load=self.load)[0]

    def read(self, timeout_s: float = 1.0) -> np.ndarray:
        self.t_s += 0.05
        return self.frame()


PRESS = tuple(np.linspace(0.025, 0.5, 20))  # load rising 0.25 N a frame, as the force map was taught


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("calib")
    fingervision_session(_RenderedCamera(), d / "fingervision", frames=6)
    # A force map of this rendered fingertip: 10 N at full load (what a press on the scale teaches).
    fv = load_fingervision_calibration(d / "fingervision.json").processor()
    cam, X, y = _RenderedCamera(), [], []
    for load in np.linspace(0.0, 0.8, 33):
        cam.load = float(load)
        r = fv.process(cam.frame())
        X.append(np.r_[r.force_px, r.torque_px2])
        y.append(10.0 * load)
    fit_force_map(np.array(X), np.array(y)).save(d / "force_map" / "force_map")
    from tactile_rig.rig.learning import substance_session

    substance_session(d / "substance", per_substance=4, figures=False)
    return {"dir": d, "fv": d / "fingervision.json", "fm": d / "force_map", "sub": d / "substance"}


def _bench(tmp_path: Path, files: dict[str, Path], **extra: str) -> Path:
    keys = {"calibration": str(files["fv"]), "force_map": str(files["fm"]), "substance_model": str(files["sub"])}
    keys.update(extra)
    body = "\n".join(f'{k} = "{v}"' for k, v in keys.items())
    p = tmp_path / "bench.toml"
    p.write_text(f'[camera_left]\nport = "rigsim://camera"\nsensor = "fingervision"\n{body}\n')
    return p


def test_the_bench_names_each_cameras_files_relative_to_itself(tmp_path, files):
    (tmp_path / "calib").symlink_to(files["dir"])
    b = load_bench(_bench(tmp_path, files, force_map="calib/force_map", substance_model="calib/substance"))
    cam = b.cameras["camera_left"]
    assert cam.force_map == tmp_path / "calib/force_map" and cam.substance_model == tmp_path / "calib/substance"
    cal = camera_calibrations(b, load=("calibration", "force_map", "substance_model"))
    assert cal.camera == "camera_left" and cal.force_map is not None and cal.substance is not None
    assert len(cal.calibration.baseline) == np.load(files["dir"] / "fingervision.npz")["positions_px"].shape[0]


def test_a_missing_model_file_names_the_command_that_makes_it(tmp_path, files):
    with pytest.raises(BenchError, match=r"force_map file .*nowhere.* does not exist; make it with: "
                                         r"tactile-rig calibrate force-map"):
        load_bench(_bench(tmp_path, files, force_map="nowhere"))
    with pytest.raises(CalibrationError, match="calibrate substance"):
        load_substance_model(tmp_path / "absent")


def test_force_map_gives_the_magnitude_and_the_markers_the_direction(files):
    fm = load_force_map(files["fm"])
    x = fm.x_fit[-1] * fm.scale + fm.center  # a training sample of the heaviest press
    f_px, tq = x[:3], x[3:]
    f_n, tq_n, mag = fm.to_newtons(f_px, tq)
    assert mag == pytest.approx(max(0.0, fm.predict(np.r_[f_px, tq][None])[0]))
    assert mag == pytest.approx(8.0, abs=0.5)
    assert np.linalg.norm(f_n) == pytest.approx(mag) and np.allclose(f_n / mag, f_px / np.linalg.norm(f_px))
    assert np.all(fm.to_newtons(np.zeros(3), np.zeros(3))[0] == 0.0)


def test_stored_baseline_is_tracked_from_the_first_frame(files):
    cal = load_fingervision_calibration(files["fv"])
    assert cal.version == 1 and cal.frame_shape == (240, 320) and cal.bg_hist is not None
    fv = cal.processor()
    r = fv.process(_RenderedCamera().frame(), 0.0)
    assert not r.calibrating and r.n_markers >= 0.9 * int(np.count_nonzero(cal.baseline.valid))
    assert np.linalg.norm(r.force_px) < 0.3  # a frame at rest against the stored rest positions


def test_calibrated_sensor_reads_newtons_for_the_controllers_and_the_recording(tmp_path, files):
    from tactile_rig.control.common import as_touch
    from tactile_rig.rig.recording import Recorder, read_recording

    cam = _RenderedCamera()
    cal = camera_calibrations(None, calibration=files["fv"], force_map=files["fm"])
    with Recorder(tmp_path / "r.mcap") as rec:
        sensor = CalibratedFingerVision(cam, cal, mm_per_px=0.1, recorder=rec)
        rest = sensor.read(1.0)
        for load in PRESS:  # a press builds up over frames, as in the force map's session
            cam.load = load
            pressed = sensor.read(1.0)
    assert isinstance(pressed, TouchReading) and as_touch(pressed) is pressed
    fm = cal.force_map
    d = sensor.last
    assert pressed.force_n == pytest.approx(tuple(fm.to_newtons(d["force_px"], d["torque_px2"])[0]))
    assert np.linalg.norm(pressed.force_n) == pytest.approx(5.0, abs=1.0)
    assert np.linalg.norm(rest.force_n) < 0.7
    msgs = read_recording(tmp_path / "r.mcap").on("/perception/left")
    assert len(msgs) == 1 + len(PRESS)
    assert msgs[-1].data["force_map_n"] == pytest.approx(np.linalg.norm(pressed.force_n))


def test_track_uses_the_stored_baseline_and_reports_newtons(tmp_path, files, capsys):
    from tactile_rig.cli import main

    cam = _RenderedCamera()
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, load in enumerate((0.0, *PRESS)):
        cam.load = load
        cv2.imwrite(str(frames / f"{i:03d}.png"), cam.frame())
    assert main(["fingervision", "track", str(frames), "--calibration", str(files["fv"]),
                 "--force-map", str(files["fm"]), "--json"]) == 0
    recs = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert not any(r["calibrating"] for r in recs)  # no frames spent rebuilding the baseline
    assert all("force_n" in r for r in recs)
    assert recs[0]["force_map_n"] < 0.7 and recs[-1]["force_map_n"] == pytest.approx(5.0, abs=1.0)
    assert np.linalg.norm(recs[-1]["force_n"]) == pytest.approx(recs[-1]["force_map_n"])
    # without files the baseline is rebuilt from the first frames and forces stay in px
    assert main(["fingervision", "track", str(frames), "--no-calibration", "--calib-frames", "2", "--json"]) == 0
    recs = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert recs[0]["calibrating"] and "force_n" not in recs[-1]


def test_substance_predict_names_the_recorded_substances(tmp_path, files, capsys):
    from tactile_rig.cli import main
    from tactile_rig.rig.learning import record_stirring_session
    from tactile_rig.sim.world.stirring import StirringScene

    rec = record_stirring_session(tmp_path / "stir.mcap", StirringScene().trials(2, seed=99))
    assert main(["substance", "predict", "--from-recording", str(rec), "--model", str(files["sub"]), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    trials = out["trials"]
    assert len(trials) == 2 * len(out["classes"])
    assert np.mean([t["substance"] == t["true_label"] for t in trials]) >= 0.75
    # the bench's substance_model is the default
    bench = _bench(tmp_path, files)
    assert main(["substance", "predict", "--from-recording", str(rec), "--bench", str(bench), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["model"] == str(files["sub"])
    assert main(["substance", "predict", "--from-recording", str(rec), "--model", str(tmp_path / "no")]) == 2


def test_a_baseline_of_another_frame_size_is_refused(tmp_path, files):
    from tactile_rig.cli import main

    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((120, 160, 3), np.uint8))
    assert main(["fingervision", "track", str(tmp_path / "small.png"), "--calibration", str(files["fv"])]) == 2
    cal = load_fingervision_calibration(files["fv"])
    with pytest.raises(CalibrationError, match="baseline is for 320x240 frames, this camera gives 160x120"):
        cal.check_frame(np.zeros((120, 160, 3), np.uint8))


def test_substance_predict_from_frames_tracks_them_with_the_stored_baseline(tmp_path, files, capsys):
    from tactile_rig.cli import main

    cam = _RenderedCamera()
    frames = tmp_path / "stir"
    frames.mkdir()
    for i in range(24):  # 2.4 s at 10 frames/s: one 2 s window
        cam.load = 0.1 + 0.05 * np.sin(i)
        cv2.imwrite(str(frames / f"{i:03d}.png"), cam.frame())
    # without a stored baseline the first 10 frames build one: 1.4 s tracked, short of a 2 s window
    assert main(["substance", "predict", str(frames), "--fps", "10", "--model", str(files["sub"]), "--json"]) == 2
    assert "shorter than one 2 s window" in capsys.readouterr().err
    bench = _bench(tmp_path, files)
    assert main(["substance", "predict", str(frames), "--fps", "10", "--bench", str(bench), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    (trial,) = out["trials"]
    assert trial["windows"] == 1 and trial["substance"] in out["classes"]
    assert main(["substance", "predict", str(frames), "--model", str(files["sub"])]) == 2  # no --fps


def test_a_bench_recording_attaches_the_cameras_models(tmp_path, files):
    from tactile_rig.rig.bench_record import record_bench
    from tactile_rig.rig.recording import read_recording

    bench = load_bench(text=f'[camera_left]\nport = "rigsim://camera"\nsensor = "fingervision"\n'
                            f'force_map = "{files["fm"]}"\nsubstance_model = "{files["sub"]}"\n')
    record_bench(bench, 0.2, tmp_path / "r.mcap")
    att = set(read_recording(tmp_path / "r.mcap").attachments)
    assert {"calibration/camera_left.force_map/force_map.json", "calibration/camera_left.force_map/force_map.npz",
            "calibration/camera_left.substance_model/substance.json",
            "calibration/camera_left.substance_model/substance.npz"} <= att

"""The rehearsal bench's parts on their own: the MJPEG-over-HTTP camera (server and driver, and a
rehearsal serving its cameras that way), the camera modes a rehearsal asks of its camera model,
recorded footage at its recorded rate, the bench file, and the command line's checks of its input."""

from __future__ import annotations

import json

import cv2
import mcap  # noqa: F401  (the record extra writes the recording)
import numpy as np
import pytest

import tactile_rig.cli as cli
from tactile_rig.cli import main
from tactile_rig.cli.bench import parse_camera_option, parse_model_option
from tactile_rig.core.clock import RealClock, VirtualClock
from tactile_rig.core.errors import ControlReadbackError, NotConnected
from tactile_rig.drivers.camera import FingertipCamera
from tactile_rig.drivers.camera_http import HttpCameraSource
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.rig.bench import load_bench
from tactile_rig.rig.bench_check import check_bench
from tactile_rig.rig.recording import Recorder, read_recording
from tactile_rig.devices.camera_models import C310, DIGIT, GELSIGHT_MINI
from tactile_rig.rig.rehearsal import CameraServer, RehearsalBench, RehearsalOptions, load_footage
from tactile_rig.rig.rehearsal.bench_file import RehearsalDevice, bench_toml
from tactile_rig.rig.rehearsal.cameras import check_mode, footage_mode

MODE = ("MJPG", 160, 120)


@pytest.fixture()
def served_camera():
    sim = SimulatedCamera(None, clock=RealClock(), name="sim", fourcc="MJPG", width=160, height=120, fps=30.0,
                          modes={MODE: 30.0})
    with CameraServer(sim) as server:
        yield server


def test_the_http_camera_sets_its_format_and_reads_controls_back(served_camera) -> None:
    src = HttpCameraSource(served_camera.url, name="cam")
    src.open()
    try:
        assert src.set_format("MJPG", 160, 120, 30.0) == ("MJPG", 160, 120, 30.0)
        assert src.set_format("MJPG", 640, 480, 30.0)[1:3] == (160, 120)  # a camera snaps to its mode
        assert src.set_control("auto_exposure", 3) and src.get_control("auto_exposure") == 3
        assert not src.set_control("exposure_time_absolute", 200)  # inactive while auto exposure is on
        assert src.set_control("exposure_auto", 1)  # the old kernel name is the same control
        assert src.set_control("exposure_time_absolute", 200) and src.get_control("exposure_time_absolute") == 200
        assert src.get_control("no_such_control") is None
        assert src.controls()["exposure_time_absolute"] == 200
        frames = [src.read(2.0) for _ in range(5)]
    finally:
        src.close()
    assert all(f is not None and f.image.shape == (120, 160, 3) for f in frames)
    seqs = [f.device_seq for f in frames]
    assert seqs == sorted(seqs) and len(set(seqs)) == 5
    assert [f.t_device_s for f in frames] == sorted(f.t_device_s for f in frames)


def test_the_camera_driver_opens_an_http_url_and_verifies_its_format(served_camera) -> None:
    with FingertipCamera(served_camera.url, name="cam", width=160, height=120, fps=30.0) as cam:
        assert isinstance(cam.source, HttpCameraSource)
        assert cam.read(2.0).image.shape == (120, 160, 3)
        cam.close()
    with pytest.raises(ControlReadbackError, match="320x240"):
        FingertipCamera(served_camera.url, name="cam", width=320, height=240, fps=30.0).open()


def test_a_camera_that_is_not_served_is_not_connected() -> None:
    with CameraServer(SimulatedCamera(None, width=160, height=120, modes={MODE: 30.0})) as server:
        url = server.url
    with pytest.raises(NotConnected, match="does not answer"):
        HttpCameraSource(url, name="gone").open()
    with pytest.raises(ValueError, match="http://HOST:PORT"):
        HttpCameraSource("rtsp://127.0.0.1/x")


def test_bench_check_reports_a_dead_camera_with_its_port(served_camera) -> None:
    dead = served_camera.url.rsplit(":", 1)[0] + ":1/stream.mjpg"
    bench = load_bench(text=f'[camera]\nport = "{served_camera.url}"\nwidth = 160\nheight = 120\nfps = 30.0\n'
                            f'[camera_b]\nport = "{dead}"\nwidth = 160\nheight = 120\nfps = 30.0\n')
    rows = {r.device: r for r in check_bench(bench)}
    assert rows["camera"].ok and rows["camera"].details["controls"]["gain"] == 64
    assert not rows["camera_b"].ok and ":1" in rows["camera_b"].problem


def _video(path, n: int, fps: float):
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (64, 48))
    for k in range(n):
        w.write(np.full((48, 64, 3), 10 + 20 * k, np.uint8))
    w.release()
    return path


def test_video_footage_plays_at_its_recorded_rate_and_loops(tmp_path) -> None:
    f = load_footage(str(_video(tmp_path / "v.avi", 12, 10.0)))
    assert len(f.frames) == 12 and f.fps == pytest.approx(10.0) and f.size_px == (64, 48)
    level = [float(f.render(t).mean()) for t in (0.05, 0.15, 1.15, 1.25)]
    assert level[0] == pytest.approx(10, abs=3) and level[1] == pytest.approx(30, abs=3)
    assert level[2] == pytest.approx(230, abs=3) and level[3] == pytest.approx(10, abs=3)  # 1.2 s loop


def test_mcap_footage_keeps_the_recorded_times(tmp_path) -> None:
    clock = VirtualClock()
    with Recorder(tmp_path / "r.mcap", clock=clock) as rec:
        for k in range(5):
            rec.write_frame("left", np.full((8, 8, 3), 50 * k, np.uint8), compress="png")
            rec.write_scale(1.0)
            clock.sleep(0.2)
    f = load_footage(str(tmp_path / "r.mcap"))
    assert len(f.frames) == 5 and f.fps == pytest.approx(5.0)
    assert f.render(0.45).mean() == 100 and f.render(0.85).mean() == 200
    assert load_footage(f"{tmp_path / 'r.mcap'}#/left/image/compressed").fps == pytest.approx(5.0)
    with pytest.raises(ValueError, match="image topics: /left/image/compressed"):
        load_footage(f"{tmp_path / 'r.mcap'}#/right/image/compressed")


def test_footage_that_is_not_there_or_not_video(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_footage(str(tmp_path / "missing.mp4"))
    (tmp_path / "notes.txt").write_text("not a video")
    with pytest.raises(ValueError, match="OpenCV cannot decode|no frames"):
        load_footage(str(tmp_path / "notes.txt"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no images"):
        load_footage(str(tmp_path / "empty"))


def test_the_bench_file_loads_as_a_bench(tmp_path) -> None:
    text = bench_toml("r", [RehearsalDevice("scale", {"port": "/dev/null", "baud": 57600, "rate_hz": 80.0}),
                            RehearsalDevice("jig", {"port": "/dev/null", "x_limits_mm": [-20.0, 20.0]}, "GRBL")],
                      header="two lines\nof header")
    bench = load_bench(text=text)
    assert list(bench.devices) == ["scale", "jig"] and bench.name == "r"
    assert bench.devices["jig"].x_limits_mm == (-20.0, 20.0) and bench.devices["scale"].rate_hz == 80.0


@pytest.mark.parametrize("text, expected", [
    ("fv=demo.mp4", ("fv", "demo.mp4", "fingervision")),
    ("left=run.mcap#/left/image/compressed@gelsight", ("left", "run.mcap#/left/image/compressed", "gelsight")),
    ("fv=me@lab.avi", ("fv", "me@lab.avi", "fingervision")),
])
def test_camera_options(text, expected) -> None:
    assert parse_camera_option(text) == expected


def test_bad_rehearsal_options_are_refused(capsys) -> None:
    with pytest.raises(ValueError, match="sensor"):
        RehearsalOptions(camera_sensors={"a": "digit"})
    with pytest.raises(ValueError, match="not 'gelsight'"):
        RehearsalOptions(cameras={"gelsight": "x.mp4"})
    with pytest.raises(ValueError, match="MJPG only"):
        RehearsalOptions(camera_transport="http", gelsight_fourcc="YUYV")
    with pytest.raises(ValueError, match="camera_transport='usb' must be one of v4l2, http"):
        RehearsalOptions(camera_transport="usb")
    with pytest.raises(ValueError, match="offers MJPG 320x240 at 30, 25, 20, 15, 10, 5 frames/s, not 24"):
        RehearsalOptions(gelsight_fps=24.0)
    with pytest.raises(ValueError, match="GelSight Mini offers MJPG at 3280x2464, not 320x240"):
        RehearsalOptions(camera_models={"gelsight": "gelsight-mini"})
    with pytest.raises(ValueError, match="'left', which is not a camera of this rehearsal"):
        RehearsalOptions(camera_models={"left": "c310"})
    with pytest.raises(ValueError, match="unknown camera model 'c920'"):
        RehearsalOptions(cameras={"left": "x.mp4"}, camera_models={"left": "c920"})
    assert main(["bench", "rehearse", "--camera", "nonsense"]) == 2
    assert "NAME=SOURCE" in capsys.readouterr().err
    assert main(["bench", "rehearse", "--camera-model", "digit"]) == 2
    assert "NAME=MODEL" in capsys.readouterr().err
    assert parse_model_option("fingervision=digit") == ("fingervision", "digit")


def test_a_camera_model_offers_the_modes_the_rehearsal_asks_for() -> None:
    check_mode(C310, "YUYV", 320, 240, 25.0, what="cam")  # the GelSight camera, uncompressed
    check_mode(DIGIT, "YUYV", 320, 240, 60.0, what="cam")
    with pytest.raises(ValueError, match="cam: a DIGIT .* offers YUYV, not MJPG"):
        check_mode(DIGIT, "MJPG", 320, 240, 30.0, what="cam")
    # Footage keeps its size where the camera offers it, else takes the size uvcvideo would pick; the
    # rate is the offered one nearest the footage's (it plays at its own rate, sampled at the camera's).
    assert footage_mode(C310, "MJPG", 320, 240, 25.0) == (320, 240, 25.0)
    assert footage_mode(C310, "MJPG", 640, 480, 24.0) == (640, 480, 25.0)
    assert footage_mode(C310, "MJPG", 1920, 1080, 29.97) == (1280, 960, 30.0)
    assert footage_mode(DIGIT, "YUYV", 240, 320, 60.0) == (320, 240, 60.0)
    assert footage_mode(GELSIGHT_MINI, "MJPG", 320, 240, 25.0) == (3280, 2464, 25.0)


@pytest.mark.pty
def test_a_rehearsal_with_http_cameras_is_read_in_this_process(tmp_path, monkeypatch, capsys) -> None:
    opts = RehearsalOptions(camera_transport="http", calibration=False)
    with RehearsalBench(tmp_path / "r", opts) as rb:
        assert rb.env == {} and rb.registry is None
        text = rb.bench_path.read_text()
        assert "v4l2_registry" not in text and "v4l2_preload" not in text
        bench = load_bench(rb.bench_path)  # every port exists in this very process
        assert bench.v4l2_registry is None and bench.cameras["camera_gelsight"].port.startswith("http://127.0.0.1:")

        def no_child(argv, emu):
            raise AssertionError(f"a bench of HTTP cameras ran {argv} in a child process")

        monkeypatch.setattr(cli.emulation, "run_in_child", no_child)
        assert main(["camera", "grab", "--bench", str(rb.bench_path), "--out", str(tmp_path / "g"), "--json"]) == 0
        files = json.loads(capsys.readouterr().out.splitlines()[-1])["files"]
        assert cv2.imread(files[0]).shape == (240, 320, 3)
        assert rb.problems() == []


def test_record_on_the_mock_bench_in_virtual_time(tmp_path, capsys) -> None:
    out = tmp_path / "m.mcap"
    assert main(["record", "--mock", "--duration", "2", "--out", str(out), "--json"]) == 0
    topics = json.loads(capsys.readouterr().out.splitlines()[-1])["topics"]
    assert topics["/scale/force"] == 160  # every sample of the sketch at 80/s
    assert 40 <= topics["/camera/image/compressed"] <= 50  # 25 fps; a late poll may miss a frame
    assert 15 <= topics["/jig/pose"] == topics["/state/jig"] <= 20
    assert topics["/state/gripper"] >= 15
    recorded = read_recording(out)
    assert recorded.topics() == topics and not recorded.truncated
    assert [m.data["seq"] for m in recorded.on("/scale/force")] == sorted(m.data["seq"] for m in recorded.on("/scale/force"))

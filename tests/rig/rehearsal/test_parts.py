"""The rehearsal bench's parts on their own: the MJPEG-over-HTTP camera (server and driver), recorded
footage at its recorded rate, the bench file, and the command line's checks of its input."""

from __future__ import annotations

import json

import cv2
import mcap  # noqa: F401  (the record extra writes the recording)
import numpy as np
import pytest

from tactile_rig.cli import main
from tactile_rig.cli.bench import parse_camera_option
from tactile_rig.core.clock import RealClock, VirtualClock
from tactile_rig.core.errors import ControlReadbackError, NotConnected
from tactile_rig.drivers.camera import FingertipCamera
from tactile_rig.drivers.camera_http import HttpCameraSource
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.rig.bench import load_bench
from tactile_rig.rig.bench_check import check_bench
from tactile_rig.rig.recording import Recorder, read_recording
from tactile_rig.rig.rehearsal import CameraServer, RehearsalOptions, load_footage
from tactile_rig.rig.rehearsal.bench_file import RehearsalDevice, bench_toml

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
    assert main(["bench", "rehearse", "--camera", "nonsense"]) == 2
    assert "NAME=SOURCE" in capsys.readouterr().err


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

"""A recording served as a mock camera through the camera driver."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import mcap  # noqa: E402,F401  (extra [record] is installed by .[all,test]; absent = fail, not skip)

from tactile_rig.core.clock import VirtualClock  # noqa: E402
from tactile_rig.core.errors import DeviceTimeout, NotConnected  # noqa: E402
from tactile_rig.rig.recording import Recorder  # noqa: E402
from tactile_rig.rig.replay import RecordedFrameSource, summarize  # noqa: E402
from tactile_rig.drivers.camera import FingertipCamera


def _frames(n: int = 10) -> list[np.ndarray]:
    return [np.full((6, 8, 3), 20 * i, np.uint8) for i in range(n)]


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    clock = VirtualClock(start_s=3.0)
    path = tmp_path / "cam.mcap"
    with Recorder(path, clock=clock) as rec:
        for i, img in enumerate(_frames()):
            rec.write_frame("left", img, compress="png" if i % 2 else None)  # raw and compressed topics
            rec.write_frame("right", img)
            clock.advance(0.04)
    return path


def test_source_yields_recorded_frames_with_times(recording: Path) -> None:
    src = RecordedFrameSource(recording, topic="/right/image")
    assert len(src) == 10
    got = list(src.frames())
    assert [t for t, _ in got] == pytest.approx([3.0 + 0.04 * i for i in range(10)])
    assert all(np.array_equal(img, ref) for (_, img), ref in zip(got, _frames()))
    with pytest.raises(ValueError, match="image topics"):
        RecordedFrameSource(recording)  # three image topics: the caller must choose
    with pytest.raises(ValueError, match="no image topic '/x'"):
        RecordedFrameSource(recording, topic="/x")
    with pytest.raises(NotConnected):
        src.read(0.1)  # not opened


def test_fingertip_camera_replays_a_recording_on_virtual_time(recording: Path) -> None:
    from tactile_rig.drivers.camera import CameraConfig, FingertipCamera

    clock = VirtualClock(start_s=100.0)
    src = RecordedFrameSource(recording, topic="/right/image", clock=clock)
    cfg = CameraConfig(fourcc="MJPG", width=8, height=6, fps=25.0, controls={"exposure_time_absolute": 100},
                       warmup_frames=0)
    cam = FingertipCamera(src, cfg, clock=clock)
    with cam:
        frames = [cam.read(timeout_s=1.0) for _ in range(10)]
        # frames come at their recorded pace on the reader's clock
        assert [f.t_host_s - 100.0 for f in frames] == pytest.approx([0.04 * i for i in range(10)])
        assert [f.t_device_s for f in frames] == pytest.approx([3.0 + 0.04 * i for i in range(10)])
        assert all(np.array_equal(f.image, ref) for f, ref in zip(frames, _frames()))
        with pytest.raises(DeviceTimeout):
            cam.read(timeout_s=0.2)  # the recording is over: the stream stopped


def test_format_reports_the_recorded_size(recording: Path) -> None:
    src = RecordedFrameSource(recording, topic="/left/image")
    assert src.set_format("MJPG", 640, 480, 25.0)[1:3] == (8, 6)


def test_looping_source_restarts(recording: Path) -> None:
    src = RecordedFrameSource(recording, topic="/right/image", loop=True)
    src.open()
    seqs = [src.read(0.0).device_seq for _ in range(12)]
    assert seqs == list(range(10)) + [0, 1]


def test_summary_counts_each_topic(recording: Path) -> None:
    s = summarize(recording)
    assert s["topics"]["/left/image"]["count"] == 5
    assert s["topics"]["/left/image/compressed"]["count"] == 5
    assert s["topics"]["/right/image"]["first_t_s"] == pytest.approx(3.0)


def test_a_bench_camera_port_can_be_a_recording(recording: Path) -> None:
    from tactile_rig.rig.bench import connect_bench, load_bench

    text = (f'[camera]\nport = "{recording}#/right/image"\nwidth = 8\nheight = 6\nfps = 25.0\n')
    rig = connect_bench(load_bench(text=text, env={}), clock=VirtualClock())
    try:
        cam = rig.cameras["camera"]
        imgs = [cam.read(timeout_s=1.0).image for _ in range(8)]  # 2 warm-up frames were skipped
        assert all(np.array_equal(a, b) for a, b in zip(imgs, _frames()[2:]))
    finally:
        rig.close()


def test_a_recording_is_a_camera_without_its_fps(tmp_path):
    clock = VirtualClock()
    path = tmp_path / "r.mcap"
    with Recorder(path, clock=clock) as rec:
        for i in range(12):
            rec.write_frame("camera_left", np.full((6, 8, 3), 10 * i, np.uint8), t_s=i * 0.0371)
    cam = FingertipCamera(RecordedFrameSource(path, clock=clock), clock=clock).open()
    try:
        assert cam.format[1:3] == (8, 6) and cam.format[3] == pytest.approx(1 / 0.0371)
        assert cam.read(1.0).image.shape == (6, 8, 3)
    finally:
        cam.close()

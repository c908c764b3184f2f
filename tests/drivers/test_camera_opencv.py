"""OpenCVSource + FingertipCamera's capture thread against a fake cv2.VideoCapture (V4L2 quirks).

These run on the real clock (the capture thread blocks in ``read()`` like cap_v4l does) with a
fast 100 fps simulated camera and short timeouts; they assert behaviour, never timings.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tactile_rig.core.clock import RealClock
from tactile_rig.drivers.camera import (
    CameraConfig,
    ControlReadbackError,
    FingertipCamera,
    FrameSource,
    OpenCVSource,
    ReopenPolicy,
    fourcc_text,
)
from tactile_rig.core.errors import DeviceTimeout, NotConnected
from tactile_rig.mocks.camera import FakeVideoCapture, SimulatedCamera

PATH = "/dev/v4l/by-id/usb-Logitech_UVC_Camera_(046d:081b)_MOCKC310A-video-index0"
MODES = {("MJPG", 64, 48): 100.0, ("YUYV", 64, 48): 100.0, ("MJPG", 32, 24): 100.0, ("YUYV", 32, 24): 100.0}


def pattern(t_s: float) -> np.ndarray:
    img = np.full((48, 64, 3), 100, np.uint8)
    img[:, int(t_s * 200) % 64, 2] = 250
    return img


@pytest.fixture
def rig():
    clock = RealClock()
    sim = SimulatedCamera(pattern, clock=clock, width=32, height=24, fps=100, modes=MODES)
    src = OpenCVSource(PATH, capture_factory=FakeVideoCapture.factory({PATH: sim}))
    cfg = CameraConfig(width=64, height=48, fps=100, reopen=ReopenPolicy(max_attempts=3, initial_backoff_s=0.02))
    cam = FingertipCamera(src, cfg, clock=clock)
    yield clock, sim, src, cam
    cam.close()


def test_opencv_source_is_a_frame_source():
    assert isinstance(OpenCVSource(0), FrameSource)


def test_threaded_capture_locks_and_streams(rig):
    clock, sim, src, cam = rig
    assert cam.threaded
    cam.open()
    assert sim.table.get("auto_exposure") == 1 and sim.table.get("white_balance_automatic") == 0
    assert cam.format == ("MJPG", 64, 48, 100.0)
    frames = [cam.read(timeout_s=2.0) for _ in range(5)]
    seqs = [f.seq for f in frames]
    assert seqs == sorted(set(seqs))
    assert all(f.image.shape == (48, 64, 3) for f in frames)
    assert all(f.t_device_s is not None and f.t_device_s > 0 for f in frames)  # CAP_PROP_POS_MSEC


def test_fourcc_write_reinitialises_the_stream_and_width_waits_for_height(rig):
    clock, sim, src, cam = rig
    sim.reset_controls_on_format = True  # a camera whose firmware resets its controls on a format change
    cap = FakeVideoCapture(sim)
    assert cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)
    assert cap.get(cv2.CAP_PROP_AUTO_EXPOSURE) == 1
    assert cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*"YUYV"))
    assert fourcc_text(cap.get(cv2.CAP_PROP_FOURCC)) == "YUYV"
    assert cap.get(cv2.CAP_PROP_AUTO_EXPOSURE) == 3  # the stream re-init reset it
    # width alone is not applied; the height call applies the pair
    cap.set(cv2.CAP_PROP_FRAME_WIDTH, 64)
    cap.set(cv2.CAP_PROP_FRAME_HEIGHT, 48)
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (64, 48)
    cap.set(cv2.CAP_PROP_FRAME_WIDTH, 32)
    assert cap.get(cv2.CAP_PROP_FRAME_WIDTH) == 64
    cap.set(cv2.CAP_PROP_FRAME_HEIGHT, 24)
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (32, 24)
    assert cap.set(cv2.CAP_PROP_ZOOM, 2) is False and cap.get(cv2.CAP_PROP_ZOOM) == -1
    assert cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 0.25) is False  # range normalisation is off in OpenCV 4+
    cap.release()


def test_unknown_path_is_not_connected():
    src = OpenCVSource("/dev/v4l/by-id/nothing", capture_factory=FakeVideoCapture.factory({}))
    with pytest.raises(NotConnected, match="cannot open video device"):
        src.open()


def test_ignored_control_fails_readback(rig):
    clock, sim, src, cam = rig
    sim.ignore_controls = {"gain"}
    cam.config.controls = {"auto_exposure": 1, "gain": 10}
    with pytest.raises(ControlReadbackError, match="gain=10 reads back as 64"):
        cam.open()


def test_stall_raises_timeout_although_read_blocks(rig):
    clock, sim, src, cam = rig
    cam.open()
    cam.read(timeout_s=2.0)
    sim.stall(clock.now_s(), clock.now_s() + 60.0)
    with pytest.raises(DeviceTimeout, match="no new frame"):
        for _ in range(5):  # frames already in flight may still arrive
            cam.read(timeout_s=0.15)


def test_unplug_reopen_and_give_up(rig):
    clock, sim, src, cam = rig
    cam.open()
    cam.read(timeout_s=2.0)
    t0 = clock.now_s()
    sim.unplug(t0, t0 + 0.05)
    deadline = t0 + 5.0
    while cam.stats.reopens == 0 and clock.now_s() < deadline:
        cam.read(timeout_s=2.0)
    assert cam.stats.reopens == 1
    assert sim.table.get("auto_exposure") == 1
    sim.unplug(clock.now_s())  # for good
    with pytest.raises(NotConnected):
        for _ in range(100):
            cam.read(timeout_s=2.0)


def test_replugged_camera_that_refuses_controls_is_reported_to_the_reader(rig):
    clock, sim, src, cam = rig
    cam.open()
    cam.read(timeout_s=2.0)
    sim.ignore_controls = {"gain"}  # the replugged unit has firmware that ignores gain
    cam.config.controls = {"auto_exposure": 1, "gain": 10}
    sim.unplug(clock.now_s(), clock.now_s() + 0.05)
    with pytest.raises(ControlReadbackError, match="gain=10"):
        for _ in range(100):
            cam.read(timeout_s=2.0)


@pytest.mark.hw
def test_real_camera_locks_and_streams():
    """On the bench: the first C310 found by discovery, opened by its stable path."""
    from tactile_rig.drivers.discovery import discover

    cams = [d for d in discover() if d.kind == "camera_c310" and (d.by_id or d.video)]
    if not cams:
        pytest.skip("no Logitech C310 plugged in")
    path = (cams[0].by_id or cams[0].video)[0]
    with FingertipCamera(path, CameraConfig(width=640, height=480, fps=30)) as cam:
        frames = [cam.read(timeout_s=2.0) for _ in range(30)]
        fourcc, width_px, height_px, fps = cam.format
    assert all(f.image.shape == (480, 640, 3) for f in frames)
    # Behaviour, not wall-clock speed: the negotiated mode, and 30 distinct frames in order.
    assert (width_px, height_px) == (640, 480) and fps >= 25.0, (fourcc, width_px, height_px, fps)
    seqs = [f.seq for f in frames]
    assert seqs == sorted(set(seqs))

"""FingertipCamera over OpenCVSource on its real path: OpenCV's own V4L2 backend streaming from an
emulated camera, in a child process started with the emulation's environment (one child runs a whole
session of faults). The driver's behaviour in virtual time is tests/drivers/test_camera.py, on the
simulated camera the contract suite holds to this path."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest

from tactile_rig.devices.camera_models import GELSIGHT_MINI
from tactile_rig.drivers.camera import CameraConfig, FingertipCamera, FrameSource, OpenCVSource
from tactile_rig.drivers.camera_frames import sdk_view_image
from tactile_rig.core.errors import NotConnected
from tactile_rig.mocks.v4l2.child import run_in_child
from tests._camera_driver_bodies import driver_on_a_model, driver_through_faults, source_without_linuxpy
from tests._v4l2 import emulated


def test_opencv_source_is_a_frame_source() -> None:
    assert isinstance(OpenCVSource(0), FrameSource)


def test_an_absent_path_is_not_connected(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", "10")  # open() sets it when absent: keep this process's
    src = OpenCVSource("/dev/v4l/by-id/usb-nothing-video-index0")  # OpenCV's backend finds no device there
    with pytest.raises(NotConnected, match="cannot open video device"):
        src.open()


@pytest.fixture(scope="module")
def session() -> dict[str, Any]:
    with emulated("c310", control_fifo=True) as cam:
        out = run_in_child(driver_through_faults, cam.port, cam.describe()["control"], env=cam.env, timeout_s=90)
        out["table"] = dict(cam.sim.table.values)
        out["unplugs"] = cam.unplugs
    return out  # type: ignore[no-any-return]


def test_it_opens_locked_and_read_back_and_streams(session: dict[str, Any]) -> None:
    assert session["threaded"] and session["format"] == ("YUYV", 320, 240, 30.0)
    assert session["readback"] == {"auto_exposure": 1.0, "white_balance_automatic": 0.0,
                                   "exposure_dynamic_framerate": 0.0, "exposure_time_absolute": 166.0,
                                   "white_balance_temperature": 4000.0, "gain": 64.0, "power_line_frequency": 1.0}
    assert session["shapes"] == [(240, 320, 3)] and session["seqs_increase"]
    assert session["select_timeout"] == "1"  # the driver bounded OpenCV's wait in its own process


def test_a_stall_shorter_than_the_select_timeout_shows_only_as_the_readers_deadline(session: dict[str, Any]) -> None:
    s = session["short_stall"]
    assert s["raised"] == "DeviceTimeout" and 0.2 < s["took_s"] < 0.6
    assert s["source_timeouts"] == 0 and s["frames_again"]


def test_a_longer_stall_also_fails_opencvs_reads_and_frames_resume(session: dict[str, Any]) -> None:
    s = session["long_stall"]
    assert s["raised"] == "DeviceTimeout" and s["took_s"] < 0.6
    assert 1 <= s["source_timeouts"] <= 3  # one per second of the 2.6 s stall
    assert s["frames_again"] and s["disconnects"] == 0  # a stall is not an unplug


def test_a_freeze_raises_frozen_stream_then_frames_move_again(session: dict[str, Any]) -> None:
    f = session["freeze"]
    assert f["raised"] == "FrozenStream" and f["duplicates"] >= 11 and f["frames_again"]


def test_an_unplug_fails_fast_then_the_camera_is_reopened_relocked_and_reverified(session: dict[str, Any]) -> None:
    u = session["unplug"]
    assert u["raised"] == "NotConnected" and u["took_s"] < 0.5
    assert all(took < 0.1 for took, _ in u["away_reads"])  # fails fast while away
    assert all("is gone" in msg and "next reconnect attempt in" in msg for _, msg in u["away_reads"])
    assert u["frames_again"] and u["stats"]["disconnects"] == 1 and u["stats"]["reconnects"] == 1
    # the camera came back with exposure_dynamic_framerate 1 and 60 Hz (power-on): locked again
    assert u["readback"] == session["readback"]
    assert session["unplugs"] == 1
    assert session["table"]["exposure_dynamic_framerate"] == 0 and session["table"]["power_line_frequency"] == 1


def test_close_during_a_stall_waits_for_the_backends_read_at_most(session: dict[str, Any]) -> None:
    assert session["close_during_stall_s"] < 1.6  # the 1 s select timeout, not the 10 s default
    assert session["closed_reads"] == "NotConnected"


def test_a_gelsight_mini_configured_from_its_model_gives_gs_sdks_view() -> None:
    """The Mini's only mode (MJPG 3280x2464 at 25 fps), its lock, and frames as gs_sdk shows them: the
    raw frame cropped (1/7 each side, 4:3 kept) and resized to 320x240, the housing left out."""
    with emulated("gelsight-mini") as cam:
        got = run_in_child(driver_on_a_model, cam.port, "gelsight-mini", "gs_sdk", env=cam.env, timeout_s=120)
        raws = [cam.rendered(int(round(t * 1e9))) for t, _ in got["frames"]]
    assert got["format"] == ("MJPG", 3280, 2464, 25.0)
    assert got["readback"]["auto_exposure"] == 1.0 and got["readback"]["power_line_frequency"] == 1.0
    view = {v.name: v for v in GELSIGHT_MINI.sdk_views}["gs_sdk"]
    for (_, img), raw in zip(got["frames"], raws):
        assert raw is not None and img.shape == (240, 320, 3)
        assert cv2.PSNR(img, sdk_view_image(raw.image, view)) > 30.0  # the view of the very frame sent
        # without the crop the frame's edges would be the dim housing around the gel
        whole = cv2.resize(raw.image, (320, 240))
        assert img[:8].mean() > 1.8 * whole[:8].mean()


def test_a_digit_configured_from_its_model_locks_its_leds_and_turns_portrait() -> None:
    with emulated("digit") as cam:
        got = run_in_child(driver_on_a_model, cam.port, "digit", "digit-interface", env=cam.env)
        raw = cam.rendered(int(round(got["frames"][0][0] * 1e9)))
    assert got["format"] == ("YUYV", 640, 480, 30.0) and got["readback"] == {"zoom_absolute": 4095.0}
    img = got["frames"][0][1]
    assert img.shape == (640, 480, 3)  # digit-interface's portrait view
    assert raw is not None
    assert cv2.PSNR(img, np.ascontiguousarray(cv2.flip(cv2.transpose(raw.image), 0))) > 30.0


def test_without_linuxpy_the_unmapped_controls_are_refused_by_name_and_an_unplug_still_shows() -> None:
    with emulated("c310", control_fifo=True) as cam:
        got = run_in_child(source_without_linuxpy, cam.port, cam.describe()["control"], env=cam.env)
    ok, why, value = got["plf"]
    assert not ok and "pip install 'tactile-rig[v4l2]'" in why and value is None
    assert got["gain"] == (True, 100.0)  # OpenCV's own properties need no extra
    assert "none" in got["stall"] and got["stall"][-1] == "frame"  # a 1.6 s stall: select timeouts, then frames
    results, took_s = got["unplug"]
    assert results[-1] == "NotConnected" and results.count("none") == 2 and took_s < 1.0  # three quick failures


def test_a_camera_config_for_the_hardware_path_is_checked_before_opening() -> None:
    with pytest.raises(ValueError, match="mains_hz"):
        FingertipCamera("/dev/video0", CameraConfig(mains_hz=0))


@pytest.mark.hw
def test_real_camera_locks_and_streams() -> None:
    """On the bench: the first C310 found by discovery, opened by its stable path."""
    from tactile_rig.drivers.discovery import discover

    cams = [d for d in discover() if d.model == "c310" and (d.by_id or d.video)]
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

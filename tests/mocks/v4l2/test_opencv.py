"""OpenCV's own V4L2 backend (``cv2.VideoCapture(path, cv2.CAP_V4L2)``) against the emulated cameras.

Each client body runs in a child process started with the camera's environment (the preload must
be there at process start); the parent holds the camera and checks what OpenCV got against what the
camera rendered and against the camera's control table. These tests pin the facts about OpenCV's
backend that docs/emulated_cameras.md states.
"""

from __future__ import annotations

import itertools
from typing import Any

import cv2
import numpy as np
import pytest

from tactile_rig.mocks.v4l2 import CameraFaults, V4L2Camera
from tactile_rig.mocks.v4l2.child import run_in_child
from tactile_rig.mocks.v4l2.frames import encode_frame
from tests._v4l2 import emulated
from tests._v4l2_clients import (FOURCC_MJPG, FOURCC_YUYV, PHOTOMETRIC, defaults_then_writes,
                                 fourcc_change_keeps_controls, grab_frames, opens_and_reads, read_log,
                                 width_then_height)


# -- helpers (parent) ------------------------------------------------------------------------------------
def _rendered(cam: V4L2Camera, pos_msec: float) -> Any:
    frame = cam.rendered(int(round(pos_msec * 1e6)))
    assert frame is not None, f"no frame was delivered with timestamp {pos_msec} ms"
    return frame


def _ioctl_names(cam: V4L2Camera) -> list[str]:
    assert cam.trace is not None
    return [name.removeprefix("VIDIOC_") for _, name, _ in cam.trace]


# -- streaming ---------------------------------------------------------------------------------------------
def test_opencv_opens_with_querycap_then_g_fmt_and_defaults_to_yuyv() -> None:
    """The backend's first ioctls are QUERYCAP and G_FMT; its automatic format choice tries
    BGR24, RGB24, YVU420, YUV420 and YUV411P (uvcvideo answers each with its default format)
    before it takes YUYV, so a C310 opened without a FOURCC streams YUYV 640x480 at 30 fps."""
    with emulated("c310", trace=True) as cam:
        got = run_in_child(grab_frames, cam.port, FOURCC_YUYV, 640, 480, 30, 1, env=cam.env)
        names = _ioctl_names(cam)
    assert got["backend"] == "V4L2"
    assert names[:2] == ["QUERYCAP", "G_FMT"]
    assert names[2:8] == ["S_FMT"] * 6
    assert (got["fourcc"], got["size"], got["fps"]) == (FOURCC_YUYV, (640, 480), 30.0)


def test_opencv_mjpg_640x480_frames_are_the_rendered_ones() -> None:
    with emulated("c310") as cam:
        got = run_in_child(grab_frames, cam.port, FOURCC_MJPG, 640, 480, 30, 8, env=cam.env)
        rendered = [_rendered(cam, ms) for ms, _ in got["frames"]]
    assert (got["fourcc"], got["size"], got["fps"]) == (FOURCC_MJPG, (640, 480), 30.0)
    for (ms, img), frame in zip(got["frames"], rendered):
        assert frame.fourcc == "MJPG" and img.shape == (480, 640, 3)
        # Bit-exact: OpenCV decoded the very JPEG the camera encoded from this image...
        same = cv2.imdecode(encode_frame(frame.image, "MJPG", cam.jpeg_quality), cv2.IMREAD_COLOR)
        assert np.array_equal(img, same)
        # ...which is the rendered image within JPEG error (quality 90).
        assert cv2.PSNR(img, frame.image) > 34.0
    # Consecutive frames differ (noise, drifting auto exposure): the pixels are not a still.
    assert not np.array_equal(got["frames"][0][1], got["frames"][1][1])
    stamps = [ms for ms, _ in got["frames"]]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))


def test_opencv_yuyv_320x240_frames_are_the_rendered_ones() -> None:
    with emulated("c310") as cam:
        got = run_in_child(grab_frames, cam.port, FOURCC_YUYV, 320, 240, 30, 8, env=cam.env)
        rendered = [_rendered(cam, ms) for ms, _ in got["frames"]]
    assert (got["fourcc"], got["size"], got["fps"]) == (FOURCC_YUYV, (320, 240), 30.0)
    for (ms, img), frame in zip(got["frames"], rendered):
        assert frame.fourcc == "YUYV"
        yuyv = encode_frame(frame.image, "YUYV").reshape(240, 320, 2)
        assert np.array_equal(img, cv2.cvtColor(yuyv, cv2.COLOR_YUV2BGR_YUYV))  # OpenCV's own conversion
        # 4:2:2 chroma and limited-range rounding: close to the rendered image.
        assert float(np.mean(cv2.absdiff(img, frame.image))) < 3.0
        assert cv2.PSNR(img, frame.image) > 30.0


@pytest.mark.parametrize("model", ["digit", "gelsight-mini"])
def test_opencv_streams_the_tactile_cameras_default_mode(model: str) -> None:
    expect = {"digit": (FOURCC_YUYV, (640, 480), 30.0), "gelsight-mini": (FOURCC_MJPG, (3280, 2464), 25.0)}[model]
    with emulated(model) as cam:
        got = run_in_child(grab_frames, cam.port, expect[0], *expect[1], expect[2], 2, env=cam.env, timeout_s=120)
        rendered = [_rendered(cam, ms) for ms, _ in got["frames"]]
    assert (got["fourcc"], got["size"], got["fps"]) == expect
    for (_, img), frame in zip(got["frames"], rendered):
        assert img.shape == (expect[1][1], expect[1][0], 3)
        assert cv2.PSNR(img, frame.image) > 30.0


# -- controls --------------------------------------------------------------------------------------------------
def test_opencv_sets_and_reads_back_every_photometric_control() -> None:
    """Manual exposure and white balance first (their values are refused while auto is on), then the
    rest; every value OpenCV reads back is the camera's own, uvcvideo's rounding included."""
    order = [PHOTOMETRIC[0], PHOTOMETRIC[2]] + [p for i, p in enumerate(PHOTOMETRIC) if i not in (0, 2)]
    writes = [(prop, float(value)) for prop, _, value in order]
    with emulated("c310") as cam:
        got = run_in_child(defaults_then_writes, cam.port, writes, env=cam.env)
        table = dict(cam.sim.table.values)
    assert got["initial"] == {
        "CAP_PROP_AUTO_EXPOSURE": 3.0, "CAP_PROP_EXPOSURE": 166.0, "CAP_PROP_AUTO_WB": 1.0,
        "CAP_PROP_WB_TEMPERATURE": 4000.0, "CAP_PROP_GAIN": 64.0, "CAP_PROP_BRIGHTNESS": 128.0,
        "CAP_PROP_CONTRAST": 32.0, "CAP_PROP_SATURATION": 32.0, "CAP_PROP_SHARPNESS": 24.0,
        "CAP_PROP_BACKLIGHT": 0.0, "CAP_PROP_HUE": -1.0, "CAP_PROP_FOCUS": -1.0}
    by_prop = {prop: name for prop, name, _ in PHOTOMETRIC}
    for prop, value, ok, readback in got["writes"]:
        assert ok, prop
        assert readback == value, prop
        assert table[by_prop[prop]] == value, prop


def test_opencv_control_refusals_and_silent_clamping() -> None:
    writes = [("CAP_PROP_EXPOSURE", 200.0),        # inactive while auto exposure is on: refused
              ("CAP_PROP_AUTO_EXPOSURE", 0.25),     # no 0.25/0.75 mapping: raw V4L2 menu values only
              ("CAP_PROP_AUTO_EXPOSURE", 1.0),
              ("CAP_PROP_EXPOSURE", 200.0),
              ("CAP_PROP_AUTO_WB", 0.0),
              ("CAP_PROP_WB_TEMPERATURE", 5005.0),  # rounded to the step of 10 by uvcvideo
              ("CAP_PROP_GAIN", 1000.0),            # accepted, clamped to the maximum
              ("CAP_PROP_HUE", 3.0)]                # the C310 has no hue control
    with emulated("c310") as cam:
        got = run_in_child(defaults_then_writes, cam.port, writes, env=cam.env)
    assert [(ok, readback) for _, _, ok, readback in got["writes"]] == [
        (False, 166.0), (False, 3.0), (True, 1.0), (True, 200.0), (True, 0.0), (True, 5010.0), (True, 255.0),
        (False, -1.0)]


# -- faults -----------------------------------------------------------------------------------------------------
def test_opencv_on_a_stall_times_out_in_select_then_recovers() -> None:
    """read() returns False after OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT seconds without a frame
    (default 10); isOpened() stays True and reading resumes when frames come back."""
    faults = CameraFaults(stall_after=4, stall_s=2.5)
    with emulated("c310", faults=faults) as cam:
        rows = run_in_child(read_log, cam.port, 10, env={**cam.env, "OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT": "1"})
    oks = [r[0] for r in rows]
    first_fail = oks.index(False)
    assert first_fail >= 1 and all(oks[:first_fail])  # frames lost to a loaded machine count too
    failed = [r for r in rows if not r[0]]
    assert 1 <= len(failed) <= 3
    assert all(0.9 < r[1] < 1.6 for r in failed), [r[1] for r in failed]
    assert all(r[4] for r in rows)
    assert oks[-1] and oks[-2], "frames after the stall are read by the same capture"
    assert faults.counts() == {"stall": 1}


def test_opencv_on_a_freeze_gets_identical_images_with_new_timestamps() -> None:
    faults = CameraFaults(freeze_after=3, freeze_s=0.25)
    with emulated("c310", faults=faults) as cam:
        rows = run_in_child(read_log, cam.port, 16, env=cam.env)
    assert all(r[0] for r in rows)
    digests = [r[3] for r in rows]
    runs = [len(list(g)) for _, g in itertools.groupby(digests)]
    assert max(runs) >= 5, digests  # 0.25 s of one image at 30 fps
    stamps = [r[2] for r in rows]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert runs[-1] == 1, "the image moves again after the freeze"


def test_opencv_on_unplug_read_fails_at_once_and_is_opened_stays_true() -> None:
    faults = CameraFaults(unplug_after=4, away_s=0.6)
    with emulated("c310", faults=faults) as cam:
        rows = run_in_child(read_log, cam.port, 9, 1.2, env={**cam.env, "OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT": "2"})
        assert cam.plugged  # back after 0.6 s
        fresh = run_in_child(opens_and_reads, cam.port, env=cam.env)
    oks = [r[0] for r in rows]
    first_fail = oks.index(False)
    assert first_fail >= 1  # the frames before the unplug (fewer when a loaded machine lost some)
    assert not any(oks[first_fail:]), "the old capture never recovers, even after the replug"
    assert all(r[1] < 0.5 for r in rows[first_fail:]), "poll reports POLLERR: no select() timeout"
    assert all(r[4] for r in rows), "isOpened() stays True after the unplug"
    # A new capture on the same path works, with the controls back at their power-on values.
    assert fresh == (True, True, 166.0, 3.0)


def test_opencv_cannot_open_an_unplugged_camera() -> None:
    with emulated("c310") as cam:
        cam.unplug()
        opened = run_in_child(opens_and_reads, cam.port, env=cam.env)
        cam.replug()
        back = run_in_child(opens_and_reads, cam.port, env=cam.env)
    assert opened[:2] == (False, False)
    assert back[:2] == (True, True)


def test_a_replugged_camera_has_its_power_on_controls() -> None:
    with emulated("c310") as cam:
        run_in_child(defaults_then_writes, cam.port, [("CAP_PROP_AUTO_EXPOSURE", 1.0), ("CAP_PROP_EXPOSURE", 300.0)],
                     env=cam.env)
        assert cam.sim.table.values["exposure_time_absolute"] == 300
        cam.unplug()
        cam.replug()
        fresh = run_in_child(opens_and_reads, cam.port, env=cam.env)
    assert fresh == (True, True, 166.0, 3.0)


def test_opencv_applies_width_and_height_as_a_pair() -> None:
    with emulated("c310") as cam:
        got = run_in_child(width_then_height, cam.port, env=cam.env)
    assert got == [(640, 480), (640, 480), (320, 240), (320, 240)]


def test_a_fourcc_change_restarts_the_stream_and_keeps_the_c310s_controls() -> None:
    """OpenCV stops streaming, frees the buffers and sets the format again; uvcvideo keeps the
    control values (no evidence that a C310's firmware resets them on a format change)."""
    with emulated("c310", trace=True) as cam:
        before, after, ok = run_in_child(fourcc_change_keeps_controls, cam.port, env=cam.env)
        names = _ioctl_names(cam)
    assert (before, after, ok) == (100.0, 100.0, True)
    i = names.index("STREAMON")
    assert "STREAMOFF" in names[i:] and "S_FMT" in names[names.index("STREAMOFF", i):]

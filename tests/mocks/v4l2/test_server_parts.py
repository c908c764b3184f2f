"""The device server's parts without a client: uvcvideo's format and interval choices, the wire
protocol against garbage, the library build and its errors, the fault plan."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import tactile_rig.mocks.v4l2.abi as abi
from tactile_rig.devices.camera_models import C310, DIGIT, GELSIGHT_MINI
from tactile_rig.mocks.v4l2 import CameraFaults, PreloadUnavailable, build, formats, protocol
from tactile_rig.mocks.v4l2.frames import build_camera
from tactile_rig.mocks.v4l2.protocol import ProtocolError, Request


def test_try_format_picks_uvcvideos_closest_size_and_default_format() -> None:
    s = formats.try_format(C310, abi.fourcc("YUYV"), 700, 500)
    assert (s.fourcc, s.width_px, s.height_px) == ("YUYV", 640, 480)
    s = formats.try_format(C310, abi.fourcc("H264"), 1280, 720)  # not offered: the default format
    assert (s.fourcc, s.width_px, s.height_px) == ("YUYV", 1280, 720)
    s = formats.try_format(GELSIGHT_MINI, abi.fourcc("YUYV"), 320, 240)  # the Mini has one mode
    assert (s.fourcc, s.width_px, s.height_px, s.fps) == ("MJPG", 3280, 2464, 25.0)
    assert (s.bytesperline, s.sizeimage) == (0, 3280 * 2464 * 2)


@given(st.sampled_from([C310, DIGIT, GELSIGHT_MINI]), st.sampled_from(["YUYV", "MJPG", "RGB3"]),
       st.integers(0, 70000), st.integers(0, 70000))
def test_try_format_always_gives_a_mode_of_the_camera(model, fourcc: str, w: int, h: int) -> None:  # type: ignore[no-untyped-def]
    s = formats.try_format(model, abi.fourcc(fourcc), w, h)
    assert (s.fourcc, s.width_px, s.height_px) in model.modes()


@pytest.mark.parametrize(("num", "den", "fps"), [(1, 30, 30.0), (1, 7, 10.0), (1, 100, 30.0), (0, 0, 5.0),
                                                 (1, 1, 5.0), (2, 15, 10.0), (1, 6, 5.0)])
def test_set_interval_snaps_to_the_closest_offered_rate(num: int, den: int, fps: float) -> None:
    """uvc_try_frame_interval walks the C310's 30, 25, 20, 15, 10, 5 fps while the distance shrinks
    (1/7 s is nearer 10 fps than 5); v4l2_fraction_to_interval saturates 0/0 to the longest interval."""
    cur = formats.try_format(C310, abi.fourcc("MJPG"), 640, 480)
    assert formats.set_interval(C310, cur, num, den).fps == fps


@given(st.binary(max_size=200))
def test_garbage_requests_are_refused_cleanly(data: bytes) -> None:
    try:
        req = Request.parse(data)
    except ProtocolError:
        return
    assert req.pack() == data


@given(st.sampled_from(sorted(protocol.OP_NAMES)), st.integers(-(2 ** 31), 2 ** 31 - 1), st.integers(0, 2 ** 64 - 1),
       st.binary(max_size=300), st.binary(max_size=300))
def test_requests_round_trip(op: int, arg0: int, cmd: int, p1: bytes, p2: bytes) -> None:
    req = Request(op, arg0, cmd, 7, 9, p1, p2)
    assert Request.parse(req.pack()) == req


def test_a_missing_compiler_names_the_debian_packages(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(build.shutil, "which", lambda name: None)
    problem = build.toolchain_problem()
    assert problem is not None and "a C compiler (cc)" in problem and "apt-get install gcc libc6-dev" in problem
    with pytest.raises(PreloadUnavailable, match="apt-get install gcc libc6-dev"):
        build.build()


def test_the_library_is_cached_by_a_hash_of_its_source(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if build.toolchain_problem() is not None:
        pytest.skip(build.toolchain_problem() or "")
    monkeypatch.setenv("TACTILE_RIG_CACHE", str(tmp_path / "cache"))
    lib = build.build()
    assert lib.is_file() and lib.parent.name == build.build_key() and lib.parent.parent == tmp_path / "cache" / "v4l2"
    assert build.build() == lib  # cached
    changed = tmp_path / "preload.c"
    shutil.copy(build.SOURCE, changed)
    changed.write_text(changed.read_text() + "\n/* another version */\n")
    monkeypatch.setattr(build, "SOURCE", changed)
    assert build.build() != lib
    changed.write_text(changed.read_text() + "\nthis is not C;\n")
    with pytest.raises(build.PreloadBuildError, match="failed"):
        build.build()


def test_fault_queries_are_checked() -> None:
    f = CameraFaults.from_query("stall_after=5&stall_s=2&seed=3")
    assert (f.stall_after, f.stall_s, f.seed) == (5, 2.0, 3)
    with pytest.raises(ValueError, match="unknown camera fault"):
        CameraFaults.from_query("explode=1")
    with pytest.raises(ValueError, match="must be a probability"):
        CameraFaults.from_query("stall=2")
    with pytest.raises(ValueError, match="is not a number"):
        CameraFaults.from_query("freeze_s=soon")


def test_a_recorded_video_is_the_sensors_view(tmp_path: Path) -> None:
    """Frame k of the file is what the sensor sees from k/fps to (k+1)/fps, looped, through the
    camera's exposure and noise."""
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (160, 120))
    colours = [(200, 30, 30), (30, 200, 30), (30, 30, 200)]  # BGR: blue, green, red frames
    for c in colours:
        writer.write(np.full((120, 160, 3), c, np.uint8))
    writer.release()
    sim = build_camera(C310, video=path)
    for k in range(6):
        img = sim.render_frame((k + 0.5) / 10.0, 640, 480)
        assert img.shape == (480, 640, 3)
        assert int(np.argmax(img.reshape(-1, 3).mean(axis=0))) == k % 3
    with pytest.raises(ValueError, match="OpenCV cannot open it"):
        build_camera(C310, video=tmp_path / "missing.avi")

"""The camera FrameSource contract: the in-process simulated camera and OpenCVSource on OpenCV's real
V4L2 backend over an emulated C310 (in a child process started with its environment) observe the
same session, and the same faults, the same way; where they differ, the V4L2 side is the fact. This
is what lets the driver's own tests run on the simulated camera in virtual time."""

from __future__ import annotations

import time
from typing import Any

import pytest

from tactile_rig.core.clock import RealClock
from tactile_rig.devices.camera_models import C310
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.mocks.v4l2.child import run_in_child
from tactile_rig.mocks.v4l2.frames import build_camera
from tests._camera_contract import observe, observe_faults, observe_faults_v4l2, observe_v4l2
from tests._v4l2 import emulated

BACKENDS = ["simulated", "v4l2"]


def _simulated() -> SimulatedCamera:
    sim = build_camera(C310)
    sim.clock = RealClock()
    return sim


@pytest.fixture(scope="module", params=BACKENDS)
def seen(request: pytest.FixtureRequest) -> dict[str, Any]:
    if request.param == "simulated":
        return observe(_simulated())
    with emulated("c310") as cam:
        return run_in_child(observe_v4l2, cam.port, env=cam.env)  # type: ignore[no-any-return]


@pytest.fixture(scope="module", params=BACKENDS)
def faults(request: pytest.FixtureRequest) -> dict[str, Any]:
    if request.param == "simulated":
        sim = _simulated()

        def inject(kind: str, seconds: float) -> None:
            now = time.monotonic()
            getattr(sim, kind)(now, now + seconds)

        out = observe_faults(sim, inject)
        out["select_timeout"] = "1"  # the simulated camera honours the read's own timeout
        return out
    with emulated("c310", control_fifo=True) as cam:
        return run_in_child(observe_faults_v4l2, cam.port, cam.describe()["control"],  # type: ignore[no-any-return]
                            env=cam.env)


def test_opens_sets_the_format_and_streams_bgr_frames(seen: dict[str, Any]) -> None:
    assert seen["open"] and seen["channel_order"] == "BGR"
    assert seen["format"] == ["MJPG", 640, 480, 30.0]
    assert seen["frames"] == 12 and seen["shapes"] == [(480, 640, 3)]
    steps = seen["stamp_steps_s"]
    assert all(s > 0 for s in steps)
    assert sorted(steps)[len(steps) // 2] == pytest.approx(1 / 30, rel=0.02)


def test_an_unoffered_size_snaps_to_the_closest_mode(seen: dict[str, Any]) -> None:
    assert seen["snapped"] == ["MJPG", 640, 480, 30.0]


def test_controls_refusals_rounding_and_clamping(seen: dict[str, Any]) -> None:
    # the C310 powers up with exposure_dynamic_framerate on (its default, GET_DEF, is 0) and at 60 Hz
    assert seen["power_on"] == {"exposure_dynamic_framerate": 1.0, "power_line_frequency": 2.0}
    assert [(name, ok, value) for name, _, ok, value in seen["writes"]] == [
        ("auto_exposure", True, 1.0),
        ("exposure_time_absolute", True, 250.0),
        ("auto_exposure", True, 3.0),
        ("exposure_time_absolute", False, 250.0),   # inactive under auto exposure: refused
        ("white_balance_automatic", True, 0.0),
        ("white_balance_temperature", True, 5010.0),  # rounded to the step of 10
        ("gain", True, 255.0),                       # accepted, clamped
        ("gain", True, 100.0),
        ("hue", False, None),                        # the C310 has no hue
        ("exposure_dynamic_framerate", True, 0.0),   # by its V4L2 id (OpenCV has no property for it)
        ("power_line_frequency", True, 1.0),         # 50 Hz, by its V4L2 id
        ("power_line_frequency", False, 1.0),        # 3 (auto) is not in the C310's menu
    ]


def test_a_format_change_keeps_the_controls(seen: dict[str, Any]) -> None:
    assert seen["format_change"] == ["YUYV", 320, 240, 30.0]
    assert seen["shape_after_format_change"] == (240, 320, 3)
    assert seen["after_format_change"] == {"gain": 100.0, "power_line_frequency": 1.0}


def test_a_closed_source_refuses_reads(seen: dict[str, Any]) -> None:
    assert seen["closed"] and seen["read_after_close"] == "NotConnected"


def test_a_freeze_gives_identical_images_with_advancing_timestamps(faults: dict[str, Any]) -> None:
    f = faults["freeze"]
    assert f["longest_identical_run"] >= 8 and f["moves_after"] and f["stamps_advance"]  # 0.5 s at 30 fps


def test_a_stall_gives_no_frame_then_frames_from_the_same_open_source(faults: dict[str, Any]) -> None:
    assert faults["stall"] == {"no_frame_seen": True, "frames_after": True, "still_open": True}
    assert faults["select_timeout"] == "1"  # OpenCVSource bounds the backend's wait to 1 s


def test_an_unplug_fails_reads_and_a_reopen_after_the_replug_has_power_on_controls(faults: dict[str, Any]) -> None:
    assert faults["unplug"] == {"read": "NotConnected", "within_s": True}
    assert faults["replug"] == {"controls": {"exposure_dynamic_framerate": 1.0, "power_line_frequency": 2.0,
                                             "auto_exposure": 3.0}, "reads": True}

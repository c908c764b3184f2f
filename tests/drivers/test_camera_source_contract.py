"""The camera FrameSource contract: the in-process simulated camera and OpenCVSource on OpenCV's real
V4L2 backend over an emulated C310 (in a child process started with its environment) observe the
same session the same way; where they differ, the V4L2 side is the fact."""

from __future__ import annotations

from typing import Any

import pytest

from tactile_rig.core.clock import RealClock
from tactile_rig.devices.camera_models import C310
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.mocks.v4l2.child import run_in_child
from tactile_rig.mocks.v4l2.frames import build_camera
from tests._camera_contract import observe, observe_v4l2
from tests._v4l2 import emulated

BACKENDS = ["simulated", "v4l2"]


@pytest.fixture(scope="module", params=BACKENDS)
def seen(request: pytest.FixtureRequest) -> dict[str, Any]:
    if request.param == "simulated":
        sim: SimulatedCamera = build_camera(C310)
        sim.clock = RealClock()
        return observe(sim)
    with emulated("c310") as cam:
        return run_in_child(observe_v4l2, cam.port, env=cam.env)  # type: ignore[no-any-return]


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
    ]


def test_a_format_change_keeps_the_controls(seen: dict[str, Any]) -> None:
    assert seen["format_change"] == ["YUYV", 320, 240, 30.0]
    assert seen["shape_after_format_change"] == (240, 320, 3)
    assert seen["gain_after_format_change"] == 100.0


def test_a_closed_source_refuses_reads(seen: dict[str, Any]) -> None:
    assert seen["closed"] and seen["read_after_close"] == "NotConnected"

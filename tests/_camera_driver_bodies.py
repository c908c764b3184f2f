"""Child-process bodies for the camera driver on its real path: ``FingertipCamera`` over
``OpenCVSource`` (OpenCV's own V4L2 backend) on an emulated camera, in a process started with the
emulation's environment (tests/drivers/test_camera_opencv.py). Faults are injected through the
camera's control FIFO at the moment the body chooses; every result is plain data."""

from __future__ import annotations

import os
import time
from typing import Any

from tactile_rig.core.clock import RealClock
from tactile_rig.core.errors import DeviceTimeout, FrozenStream, NotConnected
from tactile_rig.devices.camera import photometric_lock
from tactile_rig.devices.camera_models import camera_model
from tactile_rig.drivers.camera import CameraConfig, FingertipCamera
from tactile_rig.drivers.reconnect import Reconnect
from tests._camera_contract import fifo_injector


def _read_until(cam: FingertipCamera, error: type[BaseException], timeout_s: float, limit_s: float) -> dict[str, Any]:
    """Read until ``error`` is raised (frames in flight before a fault may still come): how long the
    raising read took and how many frames came first."""
    t_end, frames = time.monotonic() + limit_s, 0
    while time.monotonic() < t_end:
        t0 = time.monotonic()
        try:
            cam.read(timeout_s=timeout_s)
            frames += 1
        except error as exc:
            return {"raised": type(exc).__name__, "took_s": time.monotonic() - t0, "frames_before": frames}
    return {"raised": None, "frames_before": frames}


def _frames_again(cam: FingertipCamera, limit_s: float) -> bool:
    t_end = time.monotonic() + limit_s
    while time.monotonic() < t_end:
        try:
            cam.read(timeout_s=0.5)
            return True
        except (DeviceTimeout, NotConnected):
            time.sleep(0.05)
    return False


def driver_through_faults(port: str, fifo: str) -> dict[str, Any]:
    """Open with the C310's photometric lock at 50 Hz mains; a stall shorter than OpenCV's select
    timeout, a longer one, a freeze, an unplug with its replug; close during a stall."""
    os.environ.pop("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", None)  # the driver's own choice
    inject = fifo_injector(fifo)
    cfg = CameraConfig(fourcc="YUYV", width=320, height=240, fps=30, mains_hz=50, frozen_after=12)
    policy = Reconnect(RealClock(), initial_s=0.05, max_s=0.4)
    out: dict[str, Any] = {}
    cam = FingertipCamera(port, cfg, reconnect_policy=policy)
    cam.open()
    out["threaded"] = cam.threaded
    out["format"] = cam.format
    out["readback"] = cam.readback
    out["select_timeout"] = os.environ.get("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT")
    first = [cam.read(timeout_s=2.0) for _ in range(5)]
    out["shapes"] = sorted({f.image.shape for f in first})
    out["seqs_increase"] = all(b.seq > a.seq for a, b in zip(first, first[1:]))

    # a stall shorter than the backend's 1 s wait: only the reader's deadline shows it
    src0 = cam.stats.source_timeouts
    inject("stall", 0.7)
    out["short_stall"] = _read_until(cam, DeviceTimeout, 0.25, 2.0)
    out["short_stall"]["frames_again"] = _frames_again(cam, 2.0)
    out["short_stall"]["source_timeouts"] = cam.stats.source_timeouts - src0

    # a stall longer than the backend's wait: the capture thread's reads fail too, and frames resume
    src0 = cam.stats.source_timeouts
    inject("stall", 2.6)
    out["long_stall"] = _read_until(cam, DeviceTimeout, 0.25, 2.0)
    out["long_stall"]["frames_again"] = _frames_again(cam, 4.0)
    out["long_stall"]["source_timeouts"] = cam.stats.source_timeouts - src0
    out["long_stall"]["disconnects"] = cam.stats.disconnects

    # a freeze: identical frames, FrozenStream once frozen_after of them came in a row
    inject("freeze", 1.0)
    out["freeze"] = _read_until(cam, FrozenStream, 1.0, 2.0)
    out["freeze"]["duplicates"] = cam.stats.duplicates
    out["freeze"]["frames_again"] = _frames_again(cam, 3.0)

    # unplug for 0.8 s: reads fail fast with NotConnected, the camera is reopened, relocked, re-verified
    inject("unplug", 0.8)
    out["unplug"] = _read_until(cam, NotConnected, 1.0, 3.0)
    t0 = time.monotonic()
    fast = []
    while cam.reconnect_policy is not None and cam.reconnect_policy.away and time.monotonic() - t0 < 5.0:
        t1 = time.monotonic()
        try:
            cam.read(timeout_s=1.0)
        except NotConnected as exc:
            fast.append((time.monotonic() - t1, str(exc)))
            time.sleep(0.05)
    out["unplug"]["away_reads"] = fast
    out["unplug"]["frames_again"] = _frames_again(cam, 3.0)
    out["unplug"]["stats"] = cam.stats.to_dict()
    out["unplug"]["readback"] = cam.read_controls()

    inject("stall", 5.0)
    time.sleep(0.2)
    t0 = time.monotonic()
    cam.close()
    out["close_during_stall_s"] = time.monotonic() - t0
    out["closed_reads"] = _read_until(cam, NotConnected, 0.5, 1.0)["raised"]
    return out


def driver_on_a_model(port: str, model_key: str, view_name: str | None, frames: int = 2) -> dict[str, Any]:
    """Open the camera as its model says (default stream, its photometric lock at 50 Hz, its SDK's view)
    and return what the driver got: format, readback, frames with their device timestamps."""
    model = camera_model(model_key)
    fmt = model.formats[0]
    frame = fmt.frames[fmt.default_frame]
    view = next((v for v in model.sdk_views if v.name == view_name), None) if view_name else None
    cfg = CameraConfig(fourcc=fmt.fourcc, width=frame.width_px, height=frame.height_px,
                       fps=model.modes()[(fmt.fourcc, frame.width_px, frame.height_px)],
                       controls=photometric_lock(model, 50), view=view)
    with FingertipCamera(port, cfg) as cam:
        got = [cam.read(timeout_s=10.0) for _ in range(frames)]
        return {"format": cam.format, "readback": cam.readback,
                "frames": [(f.t_device_s, f.image) for f in got]}


def source_without_linuxpy(port: str, fifo: str) -> dict[str, Any]:
    """OpenCVSource where linuxpy is not installed: the controls OpenCV has no property for are refused
    naming the extra, and a stall is still told from an unplug (by how soon the reads fail)."""
    import tactile_rig.drivers.camera_opencv as camera_opencv

    camera_opencv.linuxpy_problem = lambda: "linuxpy is not installed: pip install 'tactile-rig[v4l2]' (linuxpy)"
    os.environ.pop("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", None)
    inject = fifo_injector(fifo)
    src = camera_opencv.OpenCVSource(port)
    src.open()
    src.set_format("YUYV", 320, 240, 30.0)
    out: dict[str, Any] = {"plf": (src.set_control("power_line_frequency", 1), src.refusal("power_line_frequency"),
                                   src.get_control("power_line_frequency")),
                           "gain": (src.set_control("gain", 100), src.get_control("gain"))}
    src.read()
    inject("stall", 1.6)
    kinds = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < 4.0:
        kinds.append("frame" if src.read() is not None else "none")
        if "none" in kinds and kinds[-1] == "frame":
            break
    out["stall"] = kinds
    inject("unplug", 5.0)
    t0 = time.monotonic()
    results = []
    while time.monotonic() - t0 < 3.0:
        try:
            results.append("frame" if src.read() is not None else "none")
        except NotConnected:
            results.append("NotConnected")
            break
    out["unplug"] = (results, time.monotonic() - t0)
    src.close()
    return out

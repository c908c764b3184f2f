"""What a camera :class:`~tactile_rig.drivers.camera_source.FrameSource` does, observed the same way on
every backend (tests/drivers/test_camera_source_contract.py compares the observations).

:func:`observe` drives a source through a session a bench runs (format, frames, controls, a format
change, close); :func:`observe_faults` through the faults (freeze, stall, unplug and replug), injected
by a callback ``inject(kind, seconds)``. Both return plain data. The ``*_v4l2`` variants run them on
OpenCVSource over a device path, in a child process started with an emulated camera's environment,
injecting faults through the camera's control FIFO.
"""

from __future__ import annotations

import hashlib
import os
import time
from typing import Any, Callable

from tactile_rig.core.errors import NotConnected
from tactile_rig.drivers.camera import OpenCVSource


def observe(source: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"channel_order": source.channel_order}
    source.open()
    out["open"] = source.is_open
    out["format"] = list(source.set_format("MJPG", 640, 480, 30.0))
    frames = [source.read(2.0) for _ in range(12)]
    out["frames"] = sum(f is not None for f in frames)
    out["shapes"] = sorted({tuple(f.image.shape) for f in frames if f is not None})
    stamps = [f.t_device_s for f in frames if f is not None]
    out["stamp_steps_s"] = [b - a for a, b in zip(stamps, stamps[1:])]
    out["snapped"] = list(source.set_format("MJPG", 700, 500, 30.0))
    out["power_on"] = {n: source.get_control(n) for n in ("exposure_dynamic_framerate", "power_line_frequency")}
    writes = [("auto_exposure", 1), ("exposure_time_absolute", 250), ("auto_exposure", 3),
              ("exposure_time_absolute", 300), ("white_balance_automatic", 0), ("white_balance_temperature", 5005),
              ("gain", 1000), ("gain", 100), ("hue", 3), ("exposure_dynamic_framerate", 0),
              ("power_line_frequency", 1), ("power_line_frequency", 3)]
    out["writes"] = [(name, value, source.set_control(name, value), source.get_control(name)) for name, value in writes]
    out["format_change"] = list(source.set_format("YUYV", 320, 240, 30.0))
    out["after_format_change"] = {n: source.get_control(n) for n in ("gain", "power_line_frequency")}
    f = source.read(2.0)
    out["shape_after_format_change"] = None if f is None else tuple(f.image.shape)
    source.close()
    out["closed"] = not source.is_open
    try:
        source.read(0.5)
        out["read_after_close"] = "returned"
    except NotConnected:
        out["read_after_close"] = "NotConnected"
    return out


def _digest(frame: Any) -> str:
    return hashlib.sha256(frame.image.tobytes()).hexdigest()[:12]


def observe_faults(source: Any, inject: Callable[[str, float], None]) -> dict[str, Any]:
    """Freeze 0.5 s, stall 1.5 s, unplug 0.6 s, each after a healthy stretch, then a reopen."""
    out: dict[str, Any] = {}
    source.open()
    source.set_format("YUYV", 320, 240, 30.0)
    for _ in range(3):
        source.read(2.0)
    inject("freeze", 0.5)
    frozen = [source.read(2.0) for _ in range(20)]
    digests = [_digest(f) for f in frozen if f is not None]
    runs, run = [], 1
    for a, b in zip(digests, digests[1:]):
        run = run + 1 if a == b else 1
        runs.append(run)
    stamps = [f.t_device_s for f in frozen if f is not None]
    out["freeze"] = {"longest_identical_run": max(runs, default=1), "moves_after": digests[-1] != digests[-2],
                     "stamps_advance": all(b > a for a, b in zip(stamps, stamps[1:]))}
    inject("stall", 1.5)
    t0, kinds = time.monotonic(), []
    while time.monotonic() - t0 < 4.0:
        f = source.read(0.3)
        kinds.append("frame" if f is not None else "none")
        if "none" in kinds and kinds[-1] == "frame":
            break
    out["stall"] = {"no_frame_seen": "none" in kinds, "frames_after": kinds[-1] == "frame",
                    "still_open": source.is_open}
    source.set_control("exposure_dynamic_framerate", 0)
    source.set_control("power_line_frequency", 1)
    inject("unplug", 0.6)
    t0, result = time.monotonic(), "frames only"
    while time.monotonic() - t0 < 3.0:
        try:
            source.read(0.5)
        except NotConnected:
            result = "NotConnected"
            break
    out["unplug"] = {"read": result, "within_s": time.monotonic() - t0 < 2.0}
    source.close()
    time.sleep(1.0)  # back under the same path by now
    source.open()
    out["replug"] = {"controls": {n: source.get_control(n) for n in ("exposure_dynamic_framerate", "power_line_frequency",
                                                                       "auto_exposure")},
                     "reads": source.set_format("YUYV", 320, 240, 30.0)[:3] == ("YUYV", 320, 240)
                     and source.read(2.0) is not None}
    source.close()
    return out


def observe_v4l2(port: str) -> dict[str, Any]:
    return observe(OpenCVSource(port))


def fifo_injector(fifo: str) -> Callable[[str, float], None]:
    """``inject(kind, seconds)`` writing ``kind seconds`` lines to an emulated camera's control FIFO."""
    def inject(kind: str, seconds: float) -> None:
        fd = os.open(fifo, os.O_WRONLY)
        try:
            os.write(fd, f"{kind} {seconds}\n".encode())
        finally:
            os.close(fd)
    return inject


def observe_faults_v4l2(port: str, fifo: str) -> dict[str, Any]:
    os.environ.pop("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", None)  # the source's own choice, 1 s
    out = observe_faults(OpenCVSource(port), fifo_injector(fifo))
    out["select_timeout"] = os.environ.get("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT")
    return out

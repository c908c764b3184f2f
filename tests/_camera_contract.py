"""What a camera :class:`~tactile_rig.drivers.camera.FrameSource` does, observed the same way on every
backend (tests/drivers/test_camera_source_contract.py compares the observations).

:func:`observe` drives a source through a session a bench runs (format, frames, controls, a format
change, close) and returns plain data; :func:`observe_v4l2` is the same on OpenCVSource over a
device path, for a child process started with an emulated camera's environment.
"""

from __future__ import annotations

from typing import Any

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
    writes = [("auto_exposure", 1), ("exposure_time_absolute", 250), ("auto_exposure", 3),
              ("exposure_time_absolute", 300), ("white_balance_automatic", 0), ("white_balance_temperature", 5005),
              ("gain", 1000), ("gain", 100), ("hue", 3)]
    out["writes"] = [(name, value, source.set_control(name, value), source.get_control(name)) for name, value in writes]
    out["format_change"] = list(source.set_format("YUYV", 320, 240, 30.0))
    out["gain_after_format_change"] = source.get_control("gain")
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


def observe_v4l2(port: str) -> dict[str, Any]:
    return observe(OpenCVSource(port))

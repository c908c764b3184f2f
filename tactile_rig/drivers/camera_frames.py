"""What the camera driver makes of a source's raw frames: the newest frame, its checks and counters.

:class:`NewestFrame` keeps only the newest frame (a slow consumer never works through a backlog of
stale ones), numbers the frames it accepts, flags duplicates (the same content or the same device
timestamp as the previous frame), counts the frames a device counter says were skipped, measures
the frame rate on arrival and says when a run of identical frames means a frozen stream. Every
frame is BGR (a source that gives RGB is converted here, once) and, when the camera's vendor SDK
crops and resizes its raw frame (:class:`~tactile_rig.devices.camera_models.SdkView`), is the view
that SDK gives, the one the perception's calibrations were made on.
"""

from __future__ import annotations

import threading
import zlib
from collections import deque
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from tactile_rig.core.deprecation import deprecated_alias
from tactile_rig.core.types import RawFrame
from tactile_rig.devices.camera_models import SdkView
from tactile_rig.drivers.base import DriverStats

__all__ = ["Frame", "CameraStats", "NewestFrame", "sdk_view_image"]


@dataclass(frozen=True)
class Frame:
    """A captured frame: ``image`` is BGR uint8; ``seq`` counts frames this driver accepted;
    ``t_host_s`` when it was accepted (driver clock), ``t_device_s`` the device's timestamp."""

    image: np.ndarray
    seq: int
    t_host_s: float
    t_device_s: float | None
    device_seq: int | None = None
    duplicate: bool = False


@dataclass
class CameraStats(DriverStats):
    """Counters since open: the port counters every driver keeps (``disconnects``, ``reconnects``),
    frames accepted, duplicates, device frames skipped (where the source has a frame counter),
    reads that raised DeviceTimeout, source reads that waited in vain (``source_timeouts``: OpenCV's
    select timeouts), the frame rate measured on arrival, whether the stream is frozen now."""

    frames: int = 0
    duplicates: int = 0
    dropped: int = 0
    timeouts: int = 0
    source_timeouts: int = 0
    measured_fps: float = 0.0
    frozen: bool = False

    reopens = deprecated_alias("reconnects")


def sdk_view_image(image: np.ndarray, view: SdkView) -> np.ndarray:
    """``image`` (a raw BGR frame) as ``view``'s SDK shows it: cropped to its crop box and resized to its
    output size with ``cv2.resize``'s default interpolation, as gs_sdk and gsrobotics do; transposed and
    flipped vertically for digit-interface's portrait view."""
    h, w = image.shape[:2]
    x0, y0, x1, y1 = view.crop_box(w, h)
    out = image[y0:y1, x0:x1]
    if view.output_px is not None and (out.shape[1], out.shape[0]) != tuple(view.output_px):
        out = cv2.resize(out, tuple(view.output_px))
    if view.transpose_flip:
        out = cv2.flip(cv2.transpose(out), 0)
    return np.ascontiguousarray(out)


class NewestFrame:
    """The newest accepted frame and the counters, shared by the thread that captures and the ones
    that read (:attr:`cond` guards them); see the module doc."""

    def __init__(self, stats: CameraStats, *, frozen_after: int, view: SdkView | None = None) -> None:
        self.stats = stats
        self.frozen_after = int(frozen_after)
        self.view = view
        self.cond = threading.Condition()
        self.latest: Frame | None = None
        self.last_read_seq = -1
        self._listeners: list[Callable[[Frame], None]] = []
        self._t_hist: deque[float] = deque(maxlen=30)
        self.new_stream()

    def new_stream(self) -> None:
        """A new stream (after a reopen): its device clock and frame counter start afresh."""
        self._last_crc: int | None = None
        self._last_t_dev: float | None = None
        self._last_dev_seq: int | None = None
        self.same_run = 0

    def accept(self, raw: RawFrame, channel_order: str, t_host_s: float) -> Frame:
        """Turn a raw frame into the next :class:`Frame`, make it the newest, tell the listeners."""
        img = raw.image
        if channel_order == "RGB":
            img = np.ascontiguousarray(img[..., ::-1])
        elif channel_order != "BGR":
            raise ValueError(f"channel_order={channel_order!r}; expected 'BGR' or 'RGB'")
        crc = zlib.crc32(np.ascontiguousarray(img).data)
        same_content = crc == self._last_crc
        same_time = raw.t_device_s is not None and raw.t_device_s == self._last_t_dev
        duplicate = same_content or same_time
        self.same_run = self.same_run + 1 if same_content else 0
        st = self.stats
        if raw.device_seq is not None and self._last_dev_seq is not None and raw.device_seq > self._last_dev_seq + 1:
            st.dropped += raw.device_seq - self._last_dev_seq - 1
        self._last_crc, self._last_t_dev, self._last_dev_seq = crc, raw.t_device_s, raw.device_seq
        if self.view is not None:
            img = sdk_view_image(img, self.view)
        with self.cond:
            frame = Frame(img, st.frames, t_host_s, raw.t_device_s, raw.device_seq, duplicate)
            st.frames += 1
            st.duplicates += int(duplicate)
            st.frozen = self.same_run + 1 >= self.frozen_after
            if not duplicate:
                self._t_hist.append(t_host_s)
            if len(self._t_hist) >= 2 and self._t_hist[-1] > self._t_hist[0]:
                st.measured_fps = (len(self._t_hist) - 1) / (self._t_hist[-1] - self._t_hist[0])
            self.latest = frame
            self.cond.notify_all()
            listeners = list(self._listeners)
        for fn in listeners:
            fn(frame)
        return frame

    def take_newer(self) -> tuple[Frame | None, bool]:
        """(the newest frame if it was not returned before, whether the stream is frozen); marks it
        returned. Call with :attr:`cond` held."""
        fr = self.latest
        if fr is None or fr.seq <= self.last_read_seq:
            return None, False
        self.last_read_seq = fr.seq  # consumed, even when it is reported as frozen
        return fr, self.stats.frozen

    def add_listener(self, fn: Callable[[Frame], None]) -> None:
        with self.cond:
            self._listeners.append(fn)

    def remove_listener(self, fn: Callable[[Frame], None]) -> None:
        with self.cond:
            if fn in self._listeners:
                self._listeners.remove(fn)

"""Replaying recordings: a summary, a message dump, and a recording served as a mock camera.

:class:`RecordedFrameSource` satisfies the :class:`tactile_rig.drivers.camera.FrameSource`
protocol, so ``FingertipCamera(RecordedFrameSource("run.mcap"), clock=VirtualClock())`` replays a
session's frames through the same driver (and perception) as a live camera, each frame with its
recorded time as the device timestamp.
"""

from __future__ import annotations

import base64
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from tactile_rig.core.clock import Clock
from tactile_rig.core.errors import NotConnected
from tactile_rig.rig.files import check_file
from tactile_rig.drivers.camera import RawFrame
from tactile_rig.rig.messages import IMAGE_SCHEMAS
from tactile_rig.rig.recording import (
    MAX_RECORDING_BYTES,
    Message,
    Recording,
    decode_image,
    iter_messages,
    read_recording,
)



def _plain(value: Any, include_bytes: bool) -> Any:
    """A decoded message's value as JSON: bytes (protobuf images, point clouds) as base64 with
    ``include_bytes``, else as ``"<N bytes>"``."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return base64.b64encode(bytes(value)).decode("ascii") if include_bytes else f"<{len(value)} bytes>"
    if isinstance(value, dict):
        return {k: _plain(v, include_bytes) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v, include_bytes) for v in value]
    return value


def summarize(path: str | Path) -> dict[str, Any]:
    """Per topic: message count, schema, first/last time (s); plus metadata names, attachments, truncation."""
    rec = Recording(check_file(path, "recording", max_bytes=MAX_RECORDING_BYTES))
    topics: dict[str, dict[str, Any]] = {}
    for m in iter_messages(path, into=rec):
        t = topics.setdefault(m.topic, {"count": 0, "schema": m.schema, "encoding": m.encoding, "first_t_s": m.t_s, "last_t_s": m.t_s})
        t["count"] += 1
        t["first_t_s"] = min(t["first_t_s"], m.t_s)
        t["last_t_s"] = max(t["last_t_s"], m.t_s)
    firsts = [t["first_t_s"] for t in topics.values()]
    lasts = [t["last_t_s"] for t in topics.values()]
    return {
        "path": str(path),
        "messages": sum(t["count"] for t in topics.values()),
        "duration_s": (max(lasts) - min(firsts)) if topics else 0.0,
        "topics": dict(sorted(topics.items())),
        "metadata": sorted(rec.metadata),
        "attachments": {k: len(v) for k, v in rec.attachments.items()},
        "truncated": rec.truncated,
        "truncation": rec.error,
    }


def dump(path: str | Path, *, topic: str | None = None, include_images: bool = False) -> Iterator[dict[str, Any]]:
    """Every message as a JSON-able dict (topic, t_s, schema, encoding, data); image and other byte
    payloads are elided as ``"<N bytes>"`` unless asked for (then base64)."""
    for m in iter_messages(path, topics={topic} if topic else None):
        data = _plain(m.data, include_images)
        if m.schema in IMAGE_SCHEMAS and not include_images and isinstance(data.get("data"), str) \
                and not data["data"].startswith("<"):  # a JSON recording's base64
            data["data"] = f"<{len(data['data']) * 3 // 4} bytes>"
        yield {"topic": m.topic, "t_s": m.t_s, "schema": m.schema, "encoding": m.encoding, "data": data}


def image_topics(rec: Recording) -> list[str]:
    return sorted({m.topic for m in rec.messages if m.schema in IMAGE_SCHEMAS})


class RecordedFrameSource:
    """A recording's frames as a camera backend (the ``FrameSource`` protocol of the camera driver).

    ``topic`` picks the camera (default: the only image topic). With a ``clock``, :meth:`read`
    returns a frame only once the clock has reached its recorded time (relative to the first frame
    and to when the source was opened), waiting on the clock for at most ``timeout_s``; without a
    clock, frames come one per read as fast as asked. ``loop`` restarts at the end; otherwise
    the end of the recording reads as a camera that stopped streaming (``read`` returns None after
    waiting ``timeout_s``, so the driver raises ``DeviceTimeout``).
    """

    channel_order = "BGR"

    def __init__(self, path: str | Path, *, topic: str | None = None, clock: Clock | None = None,
                 loop: bool = False) -> None:
        rec = read_recording(path)
        topics = image_topics(rec)
        if topic is None:
            if len(topics) != 1:
                raise ValueError(f"recording {path}: pick a camera topic with topic=...; image topics: "
                                 f"{', '.join(topics) or '(none)'}")
            topic = topics[0]
        elif topic not in topics:
            raise ValueError(f"recording {path}: no image topic {topic!r}; image topics: "
                             f"{', '.join(topics) or '(none)'}")
        self.name = f"replay:{Path(path).name}{topic}"
        self.topic = topic
        self._messages: list[Message] = rec.on(topic)
        self.clock = clock
        self.loop = loop
        self._i = 0
        self._open = False
        self._t_open_s = 0.0
        self._format: tuple[str, int, int, float] | None = None
        self._controls: dict[str, float] = {}

    def __len__(self) -> int:
        return len(self._messages)

    @property
    def is_open(self) -> bool:
        return self._open

    def open(self) -> None:
        self._open = True
        self._i = 0
        self._t_open_s = self.clock.now_s() if self.clock is not None else 0.0

    def close(self) -> None:
        self._open = False

    def native_format(self) -> tuple[int, int, float]:
        """(width, height, fps) as recorded: the format a camera on this source opens in by default."""
        if not self._messages:
            raise ValueError(f"{self.name}: the recording holds no frames on {self.topic}")
        first = self._messages[0].image()
        span = self._messages[-1].t_s - self._messages[0].t_s
        fps = (len(self._messages) - 1) / span if span > 0 else 30.0
        return int(first.shape[1]), int(first.shape[0]), float(fps)

    def set_format(self, fourcc: str, width: int, height: int, fps: float) -> tuple[str, int, int, float]:
        """A recording has the format it was recorded in: report that one (the driver checks it)."""
        if not self._messages:
            return (fourcc, width, height, fps)
        first = self._messages[0].image()
        span = self._messages[-1].t_s - self._messages[0].t_s
        rec_fps = (len(self._messages) - 1) / span if span > 0 else fps
        # Timestamps jitter: a requested rate within 10 % of the recorded one is what was recorded.
        got_fps = fps if abs(rec_fps - fps) <= 0.1 * fps else rec_fps
        self._format = (fourcc, int(first.shape[1]), int(first.shape[0]), float(got_fps))
        return self._format

    def set_control(self, name: str, value: float) -> bool:
        self._controls[name] = float(value)  # recorded frames ignore controls; read-back agrees
        return True

    def get_control(self, name: str) -> float | None:
        return self._controls.get(name)

    def frames(self) -> Iterator[tuple[float, np.ndarray]]:
        """Every recorded frame as ``(t_s, image)``, in order."""
        for m in self._messages:
            yield m.t_s, decode_image(m.schema, m.data, f"{self.name} at {m.t_s:.3f} s")

    def read(self, timeout_s: float | None = None) -> Any:
        """The next frame as a ``RawFrame`` (recorded time as device time), or None on timeout."""

        if not self._open:
            raise NotConnected("replay source is not open", device=self.name)
        if self._i >= len(self._messages):
            if not self.loop or not self._messages:
                if self.clock is not None and timeout_s:
                    self.clock.sleep(timeout_s)
                return None
            self._i = 0
            self._t_open_s = self.clock.now_s() if self.clock is not None else 0.0
        m = self._messages[self._i]
        if self.clock is not None:
            due_s = self._t_open_s + (m.t_s - self._messages[0].t_s)
            wait_s = due_s - self.clock.now_s()
            if wait_s > 0:
                if timeout_s is not None and wait_s > timeout_s:
                    self.clock.sleep(timeout_s)
                    return None
                self.clock.sleep(wait_s)
        self._i += 1
        return RawFrame(image=m.image(), t_device_s=m.t_s, device_seq=self._i - 1)

"""Live view: a running session's messages over the Foxglove WebSocket protocol on 127.0.0.1.

:class:`LiveServer` publishes the same topics, schemas and JSON bodies as a session recording
(:mod:`tactile_rig.rig.recording`: ``/<name>/image/compressed`` as ``foxglove.CompressedImage``,
``/perception/<name>``, ``/state/<device>``, ``/command/<device>``, ``/jig/pose``, ``/scale/force``),
so the Foxglove app shows a live session with the layout it uses for the recordings. It has the
recorder's ``write_*`` methods; :class:`Tee` sends every message to a recorder and a live server.

The server is the ``foxglove-sdk`` package (the optional extra ``live``), imported when a server
starts. Channels are created on first use and advertised to connected clients then; a client sees
messages from the moment it subscribes (nothing is replayed). Each server has its own
``foxglove.Context`` so two servers in one process do not share channels.
"""

from __future__ import annotations

import base64
import json
import threading
import time
from typing import Any, Mapping

import numpy as np

from tactile_rig.core.clock import Clock, RealClock
from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.recording import SCHEMAS, TopicWriter, camera_topic

__all__ = ["DEFAULT_LIVE_PORT", "LiveServer", "Tee", "require_foxglove"]

DEFAULT_LIVE_PORT = 8765  # the Foxglove app's default for "Foxglove WebSocket"
LINGER_S = 0.5  # close(): time for queued messages to reach a subscribed viewer
BACKLOG_MESSAGES = 16384  # per client; a simulated episode's trace arrives as one burst


def require_foxglove() -> Any:
    """The ``foxglove`` module, or ModuleNotFoundError saying which extra installs it."""
    try:
        import foxglove
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError("the live view needs the 'foxglove-sdk' package: pip install 'tactile-rig[live]'",
                                  name=exc.name) from exc
    return foxglove


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(type(obj).__name__)


def _encode(body: Mapping[str, Any]) -> bytes:
    try:
        return json.dumps(body, separators=(",", ":"), allow_nan=False, default=_default).encode()
    except (TypeError, ValueError):
        return json.dumps(to_jsonable(dict(body)), separators=(",", ":"), allow_nan=False).encode()


class LiveServer(TopicWriter):
    """A Foxglove WebSocket server on ``host:port`` (``port=0``: any free port; see :attr:`port`).

    ``clock`` gives each message's ``t_s`` (default: monotonic wall time); log times are Unix ns.
    ``jpeg_quality`` applies to frames (the live view always sends JPEG: it is a view, not a record).
    """

    def __init__(self, *, port: int = DEFAULT_LIVE_PORT, host: str = "127.0.0.1", name: str = "tactile-rig",
                 clock: Clock | None = None, jpeg_quality: int = 80) -> None:
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ValueError(f"live view host {host!r}: the live view serves on loopback only (127.0.0.1)")
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"live view port {port!r} must be in 0..65535")
        fg = require_foxglove()
        self.clock: Clock = clock if clock is not None else RealClock()
        self.jpeg_quality = int(jpeg_quality)
        self._fg = fg
        self._ctx = fg.Context()
        self._sub_cond = threading.Condition()
        self.subscribed_topics: set[str] = set()
        self._server = fg.start_server(name=name, host=host, port=int(port), context=self._ctx,
                                       server_listener=_Listener(self), message_backlog_size=BACKLOG_MESSAGES)
        self._channels: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._epoch_ns = time.time_ns() - int(self.clock.now_s() * 1e9)
        self.published = 0

    def advertise(self, topic: str, schema: str = "tactile_rig.Json") -> None:
        """Create ``topic``'s channel now (clients see it and may subscribe before its first message)."""
        self._channel(topic, schema)

    def wait_for_subscriber(self, timeout_s: float, topics: set[str] | None = None) -> bool:
        """Block until a client has subscribed to every topic of ``topics`` (None: to any channel), or
        ``timeout_s`` passes; True if it did. A session that publishes a burst at once (a simulated
        episode) waits so a viewer sees it from its first message."""
        def ready() -> bool:
            return bool(self.subscribed_topics) if topics is None else topics <= self.subscribed_topics

        with self._sub_cond:
            return self._sub_cond.wait_for(ready, timeout=max(0.0, float(timeout_s)))

    def use_clock(self, clock: Clock) -> None:
        """Time messages by ``clock`` from now on (a session's clock, virtual or real)."""
        self.clock = clock
        self._epoch_ns = time.time_ns() - int(clock.now_s() * 1e9)

    @property
    def port(self) -> int:
        """The TCP port the server listens on."""
        return int(self._server.port)

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    def _channel(self, topic: str, schema: str) -> Any:
        ch = self._channels.get(topic)
        if ch is None:
            with self._lock:
                ch = self._channels.get(topic)
                if ch is None:
                    body = json.dumps(SCHEMAS.get(schema, SCHEMAS["tactile_rig.Json"])).encode()
                    ch = self._fg.Channel(topic, schema=self._fg.Schema(name=schema, encoding="jsonschema", data=body),
                                          message_encoding="json", context=self._ctx)
                    self._channels[topic] = ch
        return ch

    def log_time_ns(self, t_s: float) -> int:
        return self._epoch_ns + int(round(t_s * 1e9))

    # -- the recorder's interface ---------------------------------------------------------------
    def write(self, topic: str, payload: Mapping[str, Any], *, t_s: float | None = None,
              schema: str = "tactile_rig.Json") -> None:
        """Publish one JSON message on ``topic`` (``t_s`` defaults to the clock's now)."""
        t = self.clock.now_s() if t_s is None else float(t_s)
        body = dict(payload)
        body.setdefault("t_s", t)
        self._channel(topic, schema).log(_encode(body), log_time=self.log_time_ns(t))
        self.published += 1

    def write_frame(self, camera: str, image: np.ndarray, *, t_s: float | None = None,
                    compress: str | None = None) -> None:
        """A camera frame as ``/<camera>/image/compressed`` (JPEG, or PNG when ``compress='png'``)."""
        import cv2

        t = self.clock.now_s() if t_s is None else float(t_s)
        ext = ".png" if compress == "png" else ".jpg"
        params = [] if ext == ".png" else [int(cv2.IMWRITE_JPEG_QUALITY), self.jpeg_quality]
        ok, buf = cv2.imencode(ext, np.ascontiguousarray(image), params)
        if not ok:
            raise ValueError(f"camera {camera!r}: OpenCV could not encode the frame")
        ns = self.log_time_ns(t)
        msg = {"timestamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}, "frame_id": camera,
               "format": "png" if ext == ".png" else "jpeg", "data": base64.b64encode(buf.tobytes()).decode("ascii")}
        self.write(camera_topic(camera, compressed=True), msg, t_s=t, schema="foxglove.CompressedImage")

    def write_trace(self, name: str, trace: Any, *, t0_s: float = 0.0) -> int:
        """A controller's :class:`~tactile_rig.core.types.Trace`, one message per sample on
        ``/perception/<name>`` at ``t0_s`` + its time; returns the number of samples."""
        for i, t in enumerate(trace.t_s):
            self.write_perception(name, {k: v[i] for k, v in trace.channels.items()}, t_s=t0_s + t)
        return len(trace.t_s)

    # Metadata and attachments belong to the recording; the live view has no place for them.
    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        pass

    def add_attachment(self, name: str, data: bytes, *, media_type: str = "") -> None:
        pass

    def add_bench(self, bench: Any) -> None:
        pass

    def add_calibration(self, name: str, **kw: Any) -> None:
        pass

    def flush(self) -> None:
        pass

    def close(self) -> None:
        """Stop the server (idempotent). With a subscriber, first give the messages still queued for it
        ``LINGER_S`` to leave (a session's last messages are the ones a viewer wants to see)."""
        server, self._server = self._server, None
        if server is not None:
            if self.subscribed_topics:
                time.sleep(LINGER_S)
            for ch in self._channels.values():
                ch.close()
            server.stop()

    def __enter__(self) -> "LiveServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Listener:
    """The SDK's server listener: counts subscriptions (see :meth:`LiveServer.wait_for_subscriber`)."""

    def __init__(self, server: LiveServer) -> None:
        self.server = server

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self.server._sub_cond:
            self.server.subscribed_topics.add(str(channel.topic))
            self.server._sub_cond.notify_all()

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        pass


class Tee:
    """Send every ``write_*`` / metadata call to several sinks (a Recorder and a LiveServer); ``None``
    sinks are skipped. :attr:`path` is the first sink's that has one (the recording's file)."""

    def __init__(self, *sinks: Any) -> None:
        self.sinks = [s for s in sinks if s is not None]
        self.path = next((s.path for s in self.sinks if hasattr(s, "path")), None)
        self.clock = self.sinks[0].clock if self.sinks else RealClock()

    def __getattr__(self, name: str) -> Any:
        if not (name.startswith("write") or name.startswith("add_") or name in ("flush",)):
            raise AttributeError(name)

        def call(*args: Any, **kw: Any) -> None:
            for s in self.sinks:
                getattr(s, name)(*args, **kw)

        return call

    def close(self) -> None:
        for s in self.sinks:
            s.close()

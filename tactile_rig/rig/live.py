"""Live view: a running session's messages over the Foxglove WebSocket protocol on 127.0.0.1.

:class:`LiveServer` is a :class:`~tactile_rig.rig.messages.TopicWriter`: it publishes the topics,
types and bytes a recording writes (:mod:`tactile_rig.rig.recording`), so the Foxglove app shows a
live session with the layout it uses for the recordings; :class:`Tee` hands every message, encoded
once, to a recorder and a live server.

A session may offer services (Foxglove's Call Service panel, JSON requests and responses): each is
queued to the session's own loop, which runs it between two polls (:meth:`LiveServer.run_pending`),
so a service never talks to a device from another thread; a service that the bench is not in a
state to do is refused with a failure naming why. Read-only parameters describe the session.

The server is the ``foxglove-sdk`` package (the optional extra ``live``), imported when a server
starts. Channels are created on first use and advertised to connected clients then; a client sees
messages from the moment it subscribes (nothing is replayed). Each server has its own
``foxglove.Context`` so two servers in one process do not share channels.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from tactile_rig.core.clock import Clock, RealClock
from tactile_rig.core.errors import RigError
from tactile_rig.rig.messages import Encoded, SchemaDef, Tee, TopicWriter, schema_for

__all__ = ["DEFAULT_LIVE_PORT", "LiveServer", "Tee", "require_foxglove", "ServiceRefused", "SERVICE_TIMEOUT_S"]

DEFAULT_LIVE_PORT = 8765  # the Foxglove app's default for "Foxglove WebSocket"
LINGER_S = 0.5  # close(): time for queued messages to reach a subscribed viewer
BACKLOG_MESSAGES = 16384  # per client; a simulated episode's trace arrives as one burst
SERVICE_TIMEOUT_S = 5.0  # a service call the session has not run by then fails (the loop is busy)

_REQUEST_SCHEMA = {"title": "tactile_rig.ServiceRequest", "type": "object",
                   "description": "arguments of the service, if any (none of the rig's services takes any)"}
_RESPONSE_SCHEMA = {"title": "tactile_rig.ServiceResponse", "type": "object",
                    "properties": {"ok": {"type": "boolean"}, "message": {"type": "string"}}}


class ServiceRefused(RigError):
    """A live service the bench is not in a state to do (the message says why)."""


def require_foxglove() -> Any:
    """The ``foxglove`` module, or ModuleNotFoundError saying which extra installs it."""
    try:
        import foxglove
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError("the live view needs the 'foxglove-sdk' package: pip install 'tactile-rig[live]'",
                                  name=exc.name) from exc
    return foxglove


@dataclass
class _Call:
    name: str
    args: dict[str, Any]
    future: Future


class LiveServer(TopicWriter):
    """A Foxglove WebSocket server on ``host:port`` (``port=0``: any free port; see :attr:`port`).

    ``clock`` gives each message's ``t_s`` (default: monotonic wall time); log times are Unix ns.
    Frames written to the server alone go as JPEG (``jpeg_quality``) unless ``compress='png'``: a
    view, not a record; through a :class:`Tee` the server sends what the recording keeps.
    """

    def __init__(self, *, port: int = DEFAULT_LIVE_PORT, host: str = "127.0.0.1", name: str = "tactile-rig",
                 clock: Clock | None = None, jpeg_quality: int = 80) -> None:
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ValueError(f"live view host {host!r}: the live view serves on loopback only (127.0.0.1)")
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"live view port {port!r} must be in 0..65535")
        if not 1 <= int(jpeg_quality) <= 100:
            raise ValueError(f"jpeg_quality={jpeg_quality!r} must be in 1..100")
        fg = require_foxglove()
        from foxglove.websocket import Capability

        self.clock = clock if clock is not None else RealClock()
        self.jpeg_quality = int(jpeg_quality)
        self._fg = fg
        self._ctx = fg.Context()
        self._sub_cond = threading.Condition()
        self.subscribed_topics: set[str] = set()
        self._params: dict[str, Any] = {}
        self._calls: queue.Queue[_Call] = queue.Queue()
        self._services: dict[str, Callable[[dict[str, Any]], str]] = {}
        self._server = fg.start_server(name=name, host=host, port=int(port), context=self._ctx,
                                       server_listener=_Listener(self), message_backlog_size=BACKLOG_MESSAGES,
                                       capabilities=[Capability.Services, Capability.Parameters],
                                       supported_encodings=["json"])
        self._channels: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._epoch_ns = time.time_ns() - int(self.clock.now_s() * 1e9)
        self.published = 0

    def advertise(self, topic: str, schema: str = "tactile_rig.Json") -> None:
        """Create ``topic``'s channel now (clients see it and may subscribe before its first message)."""
        self._channel(topic, schema_for(schema))

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

    def _channel(self, topic: str, schema: SchemaDef) -> Any:
        ch = self._channels.get(topic)
        if ch is None:
            with self._lock:
                ch = self._channels.get(topic)
                if ch is None:
                    ch = self._fg.Channel(topic, schema=self._fg.Schema(name=schema.name, encoding=schema.encoding,
                                                                        data=schema.data),
                                          message_encoding=schema.message_encoding, context=self._ctx)
                    self._channels[topic] = ch
        return ch

    def log_time_ns(self, t_s: float) -> int:
        return self._epoch_ns + int(round(t_s * 1e9))

    def publish(self, msg: Encoded) -> None:
        """Send one encoded message to the subscribed clients."""
        if self._server is None:
            raise ValueError("the live view is closed")
        self._channel(msg.topic, msg.schema).log(msg.data, log_time=msg.log_time_ns)
        self.published += 1

    def write_frame(self, camera: str, image: np.ndarray, *, t_s: float | None = None,
                    compress: str | None = None) -> None:
        """A camera frame as ``/<camera>/image/compressed`` (JPEG, or PNG when ``compress='png'``)."""
        super().write_frame(camera, image, t_s=t_s, compress="png" if compress == "png" else "jpeg")

    # -- services and parameters ----------------------------------------------------------------
    def add_service(self, name: str, handler: Callable[[dict[str, Any]], str]) -> None:
        """Offer service ``name``: a call is queued and ``handler(args)`` runs in the session's loop
        (:meth:`run_pending`); its return is the response's message, a :class:`ServiceRefused` (or
        any RigError/ValueError) a failure with its text."""
        if name in self._services:
            raise ValueError(f"live service {name!r} is already offered")
        fg = self._fg

        def schema(body: dict[str, Any]) -> Any:
            return fg.MessageSchema(encoding="json", schema=fg.Schema(name=str(body["title"]), encoding="jsonschema",
                                                                      data=json.dumps(body).encode()))

        svc = fg.Service(name, schema=fg.ServiceSchema(f"tactile_rig.{name}", request=schema(_REQUEST_SCHEMA),
                                                       response=schema(_RESPONSE_SCHEMA)),
                         handler=lambda req: self._call(name, req))
        self._services[name] = handler
        self._server.add_services([svc])

    def _call(self, name: str, request: Any) -> bytes:
        """The SDK's handler (its thread): queue the call, wait for the loop to run it."""
        try:
            args = json.loads(bytes(request.payload) or b"{}") if request.payload else {}
        except ValueError:
            raise ValueError(f"{name}: the request is not JSON") from None
        if not isinstance(args, dict):
            raise ValueError(f"{name}: the request must be a JSON object, got {type(args).__name__}")
        call = _Call(name, args, Future())
        self._calls.put(call)
        try:
            message = call.future.result(timeout=SERVICE_TIMEOUT_S)
        except TimeoutError:
            call.future.cancel()
            raise ServiceRefused(f"{name}: the session did not take the request within {SERVICE_TIMEOUT_S:g} s") from None
        return json.dumps({"ok": True, "message": message}).encode()

    def run_pending(self, log: TopicWriter | None = None) -> int:
        """Run the service calls queued since the last time (in the caller's thread: the session's
        loop); returns how many ran. Each outcome goes to ``/log`` of ``log`` (the session's
        :class:`Tee`, so the recording keeps it too; default: this server)."""
        sink = log if log is not None else self
        n = 0
        while True:
            try:
                call = self._calls.get_nowait()
            except queue.Empty:
                return n
            if not call.future.set_running_or_notify_cancel():
                continue
            n += 1
            try:
                message = self._services[call.name](call.args)
            except (RigError, ValueError) as exc:
                sink.write_log("live", f"{call.name} refused: {exc}", level="warning")
                call.future.set_exception(ServiceRefused(f"{call.name} refused: {exc}"))
            else:
                sink.write_log("live", f"{call.name}: {message}")
                call.future.set_result(message)

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """Read-only parameters a client may get (strings, numbers, booleans); set requests are refused."""
        self._params.update({str(k): v for k, v in values.items()})
        if self._server is not None:
            self._server.publish_parameter_values(self._parameters(list(values)))

    def _parameters(self, names: list[str] | None = None) -> list[Any]:
        keys = sorted(self._params) if not names else [n for n in names if n in self._params]
        return [self._fg.Parameter(k, value=self._params[k]) for k in keys]

    # -- closing --------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the server (idempotent). With a subscriber, first give the messages still queued for it
        ``LINGER_S`` to leave (a session's last messages are the ones a viewer wants to see)."""
        server, self._server = self._server, None
        if server is not None:
            if self.subscribed_topics:
                time.sleep(LINGER_S)
            while True:  # calls nobody will run: fail them now rather than at their timeout
                try:
                    self._calls.get_nowait().future.cancel()
                except queue.Empty:
                    break
            for ch in self._channels.values():
                ch.close()
            server.stop()

    def __enter__(self) -> "LiveServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Listener:
    """The SDK's server listener: counts subscriptions (see :meth:`LiveServer.wait_for_subscriber`),
    answers parameter requests from :meth:`LiveServer.set_parameters` and refuses to set them."""

    def __init__(self, server: LiveServer) -> None:
        self.server = server

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self.server._sub_cond:
            self.server.subscribed_topics.add(str(channel.topic))
            self.server._sub_cond.notify_all()

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        pass

    def on_get_parameters(self, client: Any, param_names: list[str], request_id: str | None = None) -> list[Any]:
        return self.server._parameters(list(param_names))

    def on_set_parameters(self, client: Any, parameters: list[Any], request_id: str | None = None) -> list[Any]:
        server = self.server._server
        if server is not None and parameters:
            names = ", ".join(str(p.name) for p in parameters)
            server.publish_status(f"parameters are read-only ({names}): they describe the session",
                                  self.server._fg.StatusLevel.Warning)
        return self.server._parameters([str(p.name) for p in parameters])

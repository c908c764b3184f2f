"""A minimal Foxglove WebSocket client for the tests: subscribes to every advertised channel and keeps
every message it receives (topic, log time, decoded body), in arrival order; calls services and gets
parameters.

It decodes on its own, from what the server advertises: ``json`` channels with the json module,
``protobuf`` channels from the advertised FileDescriptorSet with protobuf's own descriptor pool and
``json_format`` (never the package's reader), so a test checks the wire against the field's library.
"""

from __future__ import annotations

import base64
import itertools
import json
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
from websockets.sync.client import connect

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode: u8 op, u32 subscription id, u64 log time (ns), payload
SERVICE_CALL_REQUEST = 0x02  # u8 op, u32 service id, u32 call id, u32 encoding length, encoding, payload
SERVICE_CALL_RESPONSE = 0x03  # the same layout


@dataclass
class Received:
    topic: str
    log_time_ns: int
    data: dict[str, Any]
    schema: str = ""
    encoding: str = "json"
    raw: bytes = b""
    message: Any = None  # the protobuf object of a protobuf channel


def protobuf_class(schema_name: str, fds_bytes: bytes) -> Any:
    """The message class of a protobuf schema from its FileDescriptorSet."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(fds_bytes)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


@dataclass
class LiveClient:
    url: str
    messages: list[Received] = field(default_factory=list)
    advertised: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    encodings: dict[str, str] = field(default_factory=dict)  # topic -> message encoding
    services: dict[str, int] = field(default_factory=dict)  # name -> service id
    server_info: dict[str, Any] = field(default_factory=dict)
    statuses: list[dict[str, Any]] = field(default_factory=list)
    error: BaseException | None = None

    def __post_init__(self) -> None:
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._ws: Any = None
        self._classes: dict[str, Any] = {}
        self._replies: dict[Any, Any] = {}
        self._reply_cond = threading.Condition()
        self._ids = itertools.count(1)

    def start(self, timeout_s: float = 10.0) -> "LiveClient":
        self._thread.start()
        if not self._connected.wait(timeout_s):
            raise RuntimeError(f"could not connect to {self.url}: {self.error!r}")
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def on(self, topic: str) -> list[Received]:
        return [m for m in self.messages if m.topic == topic]

    def wait_for(self, topic: str, count: int, timeout_s: float = 10.0) -> bool:
        """Wait until ``count`` messages of ``topic`` have arrived (a loaded machine delivers late)."""
        deadline = time.monotonic() + timeout_s
        while len(self.on(topic)) < count and time.monotonic() < deadline and self._thread.is_alive():
            time.sleep(0.01)
        return len(self.on(topic)) >= count

    def _wait_reply(self, key: Any, timeout_s: float) -> Any:
        with self._reply_cond:
            if not self._reply_cond.wait_for(lambda: key in self._replies, timeout=timeout_s):
                raise TimeoutError(f"no reply to {key!r} within {timeout_s} s")
            return self._replies.pop(key)

    def wait_for_service(self, name: str, timeout_s: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while name not in self.services and time.monotonic() < deadline:
            time.sleep(0.01)
        return name in self.services

    def call_service(self, name: str, request: dict[str, Any] | None = None, timeout_s: float = 10.0) -> tuple[bool, Any]:
        """(True, decoded JSON response) or (False, the failure's message)."""
        if not self.wait_for_service(name, timeout_s):
            raise RuntimeError(f"service {name!r} not advertised; have {sorted(self.services)}")
        call_id = next(self._ids)
        enc = b"json"
        payload = json.dumps(request or {}).encode()
        self._ws.send(struct.pack("<BIII", SERVICE_CALL_REQUEST, self.services[name], call_id, len(enc)) + enc + payload)
        return self._wait_reply(("call", call_id), timeout_s)  # type: ignore[no-any-return]

    def get_parameters(self, names: list[str], timeout_s: float = 10.0) -> dict[str, Any]:
        rid = f"get-{next(self._ids)}"
        self._ws.send(json.dumps({"op": "getParameters", "parameterNames": names, "id": rid}))
        params = self._wait_reply(("params", rid), timeout_s)
        return {p["name"]: p.get("value") for p in params}

    def set_parameters(self, values: dict[str, Any], timeout_s: float = 10.0) -> dict[str, Any]:
        rid = f"set-{next(self._ids)}"
        self._ws.send(json.dumps({"op": "setParameters", "id": rid,
                                  "parameters": [{"name": k, "value": v} for k, v in values.items()]}))
        params = self._wait_reply(("params", rid), timeout_s)
        return {p["name"]: p.get("value") for p in params}

    def _decode(self, topic: str, payload: bytes) -> tuple[dict[str, Any], Any]:
        if self.encodings.get(topic) == "protobuf":
            msg = self._classes[topic].FromString(payload)
            return json_format.MessageToDict(msg, preserving_proto_field_name=True), msg
        return json.loads(payload), None

    def _run(self) -> None:
        deadline = time.monotonic() + 10.0
        ws = None
        while ws is None:
            try:
                ws = connect(self.url, subprotocols=[SUBPROTOCOL], open_timeout=2.0, max_size=None)
            except OSError as exc:  # the server is not up yet
                self.error = exc
                if time.monotonic() > deadline:
                    return
                time.sleep(0.05)
        self._ws = ws
        self._connected.set()
        subs: dict[int, str] = {}
        with ws:
            while not self._stop.is_set():
                try:
                    msg = ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                except Exception as exc:  # noqa: BLE001 - the server went away: keep what arrived
                    self.error = exc
                    return
                if isinstance(msg, str):
                    self._on_text(ws, json.loads(msg), subs)
                elif msg[0] == MESSAGE_DATA:
                    sid, t_ns = struct.unpack_from("<IQ", msg, 1)
                    topic = subs[sid]
                    data, pb = self._decode(topic, bytes(msg[13:]))
                    self.messages.append(Received(topic, t_ns, data, self.advertised.get(topic, ""),
                                                  self.encodings.get(topic, ""), bytes(msg[13:]), pb))
                elif msg[0] == SERVICE_CALL_RESPONSE:
                    _sid, call_id, n = struct.unpack_from("<III", msg, 1)
                    body = bytes(msg[13 + n:])
                    self._reply(("call", call_id), (True, json.loads(body) if body else None))

    def _reply(self, key: Any, value: Any) -> None:
        with self._reply_cond:
            self._replies[key] = value
            self._reply_cond.notify_all()

    def _on_text(self, ws: Any, d: dict[str, Any], subs: dict[int, str]) -> None:
        op = d.get("op")
        if op == "serverInfo":
            self.server_info = d
        elif op == "advertise":
            new = []
            for ch in d["channels"]:
                sid = len(subs) + 1
                subs[sid] = ch["topic"]
                self.advertised[ch["topic"]] = ch.get("schemaName", "")
                self.encodings[ch["topic"]] = ch.get("encoding", "")
                if ch.get("encoding") == "protobuf":
                    self._classes[ch["topic"]] = protobuf_class(ch["schemaName"], base64.b64decode(ch["schema"]))
                new.append({"id": sid, "channelId": ch["id"]})
            ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
        elif op == "advertiseServices":
            for s in d["services"]:
                self.services[s["name"]] = s["id"]
        elif op == "serviceCallFailure":
            self._reply(("call", d["callId"]), (False, d.get("message", "")))
        elif op == "parameterValues":
            self._reply(("params", d.get("id")), d.get("parameters", []))
        elif op == "status":
            self.statuses.append(d)

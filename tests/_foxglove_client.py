"""A minimal Foxglove WebSocket client for the tests: subscribes to every advertised channel and keeps
every message it receives (topic, log time, decoded JSON), in arrival order."""

from __future__ import annotations

import json
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from websockets.sync.client import connect

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode: u8 op, u32 subscription id, u64 log time (ns), payload


@dataclass
class Received:
    topic: str
    log_time_ns: int
    data: dict[str, Any]


@dataclass
class LiveClient:
    url: str
    messages: list[Received] = field(default_factory=list)
    advertised: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    server_info: dict[str, Any] = field(default_factory=dict)
    error: BaseException | None = None

    def __post_init__(self) -> None:
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

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
                    d = json.loads(msg)
                    if d.get("op") == "serverInfo":
                        self.server_info = d
                    elif d.get("op") == "advertise":
                        new = []
                        for ch in d["channels"]:
                            sid = len(subs) + 1
                            subs[sid] = ch["topic"]
                            self.advertised[ch["topic"]] = ch.get("schemaName", "")
                            new.append({"id": sid, "channelId": ch["id"]})
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                elif msg[0] == MESSAGE_DATA:
                    sid, t_ns = struct.unpack_from("<IQ", msg, 1)
                    self.messages.append(Received(subs[sid], t_ns, json.loads(msg[13:])))

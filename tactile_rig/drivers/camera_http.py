"""A camera served as MJPEG over HTTP (the rehearsal bench's cameras with ``--camera-transport http``, or
any network camera that speaks the same small protocol), as a :class:`~tactile_rig.drivers.camera.FrameSource`.

The port of such a camera in a bench file is its stream URL, ``http://127.0.0.1:PORT/stream.mjpg``.
The protocol (served by :mod:`tactile_rig.rig.rehearsal.camera_server`) mirrors what the V4L2 path
does with ioctls:

``GET  /format``                       ``{"fourcc", "width", "height", "fps"}``
``POST /format?fourcc=&width=&height=&fps=``  set it; answers the format the camera runs (it snaps)
``GET  /control?name=N``               ``{"name", "value"}`` (value null: no such control)
``POST /control?name=N&value=V``       ``{"accepted", "value"}`` (a write to an inactive control is refused)
``GET  /stream.mjpg``                  ``multipart/x-mixed-replace``: one JPEG per part, with headers
                                       ``X-Frame-Seq`` (the device's frame counter) and
                                       ``X-Timestamp-S`` (device time of exposure, s)

Each JPEG is decoded with OpenCV (``cv2.imdecode``); the frame counter and device time travel in the
part headers, so the driver sees dropped frames and duplicates as it does on V4L2 (the reason this
client parses the stream itself instead of handing the URL to ``cv2.VideoCapture``, whose FFmpeg
backend drops those headers and buffers frames out of the driver's sight).
"""

from __future__ import annotations

import http.client
import json
import socket
import threading
from typing import Any
from urllib.parse import urlencode, urlsplit

import numpy as np

from tactile_rig.core.errors import LinkCorrupt, NotConnected
from tactile_rig.core.types import RawFrame
from tactile_rig.devices.camera import canonical_control

__all__ = ["HttpCameraSource", "is_http_camera"]

_MAX_PART_BYTES = 16 * 1024 * 1024  # a JPEG bigger than this is a broken stream, not a frame


def is_http_camera(port: Any) -> bool:
    """True for a camera port that names an HTTP MJPEG stream."""
    return isinstance(port, str) and port.startswith(("http://", "https://"))


def _cv2() -> Any:
    import cv2

    return cv2


class HttpCameraSource:
    """Frames, format and controls of an MJPEG-over-HTTP camera (see the module doc).

    ``url`` is the stream URL; the control and format endpoints are on the same host and port.
    ``request_timeout_s`` bounds every control request.
    """

    channel_order = "BGR"

    def __init__(self, url: str, *, name: str | None = None, request_timeout_s: float = 2.0) -> None:
        parts = urlsplit(url)
        if parts.scheme != "http" or not parts.hostname:
            raise ValueError(f"camera URL {url!r} must look like http://HOST:PORT/stream.mjpg")
        self.url = url
        self.name = name or url
        self.host = parts.hostname
        self.port = int(parts.port or 80)
        self.path = parts.path or "/stream.mjpg"
        self.request_timeout_s = float(request_timeout_s)
        self._open = False
        self._conn: http.client.HTTPConnection | None = None
        self._resp: http.client.HTTPResponse | None = None
        self._boundary = b""
        self._lock = threading.Lock()

    # -- requests -------------------------------------------------------------------------------
    def _request(self, method: str, path: str, query: dict[str, Any] | None = None) -> dict[str, Any]:
        target = path + ("?" + urlencode(query) if query else "")
        conn = http.client.HTTPConnection(self.host, self.port, timeout=self.request_timeout_s)
        try:
            conn.request(method, target)
            resp = conn.getresponse()
            body = resp.read()
        except (OSError, http.client.HTTPException) as exc:
            raise NotConnected(f"camera at {self.host}:{self.port} does not answer {method} {path} ({exc})",
                               device=self.name) from None
        finally:
            conn.close()
        if resp.status != 200:
            raise LinkCorrupt(f"{method} {path} answered HTTP {resp.status}: {body[:200]!r} (expected 200)",
                              device=self.name)
        try:
            return json.loads(body)
        except ValueError:
            raise LinkCorrupt(f"{method} {path} answered {body[:200]!r}; expected JSON", device=self.name) from None

    # -- FrameSource ----------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._open

    def open(self) -> None:
        self._request("GET", "/format")  # raises NotConnected when nothing serves there
        self._open = True

    def close(self) -> None:
        self._open = False
        self._close_stream()

    def _need(self) -> None:
        if not self._open:
            raise NotConnected("camera is not open", device=self.name)

    def get_format(self) -> tuple[str, int, int, float]:
        d = self._request("GET", "/format")
        return str(d["fourcc"]), int(d["width"]), int(d["height"]), float(d["fps"])

    def set_format(self, fourcc: str, width: int, height: int, fps: float) -> tuple[str, int, int, float]:
        self._need()
        self._close_stream()  # a new format is a new stream, as on V4L2
        d = self._request("POST", "/format", {"fourcc": fourcc, "width": int(width), "height": int(height),
                                              "fps": float(fps)})
        return str(d["fourcc"]), int(d["width"]), int(d["height"]), float(d["fps"])

    def set_control(self, name: str, value: float) -> bool:
        self._need()
        d = self._request("POST", "/control", {"name": canonical_control(name), "value": float(value)})
        return bool(d.get("accepted"))

    def get_control(self, name: str) -> float | None:
        self._need()
        v = self._request("GET", "/control", {"name": canonical_control(name)}).get("value")
        return None if v is None else float(v)

    def controls(self) -> dict[str, float]:
        """Every control the camera has, with its value."""
        return {str(k): float(v) for k, v in self._request("GET", "/controls").items()}

    # -- the stream -----------------------------------------------------------------------------
    def _open_stream(self, timeout_s: float) -> None:
        conn = http.client.HTTPConnection(self.host, self.port, timeout=max(timeout_s, 0.05))
        try:
            conn.request("GET", self.path)
            resp = conn.getresponse()
        except (OSError, http.client.HTTPException) as exc:
            conn.close()
            raise NotConnected(f"stream {self.url} does not open ({exc})", device=self.name) from None
        ctype = resp.getheader("Content-Type", "")
        if resp.status != 200 or "boundary=" not in ctype:
            conn.close()
            raise LinkCorrupt(f"stream {self.url} answered HTTP {resp.status} {ctype!r}; expected "
                              "multipart/x-mixed-replace with a boundary", device=self.name)
        self._boundary = b"--" + ctype.split("boundary=", 1)[1].strip().strip('"').encode()
        self._conn, self._resp = conn, resp

    def _close_stream(self) -> None:
        with self._lock:
            conn, self._conn, self._resp = self._conn, None, None
        if conn is not None:
            sock = conn.sock
            if sock is not None:
                try:  # unblocks a capture thread waiting in recv
                    sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
            conn.close()

    def read(self, timeout_s: float | None = None) -> RawFrame | None:
        self._need()
        t = 1.0 if timeout_s is None else max(0.05, float(timeout_s))
        if self._resp is None:
            self._open_stream(t)
        conn, resp = self._conn, self._resp
        if conn is None or resp is None:
            raise NotConnected("stream closed", device=self.name)
        if conn.sock is not None:
            conn.sock.settimeout(t)
        try:
            headers = self._part_headers(resp)
            length = int(headers.get("content-length", "-1"))
            if not 0 < length <= _MAX_PART_BYTES:
                raise LinkCorrupt(f"stream part without a valid Content-Length ({headers})", device=self.name)
            data = resp.read(length)
        except (socket.timeout, TimeoutError):
            self._close_stream()  # a part cut in the middle cannot be resumed: start a new stream
            return None
        except (OSError, ValueError, http.client.HTTPException) as exc:
            self._close_stream()
            if not self._open:
                raise NotConnected("camera closed", device=self.name) from None
            raise NotConnected(f"stream broke ({exc})", device=self.name) from None
        if len(data) != length:
            self._close_stream()
            raise NotConnected(f"stream ended inside a frame ({len(data)} of {length} bytes)", device=self.name)
        img = _cv2().imdecode(np.frombuffer(data, np.uint8), _cv2().IMREAD_COLOR)
        if img is None:
            raise LinkCorrupt(f"a {length}-byte stream part is not a JPEG OpenCV decodes", device=self.name)
        seq = headers.get("x-frame-seq")
        ts = headers.get("x-timestamp-s")
        return RawFrame(img, float(ts) if ts is not None else None, int(seq) if seq is not None else None)

    def _part_headers(self, resp: Any) -> dict[str, str]:
        """Skip to the next boundary and read the part's headers (lower-case names)."""
        while True:
            line = resp.readline(1024)
            if not line:
                raise NotConnected("stream ended", device=self.name)
            if line.strip() == self._boundary:
                break
        headers: dict[str, str] = {}
        while True:
            line = resp.readline(1024)
            if not line:
                raise NotConnected("stream ended", device=self.name)
            line = line.strip()
            if not line:
                return headers
            key, _, value = line.decode("latin-1").partition(":")
            headers[key.strip().lower()] = value.strip()

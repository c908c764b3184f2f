"""Serve a :class:`~tactile_rig.drivers.camera.FrameSource` (a simulated UVC camera) as MJPEG over HTTP
on 127.0.0.1, with its format and controls (the protocol is in :mod:`tactile_rig.drivers.camera_http`).

One capture thread pulls frames from the source at its own pace while at least one client streams,
encodes each as JPEG with OpenCV and hands it to every streaming client; a client that falls behind
gets the newest frame (a camera does not queue for a slow reader). Control and format requests go to
the same source, under one lock, as ioctls go to one V4L2 device.
"""

from __future__ import annotations

import json
import logging
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qs, urlsplit

import cv2

log = logging.getLogger("tactile_rig.rehearsal.camera")

BOUNDARY = "tactilerigframe"


class CameraServer:
    """HTTP server of one camera; ``url`` is the stream URL a bench names. ``jpeg_quality`` 0..100."""

    def __init__(self, source: Any, *, host: str = "127.0.0.1", port: int = 0, jpeg_quality: int = 95) -> None:
        if not 0 <= jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality={jpeg_quality!r} must be in 0..100")
        self.source = source
        self.jpeg_quality = int(jpeg_quality)
        self._io = threading.Lock()  # one "ioctl" at a time
        self._cond = threading.Condition()
        self._frame: tuple[int, bytes, float | None, int | None] | None = None  # (n, jpeg, t_dev, seq)
        self._n = 0
        self._clients = 0
        self._capture: threading.Thread | None = None
        self._running = True
        self.frames_served = 0
        self.error: BaseException | None = None
        self._httpd = ThreadingHTTPServer((host, port), self._handler_class())
        self._httpd.daemon_threads = True
        self._thread: threading.Thread | None = None
        self.source.open()

    @property
    def url(self) -> str:
        host, port = self._httpd.server_address[:2]
        host_text = host.decode() if isinstance(host, bytes) else str(host)
        return f"http://{host_text}:{port}/stream.mjpg"

    def start(self) -> "CameraServer":
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="camera-http", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._running = False
        with self._cond:
            self._cond.notify_all()
        self._httpd.shutdown()
        self._httpd.server_close()
        if self._capture is not None:
            self._capture.join(timeout=2.0)
        self.source.close()

    def __enter__(self) -> "CameraServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- format and controls --------------------------------------------------------------------
    def get_format(self) -> dict[str, Any]:
        s = self.source
        return {"fourcc": s.fourcc, "width": int(s.width), "height": int(s.height), "fps": float(s.fps)}

    def set_format(self, fourcc: str, width: int, height: int, fps: float) -> dict[str, Any]:
        with self._io:
            f = self.source.set_format(fourcc, width, height, fps)
        return {"fourcc": f[0], "width": int(f[1]), "height": int(f[2]), "fps": float(f[3])}

    def set_control(self, name: str, value: float) -> dict[str, Any]:
        with self._io:
            ok = self.source.set_control(name, value)
            return {"accepted": bool(ok), "value": self.source.get_control(name)}

    def get_control(self, name: str) -> dict[str, Any]:
        with self._io:
            return {"name": name, "value": self.source.get_control(name)}

    def controls(self) -> dict[str, float]:
        table = getattr(self.source, "table", None)
        if table is None:
            return {}
        with self._io:
            return {k: float(v) for k, v in table.values.items()}

    # -- frames ---------------------------------------------------------------------------------
    def _capture_loop(self) -> None:
        params = [int(cv2.IMWRITE_JPEG_QUALITY), self.jpeg_quality]
        while self._running:
            with self._cond:
                if self._clients == 0:
                    self._capture = None
                    return
            try:
                with self._io:
                    raw = self.source.read(0.5)
            except Exception as exc:  # noqa: BLE001 - the stream ends for every client; reported once
                log.error("camera source failed: %r", exc)
                self.error = exc
                with self._cond:
                    self._capture = None
                    self._cond.notify_all()
                return
            if raw is None:
                continue
            ok, buf = cv2.imencode(".jpg", raw.image, params)
            if not ok:
                continue
            with self._cond:
                self._n += 1
                self._frame = (self._n, buf.tobytes(), raw.t_device_s, raw.device_seq)
                self._cond.notify_all()

    def _next_frame(self, after: int, timeout_s: float) -> tuple[int, bytes, float | None, int | None] | None:
        with self._cond:
            self._cond.wait_for(lambda: not self._running or self.error is not None
                                or (self._frame is not None and self._frame[0] > after), timeout=timeout_s)
            if self._frame is not None and self._frame[0] > after:
                return self._frame
            return None

    def _join(self) -> None:
        with self._cond:
            self._clients += 1
            if self._capture is None:
                self._capture = threading.Thread(target=self._capture_loop, name="camera-capture", daemon=True)
                self._capture.start()

    def _leave(self) -> None:
        with self._cond:
            self._clients -= 1

    def _handler_class(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.0"

            def log_message(self, fmt: str, *args: Any) -> None:  # quiet: the bench's stdout is its JSON line
                log.debug("%s " + fmt, self.address_string(), *args)

            def _json(self, obj: Any, status: int = 200) -> None:
                body = json.dumps(obj).encode()
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def _query(self) -> tuple[str, dict[str, str]]:
                parts = urlsplit(self.path)
                return parts.path, {k: v[-1] for k, v in parse_qs(parts.query).items()}

            def do_GET(self) -> None:  # noqa: N802 - http.server's name
                path, q = self._query()
                if path == "/format":
                    self._json(server.get_format())
                elif path == "/control" and "name" in q:
                    self._json(server.get_control(q["name"]))
                elif path == "/controls":
                    self._json(server.controls())
                elif path == "/stream.mjpg":
                    self._stream()
                else:
                    self._json({"error": f"no such resource {path!r}"}, 404)

            def do_POST(self) -> None:  # noqa: N802
                path, q = self._query()
                try:
                    if path == "/format":
                        self._json(server.set_format(q["fourcc"], int(q["width"]), int(q["height"]), float(q["fps"])))
                    elif path == "/control":
                        self._json(server.set_control(q["name"], float(q["value"])))
                    else:
                        self._json({"error": f"no such resource {path!r}"}, 404)
                except (KeyError, ValueError) as exc:
                    self._json({"error": f"bad request: {exc}"}, 400)

            def _stream(self) -> None:
                self.send_response(200)
                self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={BOUNDARY}")
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                server._join()
                try:
                    last = server._frame[0] if server._frame is not None else 0
                    while server._running:
                        fr = server._next_frame(last, 1.0)
                        if fr is None:
                            if server.error is not None:
                                return
                            continue
                        last, jpeg, t_dev, seq = fr
                        head = (f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(jpeg)}\r\n"
                                + (f"X-Frame-Seq: {seq}\r\n" if seq is not None else "")
                                + (f"X-Timestamp-S: {t_dev!r}\r\n" if t_dev is not None else "") + "\r\n")
                        self.wfile.write(head.encode("ascii") + jpeg + b"\r\n")
                        self.wfile.flush()
                        server.frames_served += 1
                except (BrokenPipeError, ConnectionResetError, OSError):
                    return
                finally:
                    server._leave()

        return Handler

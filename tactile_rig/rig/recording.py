"""Session recordings in MCAP (opens in Foxglove), written so a crash loses at most the last second.

Channels (all JSON-encoded, so Foxglove and :mod:`tactile_rig.rig.replay` read them without
plugins)::

    /<camera>/image             foxglove.RawImage (bgr8 / mono8)
    /<camera>/image/compressed  foxglove.CompressedImage (png, jpeg)   (the ROS image_transport names)
    /perception/<name>          tactile_rig.Perception   any JSON-able result of a perception step
    /state/<device>             tactile_rig.DeviceState  a device's state snapshot
    /command/<device>           tactile_rig.Command      what was sent to a device
    /jig/pose                   tactile_rig.JigPose      x_mm, y_mm, z_mm, theta_deg (+ true pose in sims)
    /scale/force                tactile_rig.ScaleReading force_n

The bench config and every calibration are stored as MCAP metadata records (flat string maps) and
as attachments (the files as they were). Every message carries ``t_s`` (the session clock, virtual
or monotonic); the MCAP ``log_time`` is that time in nanoseconds (plus the Unix time at the start
for wall-clock sessions, so Foxglove shows real dates).

Crash safety: chunks are closed and the file flushed whenever the session clock or the wall
clock has moved ``flush_interval_s`` (default 1 s) past the last flush, and, on wall-clock
sessions, by a background timer too, so idle periods do not hold data in memory. :func:`read_recording` reads a
file cut off anywhere (SIGKILL, full disk, power loss) and returns every complete chunk.

``mcap`` is the optional extra ``record``; it is imported only when a recording is opened.
"""

from __future__ import annotations

import base64
import json
import os
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from tactile_rig.core.clock import Clock, RealClock
from tactile_rig.core.errors import BadFile
from tactile_rig.rig.files import MAX_JSON_DEPTH, check_file, decode_image_bytes, json_depth
from tactile_rig.core.jsonable import to_jsonable

__all__ = ["Recorder", "Recording", "Message", "read_recording", "iter_messages", "SCHEMAS", "camera_topic", "MAX_RECORDING_BYTES"]


def camera_topic(camera: str, *, compressed: bool = False) -> str:
    """``/<camera>/image`` or ``/<camera>/image/compressed`` (a bench camera named ``camera_left``
    records on ``/camera_left/image``); find image topics by schema, not by name."""
    name = camera.strip("/")
    if not name:
        raise ValueError("camera name is empty; expected the bench table name, e.g. 'camera_left'")
    return f"/{name}/image/compressed" if compressed else f"/{name}/image"

_TIME = {"type": "object", "title": "time",
         "properties": {"sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}

SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.RawImage": {
        "title": "foxglove.RawImage", "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"},
                       "width": {"type": "integer"}, "height": {"type": "integer"},
                       "encoding": {"type": "string"}, "step": {"type": "integer"},
                       "data": {"type": "string", "contentEncoding": "base64"}},
    },
    "foxglove.CompressedImage": {
        "title": "foxglove.CompressedImage", "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"},
                       "format": {"type": "string"},
                       "data": {"type": "string", "contentEncoding": "base64"}},
    },
    "tactile_rig.Perception": {"title": "tactile_rig.Perception", "type": "object",
                               "properties": {"t_s": {"type": "number"}}},
    "tactile_rig.DeviceState": {"title": "tactile_rig.DeviceState", "type": "object",
                                "properties": {"t_s": {"type": "number"}}},
    "tactile_rig.Command": {"title": "tactile_rig.Command", "type": "object",
                            "properties": {"t_s": {"type": "number"}, "command": {"type": "string"}}},
    "tactile_rig.JigPose": {"title": "tactile_rig.JigPose", "type": "object",
                            "properties": {"t_s": {"type": "number"}, "x_mm": {"type": "number"},
                                           "y_mm": {"type": "number"}, "z_mm": {"type": "number"},
                                           "theta_deg": {"type": "number"}}},
    "tactile_rig.ScaleReading": {"title": "tactile_rig.ScaleReading", "type": "object",
                                 "properties": {"t_s": {"type": "number"}, "force_n": {"type": "number"}}},
    "tactile_rig.Json": {"title": "tactile_rig.Json", "type": "object"},
}

PROFILE = ""  # JSON channels need no profile
LIBRARY = "tactile-rig"


def _jsonable(obj: Any) -> Any:
    return to_jsonable(obj)


def _require_mcap() -> None:
    try:
        import mcap  # noqa: F401
    except ModuleNotFoundError as exc:  # pragma: no cover - depends on the install
        raise ModuleNotFoundError("recordings need the 'mcap' package: pip install 'tactile-rig[record]'",
                                  name=exc.name) from exc


def _fast_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(type(obj).__name__)


def _stamp(t_ns: int) -> dict[str, int]:
    return {"sec": max(0, t_ns) // 1_000_000_000, "nsec": max(0, t_ns) % 1_000_000_000}


class TopicWriter:
    """The typed topics a session publishes, shared by the recording and the live view (same topics,
    same schemas): each ``write_*`` builds its message and hands it to ``self.write``."""

    def write(self, topic: str, payload: Mapping[str, Any], *, t_s: float | None = None,
              schema: str = "tactile_rig.Json") -> None:
        raise NotImplementedError

    def write_perception(self, name: str, result: Any, *, t_s: float | None = None) -> None:
        """A perception result on ``/perception/<name>``."""
        self.write(f"/perception/{name}", _as_dict(result), t_s=t_s, schema="tactile_rig.Perception")

    def write_state(self, device: str, state: Any, *, t_s: float | None = None) -> None:
        """A device's state on ``/state/<device>``."""
        self.write(f"/state/{device}", _as_dict(state), t_s=t_s, schema="tactile_rig.DeviceState")

    def write_command(self, device: str, command: str, *, t_s: float | None = None, **args: Any) -> None:
        """A command sent to a device, on ``/command/<device>``."""
        self.write(f"/command/{device}", {"command": command, **args}, t_s=t_s, schema="tactile_rig.Command")

    def write_jig_pose(self, pose: Any, *, t_s: float | None = None, **extra: Any) -> None:
        """The jig's pose (mm, deg) on ``/jig/pose``."""
        self.write("/jig/pose", {**_as_dict(pose), **extra}, t_s=t_s, schema="tactile_rig.JigPose")

    def write_scale(self, force_n: float, *, t_s: float | None = None, **extra: Any) -> None:
        """A scale reading (N) on ``/scale/force``."""
        self.write("/scale/force", {"force_n": float(force_n), **extra}, t_s=t_s,
                   schema="tactile_rig.ScaleReading")


class Recorder(TopicWriter):
    """Write one session to an MCAP file, incrementally.

    ``clock`` gives every message's time (default wall time). ``flush_interval_s`` bounds what a
    crash can lose. Use as a context manager; :meth:`close` writes the summary (a file that was not
    closed is still readable up to its last flush).
    """

    def __init__(self, path: str | Path, *, clock: Clock | None = None, flush_interval_s: float = 1.0,
                 compression: str = "zstd", chunk_size: int = 256 * 1024,
                 background_flush: bool | None = None) -> None:
        _require_mcap()
        from mcap.writer import CompressionType, Writer

        if not 0 < flush_interval_s <= 1.0:
            raise ValueError(f"flush_interval_s={flush_interval_s!r} must be in (0, 1] s "
                             "(a crash may lose at most one second)")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.clock: Clock = clock if clock is not None else RealClock()
        self.flush_interval_s = float(flush_interval_s)
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}.get(compression)
        if comp is None:
            raise ValueError(f"compression={compression!r} must be 'zstd', 'lz4' or 'none'")
        self._file = open(self.path, "wb")
        try:
            self._writer = Writer(self._file, chunk_size=chunk_size, compression=comp, enable_data_crcs=True)
        except Exception:  # noqa: BLE001 - the codec library is missing: write uncompressed
            self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.NONE,
                                  enable_data_crcs=True)
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._lock = threading.RLock()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._dirty = False
        self._closed = False
        # Wall-clock sessions get Unix-epoch log times (Foxglove shows dates); virtual ones start at 0.
        self._t0_s = self.clock.now_s()
        self._epoch_ns = 0 if self.clock.is_virtual else time.time_ns() - int(self._t0_s * 1e9)
        self._last_flush_s = self._t0_s
        self._last_flush_wall_s = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if background_flush if background_flush is not None else not self.clock.is_virtual:
            self._thread = threading.Thread(target=self._flush_loop, name="mcap-flush", daemon=True)
            self._thread.start()
        self.add_metadata("recording", {"clock": "virtual" if self.clock.is_virtual else "monotonic",
                                      "t0_s": repr(self._t0_s), "epoch_offset_ns": str(self._epoch_ns),
                                      "flush_interval_s": repr(self.flush_interval_s)})
        # Readable from the moment it exists: the magic and header reach the OS now, so a reader never
        # sees the zero-byte file that read_recording refuses.
        with self._lock:
            self._file.flush()

    # -- low level --------------------------------------------------------------------------
    def _channel(self, topic: str, schema: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            sid = self._schemas.get(schema)
            if sid is None:
                body = json.dumps(SCHEMAS.get(schema, SCHEMAS["tactile_rig.Json"])).encode()
                sid = self._writer.register_schema(name=schema, encoding="jsonschema", data=body)
                self._schemas[schema] = sid
            cid = self._writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)
            self._channels[topic] = cid
            self._seq[cid] = 0
        return cid

    def log_time_ns(self, t_s: float) -> int:
        """The MCAP log time of session time ``t_s``."""
        return self._epoch_ns + int(round(t_s * 1e9))

    def write(self, topic: str, payload: Mapping[str, Any], *, t_s: float | None = None,
              schema: str = "tactile_rig.Json") -> None:
        """Write one JSON message on ``topic`` at session time ``t_s`` (default: the clock's now)."""
        t = self.clock.now_s() if t_s is None else float(t_s)
        body = dict(payload)
        body.setdefault("t_s", t)
        try:  # fast path: plain values and numpy arrays/scalars
            data = json.dumps(body, separators=(",", ":"), allow_nan=False, default=_fast_default).encode()
        except (TypeError, ValueError):  # NaN/inf (→ null), dataclasses, enums...
            data = json.dumps(_jsonable(body), separators=(",", ":"), allow_nan=False).encode()
        self._add(topic, schema, data, t)

    def _add(self, topic: str, schema: str, data: bytes, t_s: float) -> None:
        ns = self.log_time_ns(t_s)
        with self._lock:
            if self._closed:
                raise ValueError(f"recording {self.path} is closed")
            cid = self._channel(topic, schema)
            self._writer.add_message(channel_id=cid, log_time=ns, publish_time=ns, data=data,
                                     sequence=self._seq[cid])
            self._seq[cid] += 1
            self._dirty = True
            # Session time and wall time: a simulation slower than real time must not hold back
            # more than a second of work either.
            if (self.clock.now_s() - self._last_flush_s >= self.flush_interval_s
                    or time.monotonic() - self._last_flush_wall_s >= self.flush_interval_s):
                self._flush_locked()

    # -- typed channels ---------------------------------------------------------------------
    def write_frame(self, camera: str, image: np.ndarray, *, t_s: float | None = None,
                    compress: str | None = None) -> None:
        """A camera frame: raw (bgr8 for HxWx3, mono8 for HxW) or ``compress='png'|'jpeg'``."""
        img = np.ascontiguousarray(image)
        if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
            raise ValueError(f"camera {camera!r}: frame must be uint8 HxW or HxWx3 BGR, got "
                             f"{img.dtype} {img.shape}")
        t = self.clock.now_s() if t_s is None else float(t_s)
        topic = camera_topic(camera)
        if compress is not None:
            import cv2

            ext = {"png": ".png", "jpeg": ".jpg", "jpg": ".jpg"}.get(compress)
            if ext is None:
                raise ValueError(f"compress={compress!r} must be None, 'png' or 'jpeg'")
            ok, buf = cv2.imencode(ext, img)
            if not ok:
                raise ValueError(f"camera {camera!r}: OpenCV could not encode the frame as {compress}")
            topic = camera_topic(camera, compressed=True)
            msg = {"timestamp": _stamp(self.log_time_ns(t)), "frame_id": camera,
                   "format": "jpeg" if ext == ".jpg" else "png",
                   "data": base64.b64encode(buf.tobytes()).decode("ascii")}
            self.write(topic, msg, t_s=t, schema="foxglove.CompressedImage")
            return
        h, w = img.shape[:2]
        enc = "bgr8" if img.ndim == 3 else "mono8"
        head = {"timestamp": _stamp(self.log_time_ns(t)), "frame_id": camera, "width": w, "height": h,
                "encoding": enc, "step": int(img.strides[0]), "t_s": t}
        # base64 is plain ASCII: splice it in rather than have json scan a megabyte for escapes.
        body = json.dumps(head, separators=(",", ":"))[:-1].encode() + b',"data":"' + \
            base64.b64encode(img.tobytes()) + b'"}'
        self._add(topic, "foxglove.RawImage", body, t)

    # -- metadata and attachments -----------------------------------------------------------
    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        """A metadata record; values that are not strings are stored as JSON text."""
        flat = {str(k): v if isinstance(v, str) else json.dumps(_jsonable(v)) for k, v in values.items()}
        with self._lock:
            self._writer.add_metadata(name, flat)

    def add_attachment(self, name: str, data: bytes, *, media_type: str = "application/octet-stream") -> None:
        ns = self.log_time_ns(self.clock.now_s())
        with self._lock:
            self._writer.add_attachment(create_time=ns, log_time=ns, name=name, media_type=media_type,
                                        data=bytes(data))

    def add_bench(self, bench: Any) -> None:
        """The bench config: a ``bench`` metadata record (one key per device) and the file itself."""
        d = bench.to_dict()
        self.add_metadata("bench", {"name": d["name"], "source": d["source"], "scene": d["scene"] or "",
                                    "seed": d["seed"], **{f"device.{k}": v for k, v in d["devices"].items()}})
        if getattr(bench, "text", ""):
            self.add_attachment("bench.toml", bench.text.encode("utf-8"), media_type="application/toml")

    def add_calibration(self, name: str, *, path: str | Path | None = None,
                        values: Mapping[str, Any] | None = None) -> None:
        """A calibration: its values as metadata ``calibration.<name>`` and its files as attachments.

        A calibration of two files (GelSight, FingerVision, the learned models: ``.json`` + ``.npz``)
        is attached whole, whichever of the two ``path`` names."""
        meta: dict[str, Any] = dict(values or {})
        if path is not None:
            p = Path(path)
            meta.setdefault("path", str(p))
            files = [p]
            if p.suffix in (".json", ".npz"):
                twin = p.with_suffix(".npz" if p.suffix == ".json" else ".json")
                if twin.is_file():
                    files = sorted([p, twin], key=lambda f: f.suffix != ".json")
            for f in files:
                self.add_attachment(f"calibration/{name}/{f.name}", f.read_bytes(),
                                    media_type="application/json" if f.suffix == ".json" else "application/octet-stream")
        self.add_metadata(f"calibration.{name}", meta)

    # -- flushing and closing ---------------------------------------------------------------
    def _flush_locked(self) -> None:
        flush = getattr(self._writer, "flush", None)
        if flush is not None:
            flush()  # mcap >= 1.2: closes the chunk in progress and flushes the stream
        self._file.flush()
        self._last_flush_s = self.clock.now_s()
        self._last_flush_wall_s = time.monotonic()
        self._dirty = False

    def flush(self) -> None:
        """Close the current chunk and push everything to the OS now."""
        with self._lock:
            if not self._closed:
                self._flush_locked()

    def sync(self) -> None:
        """Flush, then have the OS write the file to the disk (``fsync``): survives a power loss."""
        with self._lock:
            if not self._closed:
                self._flush_locked()
                os.fsync(self._file.fileno())

    def replace(self, target: str | Path) -> None:
        """Sync this file and atomically rename it to ``target`` (replacing any file there), then go
        on recording into it. Write-then-rename: until the rename ``target`` is untouched; after it
        ``target`` holds everything written so far."""
        target = Path(target)
        with self._lock:
            if self._closed:
                raise ValueError(f"recording {self.path} is closed")
            self._flush_locked()
            os.fsync(self._file.fileno())
            os.replace(self.path, target)
            _fsync_dir(target.parent)
            self.path = target

    def _flush_loop(self) -> None:
        period = self.flush_interval_s / 2  # so data never waits longer than the interval
        while not self._stop.wait(period):
            with self._lock:
                if self._closed:
                    return
                if self._dirty:
                    self._flush_locked()

    def close(self) -> None:
        """Write the summary and close the file (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._writer.finish()
            self._file.close()

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (POSIX: fsync the directory); a no-op where unsupported."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover - e.g. Windows
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def _as_dict(obj: Any) -> dict[str, Any]:
    import dataclasses

    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return _jsonable(obj)
    if isinstance(obj, Mapping):
        return dict(obj)
    if hasattr(obj, "__dict__"):
        return {k: v for k, v in vars(obj).items() if not k.startswith("_")}
    return {"value": obj}


# -- reading ----------------------------------------------------------------------------------
@dataclass
class Message:
    """One recorded message: topic, schema name, MCAP log time (ns) and the decoded JSON."""

    topic: str
    schema: str
    log_time_ns: int
    data: dict[str, Any]

    @property
    def t_s(self) -> float:
        """The session time the message was recorded at (s)."""
        v = self.data.get("t_s")
        return float(v) if isinstance(v, (int, float)) else self.log_time_ns / 1e9

    def image(self) -> np.ndarray:
        """Decode a RawImage / CompressedImage message into a BGR (or mono) uint8 array."""
        return decode_image(self.schema, self.data, f"message on {self.topic}")


def decode_image(schema: str, data: Mapping[str, Any], source: str = "recording") -> np.ndarray:
    """A recorded image message as a uint8 array; sizes are checked before anything is allocated
    or decoded (a :class:`BadFile` naming ``source`` otherwise)."""
    try:
        raw = base64.b64decode(data["data"], validate=True)
    except (KeyError, TypeError, ValueError):
        raise BadFile(source, f"a {schema} message has no valid base64 'data'", "a recorded image") from None
    if schema == "foxglove.CompressedImage":
        return decode_image_bytes(raw, source, f"a {data.get('format')} image message")
    if schema != "foxglove.RawImage":
        raise ValueError(f"schema {schema!r} is not an image")
    try:
        h, w, step = int(data["height"]), int(data["width"]), int(data["step"])
    except (KeyError, TypeError, ValueError):
        raise BadFile(source, "a RawImage message lacks integer height, width, step", "a foxglove.RawImage") from None
    channels = {"bgr8": 3, "rgb8": 3, "mono8": 1, "8UC1": 1, "8UC3": 3}.get(str(data.get("encoding")))
    if channels is None:
        raise BadFile(source, f"unsupported RawImage encoding {data.get('encoding')!r}", "bgr8, rgb8 or mono8")
    if not (0 < h <= 16384 and 0 < w <= 16384 and w * channels <= step <= 4 * w * channels and len(raw) >= h * step):
        raise BadFile(source, f"a RawImage message declares {w}x{h} px, step {step}, with {len(raw)} bytes",
                      "a consistent size of at most 16384 px a side")
    rows = np.frombuffer(raw, np.uint8)[: h * step].reshape(h, step)[:, : w * channels]
    img = rows.reshape(h, w, channels) if channels == 3 else rows.reshape(h, w)
    if data["encoding"] == "rgb8":
        img = img[:, :, ::-1]
    return np.ascontiguousarray(img)


@dataclass
class Recording:
    """A recording as read back; ``truncated`` is True when the file ended mid-way (a crash)."""

    path: Path
    messages: list[Message] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    truncated: bool = False
    error: str | None = None

    def topics(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for m in self.messages:
            counts[m.topic] = counts.get(m.topic, 0) + 1
        return counts

    def on(self, topic: str) -> list[Message]:
        return [m for m in self.messages if m.topic == topic]

    def metadata_json(self, name: str) -> dict[str, Any]:
        """A metadata record with JSON values decoded where they parse."""
        out: dict[str, Any] = {}
        for k, v in self.metadata.get(name, {}).items():
            try:
                out[k] = json.loads(v)
            except ValueError:
                out[k] = v
        return out


MCAP_MAGIC = b"\x89MCAP0\r\n"
MAX_RECORD_BYTES = 1 << 30  # no record this rig writes comes near it; a flipped length field does
MAX_RECORDING_BYTES = 1 << 40  # recordings are streamed chunk by chunk: hours of raw frames are fine


def _where(kind: str, index: int, offset: int) -> str:
    return f"{kind} {index} (byte {offset})"


def _records(path: Path, result: Recording) -> Iterator[tuple[Any, str]]:
    """Every record of the file in order with where it lies (``"chunk 3 (byte 1234) message 7"``).

    CRCs are checked (each chunk's, the attachments', the data section's). A file cut off
    mid-record (SIGKILL, full disk, power loss: no end magic) ends the iteration and sets
    ``truncated``; a file that is complete but fails a check, or whose records do not parse, is
    a :class:`BadFile` naming the chunk or record (exit 2 in the CLI)."""
    _require_mcap()
    from mcap.exceptions import EndOfFile, McapError
    from mcap.records import Chunk, DataEnd, Footer
    from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

    p = check_file(path, "recording", max_bytes=MAX_RECORDING_BYTES)
    size = p.stat().st_size
    with open(p, "rb") as f:
        head = f.read(8)
        f.seek(max(0, size - 8))
        tail = f.read(8)
        f.seek(0)
        if len(head) < 8 or not head.startswith(b"\x89MCAP"):
            raise BadFile(p, f"recording is not an MCAP recording (it starts with {head!r})",
                          "an MCAP file (magic \\x89MCAP0)")
        complete = size >= 16 and tail == MCAP_MAGIC  # closed properly: an early end is damage, not a crash
        reader = StreamReader(f, skip_magic=False, emit_chunks=True, validate_crcs=True,
                              record_size_limit=MAX_RECORD_BYTES)
        it = reader.records
        n_chunks = 0
        n_records = 0
        while True:
            pos = f.tell() if n_records else 8
            try:
                rec = next(it)
            except StopIteration:
                return
            except CRCValidationError as exc:
                if isinstance(exc.record, DataEnd):
                    raise BadFile(p, f"the data section fails its CRC (stored {exc.expected:#010x}, computed "
                                  f"{exc.actual:#010x}): a record outside the chunks is damaged",
                                  "an intact MCAP recording") from None
                raise BadFile(p, f"{type(exc.record).__name__.lower()} at byte {pos} fails its CRC",
                              "an intact MCAP recording") from None
            except (EndOfFile, McapError, ValueError, struct.error, UnicodeDecodeError, MemoryError,
                    OverflowError, IndexError) as exc:
                declared_end = _declared_end(p, pos, size)
                cut_off = declared_end is None or declared_end > size
                if cut_off and not complete and n_records == 0:
                    raise BadFile(p, f"recording holds no complete record ({size} bytes: cut off right after it "
                                  "was opened)", "an MCAP recording with at least its header") from None
                if cut_off and not complete:
                    result.truncated = True
                    result.error = f"cut off at byte {pos} of {size} ({type(exc).__name__}{': ' + str(exc) if str(exc) else ''})"
                    return
                raise BadFile(p, f"record {n_records} at byte {pos} is corrupt ({type(exc).__name__}"
                              f"{': ' + str(exc)[:120] if str(exc) else ''})", "an intact MCAP recording") from None
            n_records += 1
            if isinstance(rec, Chunk):
                where = _where("chunk", n_chunks, pos)
                t0, t1 = rec.message_start_time / 1e9, rec.message_end_time / 1e9
                if rec.uncompressed_size > MAX_RECORD_BYTES:
                    raise BadFile(p, f"{where} declares {rec.uncompressed_size} bytes uncompressed",
                                  f"at most {MAX_RECORD_BYTES} bytes (a damaged chunk header)")
                try:
                    inner = breakup_chunk(rec, validate_crc=True)
                except CRCValidationError as exc:
                    raise BadFile(p, f"{where}, log time {t0:.3f}..{t1:.3f} s, fails its CRC (stored "
                                  f"{exc.expected:#010x}, computed {exc.actual:#010x}): its messages are corrupt",
                                  "an intact MCAP recording") from None
                except Exception as exc:  # noqa: BLE001 - the codec's own errors (zstd, lz4) vary by version
                    raise BadFile(p, f"{where}, log time {t0:.3f}..{t1:.3f} s, cannot be decoded "
                                  f"({type(exc).__name__}: {str(exc)[:120]})", "an intact MCAP recording") from None
                for k, r in enumerate(inner):
                    yield r, f"{where} record {k}"
                n_chunks += 1
                continue
            yield rec, f"record {n_records - 1} (byte {pos})"
            # The data section ends at DataEnd (its CRC checked above); the summary after it only
            # repeats the data section's schemas and channels, so it is not read.
            if isinstance(rec, (DataEnd, Footer)):
                if not complete:
                    result.truncated = True
                    result.error = "cut off in the summary after the data section (every message is intact)"
                return


def _declared_end(p: Path, pos: int, size: int) -> int | None:
    """Where the record starting at ``pos`` would end by its length field (None: no full header)."""
    with open(p, "rb") as f:
        f.seek(pos)
        head = f.read(9)
    if len(head) < 9:
        return None
    return pos + 9 + struct.unpack("<Q", head[1:9])[0]


def _decode_json(data: bytes, p: Path, where: str, topic: str) -> dict[str, Any]:
    # Brackets are rare in this rig's messages (base64 images have none): scan the depth only when
    # there are enough of them to matter, so a hostile nesting never reaches json's recursion.
    if data.count(b"[") + data.count(b"{") > MAX_JSON_DEPTH:
        depth = json_depth(data)
        if depth > MAX_JSON_DEPTH:
            raise BadFile(p, f"{where} on {topic} nests its JSON {depth} levels deep",
                          f"at most {MAX_JSON_DEPTH} levels")
    try:
        value = json.loads(data)
    except (ValueError, RecursionError):
        return {"raw": base64.b64encode(data).decode("ascii")}
    return value if isinstance(value, dict) else {"value": value}


def iter_messages(path: str | Path, *, topics: set[str] | None = None,
                  into: Recording | None = None) -> Iterator[Message]:
    """Stream the messages of a (possibly truncated) recording, CRCs checked; metadata goes into
    ``into``. A corrupt chunk or message is a :class:`BadFile` naming it."""
    from mcap.records import Attachment, Channel, Metadata, Schema
    from mcap.records import Message as McapMessage

    p = Path(path)
    rec_out = into if into is not None else Recording(p)
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, int]] = {}
    for rec, where in _records(p, rec_out):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec.name
        elif isinstance(rec, Channel):
            channels[rec.id] = (rec.topic, rec.schema_id)
        elif isinstance(rec, McapMessage):
            topic, sid = channels.get(rec.channel_id, (f"<channel {rec.channel_id}>", 0))
            if topics is not None and topic not in topics:
                continue
            yield Message(topic, schemas.get(sid, ""), rec.log_time, _decode_json(rec.data, p, where, topic))
        elif isinstance(rec, Metadata):
            rec_out.metadata[rec.name] = dict(rec.metadata)
        elif isinstance(rec, Attachment):
            rec_out.attachments[rec.name] = bytes(rec.data)


def read_recording(path: str | Path, *, topics: set[str] | None = None) -> Recording:
    """Read a whole recording (tolerating a truncated tail). ``topics`` keeps only those topics."""
    p = check_file(path, "recording", max_bytes=MAX_RECORDING_BYTES)
    out = Recording(p)
    out.messages = list(iter_messages(p, topics=topics, into=out))
    return out

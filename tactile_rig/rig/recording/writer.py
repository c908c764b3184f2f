"""The crash-safe MCAP writer of session recordings (see :mod:`tactile_rig.rig.recording`)."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import Any, Mapping

from tactile_rig.core.clock import Clock, RealClock
from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.messages import Encoded, SchemaDef, TopicWriter

__all__ = ["Recorder", "PROFILE", "LIBRARY", "require_mcap"]

PROFILE = ""  # protobuf and JSON channels need no profile
LIBRARY = "tactile-rig"


def require_mcap() -> None:
    """ModuleNotFoundError naming the extra when ``mcap``, ``foxglove-sdk`` or ``protobuf`` is missing."""
    for module, package in (("mcap", "mcap"), ("foxglove", "foxglove-sdk"), ("google.protobuf", "protobuf")):
        try:
            __import__(module)
        except ModuleNotFoundError as exc:  # pragma: no cover - depends on the install
            raise ModuleNotFoundError(f"recordings need the '{package}' package: pip install 'tactile-rig[record]'",
                                      name=exc.name) from exc


class Recorder(TopicWriter):
    """Write one session to an MCAP file, incrementally.

    ``clock`` gives every message's time (default wall time). ``flush_interval_s`` bounds what a
    crash can lose. Use as a context manager; :meth:`close` writes the summary (a file that was not
    closed is still readable up to its last flush). The ``write_*`` methods are
    :class:`~tactile_rig.rig.messages.TopicWriter`'s: the same messages a live view gets.
    """

    def __init__(self, path: str | Path, *, clock: Clock | None = None, flush_interval_s: float = 1.0,
                 compression: str = "zstd", chunk_size: int = 256 * 1024,
                 background_flush: bool | None = None) -> None:
        require_mcap()
        from mcap.writer import CompressionType, Writer

        if not 0 < flush_interval_s <= 1.0:
            raise ValueError(f"flush_interval_s={flush_interval_s!r} must be in (0, 1] s "
                             "(a crash may lose at most one second)")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.clock = clock if clock is not None else RealClock()
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
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._dirty = False
        self._closed = False
        self.messages_written = 0
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
    def _channel(self, topic: str, schema: SchemaDef) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            key = (schema.name, schema.encoding, schema.data)
            sid = self._schemas.get(key)
            if sid is None:
                sid = self._writer.register_schema(name=schema.name, encoding=schema.encoding, data=schema.data)
                self._schemas[key] = sid
            cid = self._writer.register_channel(topic=topic, message_encoding=schema.message_encoding, schema_id=sid)
            self._channels[topic] = cid
            self._seq[cid] = 0
        return cid

    def log_time_ns(self, t_s: float) -> int:
        """The MCAP log time of session time ``t_s``."""
        return self._epoch_ns + int(round(t_s * 1e9))

    def publish(self, msg: Encoded) -> None:
        """Write one encoded message (its topic's channel is created on first use)."""
        with self._lock:
            if self._closed:
                raise ValueError(f"recording {self.path} is closed")
            cid = self._channel(msg.topic, msg.schema)
            self._writer.add_message(channel_id=cid, log_time=msg.log_time_ns, publish_time=msg.log_time_ns,
                                     data=msg.data, sequence=self._seq[cid])
            self._seq[cid] += 1
            self.messages_written += 1
            self._dirty = True
            # Session time and wall time: a simulation slower than real time must not hold back
            # more than a second of work either.
            if (self.clock.now_s() - self._last_flush_s >= self.flush_interval_s
                    or time.monotonic() - self._last_flush_wall_s >= self.flush_interval_s):
                self._flush_locked()

    # -- metadata and attachments -----------------------------------------------------------
    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        """A metadata record; values that are not strings are stored as JSON text."""
        flat = {str(k): v if isinstance(v, str) else json.dumps(to_jsonable(v)) for k, v in values.items()}
        with self._lock:
            self._writer.add_metadata(name, flat)

    def add_attachment(self, name: str, data: bytes, *, media_type: str = "application/octet-stream") -> None:
        ns = self.log_time_ns(self.clock.now_s())
        with self._lock:
            self._writer.add_attachment(create_time=ns, log_time=ns, name=name, media_type=media_type,
                                        data=bytes(data))

    def add_bench(self, bench: Any) -> None:
        """The bench config: a ``bench`` metadata record (one key per device) and the file itself; its
        cameras become sensor frames of the 3-D scene."""
        super().add_bench(bench)
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

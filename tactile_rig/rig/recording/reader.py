"""Reading session recordings: every complete chunk of a file cut off anywhere, CRCs checked, each
message decoded by its channel's encoding (protobuf: Foxglove's types; json: the rig's own topics and
recordings in the JSON encoding)."""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from tactile_rig.core.errors import BadFile
from tactile_rig.rig.files import MAX_JSON_DEPTH, check_file, decode_image_bytes, json_depth
from tactile_rig.rig.messages import SchemaDef
from tactile_rig.rig.recording.protobuf import ProtobufDecoder
from tactile_rig.rig.recording.writer import require_mcap

__all__ = ["Message", "Recording", "decode_image", "iter_messages", "read_recording", "MCAP_MAGIC",
           "MAX_RECORD_BYTES", "MAX_RECORDING_BYTES"]


@dataclass
class Message:
    """One recorded message: topic, schema name, MCAP log time (ns) and the decoded fields.

    ``encoding`` is the channel's message encoding (``protobuf`` or ``json``), ``raw`` the bytes as
    recorded and ``schema_def`` the channel's schema (what :meth:`TopicWriter.write_message` copies).
    """

    topic: str
    schema: str
    log_time_ns: int
    data: dict[str, Any]
    encoding: str = "json"
    raw: bytes = field(default=b"", repr=False, compare=False)
    schema_def: SchemaDef | None = field(default=None, repr=False, compare=False)
    epoch_ns: int = field(default=0, repr=False, compare=False)

    @property
    def t_s(self) -> float:
        """The session time the message was recorded at (s): the body's ``t_s`` (JSON), else the log
        time less the recording's epoch offset (typed messages)."""
        v = self.data.get("t_s")
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            return float(v)
        return (self.log_time_ns - self.epoch_ns) / 1e9

    def image(self) -> np.ndarray:
        """Decode a RawImage / CompressedImage message into a BGR (or mono) uint8 array."""
        return decode_image(self.schema, self.data, f"message on {self.topic}")


def _image_bytes(schema: str, data: Mapping[str, Any], source: str) -> bytes:
    raw = data.get("data")
    if isinstance(raw, (bytes, bytearray, memoryview)):
        return bytes(raw)
    try:
        return base64.b64decode(raw, validate=True)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise BadFile(source, f"a {schema} message has no valid base64 'data'", "a recorded image") from None


def decode_image(schema: str, data: Mapping[str, Any], source: str = "recording") -> np.ndarray:
    """A recorded image message (protobuf bytes or JSON base64) as a uint8 array; sizes are checked
    before anything is allocated or decoded (a :class:`BadFile` naming ``source`` otherwise)."""
    if schema not in ("foxglove.CompressedImage", "foxglove.RawImage"):
        raise ValueError(f"schema {schema!r} is not an image")
    raw = _image_bytes(schema, data, source)
    if schema == "foxglove.CompressedImage":
        return decode_image_bytes(raw, source, f"a {data.get('format')} image message")
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
    library: str = ""

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
    require_mcap()
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
    ``into``. A corrupt chunk or a message that does not decode by its channel's encoding is a
    :class:`BadFile` naming it (chunk, record, byte offset, topic). Channels of other encodings
    (a ROS 2 bag's ``cdr``) give messages with empty ``data`` and their ``raw`` bytes."""
    from mcap.records import Attachment, Channel, Header, Metadata, Schema
    from mcap.records import Message as McapMessage

    p = Path(path)
    rec_out = into if into is not None else Recording(p)
    schemas: dict[int, SchemaDef] = {}
    channels: dict[int, tuple[str, int, str]] = {}
    pb = ProtobufDecoder(p)
    epoch_ns = 0
    for rec, where in _records(p, rec_out):
        if isinstance(rec, McapMessage):
            topic, sid, enc = channels.get(rec.channel_id, (f"<channel {rec.channel_id}>", 0, ""))
            if topics is not None and topic not in topics:
                continue
            sd = schemas.get(sid)
            name = sd.name if sd is not None else ""
            if enc == "protobuf":
                data = pb.decode(sid, rec.data, where, topic, name)
            elif enc == "json":
                data = _decode_json(rec.data, p, where, topic)
            else:
                data = {}
            yield Message(topic, name, rec.log_time, data, enc, rec.data, sd, epoch_ns)
        elif isinstance(rec, Schema):
            schemas[rec.id] = SchemaDef(rec.name, rec.encoding, bytes(rec.data),
                                        "protobuf" if rec.encoding == "protobuf" else "json")
            if rec.encoding == "protobuf":
                pb.add_schema(rec.id, rec.name, rec.data)
        elif isinstance(rec, Channel):
            channels[rec.id] = (rec.topic, rec.schema_id, rec.message_encoding)
        elif isinstance(rec, Metadata):
            rec_out.metadata[rec.name] = dict(rec.metadata)
            if rec.name == "recording":
                try:
                    epoch_ns = int(rec.metadata.get("epoch_offset_ns", "0"))
                except ValueError:
                    raise BadFile(p, f"{where}: metadata 'recording' has epoch_offset_ns "
                                  f"{rec.metadata.get('epoch_offset_ns')!r}", "an integer (ns)") from None
        elif isinstance(rec, Attachment):
            rec_out.attachments[rec.name] = bytes(rec.data)
        elif isinstance(rec, Header):
            rec_out.library = str(rec.library)


def read_recording(path: str | Path, *, topics: set[str] | None = None) -> Recording:
    """Read a whole recording (tolerating a truncated tail). ``topics`` keeps only those topics."""
    p = check_file(path, "recording", max_bytes=MAX_RECORDING_BYTES)
    out = Recording(p)
    out.messages = list(iter_messages(p, topics=topics, into=out))
    return out

"""Independent readers for the tests: a session recording through ``mcap`` + ``mcap-protobuf-support``
(Foxglove's types decoded from the schema in the file, never through the package's reader), and a
ROS 2 bag through ``rosbags``' reader and typestore."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

from mcap.decoder import DecoderFactory as _Base
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore


class JsonDecoderFactory(_Base):
    """``json`` channels decoded with the json module."""

    def decoder_for(self, message_encoding: str, schema: Any) -> Any:
        return json.loads if message_encoding == "json" else None


def typed_messages(path: Path) -> dict[str, list[tuple[str, Any, int]]]:
    """Per topic: (schema name, decoded message, log time ns), in file order. Protobuf messages are
    the protobuf objects ``mcap-protobuf-support`` builds; JSON ones dicts."""
    out: dict[str, list[tuple[str, Any, int]]] = defaultdict(list)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[ProtobufDecoderFactory(), JsonDecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            out[channel.topic].append((schema.name if schema is not None else "", decoded, message.log_time))
    return dict(out)


def full_names(messages: dict[str, list[tuple[str, Any, int]]]) -> dict[str, str]:
    """Per protobuf topic, the full name of the decoded message's type (``foxglove.CompressedImage``)."""
    return {t: ms[0][1].DESCRIPTOR.full_name for t, ms in messages.items() if hasattr(ms[0][1], "DESCRIPTOR")}


TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)


def bag_messages(path: Path) -> dict[str, list[tuple[str, Any, int]]]:
    """Per topic of a ROS 2 bag: (message type, deserialized message, bag time ns)."""
    out: dict[str, list[tuple[str, Any, int]]] = defaultdict(list)
    with Reader(path) as reader:
        for conn, t_ns, raw in reader.messages():
            out[conn.topic].append((conn.msgtype, TYPESTORE.deserialize_cdr(raw, conn.msgtype), t_ns))
    return dict(out)


def bag_connections(path: Path) -> dict[str, Any]:
    with Reader(path) as reader:
        return {c.topic: c for c in reader.connections}

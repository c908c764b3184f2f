"""What every typed message is made of: its schema (name, encoding, definition), its encoded bytes, its
topic and its time, so a recording and a live view hand on the very same bytes.

Foxglove's types come from ``foxglove-sdk`` (``foxglove.messages``: the message classes encode
themselves as protobuf and give their schema as a FileDescriptorSet). The package is the optional
extra ``record`` / ``live``; it is imported on the first typed message, not when this module loads, so
the rig's other commands run without it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Mapping

import numpy as np

from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.messages.schemas import SCHEMAS

__all__ = ["SchemaDef", "Encoded", "foxglove_messages", "foxglove_schema", "json_schema", "schema_for",
           "encode_json", "timestamp", "is_typed"]


@dataclass(frozen=True)
class SchemaDef:
    """A channel's schema: ``name`` (``foxglove.CompressedImage``, ``tactile_rig.ScaleReading``),
    ``encoding`` (``protobuf``: a FileDescriptorSet; ``jsonschema``), its ``data`` and the
    ``message_encoding`` of the channel's messages (``protobuf`` or ``json``)."""

    name: str
    encoding: str
    data: bytes
    message_encoding: str


@dataclass(frozen=True)
class Encoded:
    """One message ready for a sink: topic, schema, bytes, session time (s) and MCAP log time (ns)."""

    topic: str
    schema: SchemaDef
    data: bytes
    t_s: float
    log_time_ns: int


def foxglove_messages() -> Any:
    """``foxglove.messages``, or ModuleNotFoundError naming the extra that installs it."""
    try:
        import foxglove.messages as fm
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError("typed recordings and the live view need the 'foxglove-sdk' package: "
                                  "pip install 'tactile-rig[record]'", name=exc.name) from exc
    return fm


@lru_cache(maxsize=None)
def foxglove_schema(type_name: str) -> SchemaDef:
    """The schema of Foxglove type ``type_name`` (``CompressedImage``), as the SDK defines it."""
    cls = getattr(foxglove_messages(), type_name)
    s = cls.get_schema()
    return SchemaDef(str(s.name), str(s.encoding), bytes(s.data), "protobuf")


@lru_cache(maxsize=None)
def json_schema(name: str) -> SchemaDef:
    """The JSON schema ``name`` of :data:`tactile_rig.rig.messages.schemas.SCHEMAS` (unknown names:
    the generic ``tactile_rig.Json``)."""
    body = SCHEMAS.get(name, SCHEMAS["tactile_rig.Json"])
    return SchemaDef(name, "jsonschema", json.dumps(body, separators=(",", ":")).encode(), "json")


def schema_for(name: str) -> SchemaDef:
    """The schema called ``name``: a Foxglove type (``foxglove.X``) or one of the rig's JSON schemas."""
    if name.startswith("foxglove."):
        return foxglove_schema(name.split(".", 1)[1])
    return json_schema(name)


def is_typed(schema_name: str) -> bool:
    """True for a schema whose messages are protobuf (Foxglove's types)."""
    return schema_name.startswith("foxglove.")


def _fast_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(type(obj).__name__)


def encode_json(body: Mapping[str, Any]) -> bytes:
    """Compact JSON; numpy values become lists/numbers, NaN and infinities ``null``."""
    try:  # fast path: plain values and numpy arrays/scalars
        return json.dumps(body, separators=(",", ":"), allow_nan=False, default=_fast_default).encode()
    except (TypeError, ValueError):  # NaN/inf (-> null), dataclasses, enums...
        return json.dumps(to_jsonable(dict(body)), separators=(",", ":"), allow_nan=False).encode()


def timestamp(log_time_ns: int) -> Any:
    """A ``foxglove.messages.Timestamp`` of a log time (ns; negative times clamp to 0)."""
    ns = max(0, int(log_time_ns))
    return foxglove_messages().Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)

"""Protobuf messages of a recording (Foxglove's types) as plain dicts, from the schema the file carries.

Each protobuf schema record holds a FileDescriptorSet; its message class is built once per schema
(``google.protobuf``'s descriptor pool and message factory, as ``mcap-protobuf-support`` does) and
each message becomes a dict of its fields: nested messages as dicts, repeated fields as lists, bytes
as bytes, enums as their numbers, ``google.protobuf.Timestamp``/``Duration`` as ``{"sec", "nsec"}``
(the JSON encoding's shape). A schema or message that does not parse is a :class:`BadFile`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tactile_rig.core.errors import BadFile

__all__ = ["ProtobufDecoder", "to_dict"]

_TIME_TYPES = ("google.protobuf.Timestamp", "google.protobuf.Duration")


def _repeated(f: Any) -> bool:
    rep = getattr(f, "is_repeated", None)  # protobuf >= 5.28; older ones only have the label
    return bool(rep) if rep is not None else f.label == f.LABEL_REPEATED


_PLAN: dict[Any, list[tuple[str, int]]] = {}  # descriptor -> (field, kind): how to convert it
_SCALAR, _LIST, _MESSAGE, _MESSAGES, _MAP = range(5)


def _plan(desc: Any) -> list[tuple[str, int]]:
    plan = _PLAN.get(desc)
    if plan is None:
        plan = []
        for f in desc.fields:
            if f.message_type is not None:
                kind = _MAP if f.message_type.GetOptions().map_entry else _MESSAGES if _repeated(f) else _MESSAGE
            else:
                kind = _LIST if _repeated(f) else _SCALAR
            plan.append((f.name, kind))
        _PLAN[desc] = plan
    return plan


def to_dict(msg: Any) -> dict[str, Any]:
    """Every field of a protobuf message (defaults included) as a plain value."""
    desc = msg.DESCRIPTOR
    if desc.full_name in _TIME_TYPES:
        return {"sec": int(msg.seconds), "nsec": int(msg.nanos)}
    out: dict[str, Any] = {}
    for name, kind in _plan(desc):
        v = getattr(msg, name)
        if kind == _SCALAR:
            out[name] = v
        elif kind == _LIST:
            out[name] = list(v)
        elif kind == _MESSAGE:
            out[name] = to_dict(v) if msg.HasField(name) else None
        elif kind == _MESSAGES:
            out[name] = [to_dict(x) for x in v]
        else:
            out[name] = {k: (to_dict(x) if hasattr(x, "DESCRIPTOR") else x) for k, x in v.items()}
    return out


class ProtobufDecoder:
    """Message classes per schema id of one file (``path`` names it in errors)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._classes: dict[int, Any] = {}

    def add_schema(self, schema_id: int, name: str, data: bytes) -> None:
        """Build the message class of a ``protobuf`` schema record (a FileDescriptorSet)."""
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
        from google.protobuf.message import DecodeError

        try:
            fds = descriptor_pb2.FileDescriptorSet.FromString(bytes(data))
            pool = descriptor_pool.DescriptorPool()
            for fd in fds.file:
                pool.Add(fd)
            self._classes[schema_id] = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
        except (DecodeError, KeyError, TypeError, ValueError) as exc:
            raise BadFile(self.path, f"protobuf schema {schema_id} ({name!r}) does not define its message "
                          f"({type(exc).__name__}: {str(exc)[:120]})",
                          "a FileDescriptorSet that defines the schema's name") from None

    def decode(self, schema_id: int, data: bytes, where: str, topic: str, schema: str) -> dict[str, Any]:
        """One message as a dict; BadFile naming ``where`` (chunk, record, byte) and ``topic`` otherwise."""
        from google.protobuf.message import DecodeError

        cls = self._classes.get(schema_id)
        if cls is None:
            raise BadFile(self.path, f"{where} on {topic} is protobuf but its channel has no protobuf schema",
                          "a protobuf channel with its FileDescriptorSet")
        try:
            return to_dict(cls.FromString(bytes(data)))
        except (DecodeError, RecursionError, ValueError) as exc:
            raise BadFile(self.path, f"{where} on {topic} is not a valid {schema} message "
                          f"({type(exc).__name__}: {str(exc)[:120]})", f"a protobuf-encoded {schema}") from None

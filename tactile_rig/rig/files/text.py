"""JSON and TOML from outside: bounded size, nesting bounded before any parser recurses, UTF-8.

The nesting depth is counted on the bytes with strings (and TOML comments) stripped, so a hostile
``[[[[...`` never reaches a recursive parser; JSON's ``NaN`` and ``Infinity`` are refused unless asked.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from tactile_rig.core.errors import BadFile
from tactile_rig.rig.files.checks import check_file, read_bytes

MAX_TEXT_BYTES = 64 << 20         # 64 MiB of JSON or TOML
MAX_JSON_DEPTH = 64
_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.S)
_TOML_STRING = re.compile(rb'"""(?:.|\n)*?"""|\'\'\'(?:.|\n)*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*')


def _nesting(data: bytes, strings: re.Pattern[bytes]) -> int:
    """Deepest bracket nesting of a JSON/TOML text, strings (and comments) stripped: found without
    parsing, so a hostile depth never reaches a recursive parser."""
    bare = np.frombuffer(strings.sub(b"", data), np.uint8)
    if bare.size == 0:
        return 0
    step = np.zeros(bare.shape, np.int64)
    step[(bare == ord("[")) | (bare == ord("{"))] = 1
    step[(bare == ord("]")) | (bare == ord("}"))] = -1
    return int(np.cumsum(step).max(initial=0))


def json_depth(data: bytes | str) -> int:
    """The bracket nesting depth of a JSON text (0 for a scalar)."""
    return _nesting(data.encode() if isinstance(data, str) else bytes(data), _JSON_STRING)


def toml_depth(text: bytes | str) -> int:
    """The bracket nesting depth of a TOML text (strings and comments stripped)."""
    return _nesting(text.encode() if isinstance(text, str) else bytes(text), _TOML_STRING)


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"the non-finite constant {name}")


def loads_json(data: bytes | str, source: str | Path, what: str = "JSON", *, max_depth: int = MAX_JSON_DEPTH,
               allow_nan: bool = False, max_bytes: int = MAX_TEXT_BYTES) -> Any:
    """Parse JSON text whose depth is bounded first (``RecursionError`` never happens); ``NaN`` and
    ``Infinity`` are refused unless ``allow_nan``. ``source`` names where the text came from."""
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    p = Path(str(source))
    if len(raw) > max_bytes:
        raise BadFile(p, f"{what} is {len(raw)} bytes", f"at most {max_bytes} bytes")
    text = _text(raw, json_depth(raw), p, what, max_depth, "UTF-8 JSON")
    try:
        return json.loads(text, parse_constant=None if allow_nan else _refuse_constant)
    except (ValueError, RecursionError) as exc:
        raise BadFile(p, f"{what} is not valid JSON ({str(exc)[:160]})", "a JSON document") from None


def _text(raw: bytes, depth: int, p: Path, what: str, max_depth: int, expected: str) -> str:
    """The bytes of a nested text format as text, once its nesting ``depth`` is within ``max_depth``."""
    if depth > max_depth:
        raise BadFile(p, f"{what} nests {depth} levels deep", f"at most {max_depth} levels")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BadFile(p, f"{what} is not UTF-8 text (byte {exc.start})", expected) from None


def load_json(path: str | Path, what: str = "JSON file", *, max_depth: int = MAX_JSON_DEPTH,
              allow_nan: bool = False, max_bytes: int = MAX_TEXT_BYTES, expect: type | None = dict) -> Any:
    """A JSON file (bounded size and depth, no NaN/Infinity); with ``expect`` its top level must be
    of that type (default an object)."""
    p = check_file(path, what, max_bytes=max_bytes)
    value = loads_json(read_bytes(p, what), p, what, max_depth=max_depth, allow_nan=allow_nan, max_bytes=max_bytes)
    if expect is not None and not isinstance(value, expect):
        raise BadFile(p, f"{what} holds a JSON {type(value).__name__}", f"a JSON {_json_name(expect)}")
    return value


def _json_name(t: type) -> str:
    return {dict: "object", list: "array", str: "string", float: "number", int: "integer"}.get(t, t.__name__)


def load_toml(path: str | Path, what: str = "TOML file", *, max_depth: int = MAX_JSON_DEPTH,
              max_bytes: int = MAX_TEXT_BYTES) -> tuple[dict[str, Any], str]:
    """A TOML file as ``(data, text)``: bounded size and nesting, UTF-8, parsed by ``tomllib``."""
    import tomllib

    p = check_file(path, what, max_bytes=max_bytes, allow_empty=True)
    raw = read_bytes(p, what)
    text = _text(raw, _nesting(raw, _TOML_STRING), p, what, max_depth, "a UTF-8 TOML file")
    try:
        return tomllib.loads(text), text
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise BadFile(p, f"{what} is not valid TOML ({str(exc)[:160]})", "a TOML file") from None


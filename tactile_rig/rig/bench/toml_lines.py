"""Line numbers of a TOML file's tables and keys (``tomllib`` keeps none), so every problem in a bench
file can name its line."""

from __future__ import annotations

import re

_HEADER_RE = re.compile(r"^\s*\[\s*([A-Za-z0-9_.\-\" ]+?)\s*\]\s*(#.*)?$")
_KEY_RE = re.compile(r"^\s*([A-Za-z0-9_\-]+|\"[^\"]*\")\s*=")
_STRING_RE = re.compile(r'"(?:[^"\\]|\\.)*"|\'[^\']*\'')


def line_index(text: str) -> tuple[dict[str, int], dict[tuple[str, str], int]]:
    """Lines (1-based) of each ``[table]`` header and each ``key =`` in it (tomllib keeps none)."""
    tables: dict[str, int] = {}
    keys: dict[tuple[str, str], int] = {}
    current = ""
    depth = 0  # bracket depth of a multi-line array: its lines hold no keys
    for n, raw in enumerate(text.splitlines(), start=1):
        code = raw
        if depth == 0:
            m = _HEADER_RE.match(raw)
            if m:
                current = m.group(1).replace('"', "").strip()
                tables.setdefault(current, n)
                continue
            k = _KEY_RE.match(raw)
            if k:
                keys.setdefault((current, k.group(1).strip('"')), n)
                code = raw[k.end():]
        # Brackets inside strings and comments do not open arrays.
        code = _STRING_RE.sub('""', code).split("#", 1)[0]
        depth = max(0, depth + code.count("[") - code.count("]"))
    return tables, keys

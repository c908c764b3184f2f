"""Helpers shared by the command modules: JSON output and common arguments."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from tactile_rig.core.jsonable import to_jsonable


def print_json(obj: Any, *, stream=None) -> None:
    """Print one JSON object on one line and flush (one line per record: easy to stream and parse)."""
    stream = stream or sys.stdout
    stream.write(json.dumps(to_jsonable(obj), separators=(",", ":")) + "\n")
    stream.flush()


def add_json_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON")

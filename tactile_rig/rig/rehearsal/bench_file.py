"""The ``bench.toml`` a rehearsal writes: every device's path as a real bench names it."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class RehearsalDevice:
    """One table of the bench file: its name and its keys (values are TOML-written with json.dumps,
    which spells strings, numbers, booleans and lists of them as TOML does)."""

    table: str
    keys: dict[str, Any]
    comment: str = ""
    pids: list[int] = field(default_factory=list)


def _value(v: Any) -> str:
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return json.dumps(v)


def bench_toml(name: str, devices: list[RehearsalDevice], *, header: str = "",
               head: dict[str, Any] | None = None) -> str:
    """The text of a bench file naming ``devices``; ``head`` holds further ``[bench]`` keys."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    lines += ["", "[bench]", f"name = {_value(name)}"]
    lines += [f"{k} = {_value(v)}" for k, v in (head or {}).items()]
    lines.append("")
    for dev in devices:
        if dev.comment:
            lines.append(f"# {dev.comment}")
        lines.append(f"[{dev.table}]")
        lines += [f"{k} = {_value(v)}" for k, v in dev.keys.items()]
        lines.append("")
    return "\n".join(lines)


def link_device(links_dir: Path, name: str, target: str) -> Path:
    """A stable name for a device path (as udev's /dev/serial/by-path links are): ``links_dir/name``."""
    links_dir.mkdir(parents=True, exist_ok=True)
    link = links_dir / name
    if link.is_symlink() or link.exists():
        link.unlink()
    link.symlink_to(target)
    return link

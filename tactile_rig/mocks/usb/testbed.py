"""The USB testbed of a bench, written two ways from one description (:mod:`.sysfs`):

* :func:`umockdev_text`: umockdev's device description format (what ``umockdev-record`` writes and
  ``umockdev-run --device FILE`` loads), for the real stack: under umockdev's preload, libusb, udev
  clients and plain file reads see these devices in ``/sys`` and ``/dev``;
* :func:`write_tree`: the same sysfs and ``/dev`` as a plain directory tree laid out as umockdev lays
  out its testbed, for ``tactile-rig devices --mock`` and tests on a machine without umockdev.

:func:`umockdev_problem` says what is missing to run the real stack (``umockdev-run`` from Debian's
``umockdev``, libusb from ``libusb-1.0-0``), or ``None``.
"""

from __future__ import annotations

import ctypes.util
import os
import shutil
from pathlib import Path

from tactile_rig.mocks.usb.bench import BENCH, Bench
from tactile_rig.mocks.usb.sysfs import SysfsDevice, build

__all__ = ["BUS_SUBSYSTEMS", "DEBIAN_PACKAGES", "REQUIRE_ENV", "escape_attribute", "umockdev_problem", "umockdev_text",
           "write_testbed", "write_tree"]

REQUIRE_ENV = "TACTILE_RIG_REQUIRE_UMOCKDEV"  # CI sets it to 1: a missing tool fails instead of skipping
DEBIAN_PACKAGES = "umockdev libusb-1.0-0"
BUS_SUBSYSTEMS = ("pci", "usb", "usb-serial")  # the rest (tty, video4linux) are classes, as umockdev sorts them


def umockdev_problem() -> str | None:
    """What is missing to run discovery under umockdev, in one line naming the Debian packages; ``None`` if nothing."""
    missing = []
    if shutil.which("umockdev-run") is None:
        missing.append("umockdev-run")
    if ctypes.util.find_library("usb-1.0") is None:
        missing.append("libusb-1.0")
    if not missing:
        return None
    return f"{' and '.join(missing)} not found; install the Debian packages {DEBIAN_PACKAGES}"


def escape_attribute(value: str) -> str:
    """An attribute value as umockdev's ``A:`` lines hold it (GLib ``g_strcompress`` undoes it)."""
    out = []
    for ch in value:
        if ch == "\\":
            out.append("\\\\")
        elif ch == "\n":
            out.append("\\n")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\{ord(ch):03o}")
        else:
            out.append(ch)
    return "".join(out)


def umockdev_text(devices: list[SysfsDevice]) -> str:
    """The devices in umockdev's text format, one block per device."""
    blocks = []
    for dev in devices:
        lines = [f"P: {dev.path}"]
        if dev.devnode:
            contents = f"={dev.devnode_contents.hex().upper()}" if dev.devnode_contents else ""
            lines.append(f"N: {dev.devnode}{contents}")
            lines += [f"S: {link}" for link in dev.devlinks]
        for key, value in dev.properties.items():
            if "\n" in value:
                raise ValueError(f"{dev.path}: property {key} holds a newline")
            lines.append(f"E: {key}={value}")
        lines += [f"A: {k}={escape_attribute(v)}" for k, v in dev.attributes.items()]
        lines += [f"H: {k}={v.hex().upper()}" for k, v in dev.binary.items()]
        lines += [f"L: {k}={v}" for k, v in dev.links.items()]
        blocks.append("\n".join(lines) + "\n")
    return "\n".join(blocks)


def write_testbed(path: str | Path, bench: Bench = BENCH) -> Path:
    """Write ``bench`` as a umockdev device file at ``path`` (for ``umockdev-run --device``)."""
    path = Path(path)
    devices, _ = build(bench)
    path.write_text(umockdev_text(devices), encoding="utf-8")
    return path


def _symlink(target: str, link: Path) -> None:
    link.parent.mkdir(parents=True, exist_ok=True)
    if link.is_symlink() or link.exists():
        link.unlink()
    os.symlink(target, link)


def write_tree(devices: list[SysfsDevice], root: str | Path) -> tuple[Path, Path]:
    """Write the devices as ``root/sys`` and ``root/dev`` (umockdev's testbed layout, relative links
    as udev makes them); returns ``(sysfs_root, dev_root)``."""
    root = Path(root)
    sysfs, dev = root / "sys", root / "dev"
    for sub in ("bus", "class"):
        (sysfs / sub).mkdir(parents=True, exist_ok=True)
    dev.mkdir(parents=True, exist_ok=True)
    for d in devices:
        ddir = sysfs / d.path.lstrip("/")
        ddir.mkdir(parents=True, exist_ok=True)
        depth = len(Path(d.path).parts) - 1  # "/devices/a/b" -> 3 levels below /sys
        name = Path(d.path).name
        if d.subsystem in BUS_SUBSYSTEMS:
            _symlink("../../.." + d.path, sysfs / "bus" / d.subsystem / "devices" / name)
            _symlink("/".join([".."] * depth) + f"/bus/{d.subsystem}", ddir / "subsystem")
        else:
            _symlink("../.." + d.path, sysfs / "class" / d.subsystem / name)
            _symlink("/".join([".."] * depth) + f"/class/{d.subsystem}", ddir / "subsystem")
        uevent = "".join(f"{k}={v[5:] if k == 'DEVNAME' and v.startswith('/dev/') else v}\n"
                         for k, v in d.properties.items())
        (ddir / "uevent").write_text(uevent, encoding="utf-8")
        for key, value in d.attributes.items():
            (ddir / key).write_text(value, encoding="utf-8")
        for key, data in d.binary.items():
            (ddir / key).write_bytes(data)
        for key, target in d.links.items():
            _symlink(target, ddir / key)
        if "dev" in d.attributes and d.devnode:
            kind = "block" if "/block/" in d.path else "char"
            _symlink("../.." + d.path, sysfs / "dev" / kind / d.attributes["dev"].strip())
        if d.devnode:
            node = dev / d.devnode
            node.parent.mkdir(parents=True, exist_ok=True)
            node.write_bytes(d.devnode_contents)
            for link in d.devlinks:
                _symlink(os.path.relpath(node, (dev / link).parent), dev / link)
    return sysfs, dev

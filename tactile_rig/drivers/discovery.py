"""Which USB device is which node: pyusb enumeration mapped through sysfs to /dev paths.

:func:`discover` lists the known devices (U2D2, Arduinos, CH340 adapters, the C310 camera; the
table is a parameter) with their bus location, serial number and nodes: ``/dev/ttyUSBn`` or
``/dev/ttyACMn``, ``/dev/videoN`` (capture node only, ``index`` 0), and the stable
``/dev/serial/by-id`` and ``/dev/v4l/by-id`` links (unique per serial number; two adapters without
one collide, as udev names them alike) and the ``by-path`` links (unique per USB port). sysfs and /dev roots are parameters, so a fake
tree (:mod:`tactile_rig.mocks.usb`) makes it testable; without a libusb backend it falls back to
reading the USB devices from sysfs alone.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["KNOWN_DEVICES", "UsbDevice", "discover", "match_kind"]

# (vendor id, product id or None for any) -> kind
KNOWN_DEVICES: dict[tuple[int, int | None], str] = {
    (0x0403, 0x6014): "u2d2",
    (0x2341, None): "arduino",
    (0x1A86, 0x7523): "ch340",
    (0x046D, 0x081B): "camera_c310",
}


@dataclass
class UsbDevice:
    """One USB device we know, and the nodes it owns."""

    kind: str
    vid: int
    pid: int
    bus: int
    port_path: str  # sysfs name, e.g. "1-1.2"
    serial: str | None = None
    product: str | None = None
    tty: list[str] = field(default_factory=list)
    video: list[str] = field(default_factory=list)
    by_id: list[str] = field(default_factory=list)
    by_path: list[str] = field(default_factory=list)

    @property
    def usb_id(self) -> str:
        return f"{self.vid:04x}:{self.pid:04x}"


def match_kind(vid: int, pid: int, table: dict[tuple[int, int | None], str] = KNOWN_DEVICES) -> str | None:
    return table.get((vid, pid)) or table.get((vid, None))


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8").strip()
    except OSError:
        return None


def _usb_from_pyusb(backend: Any) -> list[tuple[int, int, int, str]] | None:
    """(vid, pid, bus, port_path) of every device pyusb sees; None when pyusb has no backend."""
    import usb.core

    try:
        devs = list(usb.core.find(find_all=True, backend=backend))
    except usb.core.NoBackendError:
        return None
    out = []
    for d in devs:
        ports = getattr(d, "port_numbers", None) or ()
        port_path = f"{d.bus}-{'.'.join(map(str, ports))}" if ports else f"usb{d.bus}"
        out.append((int(d.idVendor), int(d.idProduct), int(d.bus), port_path))
    return out


def _usb_from_sysfs(sysfs: Path) -> list[tuple[int, int, int, str]]:
    out = []
    base = sysfs / "bus" / "usb" / "devices"
    for d in sorted(base.glob("*")) if base.is_dir() else []:
        if ":" in d.name:
            continue  # an interface, not a device
        vid, pid, bus = _read(d / "idVendor"), _read(d / "idProduct"), _read(d / "busnum")
        if vid and pid:
            out.append((int(vid, 16), int(pid, 16), int(bus or d.name.split("-")[0].lstrip("usb") or 0), d.name))
    return out


def _owner(node_dir: Path, usb_dirs: dict[str, Path]) -> str | None:
    """The USB device (port path) a tty/video class entry belongs to, by walking up its device link."""
    try:
        real = (node_dir / "device").resolve()
    except OSError:
        return None
    for p in (real, *real.parents):
        if p.name in usb_dirs and (p / "idVendor").exists():
            return p.name
    return None


def _links(dev: Path, sub: str) -> dict[str, list[str]]:
    """node name (ttyUSB0, video0) -> stable symlinks in ``dev/sub``."""
    out: dict[str, list[str]] = {}
    d = dev / sub
    for link in sorted(d.glob("*")) if d.is_dir() else []:
        if link.is_symlink():
            out.setdefault(Path(os.readlink(link)).name, []).append(str(link))
    return out


def discover(*, backend: Any = None, sysfs_root: str | Path = "/sys", dev_root: str | Path = "/dev",
             table: dict[tuple[int, int | None], str] = KNOWN_DEVICES, use_pyusb: bool = True) -> list[UsbDevice]:
    """The known USB devices plugged in, with their nodes (paths under ``dev_root``)."""
    sysfs, dev = Path(sysfs_root), Path(dev_root)
    found = _usb_from_pyusb(backend) if use_pyusb else None
    if found is None:
        found = _usb_from_sysfs(sysfs)
    usb_base = sysfs / "bus" / "usb" / "devices"
    usb_dirs = {p.name: p.resolve() for p in usb_base.glob("*")} if usb_base.is_dir() else {}
    owners: dict[str, list[tuple[str, str]]] = {}
    for cls, node_kind in (("tty", "tty"), ("video4linux", "video")):
        for entry in sorted((sysfs / "class" / cls).glob("*")):
            if node_kind == "video" and _read(entry / "index") not in (None, "0"):
                continue  # metadata node of a UVC camera
            owner = _owner(entry, usb_dirs)
            if owner:
                owners.setdefault(owner, []).append((node_kind, entry.name))
    links = {k: _links(dev, k) for k in ("serial/by-id", "v4l/by-id", "serial/by-path", "v4l/by-path")}
    result = []
    for vid, pid, bus, port_path in found:
        kind = match_kind(vid, pid, table)
        if kind is None:
            continue
        udir = usb_dirs.get(port_path)
        u = UsbDevice(kind, vid, pid, bus, port_path,
                      serial=_read(udir / "serial") if udir else None,
                      product=_read(udir / "product") if udir else None)
        for nkind, node in owners.get(port_path, []):
            (u.tty if nkind == "tty" else u.video).append(str(dev / node))
            family = "serial" if nkind == "tty" else "v4l"
            u.by_id += links[f"{family}/by-id"].get(node, [])
            u.by_path += links[f"{family}/by-path"].get(node, [])
        result.append(u)
    return result

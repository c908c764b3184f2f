"""Which USB device is which node: pyusb enumeration mapped through sysfs to /dev paths.

:func:`discover` lists the known devices (the serial adapters of :mod:`tactile_rig.devices.usb`,
Arduinos, and the cameras of :mod:`tactile_rig.devices.camera_models`: the C310, GelSight Mini and
DIGIT, each named by its model key as ``bench.toml`` names it; the table is a parameter) with their bus
location, serial number and nodes: ``/dev/ttyUSBn`` or ``/dev/ttyACMn``, ``/dev/videoN`` (the
capture node only, ``index`` 0; a UVC camera's metadata node, ``index`` 1, is left out), and the
stable ``/dev/serial/by-id`` and ``/dev/v4l/by-id`` links (unique per serial number; two adapters
without one claim the same name and udev gives it to the last one plugged in) and the ``by-path``
links (unique per USB port).

Enumeration goes through pyusb with the first backend it can load (libusb-1.0, then libusb-0.1,
then OpenUSB, pyusb's own order), or a backend given as a parameter; each device records which one
found it (``enumerated_by``: ``libusb1``, ``fake``, ... or ``sysfs`` when no backend loads and the
USB devices are read from ``/sys/bus/usb/devices`` alone). Strings and nodes come from sysfs, which
needs no access to the device. The sysfs and /dev roots are parameters, so a tree written by
:mod:`tactile_rig.mocks.usb` makes it testable without umockdev; under umockdev the defaults read
the testbed. An attribute that does not parse (an id that is not 4 hex digits, a bus number that is
not a number) makes that device or node unknown, with a warning naming the file and the value.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb
import usb.core

from tactile_rig.devices.camera_models import CAMERA_MODELS, camera_model_by_usb_kind
from tactile_rig.devices.usb import ARDUINO_VENDOR_ID, SERIAL_ADAPTERS

__all__ = ["KNOWN_DEVICES", "DeviceMatch", "UsbDevice", "backend_name", "discover", "match_kind", "parse_decimal",
           "parse_usb_id"]

_log = logging.getLogger(__name__)


class DeviceMatch(NamedTuple):
    """A rule of the device table: ids (``pid`` None: any product of the vendor) and, for ids several
    products share, a prefix of the product string."""

    kind: str
    vid: int
    pid: int | None = None
    product_prefix: str | None = None


KNOWN_DEVICES: tuple[DeviceMatch, ...] = (
    *(DeviceMatch(a.kind, a.vid, a.pid) for a in SERIAL_ADAPTERS if a.vid != ARDUINO_VENDOR_ID),
    DeviceMatch("arduino", ARDUINO_VENDOR_ID),
    *(DeviceMatch(m.usb_kind, m.vendor_id, m.product_id, m.product_prefix) for m in CAMERA_MODELS.values()
      if m.vendor_id is not None),
)


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
    enumerated_by: str = "sysfs"  # the pyusb backend that listed it ("libusb1", "fake"), or "sysfs"

    @property
    def model(self) -> str | None:
        """The camera model key (``c310``, ``gelsight-mini``, ``digit``: what ``bench.toml``'s
        ``model =`` takes) of a camera, else None."""
        m = camera_model_by_usb_kind(self.kind)
        return m.key if m is not None else None

    @property
    def usb_id(self) -> str:
        return f"{self.vid:04x}:{self.pid:04x}"


def match_kind(vid: int, pid: int, product: str | None = None,
               table: tuple[DeviceMatch, ...] = KNOWN_DEVICES) -> str | None:
    """The kind of a device: the most specific matching rule (product prefix, then ids, then vendor)."""
    best: tuple[int, str] | None = None
    for rule in table:
        if rule.vid != vid or rule.pid not in (None, pid):
            continue
        if rule.product_prefix is not None and not (product or "").startswith(rule.product_prefix):
            continue
        rank = 2 if rule.product_prefix is not None else 1 if rule.pid is not None else 0
        if best is None or rank > best[0]:
            best = (rank, rule.kind)
    return best[1] if best else None


def parse_usb_id(text: str | None) -> int | None:
    """A sysfs ``idVendor`` / ``idProduct`` value (4 hex digits); None for anything else."""
    if text is None or len(text) != 4 or any(c not in "0123456789abcdefABCDEF" for c in text):
        return None
    return int(text, 16)


def parse_decimal(text: str | None, high: int = 1 << 16) -> int | None:
    """A sysfs decimal value such as ``busnum``, ``devnum`` or a video ``index`` in 0..high; None otherwise."""
    if text is None or not text.isascii() or not text.isdigit() or len(text) > 6:
        return None
    value = int(text)
    return value if value <= high else None


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8", errors="replace").strip()
    except (OSError, ValueError):
        return None


def _default_backend() -> Any:
    """The backend pyusb would pick, resolved here so that the result can name it."""
    for module in (usb.backend.libusb1, usb.backend.libusb0, usb.backend.openusb):
        backend = module.get_backend()
        if backend is not None:
            return backend
    return None


def backend_name(backend: Any) -> str:
    """A short name of a pyusb backend: its module's last part (``libusb1``, ``libusb0``, ``openusb``)."""
    return str(getattr(backend, "name", None) or type(backend).__module__.rsplit(".", 1)[-1])


def _usb_from_pyusb(backend: Any) -> list[tuple[int, int, int, str]] | None:
    """(vid, pid, bus, port_path) of every device pyusb lists; None when pyusb has no backend."""
    if backend is None:
        return None
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
    for d in sorted(base.iterdir()) if base.is_dir() else []:
        if ":" in d.name:
            continue  # an interface, not a device
        raw = {name: _read(d / name) for name in ("idVendor", "idProduct", "busnum")}
        vid, pid, bus = parse_usb_id(raw["idVendor"]), parse_usb_id(raw["idProduct"]), parse_decimal(raw["busnum"])
        if vid is None or pid is None or bus is None:
            _log.warning("%s: idVendor %r, idProduct %r, busnum %r; expected 4 hex digits, 4 hex digits, "
                         "a decimal: skipped", d, raw["idVendor"], raw["idProduct"], raw["busnum"])
            continue
        out.append((vid, pid, bus, d.name))
    return out


def _owner(node_dir: Path, usb_dirs: dict[str, Path]) -> str | None:
    """The USB device (port path) a tty/video class entry belongs to, by walking up its device link."""
    try:
        real = (node_dir / "device").resolve()
    except (OSError, RuntimeError):
        return None
    for p in (real, *real.parents):
        if ":" not in p.name and usb_dirs.get(p.name) == p:  # a device, not one of its interfaces
            return p.name
    return None


def _links(dev: Path, sub: str) -> dict[str, list[str]]:
    """node name (ttyUSB0, video0) -> stable symlinks in ``dev/sub``."""
    out: dict[str, list[str]] = {}
    d = dev / sub
    for link in sorted(d.iterdir()) if d.is_dir() else []:
        if link.is_symlink():
            out.setdefault(Path(os.readlink(link)).name, []).append(str(link))
    return out


def discover(*, backend: Any = None, sysfs_root: str | Path = "/sys", dev_root: str | Path = "/dev",
             table: tuple[DeviceMatch, ...] = KNOWN_DEVICES, use_pyusb: bool = True) -> list[UsbDevice]:
    """The known USB devices plugged in, with their nodes (paths under ``dev_root``)."""
    sysfs, dev = Path(sysfs_root), Path(dev_root)
    if use_pyusb and backend is None:
        backend = _default_backend()
    found = _usb_from_pyusb(backend) if use_pyusb else None
    source = backend_name(backend) if found is not None else "sysfs"
    if found is None:
        found = _usb_from_sysfs(sysfs)
    usb_base = sysfs / "bus" / "usb" / "devices"
    usb_dirs = {p.name: p.resolve() for p in usb_base.iterdir()} if usb_base.is_dir() else {}
    owners: dict[str, list[tuple[str, str]]] = {}
    for cls, node_kind in (("tty", "tty"), ("video4linux", "video")):
        class_dir = sysfs / "class" / cls
        for entry in sorted(class_dir.iterdir()) if class_dir.is_dir() else []:
            if node_kind == "video":
                raw_index = _read(entry / "index")
                if raw_index is not None and parse_decimal(raw_index) is None:
                    _log.warning("%s: index %r, expected a decimal: skipped", entry / "index", raw_index)
                    continue
                if raw_index not in (None, "0"):
                    continue  # a UVC camera's metadata node
            owner = _owner(entry, usb_dirs)
            if owner:
                owners.setdefault(owner, []).append((node_kind, entry.name))
    links = {k: _links(dev, k) for k in ("serial/by-id", "v4l/by-id", "serial/by-path", "v4l/by-path")}
    result = []
    for vid, pid, bus, port_path in found:
        udir = usb_dirs.get(port_path)
        product = _read(udir / "product") if udir else None
        kind = match_kind(vid, pid, product, table)
        if kind is None:
            continue
        u = UsbDevice(kind, vid, pid, bus, port_path, serial=_read(udir / "serial") if udir else None,
                      product=product, enumerated_by=source)
        for nkind, node in owners.get(port_path, []):
            (u.tty if nkind == "tty" else u.video).append(str(dev / node))
            family = "serial" if nkind == "tty" else "v4l"
            u.by_id += links[f"{family}/by-id"].get(node, [])
            u.by_path += links[f"{family}/by-path"].get(node, [])
        result.append(u)
    # libusb lists the newest device first, sysfs by name: give one order, by bus and port
    result.sort(key=lambda u: (u.bus, [int(p) if p.isdigit() else -1 for p in u.port_path.split("-")[-1].split(".")]))
    return result

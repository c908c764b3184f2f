"""Fake USB: a pyusb backend and a sysfs + /dev tree that list the mock devices.

:class:`FakeUsbBackend` implements the part of ``usb.backend.IBackend`` that enumeration needs
(``enumerate_devices``, ``get_device_descriptor``, ``get_parent``), so ``usb.core.find(backend=...)``
and VID/PID filtering work unchanged. :func:`build_fake_tree` writes the matching sysfs layout
(``bus/usb/devices/<bus>-<ports>`` with ``idVendor``/``idProduct``/``serial``/``product``,
interfaces, ``class/tty/*/device`` and ``class/video4linux/*/{device,index,name}`` links) and the
``/dev/serial/by-id``, ``/dev/serial/by-path``, ``/dev/v4l/by-id`` and ``/dev/v4l/by-path`` symlinks, so :func:`tactile_rig.drivers.discovery.discover`
runs end to end on it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import usb.backend

__all__ = ["FakeUsbDevice", "MOCK_DEVICES", "FakeUsbBackend", "build_fake_tree"]


@dataclass(frozen=True)
class FakeUsbDevice:
    """A USB device: ids, location, strings, and the nodes its driver creates."""

    vid: int
    pid: int
    bus: int
    ports: tuple[int, ...]
    serial: str
    product: str
    manufacturer: str
    tty: str | None = None  # "ttyUSB0" / "ttyACM0"
    video: tuple[str, ...] = ()  # ("video0", "video1"): capture node, metadata node
    address: int = 2

    @property
    def port_path(self) -> str:
        return f"{self.bus}-{'.'.join(map(str, self.ports))}"


MOCK_DEVICES: tuple[FakeUsbDevice, ...] = (
    FakeUsbDevice(0x0403, 0x6014, 1, (1, 1), "FT5MOCK1", "USB <-> Serial Converter", "FTDI", tty="ttyUSB0", address=3),
    FakeUsbDevice(0x2341, 0x0043, 1, (1, 2), "75833353035351F0A1B1", "Arduino Uno", "Arduino (www.arduino.cc)",
                  tty="ttyACM0", address=4),
    FakeUsbDevice(0x1A86, 0x7523, 1, (1, 3), "", "USB Serial", "QinHeng", tty="ttyUSB1", address=5),
    FakeUsbDevice(0x046D, 0x081B, 1, (1, 4), "MOCKC310A", "UVC Camera (046d:081b)", "Logitech",
                  video=("video0", "video1"), address=6),
    FakeUsbDevice(0x046D, 0xC52B, 1, (2,), "", "USB Receiver", "Logitech", address=7),  # a mouse dongle: not ours
)


class _Descriptor:
    def __init__(self, d: FakeUsbDevice) -> None:
        self.bLength, self.bDescriptorType, self.bcdUSB = 18, 1, 0x0200
        self.bDeviceClass = self.bDeviceSubClass = self.bDeviceProtocol = 0
        self.bMaxPacketSize0, self.idVendor, self.idProduct, self.bcdDevice = 64, d.vid, d.pid, 0x0100
        self.iManufacturer, self.iProduct, self.iSerialNumber, self.bNumConfigurations = 1, 2, 3, 1
        self.bus, self.address, self.port_number, self.port_numbers = d.bus, d.address, d.ports[-1], d.ports
        self.speed = 3


class FakeUsbBackend(usb.backend.IBackend):
    """Enumerates ``devices`` for ``usb.core.find(find_all=True, backend=FakeUsbBackend(...))``."""

    def __init__(self, devices: tuple[FakeUsbDevice, ...] = MOCK_DEVICES) -> None:
        self.devices = devices

    def enumerate_devices(self):  # noqa: ANN201  (pyusb API)
        return iter(self.devices)

    def get_device_descriptor(self, dev: FakeUsbDevice) -> _Descriptor:
        return _Descriptor(dev)

    def get_parent(self, dev: FakeUsbDevice) -> None:
        return None


def _link(target: Path, link: Path) -> None:
    link.parent.mkdir(parents=True, exist_ok=True)
    if link.is_symlink() or link.exists():
        link.unlink()
    os.symlink(os.path.relpath(target, link.parent), link)


def _by_id_name(d: FakeUsbDevice) -> str:
    return f"usb-{d.manufacturer.split()[0]}_{d.product.replace(' ', '_')}_{d.serial or 'noserial'}"


def _by_path_prefix(d: FakeUsbDevice) -> str:
    return f"pci-0000:00:14.{d.bus - 1}-usb-0:{'.'.join(map(str, d.ports))}"  # one controller per bus


def build_fake_tree(root: str | Path, devices: tuple[FakeUsbDevice, ...] = MOCK_DEVICES) -> tuple[Path, Path]:
    """Write a fake sysfs and /dev for ``devices`` under ``root``; returns (sysfs_root, dev_root)."""
    root = Path(root)
    sysfs, dev = root / "sys", root / "dev"
    devices_dir = sysfs / "devices" / "pci0000:00" / "0000:00:14.0"
    dev.mkdir(parents=True, exist_ok=True)
    for d in devices:
        real = devices_dir / f"usb{d.bus}" / d.port_path
        real.mkdir(parents=True, exist_ok=True)
        for name, value in (("idVendor", f"{d.vid:04x}"), ("idProduct", f"{d.pid:04x}"), ("busnum", str(d.bus)),
                            ("devnum", str(d.address)), ("product", d.product), ("manufacturer", d.manufacturer)):
            (real / name).write_text(value + "\n")
        if d.serial:
            (real / "serial").write_text(d.serial + "\n")
        _link(real, sysfs / "bus" / "usb" / "devices" / d.port_path)
        intf = real / f"{d.port_path}:1.0"
        intf.mkdir(exist_ok=True)
        if d.tty:
            # ftdi_sio/ch341 hang the tty under a usb-serial port; cdc_acm under the interface itself.
            parent = intf / d.tty if d.tty.startswith("ttyUSB") else intf
            parent.mkdir(exist_ok=True)
            cls = sysfs / "class" / "tty" / d.tty
            cls.mkdir(parents=True, exist_ok=True)
            _link(parent, cls / "device")
            (dev / d.tty).touch()
            suffix = "-if00-port0" if d.tty.startswith("ttyUSB") else "-if00"
            # Like udev: two adapters without a serial number get the same by-id name (the last one
            # wins); the by-path name, from the USB port, is always unique.
            _link(dev / d.tty, dev / "serial" / "by-id" / (_by_id_name(d) + suffix))
            _link(dev / d.tty, dev / "serial" / "by-path" / f"{_by_path_prefix(d)}:1.0{suffix[5:] or ''}")
        for index, node in enumerate(d.video):
            cls = sysfs / "class" / "video4linux" / node
            cls.mkdir(parents=True, exist_ok=True)
            _link(intf, cls / "device")
            (cls / "index").write_text(f"{index}\n")
            (cls / "name").write_text(d.product + "\n")
            (dev / node).touch()
            _link(dev / node, dev / "v4l" / "by-id" / f"{_by_id_name(d)}-video-index{index}")
            _link(dev / node, dev / "v4l" / "by-path" / f"{_by_path_prefix(d)}:1.0-video-index{index}")
    return sysfs, dev

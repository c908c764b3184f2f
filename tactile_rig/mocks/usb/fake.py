"""A pyusb backend and a plain sysfs + /dev tree for a bench, without umockdev or libusb.

:class:`FakeUsbBackend` implements the enumeration part of ``usb.backend.IBackend``
(``enumerate_devices``, ``get_device_descriptor``, ``get_configuration_descriptor``,
``get_interface_descriptor``, ``get_endpoint_descriptor``, ``get_parent``) from the same devices the
umockdev testbed holds: each device's ``descriptors`` bytes read as libusb reads them
(:mod:`.descriptors`), with its bus, address, port numbers and speed from sysfs. So
``usb.core.find(backend=FakeUsbBackend())``, VID/PID filtering and walking configurations work
unchanged. :func:`build_fake_tree` writes the matching sysfs and ``/dev`` (:func:`.testbed.write_tree`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Iterator

import usb.backend

from tactile_rig.mocks.usb.bench import BENCH, Bench
from tactile_rig.mocks.usb.descriptors import (AltSetting, Configuration, Endpoint, parse_configuration,
                                                parse_device_descriptor, split_configurations)
from tactile_rig.mocks.usb.sysfs import build
from tactile_rig.mocks.usb.testbed import write_tree

__all__ = ["FakeUsbBackend", "FakeUsbDevice", "build_fake_tree"]

# sysfs "speed" -> libusb_speed, as libusb's Linux backend maps it
_SPEEDS = {"1.5": 1, "12": 2, "480": 3, "5000": 4, "10000": 5, "20000": 5}


@dataclass(frozen=True)
class FakeUsbDevice:
    """A USB device as the backend hands it to pyusb: its descriptors and where it is."""

    descriptors: bytes
    bus: int
    address: int
    ports: tuple[int, ...]
    speed: int
    sysfs_name: str

    def configurations(self) -> list[Configuration]:
        return [parse_configuration(c, source=f"{self.sysfs_name} configuration {i}")
                for i, c in enumerate(split_configurations(self.descriptors, source=self.sysfs_name))]


def _devices(bench: Bench) -> list[FakeUsbDevice]:
    out = []
    for d in build(bench)[0]:
        if d.subsystem != "usb" or "descriptors" not in d.binary:
            continue
        name = Path(d.path).name
        ports = tuple(int(p) for p in name.split("-", 1)[1].split(".")) if "-" in name else ()
        out.append(FakeUsbDevice(d.binary["descriptors"], int(d.attributes["busnum"]), int(d.attributes["devnum"]),
                                 ports, _SPEEDS[d.attributes["speed"].strip()], name))
    return out


def _descriptor(obj: Configuration | AltSetting | Endpoint) -> SimpleNamespace:
    """The fields pyusb reads from a backend's descriptor, ``extra_descriptors`` as libusb's extra bytes."""
    values: dict[str, Any] = {k: v for k, v in vars(obj).items()
                              if k not in ("endpoints", "interfaces", "all_descriptors", "extra")}
    return SimpleNamespace(**values, extra_descriptors=list(obj.extra))


class FakeUsbBackend(usb.backend.IBackend):
    """Lists the USB devices of ``bench`` for ``usb.core.find(find_all=True, backend=FakeUsbBackend(...))``."""

    name = "fake"

    def __init__(self, bench: Bench = BENCH) -> None:
        self.bench = bench
        self.devices = _devices(bench)

    def enumerate_devices(self) -> Iterator[FakeUsbDevice]:
        return iter(self.devices)

    def get_device_descriptor(self, dev: FakeUsbDevice) -> SimpleNamespace:
        desc = parse_device_descriptor(dev.descriptors, source=dev.sysfs_name)
        return SimpleNamespace(**vars(desc), bus=dev.bus, address=dev.address,
                               port_number=dev.ports[-1] if dev.ports else 0, port_numbers=dev.ports or None,
                               speed=dev.speed)

    def _config(self, dev: FakeUsbDevice, config: int) -> Configuration:
        configs = dev.configurations()
        if not 0 <= config < len(configs):
            raise IndexError("Invalid configuration index " + str(config))
        return configs[config]

    def get_configuration_descriptor(self, dev: FakeUsbDevice, config: int) -> SimpleNamespace:
        return _descriptor(self._config(dev, config))

    def _alt(self, dev: FakeUsbDevice, intf: int, alt: int, config: int) -> AltSetting:
        interfaces = self._config(dev, config).interfaces
        if not 0 <= intf < len(interfaces):
            raise IndexError("Invalid interface index " + str(intf))
        if not 0 <= alt < len(interfaces[intf]):
            raise IndexError("Invalid alternate setting index " + str(alt))
        return interfaces[intf][alt]

    def get_interface_descriptor(self, dev: FakeUsbDevice, intf: int, alt: int, config: int) -> SimpleNamespace:
        return _descriptor(self._alt(dev, intf, alt, config))

    def get_endpoint_descriptor(self, dev: FakeUsbDevice, ep: int, intf: int, alt: int, config: int) -> SimpleNamespace:
        endpoints: tuple[Endpoint, ...] = self._alt(dev, intf, alt, config).endpoints
        if not 0 <= ep < len(endpoints):
            raise IndexError("Invalid endpoint index " + str(ep))
        return _descriptor(endpoints[ep])

    def get_parent(self, dev: FakeUsbDevice) -> FakeUsbDevice | None:
        for other in self.devices:
            if other.bus == dev.bus and dev.ports and other.ports == dev.ports[:-1]:
                return other
        return None


def build_fake_tree(root: str | Path, bench: Bench = BENCH) -> tuple[Path, Path]:
    """Write the sysfs and /dev of ``bench`` under ``root``; returns (sysfs_root, dev_root)."""
    return write_tree(build(bench)[0], root)

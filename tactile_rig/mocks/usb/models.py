"""USB device models: what one kind of device reports (descriptors, strings, speed) and which kernel
driver binds each of its interfaces, read from the files in ``models/``.

A model file is TOML: ``[device]`` holds the device descriptor's fields, ``[descriptors]
configuration`` the configuration in the text form of :mod:`.descriptors`, ``[interfaces.N]`` the
driver of interface N and the nodes it creates (``tty``, ``video``, ``video-metadata``). A serial
adapter names its ``adapter`` kind and takes its ids and strings from
:mod:`tactile_rig.devices.usb`; a camera names its ``camera`` model and takes its ids, strings,
serial-number presence and ``bcdDevice`` from :mod:`tactile_rig.devices.camera_models` (the file
must not restate them); any other device states ``vendor_id``, ``product_id``, ``manufacturer``,
``product`` and ``has_serial_number`` itself. Every file cites where its facts
come from. Loading checks the descriptors as a host would (lengths, counts, ``wTotalLength``) and
that the strings the descriptor points at exist, so a model that loads is one libusb can read.
"""

from __future__ import annotations

import functools
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tactile_rig.core.errors import BadFile, LinkCorrupt
from tactile_rig.devices.camera_models import camera_model
from tactile_rig.devices.usb import serial_adapter
from tactile_rig.mocks.usb.descriptors import (Configuration, DeviceDescriptor, assemble, parse_configuration)

__all__ = ["MODELS_DIR", "InterfaceBinding", "UsbModel", "load_model", "model_names"]

MODELS_DIR = Path(__file__).resolve().parent / "models"
NODE_KINDS = ("tty", "video", "video-metadata")
SPEEDS_MBPS = ("1.5", "12", "480", "5000", "10000", "20000")  # what sysfs "speed" holds
_DEVICE_FIELDS = ("bcdUSB", "bDeviceClass", "bDeviceSubClass", "bDeviceProtocol", "bMaxPacketSize0", "bcdDevice",
                  "iManufacturer", "iProduct", "iSerialNumber")


@dataclass(frozen=True)
class InterfaceBinding:
    """The kernel driver bound to one interface and the device nodes it creates there."""

    driver: str
    nodes: tuple[str, ...] = ()


@dataclass(frozen=True)
class UsbModel:
    """One kind of USB device as the host sees it."""

    name: str  # the file stem: "u2d2", "logitech_c310"
    title: str
    device: DeviceDescriptor
    configuration: bytes
    manufacturer: str | None  # the strings the kernel reads into sysfs; None: the device has none
    product: str | None
    has_serial_number: bool
    speed_mbps: str
    interfaces: dict[int, InterfaceBinding]
    hub_ports: int = 0
    source: str = ""

    @property
    def vid(self) -> int:
        return self.device.idVendor

    @property
    def pid(self) -> int:
        return self.device.idProduct

    def parsed_configuration(self) -> Configuration:
        return parse_configuration(self.configuration, source=f"{self.source} configuration")

    def descriptors(self) -> bytes:
        """What the kernel's sysfs ``descriptors`` file holds: the device descriptor, then the configuration."""
        return self.device.to_bytes() + self.configuration

    def function_string_index(self, interface: int) -> int:
        """The string uvcvideo appends to a node name: the iFunction of the interface association that
        holds ``interface``, else the interface's own iInterface (0: none)."""
        config = self.parsed_configuration()
        extras = [config.extra] + [a.extra + b"".join(e.extra for e in a.endpoints) for g in config.interfaces
                                   for a in g]
        for blob in extras:
            at = 0
            while at + 8 <= len(blob):
                length = blob[at]
                if length < 2:
                    break
                if blob[at + 1] == 11 and length >= 8 and blob[at + 2] <= interface < blob[at + 2] + blob[at + 3]:
                    return blob[at + 7]
                at += length
        for group in config.interfaces:
            if group[0].bInterfaceNumber == interface:
                return group[0].iInterface
        return 0


def _int(table: dict[str, Any], key: str, where: str, low: int, high: int) -> int:
    value = table.get(key)
    if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
        raise BadFile(where, f"{key} = {value!r}", f"an integer in {low}..{high}")
    return value


def _string(table: dict[str, Any], key: str, where: str) -> str | None:
    value = table.get(key)
    if value is not None and (not isinstance(value, str) or not value or len(value) > 126):
        raise BadFile(where, f"{key} = {value!r}", "a string of 1..126 characters (a USB string descriptor)")
    return value


def _parse(path: Path, data: dict[str, Any]) -> UsbModel:
    where = str(path)
    fields = data.get("device")
    if not isinstance(fields, dict):
        raise BadFile(where, "no [device] table", "the device descriptor's fields")
    camera = None
    if "camera" in data:
        try:
            camera = camera_model(str(data["camera"]))
        except ValueError as e:
            raise BadFile(where, str(e), "a key of tactile_rig.devices.camera_models.CAMERA_MODELS") from None
        restated = sorted({"vendor_id", "product_id", "manufacturer", "product", "has_serial_number"} & set(data)
                          | ({"bcdDevice"} & set(fields)))
        if restated:
            raise BadFile(where, f"camera = {camera.key!r} and {', '.join(restated)}",
                          "no ids, strings or bcdDevice beside camera = (they come from its camera model)")
        if camera.vendor_id is None or camera.product_id is None or camera.bcd_device is None:
            raise BadFile(where, f"camera model {camera.key!r} has no USB ids or bcdDevice", "a USB camera model")
        fields = {**fields, "bcdDevice": camera.bcd_device}
    values = {k: _int(fields, k, where, 0, 0xFFFF if k.startswith(("bcd", "id")) else 0xFF) for k in _DEVICE_FIELDS}
    if camera is not None:
        assert camera.vendor_id is not None and camera.product_id is not None
        vid, pid = camera.vendor_id, camera.product_id
        manufacturer, product, has_serial = camera.manufacturer, camera.product, camera.has_serial_number
    elif "adapter" in data:
        try:
            adapter = serial_adapter(str(data["adapter"]))
        except KeyError as e:
            raise BadFile(where, str(e.args[0]), "a kind of tactile_rig.devices.usb.SERIAL_ADAPTERS") from None
        vid, pid = adapter.vid, adapter.pid
        manufacturer, product, has_serial = adapter.manufacturer, adapter.product, adapter.has_serial_number
    else:
        vid = _int(data, "vendor_id", where, 0, 0xFFFF)
        pid = _int(data, "product_id", where, 0, 0xFFFF)
        manufacturer, product = _string(data, "manufacturer", where), _string(data, "product", where)
        has_serial = data.get("has_serial_number", False) is True
    device = DeviceDescriptor(bNumConfigurations=1, idVendor=vid, idProduct=pid, **values)
    text = data.get("descriptors", {}).get("configuration") if isinstance(data.get("descriptors"), dict) else None
    if not isinstance(text, str):
        raise BadFile(where, "no [descriptors] configuration", "the configuration descriptors as text")
    configuration = assemble(text, source=f"{where} [descriptors] configuration")
    try:
        config = parse_configuration(configuration, source=f"{where} configuration")
    except LinkCorrupt as e:
        raise BadFile(where, str(e), "a configuration a host can read") from None
    for index, text_value, name in ((device.iManufacturer, manufacturer, "manufacturer"),
                                    (device.iSerialNumber, has_serial or None, "serial number")):
        if bool(index) != bool(text_value):
            raise BadFile(where, f"string index {index} for the {name}, which the model "
                                 f"{'has' if text_value else 'does not have'}", "both or neither")
    if product is not None and not device.iProduct:
        raise BadFile(where, "a product string but iProduct 0", "iProduct naming the product string")
    speed = str(data.get("speed_mbps", ""))
    if speed not in SPEEDS_MBPS:
        raise BadFile(where, f"speed_mbps = {speed!r}", f"one of {', '.join(SPEEDS_MBPS)}")
    numbers = {alt.bInterfaceNumber for group in config.interfaces for alt in group}
    interfaces: dict[int, InterfaceBinding] = {}
    for key, spec in dict(data.get("interfaces", {})).items():
        if not key.isdigit() or int(key) not in numbers or not isinstance(spec, dict):
            raise BadFile(where, f"[interfaces.{key}]", f"one of the interfaces {sorted(numbers)} of the configuration")
        nodes = tuple(spec.get("nodes", ()))
        if any(n not in NODE_KINDS for n in nodes) or not isinstance(spec.get("driver"), str):
            raise BadFile(where, f"[interfaces.{key}] driver {spec.get('driver')!r} nodes {list(nodes)}",
                          f"a driver name and nodes among {', '.join(NODE_KINDS)}")
        interfaces[int(key)] = InterfaceBinding(spec["driver"], nodes)
    hub_ports = _int(data, "hub_ports", where, 0, 31) if "hub_ports" in data else 0
    if (hub_ports > 0) != (device.bDeviceClass == 9):
        raise BadFile(where, f"hub_ports = {hub_ports} for device class {device.bDeviceClass}",
                      "hub_ports on hubs (class 9) only")
    return UsbModel(path.stem, str(data.get("title", path.stem)), device, configuration, manufacturer, product,
                    has_serial, speed, interfaces, hub_ports, where)


@functools.lru_cache(maxsize=None)
def load_model(name_or_path: str) -> UsbModel:
    """The model named ``name_or_path`` (a file stem in :data:`MODELS_DIR`, or a path to a model file)."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        path = MODELS_DIR / f"{name_or_path}.toml"
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BadFile(path, "no such USB model file", f"one of {', '.join(model_names())} or a .toml path") from None
    except tomllib.TOMLDecodeError as e:
        raise BadFile(path, f"not TOML: {e}", "a USB model file") from None
    return _parse(path, data)


def model_names() -> list[str]:
    """The models shipped in :data:`MODELS_DIR`."""
    return sorted(p.stem for p in MODELS_DIR.glob("*.toml"))

"""Model files from a umockdev recording of a real bench (``umockdev-record``), so that a device a lab
owns can join the testbed with the descriptors it really reports.

:func:`read_recording` reads umockdev's text format (``P:`` device path, ``E:`` udev property,
``A:`` attribute, ``H:`` binary attribute, ``L:`` link, ``N:`` node, ``S:`` node link; one block per
device). :func:`models_from_recording` turns each USB device in it (``DEVTYPE=usb_device`` with a
``descriptors`` attribute) into the text of a model file: the device descriptor's fields, the
configuration one descriptor per line, the strings sysfs showed, the drivers bound to its
interfaces and the tty / video4linux nodes they made. Root hubs (vendor 1d6b) are left out.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from tactile_rig.core.errors import BadFile
from tactile_rig.mocks.usb.descriptors import parse_device_descriptor, split_configurations

__all__ = ["Recorded", "models_from_recording", "read_recording"]

_LINUX_FOUNDATION = 0x1D6B


@dataclass
class Recorded:
    """One device block of a recording."""

    path: str
    properties: dict[str, str] = field(default_factory=dict)
    attributes: dict[str, str] = field(default_factory=dict)
    binary: dict[str, bytes] = field(default_factory=dict)


def read_recording(text: str, *, source: str = "<recording>") -> list[Recorded]:
    """The device blocks of a umockdev recording, in file order."""
    out: list[Recorded] = []
    current: Recorded | None = None
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            current = None
            continue
        kind, sep, rest = line.partition(": ")
        if not sep or len(kind) != 1 or kind not in "PEAHLNS":
            raise BadFile(source, f"line {number} {line[:60]!r}",
                          "umockdev lines 'X: ...' with X in P, E, A, H, L, N, S")
        if kind == "P":
            current = Recorded(rest)
            out.append(current)
            continue
        if current is None:
            raise BadFile(source, f"line {number} before any 'P:' line",
                          "each device block to start with 'P: /devices/...'")
        if kind in "EAH":
            key, eq, value = rest.partition("=")
            if not eq:
                raise BadFile(source, f"line {number} {line[:60]!r} has no '='", "KEY=value")
            if kind == "E":
                current.properties[key] = value
            elif kind == "A":
                current.attributes[key] = value.replace("\\n", "\n").strip()
            else:
                try:
                    current.binary[key] = bytes.fromhex(value)
                except ValueError:
                    raise BadFile(source, f"line {number}: {key} is not hex", "an even number of hex digits") from None
    return out


def _descriptor_lines(config: bytes) -> list[str]:
    lines, at = [], 0
    while at < len(config):
        d = config[at:at + config[at]]
        lines.append(f"b:{d[1]:#04x}" + (f" x:{d[2:].hex()}" if len(d) > 2 else ""))
        at += len(d)
    return lines


def _toml_string(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'


def models_from_recording(text: str, *, source: str = "<recording>") -> dict[str, str]:
    """Model file texts (by a name made of the ids) for the USB devices of a umockdev recording."""
    blocks = read_recording(text, source=source)
    models: dict[str, str] = {}
    for dev in blocks:
        if dev.properties.get("DEVTYPE") != "usb_device" or "descriptors" not in dev.binary:
            continue
        d = parse_device_descriptor(dev.binary["descriptors"], source=f"{source} {dev.path}")
        if d.idVendor == _LINUX_FOUNDATION:
            continue
        configs = split_configurations(dev.binary["descriptors"], source=f"{source} {dev.path}")
        interfaces: dict[int, tuple[str, list[str]]] = {}
        for child in blocks:
            if child.path.startswith(dev.path + "/") and child.properties.get("DEVTYPE") == "usb_interface":
                number = int(child.attributes.get("bInterfaceNumber", "0"), 16)
                nodes = []
                for node in blocks:
                    if node.path.startswith(child.path + "/"):
                        subsystem = node.properties.get("SUBSYSTEM")
                        if subsystem == "tty":
                            nodes.append("tty")
                        elif subsystem == "video4linux":
                            nodes.append("video" if node.attributes.get("index", "0") == "0" else "video-metadata")
                if child.properties.get("DRIVER"):
                    order = ("tty", "video", "video-metadata")
                    interfaces[number] = (child.properties["DRIVER"], sorted(nodes, key=order.index))
        a = dev.attributes
        name = f"usb_{d.idVendor:04x}_{d.idProduct:04x}"
        lines = [f"# Recorded with umockdev-record: {dev.path} in {Path(source).name}. Cite where it comes from.",
                 f"title = {_toml_string(a.get('product') or name)}",
                 f"vendor_id = {d.idVendor:#06x}", f"product_id = {d.idProduct:#06x}"]
        lines += [f"{key} = {_toml_string(a[key])}" for key in ("manufacturer", "product") if a.get(key)]
        lines += [f"has_serial_number = {'true' if d.iSerialNumber else 'false'}",
                  f"speed_mbps = {_toml_string(a.get('speed', '480'))}"]
        if d.bDeviceClass == 9:
            lines.append(f"hub_ports = {int(a.get('maxchild', '4'))}")
        lines += ["", "[device]"]
        lines += [f"{k} = {getattr(d, k):#06x}" if k.startswith("bcd") else f"{k} = {getattr(d, k)}"
                  for k in ("bcdUSB", "bDeviceClass", "bDeviceSubClass", "bDeviceProtocol", "bMaxPacketSize0",
                            "bcdDevice", "iManufacturer", "iProduct", "iSerialNumber")]
        for number, (driver, nodes) in sorted(interfaces.items()):
            lines += ["", f"[interfaces.{number}]", f"driver = {_toml_string(driver)}"]
            if nodes:
                lines.append("nodes = [" + ", ".join(_toml_string(n) for n in nodes) + "]")
        lines += ["", "[descriptors]", 'configuration = """', *_descriptor_lines(configs[0]), '"""', ""]
        models[name] = "\n".join(lines)
    return models

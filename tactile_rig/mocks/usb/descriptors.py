"""USB descriptors: written as text in the model files, assembled into the bytes a device reports,
and read back the way libusb reads them.

The text form has one descriptor per line, every field after ``bLength`` (which is computed) as a
``width:value`` token, ``#`` starting a comment::

    b:2 w:32 b:1 b:1 b:0 b:0x80 b:45          # configuration: 32 bytes, 1 interface, bus powered, 90 mA
    b:4 b:0 b:0 b:2 b:0xff b:0xff b:0xff b:2  # interface 0: vendor specific, 2 endpoints

Widths: ``b`` 1 byte, ``w`` 2, ``t`` 3, ``d`` 4 (little endian, as USB sends them), ``g`` a GUID
written as ``lsusb`` of its time printed it (16 bytes in the printed order), ``x`` raw hex bytes.

:func:`parse_configuration` reads a configuration the way libusb's ``parse_configuration`` does:
interfaces are groups of consecutive alternate settings with the same ``bInterfaceNumber``, and
descriptors that are neither interface nor endpoint are kept as the ``extra`` bytes of what precedes
them (the configuration, an alternate setting, an endpoint). Malformed bytes raise
:class:`~tactile_rig.core.errors.LinkCorrupt` naming the offset, the value and what was expected.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from tactile_rig.core.errors import BadFile, LinkCorrupt

__all__ = ["AltSetting", "Configuration", "DeviceDescriptor", "Endpoint", "assemble", "device_descriptor",
           "parse_configuration", "parse_device_descriptor", "split_configurations"]

DT_DEVICE, DT_CONFIG, DT_STRING, DT_INTERFACE, DT_ENDPOINT = 1, 2, 3, 4, 5
DEVICE_SIZE, CONFIG_SIZE, INTERFACE_SIZE, ENDPOINT_SIZE, ENDPOINT_AUDIO_SIZE = 18, 9, 9, 7, 9
_PROPER = {DT_DEVICE, DT_CONFIG, DT_INTERFACE, DT_ENDPOINT}  # what ends a run of extra descriptors
_WIDTHS = {"b": 1, "w": 2, "t": 3, "d": 4}
_GUID = re.compile(r"^\{([0-9a-fA-F]{8})-([0-9a-fA-F]{4})-([0-9a-fA-F]{4})-([0-9a-fA-F]{4})-([0-9a-fA-F]{12})\}$")


def _token_bytes(token: str, where: str) -> bytes:
    width, sep, value = token.partition(":")
    if not sep or not value:
        raise BadFile(where, f"token {token!r} is not width:value", "b:, w:, t:, d:, g: or x: followed by a value")
    if width in _WIDTHS:
        try:
            number = int(value, 0)
        except ValueError:
            raise BadFile(where, f"token {token!r} has no integer value", "decimal or 0x hex") from None
        size = _WIDTHS[width]
        if not 0 <= number < 1 << (8 * size):
            raise BadFile(where, f"token {token!r} does not fit in {size} byte(s)", f"0..{(1 << (8 * size)) - 1}")
        return number.to_bytes(size, "little")
    if width == "g":
        match = _GUID.match(value)
        if not match:
            raise BadFile(where, f"token {token!r} is not a GUID", "{xxxxxxxx-xxxx-xxxx-xxxx-xxxxxxxxxxxx}")
        return bytes.fromhex("".join(match.groups()))
    if width == "x":
        try:
            return bytes.fromhex(value)
        except ValueError:
            raise BadFile(where, f"token {token!r} is not hex bytes", "an even number of hex digits") from None
    raise BadFile(where, f"token {token!r} has an unknown width {width!r}", "b, w, t, d, g or x")


def assemble(text: str, *, source: str = "<descriptors>") -> bytes:
    """The bytes of the descriptors written in ``text`` (one per line), each with its ``bLength`` first."""
    out = bytearray()
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"{source} line {number}"
        body = b"".join(_token_bytes(token, where) for token in line.split())
        if not 1 <= len(body) <= 254:
            raise BadFile(where, f"a descriptor of {len(body) + 1} bytes", "2..255 bytes (bLength is one byte)")
        out += bytes([len(body) + 1]) + body
    return bytes(out)


@dataclass(frozen=True)
class DeviceDescriptor:
    """The 18-byte device descriptor, field for field (USB 2.0 table 9-8)."""

    bcdUSB: int
    bDeviceClass: int
    bDeviceSubClass: int
    bDeviceProtocol: int
    bMaxPacketSize0: int
    idVendor: int
    idProduct: int
    bcdDevice: int
    iManufacturer: int
    iProduct: int
    iSerialNumber: int
    bNumConfigurations: int
    bLength: int = DEVICE_SIZE
    bDescriptorType: int = DT_DEVICE

    def to_bytes(self) -> bytes:
        return (bytes([DEVICE_SIZE, DT_DEVICE]) + self.bcdUSB.to_bytes(2, "little")
                + bytes([self.bDeviceClass, self.bDeviceSubClass, self.bDeviceProtocol, self.bMaxPacketSize0])
                + self.idVendor.to_bytes(2, "little") + self.idProduct.to_bytes(2, "little")
                + self.bcdDevice.to_bytes(2, "little")
                + bytes([self.iManufacturer, self.iProduct, self.iSerialNumber, self.bNumConfigurations]))


def device_descriptor(**fields: int) -> bytes:
    """The device descriptor bytes of ``fields`` (every :class:`DeviceDescriptor` field but the first two)."""
    return DeviceDescriptor(**fields).to_bytes()


def _u16(data: bytes, at: int) -> int:
    return data[at] | data[at + 1] << 8


def parse_device_descriptor(blob: bytes, *, source: str = "descriptors") -> DeviceDescriptor:
    """The device descriptor at the start of ``blob`` (a sysfs ``descriptors`` file)."""
    if len(blob) < DEVICE_SIZE:
        raise LinkCorrupt(f"{source}: {len(blob)} bytes, expected at least the {DEVICE_SIZE}-byte device descriptor")
    if blob[0] != DEVICE_SIZE or blob[1] != DT_DEVICE:
        raise LinkCorrupt(f"{source}: starts with bLength {blob[0]}, type {blob[1]}; expected {DEVICE_SIZE}, "
                          f"{DT_DEVICE} (a device descriptor)")
    return DeviceDescriptor(_u16(blob, 2), blob[4], blob[5], blob[6], blob[7], _u16(blob, 8), _u16(blob, 10),
                            _u16(blob, 12), blob[14], blob[15], blob[16], blob[17])


def split_configurations(blob: bytes, *, source: str = "descriptors") -> list[bytes]:
    """The configurations after the device descriptor in ``blob``, each cut at its ``wTotalLength``."""
    device = parse_device_descriptor(blob, source=source)
    out, at = [], DEVICE_SIZE
    for index in range(device.bNumConfigurations):
        if len(blob) - at < CONFIG_SIZE or blob[at + 1] != DT_CONFIG:
            raise LinkCorrupt(f"{source}: configuration {index} at byte {at} missing or not a configuration "
                              f"descriptor; the device descriptor announces {device.bNumConfigurations}")
        total = _u16(blob, at + 2)
        if total < CONFIG_SIZE or at + total > len(blob):
            raise LinkCorrupt(f"{source}: configuration {index} wTotalLength {total} at byte {at}; expected "
                              f"{CONFIG_SIZE}..{len(blob) - at} (the bytes left)")
        out.append(blob[at:at + total])
        at += total
    if at != len(blob):
        raise LinkCorrupt(f"{source}: {len(blob) - at} bytes after the last configuration, expected none")
    return out


@dataclass(frozen=True)
class Endpoint:
    bEndpointAddress: int
    bmAttributes: int
    wMaxPacketSize: int
    bInterval: int
    bRefresh: int = 0
    bSynchAddress: int = 0
    bLength: int = ENDPOINT_SIZE
    bDescriptorType: int = DT_ENDPOINT
    extra: bytes = b""


@dataclass(frozen=True)
class AltSetting:
    bInterfaceNumber: int
    bAlternateSetting: int
    bNumEndpoints: int
    bInterfaceClass: int
    bInterfaceSubClass: int
    bInterfaceProtocol: int
    iInterface: int
    endpoints: tuple[Endpoint, ...] = ()
    bLength: int = INTERFACE_SIZE
    bDescriptorType: int = DT_INTERFACE
    extra: bytes = b""


@dataclass(frozen=True)
class Configuration:
    wTotalLength: int
    bNumInterfaces: int
    bConfigurationValue: int
    iConfiguration: int
    bmAttributes: int
    bMaxPower: int
    interfaces: tuple[tuple[AltSetting, ...], ...] = ()  # by interface index, then alternate setting index
    bLength: int = CONFIG_SIZE
    bDescriptorType: int = DT_CONFIG
    extra: bytes = b""
    all_descriptors: tuple[bytes, ...] = field(default=(), repr=False)  # every descriptor in order


def _walk(data: bytes, source: str) -> list[tuple[int, bytes]]:
    """(offset, descriptor bytes) of every descriptor in ``data``; each bLength checked against what is left."""
    out, at = [], 0
    while at < len(data):
        if len(data) - at < 2:
            raise LinkCorrupt(f"{source}: 1 stray byte at offset {at}, expected a 2-byte descriptor header")
        length = data[at]
        if length < 2 or at + length > len(data):
            raise LinkCorrupt(f"{source}: bLength {length} at offset {at}; expected 2..{len(data) - at}")
        out.append((at, data[at:at + length]))
        at += length
    return out


def parse_configuration(data: bytes, *, source: str = "configuration") -> Configuration:
    """A configuration descriptor and everything under it, grouped as libusb groups them."""
    items = _walk(data, source)
    if not items or items[0][1][1] != DT_CONFIG or len(items[0][1]) < CONFIG_SIZE:
        raise LinkCorrupt(f"{source}: does not start with a {CONFIG_SIZE}-byte configuration descriptor")
    head = items[0][1]
    if _u16(head, 2) != len(data):
        raise LinkCorrupt(f"{source}: wTotalLength {_u16(head, 2)}, but the configuration holds {len(data)} bytes")
    config_extra = bytearray()
    groups: list[list[AltSetting]] = []
    alt_raw: bytes | None = None  # the interface descriptor of the alternate setting being filled
    endpoints: list[Endpoint] = []
    ep_extra = bytearray()
    alt_extra = bytearray()
    pending_ep: bytes | None = None

    def close_endpoint() -> None:
        nonlocal pending_ep, ep_extra
        if pending_ep is not None:
            raw = pending_ep
            audio = len(raw) >= ENDPOINT_AUDIO_SIZE
            endpoints.append(Endpoint(raw[2], raw[3], _u16(raw, 4), raw[6], raw[7] if audio else 0,
                                      raw[8] if audio else 0, len(raw), DT_ENDPOINT, bytes(ep_extra)))
        pending_ep, ep_extra = None, bytearray()

    def close_alt() -> None:
        nonlocal alt_raw, endpoints, alt_extra
        close_endpoint()
        if alt_raw is not None:
            raw = alt_raw
            if len(endpoints) != raw[4]:
                raise LinkCorrupt(f"{source}: interface {raw[2]} alternate {raw[3]} announces {raw[4]} "
                                  f"endpoint(s) and has {len(endpoints)}")
            alt = AltSetting(raw[2], raw[3], raw[4], raw[5], raw[6], raw[7], raw[8], tuple(endpoints), len(raw),
                             DT_INTERFACE, bytes(alt_extra))
            if groups and groups[-1][0].bInterfaceNumber == alt.bInterfaceNumber:
                groups[-1].append(alt)
            else:
                groups.append([alt])
        alt_raw, endpoints, alt_extra = None, [], bytearray()

    for at, raw in items[1:]:
        kind = raw[1]
        if kind in (DT_DEVICE, DT_CONFIG):
            raise LinkCorrupt(f"{source}: a descriptor of type {kind} at offset {at} inside a configuration")
        if kind == DT_INTERFACE:
            if len(raw) < INTERFACE_SIZE:
                raise LinkCorrupt(f"{source}: interface descriptor of {len(raw)} bytes at offset {at}, "
                                  f"expected {INTERFACE_SIZE}")
            close_alt()
            alt_raw = raw
        elif kind == DT_ENDPOINT:
            if alt_raw is None:
                raise LinkCorrupt(f"{source}: endpoint descriptor at offset {at} before any interface")
            if len(raw) < ENDPOINT_SIZE:
                raise LinkCorrupt(f"{source}: endpoint descriptor of {len(raw)} bytes at offset {at}, "
                                  f"expected {ENDPOINT_SIZE} or {ENDPOINT_AUDIO_SIZE}")
            close_endpoint()
            pending_ep = raw
        elif pending_ep is not None:
            ep_extra += raw
        elif alt_raw is not None:
            alt_extra += raw
        else:
            config_extra += raw
    close_alt()
    if len(groups) != head[4]:
        raise LinkCorrupt(f"{source}: bNumInterfaces {head[4]}, but {len(groups)} interface(s) follow")
    return Configuration(_u16(head, 2), head[4], head[5], head[6], head[7], head[8],
                         tuple(tuple(g) for g in groups), len(head), DT_CONFIG, bytes(config_extra),
                         tuple(raw for _, raw in items))

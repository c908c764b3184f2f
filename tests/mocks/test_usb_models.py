"""The USB device models against the published descriptors of the real devices (golden facts from the
dumps each model file cites), read back by our parser and, under umockdev, by lsusb and libusb."""

from __future__ import annotations

import re
import tomllib

import pytest

from tactile_rig.core.errors import BadFile
from tactile_rig.devices import usb as usb_ids
from tactile_rig.devices.camera_models import CAMERA_MODELS
from tactile_rig.drivers.discovery import match_kind
from tactile_rig.mocks.usb.descriptors import parse_device_descriptor, split_configurations
from tactile_rig.mocks.usb.models import MODELS_DIR, load_model, model_names
from tests import _umockdev

# lsusb -v of an Arduino Uno R3 as published ("USB Descriptors of Arduino UNO"), the numeric fields
# in print order: what lsusb prints back from our bytes must be these.
UNO_LSUSB = """
bLength 18 bDescriptorType 1 bcdUSB 1.10 bDeviceClass 2 bDeviceSubClass 0 bDeviceProtocol 0 bMaxPacketSize0 8
idVendor 0x2341 idProduct 0x0043 bcdDevice 0.01 iManufacturer 1 iProduct 2 iSerial 220 bNumConfigurations 1
bLength 9 bDescriptorType 2 wTotalLength 62 bNumInterfaces 2 bConfigurationValue 1 iConfiguration 0
bmAttributes 0xc0 MaxPower 100mA
bLength 9 bDescriptorType 4 bInterfaceNumber 0 bAlternateSetting 0 bNumEndpoints 1 bInterfaceClass 2
bInterfaceSubClass 2 bInterfaceProtocol 1 iInterface 0 bcdCDC 10.01 bmCapabilities 0x06 bMasterInterface 0
bSlaveInterface 1
bLength 7 bDescriptorType 5 bEndpointAddress 0x82 bmAttributes 3 wMaxPacketSize 0x0008 bInterval 255
bLength 9 bDescriptorType 4 bInterfaceNumber 1 bAlternateSetting 0 bNumEndpoints 2 bInterfaceClass 10
bInterfaceSubClass 0 bInterfaceProtocol 0 iInterface 0
bLength 7 bDescriptorType 5 bEndpointAddress 0x04 bmAttributes 2 wMaxPacketSize 0x0040 bInterval 1
bLength 7 bDescriptorType 5 bEndpointAddress 0x83 bmAttributes 2 wMaxPacketSize 0x0040 bInterval 1
"""

# The hub as umockdev-record captured it (martinpitt/umockdev, devices/input/usbkbd.umockdev, 1-1.5).
HUB_RECORDED = ("1201000209000240EF17051001000000000109022900010100E0010904000001090001000705810301000C"
                "0904000101090002000705810301000C")


def _frames(extra: bytes) -> list[tuple]:
    """(subtype, index, width, height, min bit rate, max bit rate, buffer, default interval, intervals) of
    the UVC frame descriptors (subtype 5 uncompressed, 7 MJPEG) in ``extra``."""
    out, at = [], 0
    while at < len(extra):
        n = extra[at]
        d = extra[at:at + n]
        if d[1] == 0x24 and d[2] in (5, 7):
            def le(i: int, size: int) -> int:
                return int.from_bytes(d[i:i + size], "little")
            intervals = [le(26 + 4 * k, 4) for k in range(d[25])]
            out.append((d[2], d[3], le(5, 2), le(7, 2), le(9, 4), le(13, 4), le(17, 4), le(21, 4), intervals))
        at += n
    return out


def test_every_model_loads_and_reads_back():
    assert {"u2d2", "arduino_uno_r3", "ch340", "logitech_c310", "gelsight_mini", "digit"} <= set(model_names())
    for name in model_names():
        m = load_model(name)
        (config,) = split_configurations(m.descriptors(), source=name)
        assert parse_device_descriptor(m.descriptors()) == m.device
        assert m.parsed_configuration().wTotalLength == len(config)


@pytest.mark.parametrize("name, adapter", [("u2d2", usb_ids.U2D2), ("arduino_uno_r3", usb_ids.ARDUINO_UNO_R3),
                                           ("ch340", usb_ids.CH340)])
def test_serial_adapters_take_ids_and_strings_from_their_one_home(name, adapter):
    raw = tomllib.loads((MODELS_DIR / f"{name}.toml").read_text())
    assert not {"vendor_id", "product_id", "manufacturer", "product"} & set(raw)
    m = load_model(name)
    assert (m.vid, m.pid, m.manufacturer, m.product) == (adapter.vid, adapter.pid, adapter.manufacturer,
                                                         adapter.product)
    assert match_kind(m.vid, m.pid, m.product) == adapter.kind


@pytest.mark.parametrize("name, key, kind", [("logitech_c310", "c310", "camera_c310"),
                                             ("gelsight_mini", "gelsight-mini", "camera_gelsight_mini"),
                                             ("digit", "digit", "camera_digit")])
def test_cameras_take_ids_strings_and_bcd_device_from_their_camera_model(name, key, kind):
    raw = tomllib.loads((MODELS_DIR / f"{name}.toml").read_text())
    assert raw["camera"] == key
    assert not {"vendor_id", "product_id", "manufacturer", "product", "has_serial_number"} & set(raw)
    assert "bcdDevice" not in raw["device"]
    cam, m = CAMERA_MODELS[key], load_model(name)
    assert (m.vid, m.pid, m.device.bcdDevice, m.manufacturer, m.product, m.has_serial_number) == (
        cam.vendor_id, cam.product_id, cam.bcd_device, cam.manufacturer, cam.product, cam.has_serial_number)
    assert match_kind(m.vid, m.pid, m.product) == kind == cam.usb_kind


@pytest.mark.parametrize("edit, problem", [
    (lambda t: t.replace('camera = "c310"', 'camera = "c920"'), "unknown camera model 'c920'"),
    (lambda t: t.replace('camera = "c310"', 'camera = "c310"\nvendor_id = 0x046d'), "vendor_id"),
    (lambda t: t.replace("bMaxPacketSize0 = 64", "bMaxPacketSize0 = 64\nbcdDevice = 0x0010"), "bcdDevice"),
])
def test_a_camera_file_restating_its_models_facts_is_refused(tmp_path, edit, problem):
    path = tmp_path / "cam.toml"
    path.write_text(edit((MODELS_DIR / "logitech_c310.toml").read_text()))
    load_model.cache_clear()
    with pytest.raises(BadFile, match=problem):
        load_model(str(path))


def test_u2d2_device_descriptor_is_the_published_one():
    d = load_model("u2d2").device  # lsusb -v of a U2D2 (OpenManipulator-X notes)
    assert (d.bcdUSB, d.bDeviceClass, d.bMaxPacketSize0, d.idVendor, d.idProduct, d.bcdDevice) == \
        (0x0200, 0, 64, 0x0403, 0x6014, 0x0900)
    assert (d.iManufacturer, d.iProduct, d.iSerialNumber) == (1, 2, 3)
    c = load_model("u2d2").parsed_configuration()
    assert c.wTotalLength == 0x20 and [a.bInterfaceClass for g in c.interfaces for a in g] == [0xFF]


def test_ch340_is_the_published_one():
    m = load_model("ch340")  # lsusb -v in memtest86plus pull request 387
    d, c = m.device, m.parsed_configuration()
    assert (d.bcdUSB, d.bDeviceClass, d.bMaxPacketSize0, d.bcdDevice, d.iManufacturer, d.iProduct, d.iSerialNumber) == \
        (0x0110, 0xFF, 8, 0x0262, 0, 2, 0)
    assert (c.wTotalLength, c.bmAttributes, c.bMaxPower * 2) == (0x27, 0x80, 98)
    ((alt,),) = c.interfaces
    assert (alt.bInterfaceClass, alt.bInterfaceSubClass, alt.bInterfaceProtocol, alt.bNumEndpoints) == (255, 1, 2, 3)
    assert m.product == "USB2.0-Serial" and not m.has_serial_number


def test_c310_configuration_holds_the_published_fields():
    m = load_model("logitech_c310")
    d, c = m.device, m.parsed_configuration()
    # github.com/AristoChen/usb-proxy/issues/30: the C310's device descriptor and configuration header
    assert (d.bDeviceClass, d.bDeviceSubClass, d.bDeviceProtocol, d.bcdDevice) == (0xEF, 2, 1, 0x0010)
    assert (d.iManufacturer, d.iProduct, d.iSerialNumber) == (0, 0, 2)
    assert (c.wTotalLength, c.bNumInterfaces, c.bmAttributes, c.bMaxPower * 2) == (0x09A5, 4, 0x80, 500)
    frames = _frames(c.interfaces[1][0].extra)
    yuyv = [f for f in frames if f[0] == 5]
    mjpeg = [f for f in frames if f[0] == 7]
    assert len(yuyv) == len(mjpeg) == 19
    assert yuyv[18][1:] == (19, 1280, 960, 98304000, 196608000, 2457600, 2000000, [1333333, 2000000])
    six = [333333, 400000, 500000, 666666, 1000000, 2000000]
    assert mjpeg[17][1:] == (18, 1280, 720, 73728000, 442368000, 1843200, 333333, six)
    assert mjpeg[18][1:] == (19, 1280, 960, 98304000, 589824000, 2457600, 333333, six)
    assert [(f[2], f[3]) for f in yuyv] == [(f[2], f[3]) for f in mjpeg]
    assert len(c.interfaces[1]) == 12  # alternate settings 0..11 of the streaming interface
    assert [a.endpoints[0].wMaxPacketSize for a in c.interfaces[1][1:]][-1] == 0x13FC  # 3x 1020 bytes


def test_hub_is_the_recorded_one():
    assert load_model("usb2_hub").descriptors().hex().upper() == HUB_RECORDED


@pytest.mark.parametrize("edit, problem", [
    (lambda t: t.replace("[device]", "[devic]"), "no \\[device\\] table"),
    (lambda t: t.replace('adapter = "u2d2"', 'adapter = "u3d3"'), "no USB serial adapter of kind 'u3d3'"),
    (lambda t: t.replace("b:2 w:32", "b:2 w:33"), "wTotalLength 33"),
    (lambda t: t.replace("iSerialNumber = 3", "iSerialNumber = 0"), "string index 0 for the serial number"),
    (lambda t: t.replace("[interfaces.0]", "[interfaces.4]"), "interfaces.4"),
    (lambda t: t.replace('nodes = ["tty"]', 'nodes = ["audio"]'), "nodes among tty"),
    (lambda t: t.replace('speed_mbps = "480"', 'speed_mbps = "481"'), "speed_mbps = '481'"),
    (lambda t: t.replace("bcdDevice = 0x0900", "bcdDevice = 0x10000"), "bcdDevice = 65536"),
    (lambda t: t.replace("speed_mbps = \"480\"", "speed_mbps = \"480\"\nhub_ports = 4"), "hub_ports on hubs"),
    (lambda t: t.replace("b:0x80 b:45", "b:0x80 b:450"), "does not fit in 1 byte"),
    (lambda t: t + "[[", "not TOML"),
])
def test_a_bad_model_file_is_a_clear_error(tmp_path, edit, problem):
    text = (MODELS_DIR / "u2d2.toml").read_text()
    path = tmp_path / "bad.toml"
    path.write_text(edit(text))
    load_model.cache_clear()
    with pytest.raises(BadFile, match=problem) as err:
        load_model(str(path))
    assert str(path) in str(err.value)


def test_an_unknown_model_names_the_known_ones():
    with pytest.raises(BadFile, match="u2d2"):
        load_model("nonesuch")


# -- judged by lsusb and libusb under umockdev ---------------------------------------------------
def _fields(text: str) -> list[tuple[str, str]]:
    """(name, first value token) of every numeric field line of lsusb -v, in print order."""
    out = []
    names = re.compile(r"^(b[A-Z]\w*|w[A-Z]\w*|dw\w+|bcd\w+|id\w+|i[A-Z]\w*|bm\w+|MaxPower)$")
    tokens = text.split()
    for i, tok in enumerate(tokens[:-1]):
        if names.match(tok):
            out.append((tok, tokens[i + 1]))
    return out


def _lsusb(ids: str) -> str:
    _umockdev.require_lsusb()
    return _umockdev.probe()["lsusb"][ids]


def test_lsusb_prints_back_the_published_uno_descriptors():
    printed = _fields(_lsusb("2341:0043"))
    expected = _fields(UNO_LSUSB)
    # lsusb 014 prints wTotalLength in hex; the 2017 dump printed 62
    printed = [(k, "62" if (k, v) == ("wTotalLength", "0x003e") else v) for k, v in printed]
    assert printed == expected


def test_lsusb_reads_the_c310_as_the_real_camera_reads():
    text = _lsusb("046d:081b")
    assert "wTotalLength       0x09a5" in text
    # the camera's processing unit is 11 bytes (UVC 1.0): lsusb warns on the real C310 and on ours
    assert text.count("Warning: Descriptor too short") == 1
    widths = [int(w) for w in re.findall(r"wWidth\s+(\d+)", text)]
    heights = [int(h) for h in re.findall(r"wHeight\s+(\d+)", text)]
    assert len(widths) == 38 and (widths[18], heights[18]) == (1280, 960)
    assert re.findall(r"tSamFreq\[ 0\]\s+(\d+)", text) == ["16000", "24000", "32000", "48000"]
    assert "iSerial                 2 5A3C6F10" in text  # the unit's serial, read as the kernel's sysfs holds it


def test_libusb_walks_every_configuration_as_our_parser_does():
    seen = {key.split("@")[0]: value for key, value in _umockdev.probe()["pyusb"].items()}
    for name in ("linux_root_hub", "usb2_hub", "u2d2", "arduino_uno_r3", "ch340", "logitech_c310", "gelsight_mini",
                 "digit"):
        m = load_model(name)
        c = m.parsed_configuration()
        ours = [[[[a.bInterfaceNumber, a.bAlternateSetting, a.bInterfaceClass, list(a.extra),
                   [[e.bEndpointAddress, e.wMaxPacketSize, list(e.extra)] for e in a.endpoints]]
                  for g in c.interfaces for a in g], list(c.extra), c.wTotalLength]]
        assert seen[f"{m.vid:04x}:{m.pid:04x}"]["configurations"] == ours, name
        assert seen[f"{m.vid:04x}:{m.pid:04x}"]["bcdDevice"] == m.device.bcdDevice


def test_libusb_and_the_fake_backend_see_the_same_devices():
    """pyusb on libusb (under umockdev) and pyusb on the fake backend, device by device."""
    import usb.core

    from tactile_rig.mocks.usb import FakeUsbBackend

    seen = _umockdev.probe()["pyusb"]
    fake = {}
    for d in usb.core.find(find_all=True, backend=FakeUsbBackend()):
        fake[f"{d.idVendor:04x}:{d.idProduct:04x}@{d.bus}-{d.address}"] = {
            "port_numbers": list(d.port_numbers or ()), "speed": d.speed, "bcdDevice": d.bcdDevice,
            "configurations": [[[[a.bInterfaceNumber, a.bAlternateSetting, a.bInterfaceClass, list(a.extra_descriptors),
                                  [[e.bEndpointAddress, e.wMaxPacketSize, list(e.extra_descriptors)] for e in a]]
                                 for a in c], list(c.extra_descriptors), c.wTotalLength] for c in d]}
    assert fake == seen

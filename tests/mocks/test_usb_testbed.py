"""The USB testbed: udev's names, the sysfs it writes, and the same devices presented two ways
(umockdev's testbed, read under umockdev; the plain tree for --mock) compared file by file."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

import tactile_rig.mocks.usb.udev as udev
from tactile_rig.mocks.usb.bench import BENCH, Bench, Plugged
from tactile_rig.mocks.usb.sysfs import build
from tactile_rig.mocks.usb.testbed import (
    escape_attribute,
    umockdev_problem,
    umockdev_text,
    write_tree,
)
from tests import _umockdev
from tests._usb_probe import walk_tree


# -- udev's names, against links users publish from real devices ----------------------------------
@pytest.mark.parametrize("vendor, model, serial, expected", [
    ("FTDI", "USB <-> Serial Converter", "FTBIN51S", "FTDI_USB__-__Serial_Converter_FTBIN51S"),  # a U2D2
    ("Arduino (www.arduino.cc)", "0043", "75833353035351F0A1B1", "Arduino__www.arduino.cc__0043_75833353035351F0A1B1"),
    ("Arducam Technology Co., Ltd.", "GelSight Mini R0B 28F5-K4RR", "28F5K4RR",
     "Arducam_Technology_Co.__Ltd._GelSight_Mini_R0B_28F5-K4RR_28F5K4RR"),
    ("1a86", "USB2.0-Serial", None, "1a86_USB2.0-Serial"),  # no serial number: no third part
    ("046d", "081b", "4B8254A0", "046d_081b_4B8254A0"),  # a C310: no strings but the serial
    ("FTDI", "FT232R USB UART", "A1,B2", "FTDI_FT232R_USB_UART"),  # a serial with a comma is ignored
])
def test_id_serial_is_what_udev_names_real_devices(vendor, model, serial, expected):
    id_serial, short = udev.id_serial(udev.usb_id_string(vendor), udev.usb_id_string(model), serial)
    assert id_serial == expected
    assert short == (serial if serial and "," not in serial else None)


def test_encoded_strings_and_path_tags():
    assert udev.encode_string("PI Engineering") == "PI\\x20Engineering"  # umockdev's recording of a real hub
    assert udev.id_path_tag("pci-0000:00:1a.0-usb-0:1.5.4.2:1.0") == "pci-0000_00_1a_0-usb-0_1_5_4_2_1_0"
    assert udev.id_path("0000:00:14.0", "1-1.4", "1.0") == "pci-0000:00:14.0-usb-0:1.4:1.0"


@given(st.text(max_size=80))
def test_usb_id_strings_hold_only_what_udev_allows(text):
    s = udev.usb_id_string(text)
    assert not any(c in s for c in " \t\n\r\v\f/,()<>")
    assert not s.startswith("_") or not text[:1].isspace()
    assert len(s) <= 63 * 2  # one character or a kept "\x" per character of the 63 read


@given(st.text(alphabet=st.characters(max_codepoint=0x7F), max_size=60))
def test_encoded_strings_decode_back(text):
    enc = udev.encode_string(text)
    assert bytes(enc, "ascii").decode("unicode_escape") == text


# -- what the testbed holds ---------------------------------------------------------------------
def _by_path(devices):
    return {d.path: d for d in devices}


def test_the_bench_in_sysfs():
    devices, nodes = build(BENCH)
    by = _by_path(devices)
    root = "/devices/pci0000:00/0000:00:14.0/usb1"
    u2d2 = by[f"{root}/1-1/1-1.1"]
    assert u2d2.attributes["idVendor"] == "0403\n" and u2d2.attributes["serial"] == "FT5MOCK1\n"
    assert u2d2.attributes["bNumInterfaces"] == " 1\n" and u2d2.attributes["version"] == " 2.00\n"
    assert u2d2.attributes["speed"] == "480\n" and u2d2.devnode == "bus/usb/001/003"
    c310 = by[f"{root}/1-1/1-1.4"]
    assert "product" not in c310.attributes and "manufacturer" not in c310.attributes  # it reports neither
    assert c310.properties["ID_USB_INTERFACES"] == ":0e0100:0e0200:010100:010200:"
    uno = by[f"{root}/1-1/1-1.2"]
    assert "product" not in uno.attributes and uno.attributes["manufacturer"] == "Arduino (www.arduino.cc)\n"
    tty = by[f"{root}/1-1/1-1.1/1-1.1:1.0/ttyUSB0/tty/ttyUSB0"]
    assert tty.links["device"] == "../../../ttyUSB0" and tty.attributes["dev"] == "188:0\n"
    acm = by[f"{root}/1-1/1-1.2/1-1.2:1.0/tty/ttyACM0"]
    assert acm.links["device"] == "../../../1-1.2:1.0" and acm.properties["ID_USB_DRIVER"] == "cdc_acm"
    video = {d.path.rsplit("/", 1)[1]: d for d in devices if d.subsystem == "video4linux"}
    assert [video[f"video{i}"].attributes["index"] for i in range(6)] == ["0\n", "1\n"] * 3
    assert video["video0"].attributes["name"] == "UVC Camera (046d:081b)\n"  # no product string
    assert video["video2"].attributes["name"] == "GelSight Mini R0B 2MOK-7C1A: Ge\n"  # as gsrobotics users see
    assert video["video4"].attributes["name"] == "DIGIT: DIGIT\n"
    assert {(n.node, n.index) for n in nodes if n.plugged.model == "logitech_c310"} == {("video0", 0), ("video1", 1)}


def test_two_adapters_without_serial_claim_one_link_and_the_last_keeps_it():
    bench = Bench((Plugged("ch340", (1,)), Plugged("ch340", (2,))))
    devices, nodes = build(bench)
    ttys = [d for d in devices if d.subsystem == "tty"]
    link = "serial/by-id/usb-1a86_USB2.0-Serial-if00-port0"
    assert all(link in d.properties["DEVLINKS"] for d in ttys)  # both claim it
    assert [link in d.devlinks for d in ttys] == [False, True]  # udev points it at the last one
    assert all(any("by-path" in x for x in d.devlinks) for d in ttys)  # by-path stays unique


@pytest.mark.parametrize("devices, problem", [
    ((Plugged("ch340", (1,)), Plugged("ch340", (1,))), "already taken"),
    ((Plugged("ch340", (1,)), Plugged("ch340", (1, 2))), "holds a device, not a hub"),
    ((Plugged("ch340", (13,)),), "ports 1..12"),
    ((Plugged("ch340", (1, 5)),), "ports 1..4"),
    ((Plugged("ch340", ()),), "empty"),
    ((Plugged("u2d2", (1,)),), "give the plugged device one"),
    ((Plugged("ch340", (1,), serial="X"),), "has no serial number"),
])
def test_a_bench_that_cannot_exist_is_refused(devices, problem):
    with pytest.raises(ValueError, match=problem):
        build(Bench(devices))


def _g_strcompress(text: str) -> str:
    """What GLib's g_strcompress (umockdev reading an ``A:`` value) makes of the escapes we write."""
    out, i = [], 0
    simple = {"n": "\n", "t": "\t", "r": "\r", "b": "\b", "f": "\f", "v": "\v", "\\": "\\", '"': '"'}
    while i < len(text):
        if text[i] != "\\":
            out.append(text[i])
            i += 1
            continue
        octal = ""
        while len(octal) < 3 and i + 1 + len(octal) < len(text) and text[i + 1 + len(octal)] in "01234567":
            octal += text[i + 1 + len(octal)]
        if octal:
            out.append(chr(int(octal, 8)))
            i += 1 + len(octal)
        else:
            out.append(simple.get(text[i + 1], text[i + 1]))
            i += 2
    return "".join(out)


@given(st.text(alphabet=st.characters(min_codepoint=1, max_codepoint=0x2FF), max_size=40))
def test_attribute_escapes_read_back_as_written(value):
    escaped = escape_attribute(value)
    assert "\n" not in escaped  # the format is one line per attribute
    assert _g_strcompress(escaped) == value


def test_umockdev_text_is_one_block_per_device():
    devices, _ = build(BENCH)
    text = umockdev_text(devices)
    blocks = text.strip("\n").split("\n\n")
    assert len(blocks) == len(devices)
    assert all(b.startswith("P: /devices/") for b in blocks)
    assert "A: busnum=1\\n" in text and "S: serial/by-id/usb-FTDI_USB__-__Serial_Converter_FT5MOCK1-if00-port0" in text
    assert "E: DEVNAME=/dev/ttyUSB0" in text and "H: descriptors=1201" in text


def test_the_plain_tree_is_the_sysfs_umockdev_presents(tmp_path):
    """--mock reads a plain tree; discovery under umockdev reads umockdev's testbed: they must hold the
    same /sys, file for file and link for link."""
    seen = _umockdev.probe()["sysfs"]
    sysfs, _ = write_tree(build(BENCH)[0], tmp_path / "tree")
    ours = walk_tree(sysfs)
    assert set(seen) == set(ours)
    assert {k: v for k, v in seen.items() if ours[k] != v} == {}


def test_umockdev_problem_names_the_packages(monkeypatch):
    monkeypatch.setattr("shutil.which", lambda name: None)
    problem = umockdev_problem()
    assert problem is not None and "umockdev-run" in problem and "umockdev libusb-1.0-0" in problem


def test_testbed_json_round_trip_through_the_cli(tmp_path, capsys):
    from tactile_rig.cli import main

    path = tmp_path / "b.umockdev"
    assert main(["devices", "--write-testbed", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"testbed": str(path)}
    assert path.read_text() == umockdev_text(build(BENCH)[0])

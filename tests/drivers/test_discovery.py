"""USB discovery on the fake pyusb backend and the plain sysfs + /dev tree (no umockdev needed)."""

from __future__ import annotations

import logging
import tempfile

import pytest
import usb.core
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_rig.drivers.discovery import (KNOWN_DEVICES, DeviceMatch, discover, match_kind, parse_decimal,
                                           parse_usb_id)
from tactile_rig.mocks.usb import BENCH, Bench, FakeUsbBackend, Plugged, build_fake_tree
from tactile_rig.mocks.usb.models import load_model
from tactile_rig.mocks.usb.sysfs import build


@pytest.fixture
def tree(tmp_path):
    return build_fake_tree(tmp_path)


def by_kind(found):
    return {d.kind: d for d in found}


def test_pyusb_filters_the_fake_backend_by_ids():
    devs = list(usb.core.find(find_all=True, idVendor=0x046D, backend=FakeUsbBackend()))
    assert [(d.idProduct, d.port_numbers, d.speed) for d in devs] == [(0x081B, (1, 4), usb.util.SPEED_HIGH)]
    (uno,) = usb.core.find(find_all=True, idVendor=0x2341, backend=FakeUsbBackend())
    assert uno.speed == usb.util.SPEED_FULL and uno.parent.port_numbers == (1,)


def test_discover_maps_the_bench_to_nodes_and_stable_links(tree):
    sysfs, dev = tree
    found = discover(backend=FakeUsbBackend(), sysfs_root=sysfs, dev_root=dev)
    assert [d.kind for d in found] == ["u2d2", "arduino", "ch340", "camera_c310", "camera_gelsight_mini",
                                       "camera_digit"]  # by bus and port; the hubs are not ours
    assert {d.enumerated_by for d in found} == {"fake"}
    k = by_kind(found)
    u2d2 = k["u2d2"]
    assert (u2d2.usb_id, u2d2.port_path, u2d2.serial, u2d2.product) == ("0403:6014", "1-1.1", "FT5MOCK1",
                                                                         "USB <-> Serial Converter")
    assert u2d2.tty == [str(dev / "ttyUSB0")]
    assert u2d2.by_id == [str(dev / "serial/by-id/usb-FTDI_USB__-__Serial_Converter_FT5MOCK1-if00-port0")]
    assert u2d2.by_path == [str(dev / "serial/by-path/pci-0000:00:14.0-usb-0:1.1:1.0-port0")]
    assert k["arduino"].tty == [str(dev / "ttyACM0")]
    assert k["arduino"].by_path == [str(dev / "serial/by-path/pci-0000:00:14.0-usb-0:1.2:1.0")]  # no -port for ACM
    ch = k["ch340"]
    assert ch.tty == [str(dev / "ttyUSB1")] and ch.serial is None
    assert ch.by_id == [str(dev / "serial/by-id/usb-1a86_USB2.0-Serial-if00-port0")]
    cam = k["camera_c310"]
    assert cam.video == [str(dev / "video0")]  # video1 is the metadata node
    assert cam.by_id == [str(dev / "v4l/by-id/usb-046d_081b_5A3C6F10-video-index0")]
    assert cam.by_path == [str(dev / "v4l/by-path/pci-0000:00:14.0-usb-0:1.4:1.0-video-index0")]
    assert (dev / "v4l/by-id/usb-046d_081b_5A3C6F10-video-index0").resolve() == (dev / "video0").resolve()
    assert k["camera_gelsight_mini"].video == [str(dev / "video2")]
    assert k["camera_digit"].by_id == [str(dev / "v4l/by-id/usb-Facebook_DIGIT_D20001-video-index0")]


def test_sysfs_fallback_finds_the_same(tree):
    sysfs, dev = tree
    a = discover(backend=FakeUsbBackend(), sysfs_root=sysfs, dev_root=dev)
    b = discover(sysfs_root=sysfs, dev_root=dev, use_pyusb=False)
    assert {d.enumerated_by for d in b} == {"sysfs"}
    for d in a + b:
        d.enumerated_by = ""
    assert [vars(x) for x in a] == [vars(x) for x in b]


def test_the_device_table_is_a_parameter(tree):
    sysfs, dev = tree
    table = KNOWN_DEVICES + (DeviceMatch("hub", 0x17EF, 0x1005),)
    found = by_kind(discover(backend=FakeUsbBackend(), sysfs_root=sysfs, dev_root=dev, table=table))
    assert found["hub"].port_path == "1-1" and found["hub"].tty == [] and found["hub"].video == []
    only = discover(backend=FakeUsbBackend(), sysfs_root=sysfs, dev_root=dev, table=(DeviceMatch("any_ftdi", 0x0403),))
    assert [d.kind for d in only] == ["any_ftdi"]


def test_match_kind_rules():
    assert match_kind(0x2341, 0x8036) == "arduino"  # any Arduino product
    assert match_kind(0x0403, 0x6001) is None  # an FT232R is not a U2D2
    assert match_kind(0x0C45, 0x636D, "GelSight Mini R0B 2BNN-4ZE7") == "camera_gelsight_mini"
    assert match_kind(0x0C45, 0x636D, "Arducam OV9281 USB Camera") is None  # Arducam's id, another camera
    assert match_kind(0x0C45, 0x636D, None) is None
    table = (DeviceMatch("vendor", 0x1234), DeviceMatch("ids", 0x1234, 1), DeviceMatch("named", 0x1234, 1, "X"))
    assert [match_kind(0x1234, p, n, table) for p, n in ((1, "Xy"), (1, "y"), (2, "X"))] == ["named", "ids", "vendor"]


def test_a_camera_with_the_minis_ids_but_another_name_is_not_a_mini(tmp_path):
    bench = Bench((Plugged("gelsight_mini", (1,), serial="SN0001", product="Arducam OV9281 USB Camera"),
                   Plugged("digit", (2,), serial="D1")))
    sysfs, dev = build_fake_tree(tmp_path, bench)
    found = discover(backend=FakeUsbBackend(bench), sysfs_root=sysfs, dev_root=dev)
    assert [d.kind for d in found] == ["camera_digit"]


def test_two_ch340_collide_on_by_id_and_keep_their_by_path(tmp_path):
    bench = Bench((Plugged("ch340", (1,)), Plugged("ch340", (2,))))
    sysfs, dev = build_fake_tree(tmp_path, bench)
    a, b = discover(backend=FakeUsbBackend(bench), sysfs_root=sysfs, dev_root=dev)
    assert (a.tty, b.tty) == ([str(dev / "ttyUSB0")], [str(dev / "ttyUSB1")])
    assert a.by_id == [] and b.by_id == [str(dev / "serial/by-id/usb-1a86_USB2.0-Serial-if00-port0")]  # last wins
    assert a.by_path != b.by_path and len(a.by_path) == len(b.by_path) == 1


def test_a_device_without_sysfs_entry_is_listed_without_nodes(tmp_path):
    sysfs, dev = build_fake_tree(tmp_path, Bench((Plugged("u2d2", (1,), serial="A"),)))
    bench = Bench((Plugged("u2d2", (1,), serial="A"), Plugged("ch340", (7,))))
    found = by_kind(discover(backend=FakeUsbBackend(bench), sysfs_root=sysfs, dev_root=dev))
    assert (found["ch340"].port_path, found["ch340"].tty, found["ch340"].serial) == ("1-7", [], None)


def test_empty_system(tmp_path):
    assert discover(backend=FakeUsbBackend(Bench(())), sysfs_root=tmp_path, dev_root=tmp_path) == []
    assert discover(sysfs_root=tmp_path / "none", dev_root=tmp_path, use_pyusb=False) == []


def test_corrupt_sysfs_attributes_are_skipped_with_a_warning(tree, caplog):
    sysfs, dev = tree
    (sysfs / "bus/usb/devices/1-1.1/idVendor").resolve().write_text("04z3\n")
    (sysfs / "class/video4linux/video0/index").resolve().write_text("zero\n")
    with caplog.at_level(logging.WARNING):
        found = by_kind(discover(sysfs_root=sysfs, dev_root=dev, use_pyusb=False))
    assert "u2d2" not in found and found["camera_c310"].video == []
    assert "'04z3'" in caplog.text and "'zero'" in caplog.text


@given(st.text(max_size=8))
def test_parse_usb_id_accepts_exactly_four_hex_digits(text):
    value = parse_usb_id(text)
    if len(text) == 4 and all(c in "0123456789abcdefABCDEF" for c in text):
        assert value == int(text, 16)
    else:
        assert value is None


@given(st.one_of(st.integers(0, 10 ** 7).map(str), st.text(max_size=8)))
def test_parse_decimal_accepts_small_decimals_only(text):
    value = parse_decimal(text)
    if value is not None:
        assert str(value) == text.lstrip("0") or (value == 0 and set(text) == {"0"})
        assert 0 <= value <= 1 << 16


@st.composite
def benches(draw):
    """Random benches: known and unknown models on distinct ports, units with and without serials."""
    models = ["u2d2", "arduino_uno_r3", "ch340", "logitech_c310", "gelsight_mini", "digit", "usb2_hub"]
    n = draw(st.integers(0, 6))
    ports = draw(st.lists(st.integers(1, 12), min_size=n, max_size=n, unique=True))
    devices = []
    for i, port in enumerate(ports):
        model = draw(st.sampled_from(models))
        serial = f"S{i}" if load_model(model).has_serial_number else None
        devices.append(Plugged(model, (port,), serial=serial,
                               product="GelSight Mini R0B X" if model == "gelsight_mini" else None))
    return Bench(tuple(devices))


@settings(max_examples=15)
@given(benches())
def test_discovery_finds_exactly_the_known_devices_and_their_nodes(bench):
    with tempfile.TemporaryDirectory() as tmp:
        sysfs, dev = build_fake_tree(tmp, bench)
        found = discover(backend=FakeUsbBackend(bench), sysfs_root=sysfs, dev_root=dev)
        _, nodes = build(bench)
        known = [p for p in sorted(bench.devices, key=lambda p: p.ports) if p.model != "usb2_hub"]
        assert [f.port_path for f in found] == [p.port_path(1) for p in known]
        for f, p in zip(found, known):
            mine = [n for n in nodes if n.plugged is p]
            assert f.tty == [str(dev / n.node) for n in mine if n.index is None]
            assert f.video == [str(dev / n.node) for n in mine if n.index == 0]  # capture nodes only
            assert len(f.by_path) == len(f.tty + f.video)  # by-path is unique per port
            assert f.serial == p.serial
            twins = [q for q in known if q.model == p.model and q.serial == p.serial]
            assert len(f.by_id) == (len(f.tty + f.video) if twins[-1] is p else 0)  # the last claimant wins


def test_the_bench_is_what_the_docs_list():
    assert [p.model for p in BENCH.devices] == ["u2d2", "arduino_uno_r3", "ch340", "logitech_c310", "gelsight_mini",
                                                 "digit"]

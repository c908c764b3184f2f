"""USB discovery on a fake pyusb backend and a fake sysfs + /dev tree."""

from __future__ import annotations

import json
import os
import tempfile

import pytest
import usb.core
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_rig.cli import main
from tactile_rig.drivers.discovery import KNOWN_DEVICES, discover, match_kind
from tactile_rig.mocks.usb import MOCK_DEVICES, FakeUsbBackend, FakeUsbDevice, build_fake_tree


@pytest.fixture
def tree(tmp_path):
    return build_fake_tree(tmp_path)


def by_kind(found):
    return {d.kind: d for d in found}


def test_pyusb_filters_the_fake_backend_by_ids():
    devs = list(usb.core.find(find_all=True, idVendor=0x046D, backend=FakeUsbBackend()))
    assert sorted(d.idProduct for d in devs) == [0x081B, 0xC52B]
    assert devs[0].port_numbers in ((1, 4), (2,))


def test_discover_maps_devices_to_nodes_and_stable_links(tree):
    sysfs, dev = tree
    found = by_kind(discover(backend=FakeUsbBackend(), sysfs_root=sysfs, dev_root=dev))
    assert set(found) == {"u2d2", "arduino", "ch340", "camera_c310"}  # the mouse dongle is not ours
    u2d2 = found["u2d2"]
    assert (u2d2.usb_id, u2d2.port_path, u2d2.serial) == ("0403:6014", "1-1.1", "FT5MOCK1")
    assert u2d2.tty == [str(dev / "ttyUSB0")]
    assert u2d2.by_id == [str(dev / "serial/by-id/usb-FTDI_USB_<->_Serial_Converter_FT5MOCK1-if00-port0")]
    assert found["arduino"].tty == [str(dev / "ttyACM0")]
    assert found["ch340"].tty == [str(dev / "ttyUSB1")] and found["ch340"].serial is None
    cam = found["camera_c310"]
    assert cam.video == [str(dev / "video0")]  # video1 is the metadata node
    assert len(cam.by_id) == 1 and cam.by_id[0].endswith("-video-index0")
    assert os.path.realpath(cam.by_id[0]) == str((dev / "video0").resolve())
    assert cam.by_path == [str(dev / "v4l/by-path/pci-0000:00:14.0-usb-0:1.4:1.0-video-index0")]
    assert found["ch340"].by_path == [str(dev / "serial/by-path/pci-0000:00:14.0-usb-0:1.3:1.0-port0")]


def test_sysfs_fallback_finds_the_same(tree):
    sysfs, dev = tree
    a = discover(backend=FakeUsbBackend(), sysfs_root=sysfs, dev_root=dev)
    b = discover(sysfs_root=sysfs, dev_root=dev, use_pyusb=False)
    assert [vars(x) for x in a] == [vars(x) for x in b]


def test_device_table_is_configurable(tree):
    sysfs, dev = tree
    table = dict(KNOWN_DEVICES)
    table[(0x046D, 0xC52B)] = "dongle"
    found = by_kind(discover(backend=FakeUsbBackend(), sysfs_root=sysfs, dev_root=dev, table=table))
    assert "dongle" in found and found["dongle"].tty == [] and found["dongle"].video == []


def test_arduino_matches_any_product_id():
    assert match_kind(0x2341, 0x8036) == "arduino"
    assert match_kind(0x0403, 0x6001) is None


def test_device_without_sysfs_entry_is_listed_without_nodes(tmp_path):
    extra = FakeUsbDevice(0x1A86, 0x7523, 3, (7,), "", "USB Serial", "QinHeng")
    sysfs, dev = build_fake_tree(tmp_path, MOCK_DEVICES[:1])
    found = discover(backend=FakeUsbBackend(MOCK_DEVICES[:1] + (extra,)), sysfs_root=sysfs, dev_root=dev)
    ch = by_kind(found)["ch340"]
    assert ch.port_path == "3-7" and ch.tty == [] and ch.serial is None


def test_empty_system(tmp_path):
    assert discover(backend=FakeUsbBackend(()), sysfs_root=tmp_path, dev_root=tmp_path) == []
    assert discover(sysfs_root=tmp_path / "none", dev_root=tmp_path, use_pyusb=False) == []


def test_cli_lists_mock_devices(capsys):
    assert main(["devices", "--mock", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    kinds = {d["kind"]: d for d in data["devices"]}
    assert set(kinds) == {"u2d2", "arduino", "ch340", "camera_c310"}
    assert kinds["camera_c310"]["video"] == ["/dev/video0"]
    assert kinds["u2d2"]["by_id"][0].startswith("/dev/serial/by-id/usb-FTDI")
    assert main(["devices", "--mock"]) == 0
    text = capsys.readouterr().out
    assert "camera_c310" in text and "/dev/v4l/by-id/" in text


def test_cli_on_an_empty_tree(tmp_path, capsys):
    assert main(["devices", "--sysfs-root", str(tmp_path), "--dev-root", str(tmp_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["devices"] == []


@st.composite
def usb_worlds(draw):
    """A random set of devices on distinct ports: known and unknown ids, ttys and cameras."""
    ids = [(0x0403, 0x6014), (0x2341, 0x0043), (0x2341, 0x8036), (0x1A86, 0x7523), (0x046D, 0x081B),
           (0x046D, 0xC52B), (0x0403, 0x6001)]
    n = draw(st.integers(0, 6))
    ports = draw(st.lists(st.tuples(st.integers(1, 3), st.integers(1, 9), st.integers(1, 4)), min_size=n, max_size=n,
                          unique=True))
    devices, n_usb, n_acm, n_video = [], 0, 0, 0
    for bus, p1, p2 in ports:
        vid, pid = draw(st.sampled_from(ids))
        serial = draw(st.sampled_from(["", "A1", "XYZ987"]))
        tty, video = None, ()
        if vid == 0x046D and pid == 0x081B:
            video, n_video = (f"video{n_video}", f"video{n_video + 1}"), n_video + 2
        elif vid == 0x2341:
            tty, n_acm = f"ttyACM{n_acm}", n_acm + 1
        elif vid != 0x046D:
            tty, n_usb = f"ttyUSB{n_usb}", n_usb + 1
        devices.append(FakeUsbDevice(vid, pid, bus, (p1, p2), serial, "Dev", "Maker", tty=tty, video=video))
    return tuple(devices)


@settings(max_examples=15)
@given(usb_worlds())
def test_discovery_finds_exactly_the_known_devices_and_their_nodes(devices):
    with tempfile.TemporaryDirectory() as tmp:
        sysfs, dev = build_fake_tree(tmp, devices)
        found = discover(backend=FakeUsbBackend(devices), sysfs_root=sysfs, dev_root=dev)
        expected = [d for d in devices if match_kind(d.vid, d.pid) is not None]
        assert [f.port_path for f in found] == [d.port_path for d in expected]
        for f, d in zip(found, expected):
            assert f.tty == ([str(dev / d.tty)] if d.tty else [])
            assert f.video == ([str(dev / d.video[0])] if d.video else [])
            assert len(f.by_path) == (1 if (d.tty or d.video) else 0)  # unique per port
            # udev names by-id links from the USB strings: devices with equal strings share one name
            kind = (d.tty or "")[:6] + ("video" if d.video else "")
            twins = [e for e in devices if (e.manufacturer, e.product, e.serial, (e.tty or "")[:6] + (
                "video" if e.video else "")) == (d.manufacturer, d.product, d.serial, kind)]
            if len(twins) == 1:
                assert len(f.by_id) == (1 if (d.tty or d.video) else 0)
            assert len(f.by_id) <= 1
            assert f.serial == (d.serial or None)

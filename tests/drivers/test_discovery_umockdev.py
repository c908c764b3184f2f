"""USB discovery through the real stack: ``tactile-rig devices`` in a child process under umockdev,
pyusb on libusb-1.0 reading the testbed's sysfs, against the bench's real descriptors."""

from __future__ import annotations

import json
import tempfile

from tactile_rig.drivers.discovery import discover
from tactile_rig.mocks.usb import BENCH, Bench, FakeUsbBackend, Plugged, build_fake_tree
from tests import _umockdev

TWO_CH340 = Bench((Plugged("ch340", (1,)), Plugged("ch340", (2,)), Plugged("u2d2", (3,), serial="FT00AB12")))
ARDUCAM_IDS = Bench((Plugged("gelsight_mini", (1,), serial="UC762", product="Arducam \\ OV9281\tUSB Camera"),
                     Plugged("gelsight_mini", (2,), serial="2BNN4ZE7", product="GelSight Mini R0B 2BNN-4ZE7")))
HUB_ONLY = Bench((Plugged("usb2_hub", (1,)),))


def devices_json(bench: Bench = BENCH) -> list[dict]:
    report = _umockdev.probe(bench)
    assert report["devices_rc"] == [0, 0], report["devices_json"]
    return report["devices_json"]["devices"]


def test_devices_finds_the_bench_through_libusb():
    found = devices_json()
    assert [d["kind"] for d in found] == ["u2d2", "arduino", "ch340", "camera_c310", "camera_gelsight_mini",
                                          "camera_digit"]
    assert {d["enumerated_by"] for d in found} == {"libusb1"}  # pyusb's libusb-1.0 backend, not the fake
    k = {d["kind"]: d for d in found}
    assert k["u2d2"]["tty"] == ["/dev/ttyUSB0"] and k["u2d2"]["serial"] == "FT5MOCK1"
    assert k["u2d2"]["by_id"] == ["/dev/serial/by-id/usb-FTDI_USB__-__Serial_Converter_FT5MOCK1-if00-port0"]
    assert k["u2d2"]["by_path"] == ["/dev/serial/by-path/pci-0000:00:14.0-usb-0:1.1:1.0-port0"]
    assert k["arduino"]["tty"] == ["/dev/ttyACM0"] and k["arduino"]["port_path"] == "1-1.2"
    assert k["arduino"]["by_id"] == ["/dev/serial/by-id/usb-Arduino__www.arduino.cc__0043_75833353035351F0A1B1-if00"]
    assert k["ch340"]["serial"] is None and k["ch340"]["tty"] == ["/dev/ttyUSB1"]
    assert k["ch340"]["by_id"] == ["/dev/serial/by-id/usb-1a86_USB2.0-Serial-if00-port0"]
    c310 = k["camera_c310"]
    assert c310["video"] == ["/dev/video0"] and c310["usb_id"] == "046d:081b"  # the metadata node video1 is left out
    assert c310["by_id"] == ["/dev/v4l/by-id/usb-046d_081b_5A3C6F10-video-index0"]
    assert c310["by_path"] == ["/dev/v4l/by-path/pci-0000:00:14.0-usb-0:1.4:1.0-video-index0"]
    assert k["camera_gelsight_mini"]["video"] == ["/dev/video2"] and k["camera_gelsight_mini"]["port_path"] == "1-2"
    assert k["camera_gelsight_mini"]["by_id"] == [
        "/dev/v4l/by-id/usb-Arducam_Technology_Co.__Ltd._GelSight_Mini_R0B_2MOK-7C1A_2MOK7C1A-video-index0"]
    assert k["camera_digit"]["video"] == ["/dev/video4"]
    assert k["camera_digit"]["by_id"] == ["/dev/v4l/by-id/usb-Facebook_DIGIT_D20001-video-index0"]
    # each camera named by its model, as bench.toml's model = takes it
    assert [d["model"] for d in found] == [None, None, None, "c310", "gelsight-mini", "digit"]


def test_the_real_stack_and_the_mock_agree():
    """What discovery finds under umockdev (libusb, the testbed's sysfs) is what --mock finds on the
    fake backend and the plain tree: any difference is a bug in one of them."""
    real = devices_json()
    with tempfile.TemporaryDirectory() as tmp:
        sysfs, dev = build_fake_tree(tmp)
        mock = [dict(vars(d), usb_id=d.usb_id, model=d.model) for d in discover(backend=FakeUsbBackend(), sysfs_root=sysfs,
                                                                 dev_root=dev)]
        mock = json.loads(json.dumps(mock).replace(str(dev), "/dev"))
    for d in real + mock:
        d.pop("enumerated_by")
    assert real == mock


def test_sysfs_alone_finds_the_same_under_umockdev():
    via_libusb, via_sysfs = _umockdev.probe(BENCH)["discover"]
    assert {d.pop("enumerated_by") for d in via_libusb} == {"libusb1"}
    assert {d.pop("enumerated_by") for d in via_sysfs} == {"sysfs"}
    assert via_libusb == via_sysfs


def test_two_ch340_under_udev_rules_collide_as_documented():
    first, second, u2d2 = devices_json(TWO_CH340)
    link = "/dev/serial/by-id/usb-1a86_USB2.0-Serial-if00-port0"
    assert first["by_id"] == [] and second["by_id"] == [link]  # the one plugged in last holds the shared name
    assert first["by_path"] == ["/dev/serial/by-path/pci-0000:00:14.0-usb-0:1:1.0-port0"]
    assert second["by_path"] == ["/dev/serial/by-path/pci-0000:00:14.0-usb-0:2:1.0-port0"]
    table = _umockdev.probe(TWO_CH340)["devices_table"]
    assert link not in table and table.count("/dev/serial/by-path/") == 2  # the table shows their by-path links
    assert "usb-FTDI_USB__-__Serial_Converter_FT00AB12-if00-port0" in table


def test_a_camera_with_arducams_id_that_is_not_a_mini_is_not_listed():
    (mini,) = devices_json(ARDUCAM_IDS)
    # the other camera's product string, backslash and tab included, reads back as the testbed wrote it
    product = _umockdev.probe(ARDUCAM_IDS)["sysfs"]["devices/pci0000:00/0000:00:14.0/usb1/1-1/product"]
    assert bytes.fromhex(product) == b"Arducam \\ OV9281\tUSB Camera\n"
    assert (mini["kind"], mini["serial"], mini["video"]) == ("camera_gelsight_mini", "2BNN4ZE7", ["/dev/video2"])


def test_hubs_alone_are_no_known_devices():
    report = _umockdev.probe(HUB_ONLY)
    assert report["devices_rc"] == [0, 0] and report["devices_table"].strip() == "no known USB devices found"
    assert report["devices_json"] == {"devices": []}

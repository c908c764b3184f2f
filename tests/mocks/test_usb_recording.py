"""Model files from a umockdev recording: read back, they describe the devices that were recorded."""

from __future__ import annotations

import json

import pytest

from tactile_rig.cli import main
from tactile_rig.core.errors import BadFile
from tactile_rig.drivers.discovery import discover
from tactile_rig.mocks.usb import BENCH, Bench, FakeUsbBackend, Plugged, build_fake_tree
from tactile_rig.mocks.usb.models import load_model
from tactile_rig.mocks.usb.recording import models_from_recording, read_recording
from tactile_rig.mocks.usb.sysfs import build
from tactile_rig.mocks.usb.testbed import umockdev_text


def test_models_from_a_recording_describe_the_recorded_devices(tmp_path):
    text = umockdev_text(build(BENCH)[0])
    models = models_from_recording(text, source="bench.umockdev")
    assert set(models) == {"usb_17ef_1005", "usb_0403_6014", "usb_2341_0043", "usb_1a86_7523", "usb_046d_081b",
                           "usb_0c45_636d", "usb_2833_0209"}  # the root hub is the kernel's, not a device
    for plugged in BENCH.devices:
        original = load_model(plugged.model)
        path = tmp_path / f"usb_{original.vid:04x}_{original.pid:04x}.toml"
        path.write_text(models[path.stem])
        recorded = load_model(str(path))
        assert recorded.descriptors() == original.descriptors()
        assert recorded.interfaces == original.interfaces
        assert (recorded.speed_mbps, recorded.has_serial_number, recorded.manufacturer) == \
            (original.speed_mbps, original.has_serial_number, original.manufacturer)


def test_a_recorded_model_joins_a_bench_and_is_found(tmp_path, capsys):
    recording = tmp_path / "lab.umockdev"
    recording.write_text(umockdev_text(build(BENCH)[0]))
    out = tmp_path / "models"
    out.mkdir()
    assert main(["devices", "--models-from-recording", str(recording), "--models-out", str(out), "--json"]) == 0
    written = json.loads(capsys.readouterr().out)["models"]
    assert str(out / "usb_0403_6014.toml") in written
    bench = Bench((Plugged(str(out / "usb_0403_6014.toml"), (1,), serial="FTLAB001"),))
    sysfs, dev = build_fake_tree(tmp_path / "tree", bench)
    (u2d2,) = discover(backend=FakeUsbBackend(bench), sysfs_root=sysfs, dev_root=dev)
    assert u2d2.kind == "u2d2" and u2d2.by_id == [str(dev / "serial/by-id/usb-FTDI_USB__-__Serial_Converter_FTLAB001"
                                                          "-if00-port0")]


@pytest.mark.parametrize("text, problem", [
    ("E: SUBSYSTEM=usb\n", "before any 'P:' line"),
    ("P: /devices/x\nQ: what\n", "umockdev lines"),
    ("P: /devices/x\nA: novalue\n", "has no '='"),
    ("P: /devices/x\nH: descriptors=zz\n", "not hex"),
])
def test_a_broken_recording_is_a_clear_error(text, problem):
    with pytest.raises(BadFile, match=problem):
        read_recording(text, source="lab.umockdev")


def test_a_recording_without_usb_devices_is_refused(tmp_path, capsys):
    path = tmp_path / "empty.umockdev"
    path.write_text("P: /devices/platform/serial8250/tty/ttyS0\nE: SUBSYSTEM=tty\n")
    assert main(["devices", "--models-from-recording", str(path), "--models-out", str(tmp_path)]) == 2
    assert "holds no USB device" in capsys.readouterr().err

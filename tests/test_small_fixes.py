"""The small bugs of issue 12: scale baud, Dynamixel bytes at DEBUG, a recording as a camera without
its fps, both calibration files attached, the camera topic, and CH340 by-id links."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

import mcap  # noqa: F401  (extras installed by .[all,test]: absent = fail, not skip)

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import ConnectErrors
from tactile_rig.rig.bench import connect_bench, load_bench, mock_bench_path
from tactile_rig.rig.recording import Recorder, read_recording

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_the_scale_runs_at_the_sketchs_57600_baud_everywhere(capsys):
    from tactile_rig.cli import main

    assert load_bench(mock_bench_path(), check_files=False).devices["scale"].baud == 57600
    rig_md = (DOCS / "rig.md").read_text()
    scale_table = rig_md.split("[scale]", 1)[1].split("[", 1)[0]
    assert "baud = 57600" in scale_table
    # the mock refuses another rate instead of adopting it ...
    assert main(["mock", "serve", "scale", "--baud", "115200"]) == 2
    assert "talks at 57600 baud only" in capsys.readouterr().err
    # ... and a bench that sets one sees what a real scale shows: no valid line at that rate
    b = load_bench(text='[scale]\nport = "rigsim://scale"\nbaud = 115200\n')
    with pytest.raises(ConnectErrors, match="at 115200 baud; check the sketch, the baud rate"):
        connect_bench(b, clock=VirtualClock())


def test_debug_logs_every_dynamixel_byte(caplog):
    from tactile_rig.drivers.dynamixel import DynamixelGripper

    with caplog.at_level(logging.DEBUG, logger="tactile_rig.transport"):
        with DynamixelGripper("rigsim://dynamixel?ids=1") as g:
            g.state()
    tx = [r.getMessage() for r in caplog.records if " TX " in r.getMessage()]
    rx = [r.getMessage() for r in caplog.records if " RX " in r.getMessage()]
    assert any(m.endswith("TX ff ff fd 00 01 03 00 01 19 4e") for m in tx)  # the ping, byte for byte
    assert rx and all("dynamixel@rigsim://dynamixel?ids=1" in m for m in tx + rx)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="tactile_rig.transport"):
        with DynamixelGripper("rigsim://dynamixel?ids=1") as g:
            g.state()
    assert not [r for r in caplog.records if " TX " in r.getMessage()]  # nothing wrapped, nothing logged


def test_a_recording_is_a_camera_without_its_fps(tmp_path):
    from tactile_rig.drivers.camera import FingertipCamera
    from tactile_rig.rig.replay import RecordedFrameSource

    clock = VirtualClock()
    path = tmp_path / "r.mcap"
    with Recorder(path, clock=clock) as rec:
        for i in range(12):
            rec.write_frame("camera_left", np.full((6, 8, 3), 10 * i, np.uint8), t_s=i * 0.0371)
    cam = FingertipCamera(RecordedFrameSource(path, clock=clock), clock=clock).open()
    try:
        assert cam.format[1:3] == (8, 6) and cam.format[3] == pytest.approx(1 / 0.0371)
        assert cam.read(1.0).image.shape == (6, 8, 3)
    finally:
        cam.close()


def test_camera_topics_and_both_calibration_files(tmp_path):
    cal_json, cal_npz = tmp_path / "gelsight.json", tmp_path / "gelsight.npz"
    cal_json.write_text(json.dumps({"format": "x"}))
    np.savez(cal_npz, a=np.arange(3))
    with Recorder(tmp_path / "r.mcap", clock=VirtualClock()) as rec:
        rec.write_frame("camera", np.zeros((4, 4, 3), np.uint8))
        rec.write_frame("camera_left", np.zeros((4, 4, 3), np.uint8), compress="jpeg")
        rec.add_calibration("gelsight", path=cal_npz)
    r = read_recording(tmp_path / "r.mcap")
    assert set(r.topics()) == {"/camera/image", "/camera_left/image/compressed"}
    assert {"calibration/gelsight/gelsight.json", "calibration/gelsight/gelsight.npz"} <= set(r.attachments)
    assert r.attachments["calibration/gelsight/gelsight.npz"] == cal_npz.read_bytes()


def test_devices_shows_the_ch340_by_path_link_in_its_table(capsys):
    from tactile_rig.cli import main

    assert main(["devices", "--mock"]) == 0
    out = capsys.readouterr().out
    ch340 = out.split("ch340", 1)[1].split("camera_c310", 1)[0]
    assert "/dev/serial/by-id/" not in ch340 and "/dev/serial/by-path/" in ch340  # no serial number: by-path
    assert "/dev/serial/by-id/usb-FTDI" in out  # adapters with a serial number keep their by-id link
    assert main(["devices", "--mock", "--json"]) == 0
    found = {d["kind"]: d for d in json.loads(capsys.readouterr().out)["devices"]}
    assert found["ch340"]["by_id"] == ["/dev/serial/by-id/usb-1a86_USB2.0-Serial-if00-port0"]  # the data stays complete

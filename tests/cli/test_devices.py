"""``tactile-rig devices``: the table a lab reads and the JSON a program reads."""

from __future__ import annotations

import json

from tactile_rig.cli import main


def test_devices_shows_the_ch340_by_path_link_in_its_table(capsys):
    assert main(["devices", "--mock"]) == 0
    out = capsys.readouterr().out
    ch340 = out.split("ch340", 1)[1].split("camera_c310", 1)[0]
    assert "/dev/serial/by-id/" not in ch340 and "/dev/serial/by-path/" in ch340  # no serial number: by-path
    assert "/dev/serial/by-id/usb-FTDI" in out  # adapters with a serial number keep their by-id link
    assert main(["devices", "--mock", "--json"]) == 0
    found = {d["kind"]: d for d in json.loads(capsys.readouterr().out)["devices"]}
    assert found["ch340"]["by_id"] == ["/dev/serial/by-id/usb-1a86_USB2.0-Serial-if00-port0"]  # the data stays complete

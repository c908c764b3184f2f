"""``tactile-rig devices``: the table, the JSON, the testbed file, on the mock bench."""

from __future__ import annotations

import json

from tactile_rig.cli import main


def test_mock_lists_the_bench_as_json(capsys):
    assert main(["devices", "--mock", "--json"]) == 0
    devices = json.loads(capsys.readouterr().out)["devices"]
    kinds = {d["kind"]: d for d in devices}
    assert list(kinds) == ["u2d2", "arduino", "ch340", "camera_c310", "camera_gelsight_mini", "camera_digit"]
    assert {d["enumerated_by"] for d in devices} == {"fake"}
    assert kinds["camera_c310"]["video"] == ["/dev/video0"] and kinds["camera_c310"]["usb_id"] == "046d:081b"
    assert kinds["u2d2"]["by_id"] == ["/dev/serial/by-id/usb-FTDI_USB__-__Serial_Converter_FT5MOCK1-if00-port0"]
    assert kinds["ch340"]["by_id"] == ["/dev/serial/by-id/usb-1a86_USB2.0-Serial-if00-port0"]  # the data is complete
    assert [d["model"] for d in devices] == [None, None, None, "c310", "gelsight-mini", "digit"]


def test_the_table_shows_by_id_for_serial_numbers_and_by_path_otherwise(capsys):
    assert main(["devices", "--mock"]) == 0
    rows = capsys.readouterr().out.splitlines()
    ch340 = rows[rows.index(next(r for r in rows if r.startswith("ch340"))) + 1].strip()
    assert ch340 == "/dev/serial/by-path/pci-0000:00:14.0-usb-0:1.3:1.0-port0"
    u2d2 = rows[rows.index(next(r for r in rows if r.startswith("u2d2"))) + 1].strip()
    assert u2d2 == "/dev/serial/by-id/usb-FTDI_USB__-__Serial_Converter_FT5MOCK1-if00-port0"
    assert any(r.startswith("camera_digit ") and "/dev/video4" in r and r.endswith("model=digit") for r in rows)
    assert any(r.startswith("camera_gelsight_mini ") and r.endswith("model=gelsight-mini") for r in rows)
    assert not any(r.startswith("u2d2 ") and "model=" in r for r in rows)


def test_an_empty_tree_lists_nothing(tmp_path, capsys):
    assert main(["devices", "--sysfs-only", "--sysfs-root", str(tmp_path), "--dev-root", str(tmp_path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"devices": []}
    assert main(["devices", "--sysfs-only", "--sysfs-root", str(tmp_path), "--dev-root", str(tmp_path)]) == 0
    assert capsys.readouterr().out.strip() == "no known USB devices found"


def test_write_testbed_into_a_missing_folder_is_one_line_exit_2(tmp_path, capsys):
    assert main(["devices", "--write-testbed", str(tmp_path / "no" / "bench.umockdev")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "bench.umockdev" in err and "Traceback" not in err

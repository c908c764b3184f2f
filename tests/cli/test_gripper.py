"""``tactile-rig gripper`` and ``tactile-rig mock serve dynamixel`` from the command line."""

from __future__ import annotations

import json

import pytest

from tactile_rig.cli import main
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.sim.world.fingers import Fingers
from tactile_rig.testing import serve_in_process, serve_in_subprocess


def test_gripper_state_go_calibrate_reboot(capsys, tmp_path) -> None:
    dev = make_bus(ids=[3], timing=False, plants={3: Fingers(object_width_m=0.05)})
    with serve_in_process(dev) as url:
        assert main(["gripper", "state", "--port", url, "--id", "3", "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert out["lifecycle"] == "connected" and out["state"]["opening_m"] == pytest.approx(0.05, abs=1e-3)
        assert main(["gripper", "go", "0.01", "--port", url, "--id", "3", "--effort", "0.2", "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert out["outcome"] == "stalled_on_object" and out["state"]["opening_m"] < 0.05
        cal = tmp_path / "cal.json"
        assert main(["gripper", "calibrate", "--port", url, "--id", "3", "--save", str(cal)]) == 0
        saved = json.loads(cal.read_text())
        # the 50 mm object is still held, so "closed" is where it stops the fingers (mid-range)
        assert 1500 < saved["closed_ticks"] < 2048 < saved["open_ticks"]
        dev.servo(3).inject_hardware_error(0x20)
        assert main(["gripper", "go", "0.02", "--port", url, "--id", "3"]) == 3  # device fault
        capsys.readouterr()
        assert main(["gripper", "reboot", "--port", url, "--id", "3", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["state"]["hardware_error"] == 0


def test_gripper_unknown_id_exits_2_with_one_line(capsys) -> None:
    dev = make_bus(ids=[1], timing=False)
    with serve_in_process(dev) as url:
        assert main(["gripper", "state", "--port", url, "--id", "4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "dynamixel[4]" in err[0] and "no status packet" in err[0]


@pytest.mark.pty
def test_mock_serve_prints_the_port_and_serves_protocol_1() -> None:
    import dynamixel_sdk as sdk

    with serve_in_subprocess("dynamixel", "--protocol", "1", "--id", "4") as info:
        assert (info["protocol"], info["ids"], info["model"], info["baud"]) == (1, [4], 310, 57600)
        port = sdk.PortHandler(info["port"])
        assert port.openPort() and port.setBaudRate(57600)
        assert sdk.PacketHandler(1.0).ping(port, 4) == (310, sdk.COMM_SUCCESS, 0)
        port.closePort()

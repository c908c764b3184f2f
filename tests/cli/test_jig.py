"""``tactile-rig jig status|home|move|unlock`` against mock URLs."""

from __future__ import annotations

import json

import pytest

from tactile_rig.cli import main


def test_jig_status_json_shows_the_alarm_on_boot(capsys) -> None:
    assert main(["jig", "status", "--port", "rigsim://jig", "--json"]) == 0
    st = json.loads(capsys.readouterr().out)
    assert st["state"] == "Alarm" and st["alarm_on_boot"] and st["mpos"] == [0.0, 0.0, 0.0]


def test_jig_home_then_move_and_unlock(capsys) -> None:
    assert main(["jig", "home", "--port", "rigsim://jig", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["state"] == "Idle"
    # Each command opens a fresh mock; unlocked without homing, GRBL's machine space starts where the
    # stage stands, so a centred work origin would be wrong: move on a jig without homing instead.
    assert main(["jig", "move", "--port", "rigsim://jig?homing=0", "--x", "3", "--theta", "-45", "--unlock",
                 "--json"]) == 0
    st = json.loads(capsys.readouterr().out)
    assert st["state"] == "Idle" and st["x_mm"] == pytest.approx(3.0) and st["theta_deg"] == pytest.approx(-45, abs=0.03)
    assert main(["jig", "unlock", "--port", "rigsim://jig"]) == 0
    assert capsys.readouterr().out.startswith("Idle")


def test_jig_move_errors_exit_nonzero(capsys) -> None:
    # Locked after boot: GRBL refuses the line (error:9), a rejected command like a Dynamixel's
    # status error, so exit 2 (bad input for the device's state), not 3 (a latched device fault).
    assert main(["jig", "move", "--port", "rigsim://jig", "--x", "3"]) == 2
    assert "error:9" in capsys.readouterr().err
    assert main(["jig", "move", "--port", "rigsim://jig"]) == 2
    assert "at least one of" in capsys.readouterr().err
    assert main(["jig", "move", "--port", "rigsim://jig?homing=0&axes=4&theta_axis=A", "--theta-axis", "A",
                 "--theta", "30", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mpos"] == pytest.approx([0, 0, 0, 30], abs=0.03)

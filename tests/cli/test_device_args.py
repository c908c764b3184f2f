"""The arguments every device command shares (``--port``, ``--bench``/``--mock``, ``--baud``,
``--json``), and the device they open: a bench's table with the bench's settings and limits, or a
bare port with the kind's defaults."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from tactile_rig.cli import build_parser, main
from tactile_rig.cli.device_args import device_target
from tactile_rig.rig.bench import GripperConfig, JigConfig, ScaleConfig

DEVICE_GROUPS = ("gripper", "scale", "jig")
SHARED = {"--port", "--bench", "--mock", "--baud", "--json"}


@pytest.fixture(autouse=True)
def _no_bench_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("TACTILE_RIG_BENCH", raising=False)


def _leaves(group: str) -> dict[str, argparse.ArgumentParser]:
    parser = build_parser(group)
    sub = parser._subparsers._group_actions[0].choices[group]  # type: ignore[union-attr]
    return dict(sub._subparsers._group_actions[0].choices)  # type: ignore[union-attr]


@pytest.mark.parametrize("group", DEVICE_GROUPS)
def test_every_device_command_takes_the_shared_arguments(group: str) -> None:
    leaves = _leaves(group)
    assert len(leaves) >= 3
    for name, leaf in leaves.items():
        options = {o for a in leaf._actions for o in a.option_strings}
        assert SHARED <= options, (group, name, SHARED - options)
        # --bench and --mock exclude each other
        with pytest.raises(SystemExit):
            build_parser(group).parse_args([group, name, "--mock", "--bench", "b.toml"])


def _bench(tmp_path: Path, **jig: str) -> Path:
    path = tmp_path / "bench.toml"
    lines = ["[jig]", 'port = "rigsim://jig?homing=0"', *(f"{k} = {v}" for k, v in jig.items()),
             "[scale]", 'port = "rigsim://scale?boot_s=0.1"', "rate_hz = 80.0",
             "[gripper]", 'port = "rigsim://dynamixel?ids=3"', "baud = 57600", "ids = [3]"]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_bench_device_keeps_its_limits_when_the_port_is_given_too(tmp_path: Path, capsys) -> None:
    bench = _bench(tmp_path, x_limits_mm="[-5.0, 5.0]")
    for extra in ([], ["--port", "rigsim://jig"]):
        assert main(["jig", "move", "--bench", str(bench), *extra, "--x", "6"]) == 2
        err = capsys.readouterr().err
        assert "x = 6 mm is outside [jig] x_limits_mm = [-5, 5] mm of" in err and str(bench) in err
    # the bare port has the kind's default travel: 6 mm is inside it (the move itself is refused later
    # by the locked firmware, a command the device refuses)
    assert main(["jig", "move", "--port", "rigsim://jig", "--x", "6"]) == 2
    assert "error:9" in capsys.readouterr().err


def test_the_mock_bench_opens_each_device(capsys) -> None:
    assert main(["scale", "read", "--mock", "--count", "2", "--json"]) == 0
    rows = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [r["seq"] for r in rows[:2]] == [0, 1] and rows[-1]["info"]["rate_sps"] == 80  # the bench's rate
    assert main(["gripper", "state", "--mock", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["lifecycle"] == "connected"
    assert main(["jig", "status", "--mock", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["state"] == "Alarm"


def test_a_bench_gripper_speaks_to_its_mock_with_the_benchs_id_and_baud(tmp_path: Path, capsys) -> None:
    # The bench says 57600 baud (its mock is built so, and the driver opens it so) and ID 3, as its URL.
    bench = _bench(tmp_path)
    assert main(["gripper", "state", "--bench", str(bench), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["lifecycle"] == "connected"
    # An ID the servo on that port does not have: no status packet, one line, exit 2.
    assert main(["gripper", "state", "--bench", str(bench), "--id", "4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no status packet" in err[0]


def test_device_target_layers_the_command_line_over_the_bench(tmp_path: Path) -> None:
    bench = _bench(tmp_path, x_limits_mm="[-5.0, 5.0]")
    ns = argparse.Namespace(port=None, baud=None, bench=str(bench), mock=False)
    jig = device_target(ns, JigConfig)
    assert jig.bench is not None and jig.config.x_limits_mm == (-5.0, 5.0) and jig.source == jig.bench.source
    ns.port, ns.baud = "/dev/ttyACM9", 9600
    jig = device_target(ns, JigConfig)
    assert (jig.config.port, jig.config.baud, jig.config.x_limits_mm) == ("/dev/ttyACM9", 9600, (-5.0, 5.0))
    grip = device_target(argparse.Namespace(port=None, baud=None, bench=str(bench), mock=False), GripperConfig,
                         ids=[7], protocol=None)
    assert grip.config.ids == [7] and grip.config.protocol == 2 and grip.config.baud == 57600
    bare = device_target(argparse.Namespace(port="rigsim://scale", baud=None, bench=None, mock=False), ScaleConfig)
    assert bare.bench is None and bare.config.baud == 57600 and "no bench" in bare.source


def test_a_device_command_without_port_or_bench_is_one_line(capsys) -> None:
    for group, action in (("gripper", "state"), ("scale", "read"), ("jig", "status")):
        assert main([group, action]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--port" in err[0] and "--bench" in err[0], err


@pytest.mark.parametrize("argv", [
    ["scale", "read", "--port", "rigsim://scale", "--baud", "0"],
    ["scale", "read", "--port", "rigsim://scale", "--boot-timeout", "0"],
    ["scale", "calibrate", "--port", "rigsim://scale", "-5"],
    ["gripper", "go", "0.02", "--port", "rigsim://dynamixel", "--effort", "1.5"],
    ["gripper", "state", "--port", "rigsim://dynamixel", "--id", "300"],
    ["jig", "home", "--port", "rigsim://jig", "--timeout", "0"],
    ["jig", "move", "--port", "rigsim://jig", "--x", "1", "--feed", "-3"],
])
def test_a_bad_device_argument_is_a_one_line_usage_error(argv: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    err = capsys.readouterr().err
    assert info.value.code == 2 and err.count("\n") == 1 and "allowed range" in err, err

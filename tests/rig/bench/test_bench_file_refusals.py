"""bench.toml refused with its line (or the environment variable) for every value that cannot be a
setting: non-finite limits and forces, duplicate IDs, empty ports, absurd frame sizes, seeds NumPy
refuses, nesting no bench needs, a folder or non-UTF-8 file in its place."""

from __future__ import annotations

from pathlib import Path

import pytest

from tactile_rig.cli import main
from tactile_rig.core.errors import BenchError
from tactile_rig.rig.bench import connect_bench, load_bench

CASES = [
    ('[jig]\nport = "rigsim://jig"\nx_limits_mm = [-inf, inf]\n', 3, "finite"),
    ('[scale]\nport = "rigsim://scale"\nmax_force_n = inf\n', 3, "finite"),
    ('[scale]\nport = "rigsim://scale"\nmax_force_n = nan\n', 3, "finite"),
    ('[gripper]\nport = "rigsim://dynamixel"\nids = [1, 1]\n', 3, "twice"),
    ('[scale]\nport = ""\n', 2, "empty"),
    ('[camera]\nport = "rigsim://camera"\nwidth = 100000000000\n', 3, "frame size"),
    ('[bench]\nseed = -5\n', 2, "seed"),
    ('[gripper]\nport = "rigsim://dynamixel"\nlatency_timer_ms = 300\n', 3, "latency timer"),
    ('[gripper]\nport = "rigsim://dynamixel"\nretries = -1\n', 3, "retries"),
]


@pytest.mark.parametrize("text,line,word", CASES)
def test_bad_values_are_refused_with_their_line(text: str, line: int, word: str) -> None:
    with pytest.raises(BenchError) as info:
        load_bench(text=text, env={})
    assert [ln for ln, _ in info.value.problems] == [line]
    assert word in str(info.value)


def test_an_environment_override_names_its_variable() -> None:
    text = '[scale]\nport = "rigsim://scale"\n'
    with pytest.raises(BenchError, match=r"max_force.*\(from \$TACTILE_RIG_SCALE__MAX_FORCE\)"):
        load_bench(text=text, env={"TACTILE_RIG_SCALE__MAX_FORCE": "5"})
    with pytest.raises(BenchError, match=r"max_force_n \(from \$TACTILE_RIG_SCALE__MAX_FORCE_N\).*finite"):
        load_bench(text=text, env={"TACTILE_RIG_SCALE__MAX_FORCE_N": "inf"})
    with pytest.raises(BenchError, match=r"TACTILE_RIG_SCALE__MAX_FORCE_N"):
        load_bench(text=text, env={"TACTILE_RIG_SCALE__MAX_FORCE_N": "[" * 5000})


def test_deep_nesting_is_refused_before_parsing() -> None:
    text = '[scale]\nport = "rigsim://scale"\nx = ' + "[" * 5000 + "]" * 5000 + "\n"
    with pytest.raises(BenchError, match="5000 levels deep"):
        load_bench(text=text, env={})


def test_a_folder_or_binary_file_is_one_line_exit_2(tmp_path: Path, capsys) -> None:
    (tmp_path / "b.toml").mkdir()
    (tmp_path / "bin.toml").write_bytes(b"\xff\xfe[scale]")
    for name, word in (("b.toml", "directory"), ("bin.toml", "UTF-8")):
        assert main(["run", "jig-accuracy", "--bench", str(tmp_path / name), "--no-record"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and word in err and name in err and "Traceback" not in err


def test_the_latency_timer_and_retries_reach_the_bus() -> None:
    bench = load_bench(text='[gripper]\nport = "rigsim://dynamixel"\nlatency_timer_ms = 4\nretries = 5\n', env={})
    cfg = bench.devices["gripper"]
    assert cfg.latency_timer_ms == 4.0 and cfg.retries == 5
    with connect_bench(bench) as rig:
        assert rig.gripper.bus.latency_timer_ms == 4.0 and rig.gripper.bus.retries == 5
    default = load_bench(text='[gripper]\nport = "rigsim://dynamixel"\n', env={}).devices["gripper"]
    assert default.latency_timer_ms == 16.0 and default.retries == 2


@pytest.mark.parametrize("text", ["", "# a bench to fill in\n", '[bench]\nname = "lab 3"\n'])
def test_a_bench_without_devices_is_refused_not_checked_as_passing(tmp_path: Path, text: str, capsys) -> None:
    # 'bench check' on a bench with no device must not pass with an empty table
    with pytest.raises(BenchError, match=r"declares no device.*\[gripper\].*\[camera_<name>\]"):
        load_bench(text=text, env={})
    (tmp_path / "bench.toml").write_text(text)
    assert main(["bench", "check", "--bench", str(tmp_path / "bench.toml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "declares no device" in err

"""``tactile-rig scene list|run``: JSON lines per episode, a summary last, refusals exit non-zero."""

from __future__ import annotations

import json

import pytest

from tactile_rig.cli import main
from tactile_rig.rig.scene_runner import list_scenes, run_episode


def _lines(capsys) -> list[dict]:
    return [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]


def test_scene_list_names_every_controller_scene_and_its_models(capsys) -> None:
    assert main(["scene", "list", "--json"]) == 0
    rows = {r["name"]: r for r in _lines(capsys)}
    kinds = {r["controller"] for r in rows.values()}
    assert {"collision_stop", "handover", "inhand_rotation", "lift_effort", "insertion", "following",
            "torque_rotation", "stick_assembly"} <= kinds
    # model only what a scene requires: no scale or fingers in a collision scene, no arm in a handover
    assert set(rows["collision_stop"]["models"].values()) == {"arm", "table"}
    assert "arm" not in rows["handover"]["models"].values()
    assert len(rows) == len(list_scenes())


def test_scene_run_prints_one_object_per_episode_and_a_summary_last(capsys) -> None:
    assert main(["scene", "run", "collision_stop", "--episodes", "3", "--seed", "7", "--json"]) == 0
    rows = _lines(capsys)
    assert len(rows) == 4 and rows[-1]["summary"] is True and rows[-1]["episodes"] == 3
    assert [r["seed"] for r in rows[:3]] == [7, 8, 9]
    for r in rows[:3]:
        assert r["ok"] is True and r["outcome"] == "success"
        assert 0 <= r["overtravel_mm"] <= r["allowed_overtravel_mm"]
        assert r["peak_force_n"] > 0
    assert rows[-1]["ok"] == 3 and rows[-1]["max_overtravel_mm"] == max(r["overtravel_mm"] for r in rows[:3])


def test_a_speed_above_the_collision_cap_is_refused_with_a_non_zero_exit(capsys) -> None:
    assert main(["scene", "run", "collision_stop", "--speed-mps", "0.05", "--json"]) == 2
    err = capsys.readouterr().err
    assert "above the collision-stop cap" in err


def test_a_fault_scene_reports_the_device_and_a_failed_property_exits_1(capsys, tmp_path) -> None:
    assert main(["scene", "run", "handover_servo_overload", "--json"]) == 0
    row = _lines(capsys)[0]
    assert row["outcome"] == "fault" and row["fault_device"] == "gripper"
    # the same scene expecting success: the episode fails its property and the exit code says so
    src = (list_scenes() and __import__("tactile_rig.sim.scenes", fromlist=["x"]).SCENE_DIR
           / "handover_servo_overload.toml").read_text()
    bad = tmp_path / "expect_success.toml"
    bad.write_text(src.replace('expect = "fault"\n', ""))
    assert main(["scene", "run", str(bad), "--json"]) == 1


def test_unknown_scenes_and_controller_kinds_are_clear_errors(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="built-in scenes"):
        run_episode("no_such_scene")
    p = tmp_path / "x.toml"
    p.write_text('[scene]\nname = "x"\n[controller]\nkind = "teleport"\n')
    with pytest.raises(ValueError, match="teleport"):
        run_episode(str(p))
    p.write_text('[scene]\nname = "x"\n[controller]\nkind = "collision_stop"\n[randomize.arm]\nx = 3\n')
    with pytest.raises(ValueError, match=r"\[low, high\]"):
        run_episode(str(p))

"""Versioned calibrations: name-vN files, a stable link to the newest, --force, and the typed error."""

from __future__ import annotations

import json
import os

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_rig.core.errors import CalibrationError, CalibrationExists
from tactile_rig.rig.calibration_sessions import read_calibration, write_calibration
from tactile_rig.rig.calibrations import (
    existing_versions,
    plan_version,
    publish,
    split_version,
    version_of,
)


def test_split_version_strips_known_suffixes():
    assert split_version("calib/scale.json") == (split_version("calib/scale")[0], None)
    base, n = split_version("calib/gelsight-v12.report.json")
    assert base.name == "gelsight" and n == 12
    assert split_version("calib/force_map/force_map-v3.npz")[1] == 3


def test_each_write_is_a_new_version_and_the_stable_name_follows_it(tmp_path):
    out = tmp_path / "scale.json"
    p1, _ = write_calibration(out, "scale", {"cal_factor_counts_per_g": 1.0}, {})
    p2, _ = write_calibration(out, "scale", {"cal_factor_counts_per_g": 2.0}, {})
    assert (p1.name, p2.name) == ("scale-v1.json", "scale-v2.json")
    assert read_calibration(p1, "scale")["cal_factor_counts_per_g"] == 1.0  # never overwritten
    assert out.is_symlink() and os.readlink(out) == "scale-v2.json"
    assert read_calibration(out, "scale")["cal_factor_counts_per_g"] == 2.0
    assert version_of(out) == 2 and existing_versions(tmp_path / "scale") == [1, 2]
    assert os.readlink(tmp_path / "scale.report.json") == "scale-v2.report.json"


def test_force_rewrites_the_newest_version(tmp_path):
    out = tmp_path / "gripper.json"
    write_calibration(out, "gripper", {"closed_ticks": 1}, {})
    write_calibration(out, "gripper", {"closed_ticks": 2}, {})
    p, _ = write_calibration(out, "gripper", {"closed_ticks": 3}, {}, force=True)
    assert p.name == "gripper-v2.json" and existing_versions(tmp_path / "gripper") == [1, 2]
    assert read_calibration(out, "gripper")["closed_ticks"] == 3
    assert read_calibration(tmp_path / "gripper-v1.json", "gripper")["closed_ticks"] == 1


def test_an_explicit_version_that_exists_needs_force(tmp_path):
    write_calibration(tmp_path / "scale.json", "scale", {"k": 1}, {})
    with pytest.raises(CalibrationExists, match=r"scale-v1.json exists.*--force") as e:
        write_calibration(tmp_path / "scale-v1.json", "scale", {"k": 9}, {})
    assert isinstance(e.value, CalibrationError) and isinstance(e.value, FileExistsError)
    assert read_calibration(tmp_path / "scale-v1.json", "scale")["k"] == 1
    write_calibration(tmp_path / "scale-v1.json", "scale", {"k": 9}, {}, force=True)
    assert read_calibration(tmp_path / "scale.json", "scale")["k"] == 9


def test_a_plain_file_at_the_stable_name_is_never_replaced_silently(tmp_path):
    legacy = tmp_path / "scale.json"
    legacy.write_text(json.dumps({"hand": "made"}))
    with pytest.raises(CalibrationExists, match="is a file, not a link.*--force"):
        write_calibration(legacy, "scale", {"k": 1}, {})
    assert json.loads(legacy.read_text()) == {"hand": "made"} and not (tmp_path / "scale-v1.json").exists()
    p, _ = write_calibration(legacy, "scale", {"k": 1}, {}, force=True)
    assert legacy.is_symlink() and p.name == "scale-v1.json"


def test_an_older_version_rewritten_keeps_the_link_on_the_newest(tmp_path):
    for k in range(3):
        write_calibration(tmp_path / "s.json", "scale", {"k": k}, {})
    write_calibration(tmp_path / "s-v1.json", "scale", {"k": 10}, {}, force=True)
    assert os.readlink(tmp_path / "s.json") == "s-v3.json"


def test_cli_error_for_an_existing_version_is_one_line_exit_2(tmp_path, capsys):
    from tactile_rig.cli import main

    write_calibration(tmp_path / "gripper.json", "gripper", {"closed_ticks": 1}, {})
    rc = main(["calibrate", "gripper", "--mock", "--out", str(tmp_path / "gripper-v1.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "gripper-v1.json exists" in err and "--force" in err and len(err.strip().splitlines()) == 1


@settings(max_examples=25, deadline=None)
@given(st.lists(st.booleans(), min_size=1, max_size=6))
def test_any_sequence_of_writes_keeps_every_version(tmp_path_factory, forces):
    """Whatever mix of plain and --force writes: versions are 1..N without gaps, the stable name
    reads the last write, and every version not forced over keeps what was written into it."""
    d = tmp_path_factory.mktemp("cal")
    kept: dict[int, int] = {}
    for i, force in enumerate(forces):
        ver = plan_version(d / "m.json", (".json",), force=force)
        ver.path(".json").write_text(str(i))
        publish(ver, (".json",))
        kept[ver.version] = i
    assert existing_versions(d / "m") == list(range(1, max(kept) + 1))
    assert (d / "m.json").read_text() == str(i)
    for v, i in kept.items():
        assert (d / f"m-v{v}.json").read_text() == str(i)

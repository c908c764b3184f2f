"""Parameter sweeps: stable keys, seeds from keys, resumable, failures reported."""

from __future__ import annotations

import concurrent.futures as cf
import json
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.rig.sweep import (
    canonical,
    grid,
    parse_axis,
    point_key,
    run_sweep,
    seed_from_key,
)

TARGET = "tactile_rig.rig.sweep:demo_point"

params_st = st.dictionaries(st.text("abcxyz_", min_size=1, max_size=6),
                            st.one_of(st.integers(-1000, 1000), st.floats(-1e3, 1e3, allow_nan=False),
                                      st.text(max_size=5), st.booleans()), max_size=5)


@given(params_st)
def test_key_ignores_order_and_int_float_spelling(params: dict) -> None:
    reordered = dict(reversed(list(params.items())))
    assert point_key(TARGET, params) == point_key(TARGET, reordered)
    as_floats = {k: float(v) if isinstance(v, int) and not isinstance(v, bool) else v for k, v in params.items()}
    assert point_key(TARGET, params) == point_key(TARGET, as_floats)
    assert 0 <= seed_from_key(point_key(TARGET, params)) < 2**32


def test_keys_differ_by_value_and_target() -> None:
    assert point_key(TARGET, {"x": 1}) != point_key(TARGET, {"x": 2})
    assert point_key(TARGET, {"x": 1}) != point_key("m:f", {"x": 1})
    assert point_key(TARGET, {"x": True}) != point_key(TARGET, {"x": 1})
    with pytest.raises(ValueError, match="not JSON-able"):
        canonical({"x": object()})
    with pytest.raises(ValueError):
        canonical({"x": float("nan")})


def test_axes_and_grid() -> None:
    assert parse_axis("theta_deg=-90:90:45") == ("theta_deg", [-90, -45, 0, 45, 90])
    assert parse_axis("x=0:0.3:0.1") == ("x", [0, 0.1, 0.2, 0.3])
    assert parse_axis("mode=a,b,3,2.5,true") == ("mode", ["a", "b", 3, 2.5, True])
    for bad in ("x", "=1", "x=", "x=1:0:1", "x=0:1:0"):
        with pytest.raises(ValueError):
            parse_axis(bad)
    g = grid({"a": [1, 2], "b": ["u", "v", "w"]}, {"c": 0})
    assert len(g) == 6 and {"a": 2, "b": "w", "c": 0} in g
    with pytest.raises(ValueError, match="no values"):
        grid({"a": []})


def test_sweep_runs_resumes_and_reports_failures(tmp_path: Path) -> None:
    points = grid({"x": [0.0, 1.0, 2.0, 3.0]}, {"noise": 0.5})
    with cf.ThreadPoolExecutor(2) as ex:
        s1 = run_sweep(TARGET, points + [points[0]], tmp_path, executor=ex)  # duplicate runs once
    assert s1.counts == {"ok": 4, "skipped": 0, "failed": 0}
    first = {p.key: p.result for p in s1.points}
    for p in s1.points:
        row = json.loads((tmp_path / p.key / "result.json").read_text())
        assert row["params"] == p.params and row["seed"] == seed_from_key(p.key) == p.result["seed"]
    # same parameters → same seed → same noisy result; a rerun skips every done point
    with cf.ThreadPoolExecutor(2) as ex:
        s2 = run_sweep(TARGET, points + [{"x": 5.0, "noise": 0.5}, {"x": 9.0, "fail": True}], tmp_path,
                       executor=ex)
    assert s2.counts == {"ok": 1, "skipped": 4, "failed": 1}
    assert {p.key: p.result for p in s2.points if p.status == "skipped"} == first
    failed = next(p for p in s2.points if p.status == "failed")
    assert "asked to fail" in failed.error
    assert not (tmp_path / failed.key / "result.json").exists()  # a failed point runs again next time
    assert (tmp_path / failed.key / "error.json").is_file()


def test_bad_target_fails_before_running(tmp_path: Path) -> None:
    for bad, msg in [("nomodule_xyz:f", "cannot import"), ("tactile_rig.rig.sweep:nope", "has no"),
                     ("justaname", "module:function")]:
        with pytest.raises(ValueError, match=msg):
            run_sweep(bad, [{"x": 1}], tmp_path)


def test_sweep_cli_on_processes(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from tactile_rig.cli import main

    argv = ["sweep", TARGET, "--param", "x=0:1:1", "--set", "noise=0", "--out", str(tmp_path), "--workers", "2",
            "--progress", "json", "--json"]
    assert main(argv) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert out["counts"] == {"ok": 2, "skipped": 0, "failed": 0}
    assert sorted(p["result"]["y"] for p in out["points"]) == [0.0, 1.0]
    progress = [json.loads(x) for x in cap.err.splitlines()]
    assert [p["done"] for p in progress] == [1, 2]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["counts"]["skipped"] == 2
    assert main(["sweep", TARGET, "--param", "x=1", "--set", "fail=true", "--out", str(tmp_path),
                 "--executor", "thread", "--progress", "off"]) == 1
    assert "FAILED" in capsys.readouterr().out


def test_scene_target_runs_scene_runner_episodes(tmp_path: Path) -> None:
    import tactile_rig.rig.scene_runner  # noqa: F401  (a broken import must fail, not skip)

    points = grid({"sensor.rate_hz": [8.0, 16.0]})
    with cf.ThreadPoolExecutor(1) as ex:
        s = run_sweep("scene:collision_stop", points, tmp_path, executor=ex)
    assert s.counts["ok"] == 2, [p.error for p in s.points]
    rates = sorted(p.result["sensing_rate_hz"] for p in s.points)
    assert rates == [8.0, 16.0]  # the swept parameter reached the scene
    assert all(p.result["seed"] == p.seed for p in s.points)  # the episode ran on the point's seed
    with pytest.raises(FileNotFoundError, match="built-in scene"):
        run_sweep("scene:no_such_scene", points, tmp_path)
    with cf.ThreadPoolExecutor(1) as ex:
        bad = run_sweep("scene:collision_stop", [{"rate_hz": 1.0}], tmp_path, executor=ex)
    assert bad.counts["failed"] == 1 and "<model>.<param>" in bad.points[0].error

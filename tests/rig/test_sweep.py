"""Parameter sweeps: stable keys, seeds from keys, resumable, failures reported."""

from __future__ import annotations

import concurrent.futures as cf
import json
import logging
from pathlib import Path

import distributed  # noqa: F401  (in the test install; it sets its logger's level on import)
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.rig.sweep import (
    canonical,
    dask_executor,
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
    with pytest.raises(ValueError, match="<model>.<param>"):  # refused before any point runs
        run_sweep("scene:collision_stop", [{"rate_hz": 1.0}], tmp_path)


# -- episodes per point, one table, one error for mistyped parameters, Dask ---------------------
def test_episodes_have_their_own_keys_and_seeds_and_episode_zero_is_the_point(tmp_path: Path) -> None:
    from tactile_rig.rig.sweep import episode_key

    params = {"x": 1.0, "noise": 1.0}
    keys = [episode_key(TARGET, params, i) for i in range(4)]
    assert keys[0] == point_key(TARGET, params) and len(set(keys)) == 4
    with cf.ThreadPoolExecutor(2) as ex:
        s3 = run_sweep(TARGET, [params], tmp_path, episodes=3, executor=ex)
    assert s3.counts == {"ok": 3, "skipped": 0, "failed": 0}
    assert sorted(p.episode for p in s3.points) == [0, 1, 2]
    assert {p.point for p in s3.points} == {keys[0]}
    assert len({p.result["y"] for p in s3.points}) == 3  # different seeds, different noise
    # more episodes later reuse the ones done
    with cf.ThreadPoolExecutor(2) as ex:
        s4 = run_sweep(TARGET, [params], tmp_path, episodes=4, executor=ex)
    assert s4.counts == {"ok": 1, "skipped": 3, "failed": 0}
    with pytest.raises(ValueError, match="episodes=0"):
        run_sweep(TARGET, [params], tmp_path, episodes=0)


class _ReversedExecutor(cf.Executor):
    """Finishes its ``n`` calls last-submitted first, once all are submitted, as a busy pool may."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.calls: list[tuple] = []
        self.futures: list[cf.Future] = []

    def submit(self, fn, /, *args, **kwargs) -> cf.Future:
        fut: cf.Future = cf.Future()
        self.calls.append((fn, args, kwargs))
        self.futures.append(fut)
        if len(self.futures) == self.n:
            for f, (g, a, k) in zip(reversed(self.futures), reversed(self.calls)):
                f.set_result(g(*a, **k))
        return fut


def test_the_summary_lists_episodes_in_the_order_of_the_points_however_they_finish(tmp_path: Path) -> None:
    points = [{"x": x, "noise": 0.0} for x in (3.0, 1.0, 2.0)]
    s = run_sweep(TARGET, points, tmp_path, episodes=2, executor=_ReversedExecutor(6))
    assert [(p.params["x"], p.episode) for p in s.points] == [(3.0, 0), (3.0, 1), (1.0, 0), (1.0, 1), (2.0, 0), (2.0, 1)]
    # resumed with a new point first: the done episodes are skipped, the new ones run
    resumed = run_sweep(TARGET, [{"x": 0.0, "noise": 0.0}, *points], tmp_path, episodes=2, executor=_ReversedExecutor(2))
    assert [(p.params["x"], p.status) for p in resumed.points] == [(0.0, "ok")] * 2 + [(x, "skipped") for x in (3.0, 3.0, 1.0, 1.0, 2.0, 2.0)]


def test_table_gives_success_rate_median_and_worst_per_point(tmp_path: Path) -> None:
    from tactile_rig.rig.sweep_report import format_table, sweep_table

    points = [{"x": 1.0, "noise": 0.0}, {"x": 2.0, "noise": 0.0}, {"x": 3.0, "noise": 0.0, "fail": True}]
    with cf.ThreadPoolExecutor(2) as ex:
        s = run_sweep(TARGET, points, tmp_path, episodes=2, executor=ex)
    rows = sweep_table(s)
    assert [r.params["x"] for r in rows] == [1.0, 2.0, 3.0]
    assert [r.success_rate for r in rows] == [1.0, 1.0, 0.0]
    assert rows[1].figures["y"].median == 4.0 and rows[1].figures["y"].worst == 4.0
    assert "seed" not in rows[0].figures and rows[2].figures == {}
    assert "asked to fail" in rows[2].errors[0]
    text = format_table(rows)
    assert text.splitlines()[0].split()[:4] == ["x", "fail", "episodes", "success"]
    assert "4 / 4" in text and "0%" in text
    with pytest.raises(ValueError, match="no such figure; they have: y"):
        sweep_table(s, figures=["z"])


def test_worst_is_the_max_unless_higher_is_better(tmp_path: Path) -> None:
    from tactile_rig.rig.sweep_report import sweep_table

    with cf.ThreadPoolExecutor(2) as ex:
        s = run_sweep(TARGET, [{"x": 0.0, "noise": 1.0}], tmp_path, episodes=5, executor=ex)
    ys = [p.result["y"] for p in s.points]
    assert sweep_table(s)[0].figures["y"].worst == max(ys)
    assert sweep_table(s, higher_is_better=["y"])[0].figures["y"].worst == min(ys)


def test_mistyped_parameters_are_one_error_before_anything_runs(tmp_path: Path) -> None:
    points = grid({"sensor.rat_hz": [8.0, 16.0], "tabel.stiffness_n_per_mm": [10.0],
                   "controller.force_esp_n": [0.3], "table.stifness_n_per_mm": [5.0]})
    with pytest.raises(ValueError) as err:
        run_sweep("scene:collision_stop", points, tmp_path / "s")
    msg = str(err.value)
    assert "4 unknown parameter(s), nothing ran" in msg
    for hint in ("did you mean 'rate_hz'", "did you mean 'table'", "did you mean 'force_eps_n'",
                 "did you mean 'stiffness_n_per_mm'"):
        assert hint in msg
    assert not (tmp_path / "s").exists()
    with pytest.raises(ValueError, match="it has no parameter 'nois'; did you mean 'noise'"):
        run_sweep(TARGET, [{"x": 1, "nois": 0.1}], tmp_path / "d")


def test_every_built_in_scene_accepts_its_own_parameters() -> None:
    import tomllib

    from tactile_rig.rig.scene_runner import list_scenes
    from tactile_rig.rig.sweep import check_params
    from tactile_rig.sim.scenes import resolve_scene_path

    for sc in list_scenes():
        raw = tomllib.loads(resolve_scene_path(sc["name"]).read_text(encoding="utf-8"))
        names = [f"{m}.{k}" for m, v in raw.get("models", {}).items() for k in v if k != "type"]
        names += [f"{sec}.{k}" for sec in ("controller", "sensor") for k in raw.get(sec, {})]
        names += [f"{t}.{k}" for t, v in raw.get("randomize", {}).items() for k in v]
        check_params(f"scene:{sc['name']}", [{n: 1 for n in names}])


def test_element_of_a_list_parameter_reaches_the_scene(tmp_path: Path) -> None:
    # the table 3 mm below the start: contact comes early, and the episode still succeeds
    with cf.ThreadPoolExecutor(1) as ex:
        s = run_sweep("scene:collision_stop", [{"table.point_mm.2": 7.0, "controller.speed_frac_of_cap": 1.0}],
                      tmp_path, executor=ex)
    assert s.counts["ok"] == 1, [p.error for p in s.points]
    assert s.points[0].result["ok"] is True


def test_cli_prints_one_table_and_plots(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from tactile_rig.cli import main

    png = tmp_path / "sweep.png"
    argv = ["sweep", TARGET, "--param", "x=0:2:1", "--set", "noise=0.1", "--episodes", "3", "--out",
            str(tmp_path / "o"), "--executor", "thread", "--progress", "off", "--plot", str(png)]
    assert main(argv) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:3] == ["x", "episodes", "success"] and len(out) >= 5
    assert out[4].startswith("3 points x 3 episodes: 9 ran")
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert main(["sweep", TARGET, "--param", "xx=1,2", "--out", str(tmp_path / "o2"), "--progress", "off"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "did you mean 'x'" in err
    assert not (tmp_path / "o2").exists()


def test_dask_local_cluster_runs_the_sweep_quietly(tmp_path: Path, capfd: pytest.CaptureFixture,
                                                   caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)  # as the CLI's --log-level INFO would: Dask's INFO chatter must not show
    before = logging.getLogger("distributed").level
    ex = dask_executor(workers=1, processes=False, threads_per_worker=2)
    try:
        s = run_sweep(TARGET, grid({"x": [0.0, 1.0, 2.0]}, {"noise": 0.0}), tmp_path, episodes=2, executor=ex)
    finally:
        ex.shutdown()
    assert s.counts == {"ok": 6, "skipped": 0, "failed": 0}
    assert sorted(p.result["y"] for p in s.points) == [0.0, 0.0, 1.0, 1.0, 4.0, 4.0]
    cap = capfd.readouterr()
    assert cap.out == "" and "distributed" not in cap.err  # no cluster chatter
    assert [r.getMessage() for r in caplog.records if r.name.startswith("distributed")] == []
    assert logging.getLogger("distributed").level == before  # restored on shutdown

"""Jig accuracy runs: the plan, the pose algebra, the statistics, the resumable store and the table."""

from __future__ import annotations

import json
import math
import statistics

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import tactile_rig.rig.jig_accuracy as jig_accuracy
from tactile_rig.sim.scenes import GELSIGHT_BALL_PRESS_SCENE
from tactile_rig.sim.world.objects import usb_connector_part, view_in_sensor
from tactile_rig.rig.jig_accuracy import (
    JigAccuracyConfig,
    JigPoint,
    Pose,
    PointResult,
    RunConflict,
    RunStore,
    format_table,
    plan_points,
    pose_from_touch_matrix,
    summarize,
    touch_matrix_from_pose,
    wrap_deg,
)

finite = st.floats(-1e3, 1e3, allow_nan=False)


# -- plan ----------------------------------------------------------------------------------------
def test_default_plan_is_the_papers_protocol():
    pts = plan_points(JigAccuracyConfig())
    rot = [p.pose.theta_deg for p in pts if p.sweep == "rotation"]
    tra = [p.pose.x_mm for p in pts if p.sweep == "translation"]
    assert rot == [float(a) for a in range(-90, 91, 10)]
    assert tra == [float(s) for s in range(-6, 7)]
    assert [p.index for p in pts] == list(range(len(pts)))
    assert all(p.pose.x_mm == 0 and p.pose.y_mm == 0 for p in pts if p.sweep == "rotation")
    assert all(p.pose.theta_deg == 0 and p.pose.y_mm == 0 for p in pts if p.sweep == "translation")


def test_plan_selects_one_sweep_and_axis():
    rot = plan_points(JigAccuracyConfig(sweep="rotation"))
    assert {p.sweep for p in rot} == {"rotation"} and len(rot) == 19
    tra = plan_points(JigAccuracyConfig(sweep="translation", shift_axis="y", shifts_mm=(-1, 1, 0.5)))
    assert [p.pose.y_mm for p in tra] == [-1.0, -0.5, 0.0, 0.5, 1.0]
    assert all(p.pose.x_mm == 0 for p in tra)


@pytest.mark.parametrize("kw, needle", [
    ({"sweep": "diagonal"}, "sweep"),
    ({"shift_axis": "z"}, "shift_axis"),
    ({"rotations_deg": (10, -10, 5)}, "rotations_deg"),
    ({"shifts_mm": (-1, 1, 0)}, "shifts_mm"),
    ({"shifts_mm": (0, 1, 1e-6)}, "1000 points"),
    ({"map_touches_mm": ()}, "map_touches_mm"),
    ({"map_min_confidence": 1.5}, "map_min_confidence"),
    ({"rotations_deg": (-200, 0, 10)}, "rotation sweep start"),
])
def test_bad_config_is_a_value_error_naming_the_setting(kw, needle):
    with pytest.raises(ValueError, match=needle):
        JigAccuracyConfig(**kw)


def test_config_round_trips_through_json_and_fingerprint_tracks_changes():
    cfg = JigAccuracyConfig(sweep="rotation", registration=(("detector", "orb"),), seed=3)
    back = JigAccuracyConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert back == cfg and back.fingerprint() == cfg.fingerprint()
    assert JigAccuracyConfig(seed=4).fingerprint() != JigAccuracyConfig(seed=3).fingerprint()
    with pytest.raises(ValueError, match="unknown jig accuracy setting"):
        JigAccuracyConfig.from_dict({"sweeps": "both"})


# -- pose algebra --------------------------------------------------------------------------------
@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_wrap_deg_range_and_equivalence(a):
    w = wrap_deg(a)
    assert -180.0 < w <= 180.0
    assert math.isclose(math.cos(math.radians(w)), math.cos(math.radians(a)), abs_tol=1e-6)


@given(finite, finite, st.floats(-180, 180, allow_nan=False))
def test_pose_matrix_round_trip(x, y, th):
    pose = Pose(x, y, theta_deg=th)
    back = pose_from_touch_matrix(touch_matrix_from_pose(pose))
    assert abs(wrap_deg(back.theta_deg - th)) < 1e-7
    assert math.hypot(back.x_mm - x, back.y_mm - y) < 1e-7 * (1 + abs(x) + abs(y))


def test_pose_from_matrix_rejects_garbage():
    with pytest.raises(ValueError, match="2x3"):
        pose_from_touch_matrix(np.eye(3))
    with pytest.raises(ValueError, match="finite"):
        pose_from_touch_matrix(np.full((2, 3), np.nan))


@pytest.mark.parametrize("pose", [Pose(2.0, -1.0, theta_deg=0.0), Pose(0.0, 0.0, theta_deg=30.0), Pose(1.5, 0.5, theta_deg=-20.0)])
def test_touch_matrix_matches_the_renderers_geometry(pose):
    """The matrix maps a sensor point of a touch at ``pose`` onto the same object point at home."""
    part = usb_connector_part(0.05)
    mm = 0.1
    shape = (61, 81)
    home = view_in_sensor(part, shape, mm)
    moved = view_in_sensor(part, shape, mm, pose.x_mm, pose.y_mm, pose.theta_deg)
    m = touch_matrix_from_pose(pose)
    rows, cols = shape
    rng = np.random.default_rng(0)
    errs = []
    for _ in range(300):
        r, c = int(rng.integers(10, rows - 10)), int(rng.integers(10, cols - 10))
        p_s = np.array([(c - (cols - 1) / 2) * mm, (r - (rows - 1) / 2) * mm])
        p_m = m[:, :2] @ p_s + m[:, 2]
        cc, rr = p_m[0] / mm + (cols - 1) / 2, p_m[1] / mm + (rows - 1) / 2
        if 1 <= cc < cols - 2 and 1 <= rr < rows - 2:
            errs.append(abs(moved[r, c] - home[int(round(rr)), int(round(cc))]))
    # Nearest-pixel lookup on a textured part: most points agree exactly, edges may differ.
    assert len(errs) > 50 and np.median(errs) < 1e-3


# -- statistics ----------------------------------------------------------------------------------
def _result(i, sweep, truth, est, conf=0.99):
    return PointResult.make(JigPoint(i, sweep, truth), truth, est, confidence=conf, method="test")


def test_summary_uses_each_sweeps_own_error_and_skips_refusals():
    res = [
        _result(0, "rotation", Pose(0, 0, theta_deg=-10), Pose(0.1, 0, theta_deg=-9.0)),
        _result(1, "rotation", Pose(0, 0, theta_deg=10), Pose(0, 0, theta_deg=13.0)),
        _result(2, "rotation", Pose(0, 0, theta_deg=20), None, conf=0.2),
        _result(3, "translation", Pose(-1, 0, theta_deg=0), Pose(-1.1, 0, theta_deg=5.0)),
        _result(4, "translation", Pose(1, 0, theta_deg=0), Pose(1.0, 0.3, theta_deg=0.0)),
    ]
    s = summarize(res)
    assert s["n_points"] == 5 and s["n_localized"] == 4 and s["n_refused"] == 1
    assert s["rotation_mae_deg"] == pytest.approx(2.0) and s["rotation_std_deg"] == pytest.approx(1.0)
    assert s["translation_mae_mm"] == pytest.approx(0.2) and s["translation_std_mm"] == pytest.approx(0.1)
    assert s["paper"]["rotation_mae_deg"] == 1.15


def test_rotation_error_wraps_across_180():
    r = _result(0, "rotation", Pose(0, 0, theta_deg=179.0), Pose(0, 0, theta_deg=-179.0))
    assert r.rotation_error_deg == pytest.approx(2.0)


def test_summary_of_one_sweep_leaves_the_other_empty():
    s = summarize([_result(0, "rotation", Pose(0, 0, theta_deg=5), Pose(0, 0, theta_deg=5.5))])
    assert s["translation_mae_mm"] is None and s["rotation_mae_deg"] == pytest.approx(0.5)
    assert summarize([])["rotation_mae_deg"] is None


@given(st.lists(st.tuples(st.floats(-90, 90), st.floats(-5, 5), st.booleans()), max_size=20))
def test_summary_is_the_mean_and_spread_of_each_sweeps_absolute_errors(rows):
    """Each sweep's MAE and std are the mean and population standard deviation of its points' absolute
    errors (computed here with ``statistics``), and the std stays inside the Bhatia-Davis bound that
    MAE and the largest error put on it: std^2 <= MAE (max - MAE)."""
    res = [_result(i, "rotation" if i % 2 else "translation", Pose(0, 0, theta_deg=a), Pose(e, 0, theta_deg=a + e) if ok else None)
           for i, (a, e, ok) in enumerate(rows)]
    s = summarize(res)
    # each row's estimate is off by e in x and e in theta: |e| is both of its errors
    errors = {sweep: [abs(e) for i, (_a, e, ok) in enumerate(rows) if ok and (i % 2) == (sweep == "rotation")]
              for sweep in ("rotation", "translation")}
    for sweep, unit in (("rotation", "deg"), ("translation", "mm")):
        mae, std, worst = s[f"{sweep}_mae_{unit}"], s[f"{sweep}_std_{unit}"], s[f"{sweep}_max_{unit}"]
        errs = errors[sweep]
        if not errs:
            assert mae is None and std is None and worst is None
            continue
        assert mae == pytest.approx(statistics.fmean(errs), abs=1e-9)
        assert std == pytest.approx(statistics.pstdev(errs), abs=1e-9)
        assert worst == pytest.approx(max(errs), abs=1e-9)
        assert 0.0 <= mae <= worst + 1e-12
        assert std ** 2 <= mae * (worst - mae) + 1e-9
    assert s["n_localized"] == sum(ok for *_, ok in rows) and s["n_refused"] == len(rows) - s["n_localized"]
    json.dumps(s, allow_nan=False)


# -- persistence ---------------------------------------------------------------------------------
def test_store_resumes_same_config_and_refuses_another(tmp_path):
    cfg = JigAccuracyConfig(sweep="rotation", rotations_deg=(-10, 10, 10))
    store = RunStore(tmp_path)
    assert store.begin(cfg, bench={"kind": "mock"}, resume=None, overwrite=False) == []
    r0 = _result(0, "rotation", Pose(0, 0, theta_deg=-10), Pose(0, 0, theta_deg=-10.2))
    store.append_point(r0)
    done = RunStore(tmp_path).begin(cfg, bench={"kind": "mock"}, resume=None, overwrite=False)
    assert [r.index for r in done] == [0] and done[0].estimate == r0.estimate
    with pytest.raises(RunConflict, match="another configuration"):
        RunStore(tmp_path).begin(JigAccuracyConfig(sweep="rotation"), bench={"kind": "mock"}, resume=None,
                                 overwrite=False)
    with pytest.raises(RunConflict, match="another configuration"):
        RunStore(tmp_path).begin(cfg, bench={"kind": "bench"}, resume=None, overwrite=False)
    with pytest.raises(RunConflict, match="--resume"):
        RunStore(tmp_path).begin(cfg, bench={"kind": "mock"}, resume=False, overwrite=False)
    assert RunStore(tmp_path).begin(cfg, bench={"kind": "mock"}, resume=None, overwrite=True) == []
    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["fingerprint"] == cfg.fingerprint() and meta["points_planned"] == 3


def test_resume_without_a_run_is_refused(tmp_path):
    with pytest.raises(RunConflict, match="no run to resume"):
        RunStore(tmp_path / "empty").begin(JigAccuracyConfig(), bench={"kind": "mock"}, resume=True, overwrite=False)


@given(st.binary(max_size=200))
def test_torn_or_garbage_tail_of_points_file_is_dropped(tmp_path_factory, tail):
    d = tmp_path_factory.mktemp("torn")
    store = RunStore(d)
    good = [_result(i, "rotation", Pose(0, 0, theta_deg=i), Pose(0, 0, theta_deg=i + 0.1)) for i in range(3)]
    for r in good:
        store.append_point(r)
    with open(store.points_path, "ab") as fh:
        fh.write(tail)
    back = store.read_points()
    assert [r.index for r in back][:3] == [0, 1, 2]
    # The file is left holding whole lines only, so the next append starts on a fresh line.
    raw = store.points_path.read_bytes()
    assert raw.endswith(b"\n")
    store.append_point(_result(9, "rotation", Pose(0, 0, theta_deg=9), None))
    assert store.read_points()[-1].index == 9


def test_point_json_round_trip():
    r = _result(4, "translation", Pose(2, 0, theta_deg=0), Pose(2.01, -0.02, theta_deg=0.1))
    back = PointResult.from_json(json.loads(json.dumps(r.to_json())))
    assert back.estimate == r.estimate and back.translation_error_mm == pytest.approx(r.translation_error_mm)
    refused = PointResult.from_json(json.loads(json.dumps(_result(5, "rotation", Pose(), None, 0.1).to_json())))
    assert refused.estimate is None and not refused.ok


def test_table_lists_every_point_and_the_papers_figures():
    res = [_result(0, "rotation", Pose(0, 0, theta_deg=-10), Pose(0, 0, theta_deg=-10.5)),
           _result(1, "translation", Pose(1, 0, theta_deg=0), None, conf=0.3)]
    text = format_table(res, summarize(res))
    assert "refused" in text and "1.15" in text and "0.14 mm" in text
    assert "-10.500" in text
    assert text.count("\n") >= 6


@pytest.mark.hw
def test_reduced_run_on_a_real_bench(request, tmp_path):
    """On hardware (``pytest --hw-bench bench.toml``): a short run localizes within the paper's bounds."""
    from tactile_rig.rig.bench import load_bench
    from tactile_rig.rig.jig_accuracy import execute_jig_accuracy

    bench = load_bench(request.config.getoption("--hw-bench"))
    cfg = JigAccuracyConfig(rotations_deg=(-20.0, 20.0, 20.0), shifts_mm=(-2.0, 2.0, 2.0))
    out = execute_jig_accuracy(cfg, tmp_path, bench=bench, report=False)
    s = out.summary
    assert s["complete"] and s["n_refused"] <= 1
    assert s["rotation_mae_deg"] < 2.0 and s["translation_mae_mm"] < 0.3


def test_the_old_press_scene_name_warns_and_names_the_ball_presses() -> None:
    with pytest.warns(DeprecationWarning, match=r"MOCK_PRESS_SCENE is tactile_rig\.sim\.scenes\.GELSIGHT_BALL_PRESS_SCENE"):
        assert jig_accuracy.MOCK_PRESS_SCENE == GELSIGHT_BALL_PRESS_SCENE
    with pytest.raises(AttributeError, match="no attribute 'NO_SUCH_SCENE'"):
        jig_accuracy.NO_SUCH_SCENE  # noqa: B018

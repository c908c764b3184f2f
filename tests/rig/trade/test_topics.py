"""The built-in trade topics measure what they say: the collision cap and overtravel from the world,
the scenes' path departure from the rendered reference."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tactile_rig.cli import main
from tactile_rig.rig import trade
from tactile_rig.rig.trade import collision, scenes


def test_collision_default_camera_gives_the_thesis_formula_cap_and_stays_within_a_millimetre():
    m = collision.run_setting(16.0, 0.0, 1.0, seeds=[0, 1, 2])
    assert m["ok"] == 3
    # skin compression and braking only lower the cap below the thesis's 1 mm x 16 Hz
    assert all(0.012 < c <= 0.016 for c in m["caps"])
    assert all(0.0 < o <= 1.0 for o in m["overtravel"])


def test_collision_table_marks_default_and_explains_it(monkeypatch):
    monkeypatch.setattr(collision, "EPISODES", {True: 2, False: 2})
    t = trade.measure("collision", quick=True, seed=0)
    assert len(t.rows) == len(collision.RATES_HZ) * len(collision.LATENCIES_S) * len(collision.ALLOWED_MM)
    d = t.rows[t.default_index]
    assert dict(d.setting) == collision.DEFAULT
    assert d.extra["formula_cap_mps"] == pytest.approx(0.016)
    for r in t.rows:  # the cap holds: measured overtravel within the allowance for every setting
        assert r.error <= r.setting["allowed_overtravel_mm"] and r.extra["over_allowance"] == 0
    assert t.default_on_front() or "camera" in t.default_note
    assert any("Thesis check" in n for n in t.notes)


def test_path_departure():
    t = np.linspace(0, 1, 11)
    xy = np.column_stack([t, 2 * t])
    assert scenes.path_departure_mm((t, xy), (t, xy)) == (0.0, 0.0)
    rms, worst = scenes.path_departure_mm((t, xy), (t, xy + [3.0, 4.0]))
    assert rms == pytest.approx(5.0) and worst == pytest.approx(5.0)
    # a path sampled at other times is interpolated; no overlap gives NaN
    t2 = np.linspace(0, 1, 5)
    assert scenes.path_departure_mm((t, xy), (t2, np.column_stack([t2, 2 * t2])))[0] == pytest.approx(0.0)
    assert math.isnan(scenes.path_departure_mm((t, xy), (t + 5, xy))[0])


def test_scenes_reference_is_the_rendered_sensor_and_the_model_departs(monkeypatch, capsys):
    monkeypatch.setattr(scenes, "RATES_HZ", (30.0,))
    monkeypatch.setattr(scenes, "DT_SCENES", {"collision_stop": "overtravel_mm"})
    monkeypatch.setattr(scenes, "DT_MS", (0.2, 1.0, 10.0))
    monkeypatch.setattr(scenes, "EPISODES", {True: 1, False: 1})
    assert main(["trade", "scenes", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["group_by"] == "scene"
    prox = {r["setting"]["sensor"]: r for r in out["rows"] if r["setting"]["scene"] == "following_proximity_rendered"}
    assert prox["rendered"]["is_default"] and prox["rendered"]["error"] == 0.0
    # the model sensor reports the true centroid, the real processor does not: the paths differ
    assert 0.0 < prox["model"]["error"] < 1.0
    assert prox["model"]["extra"]["same_verdict"] == 1.0
    arm = {r["setting"]["arm_dt_ms"]: r for r in out["rows"] if r["setting"]["scene"] == "collision_stop"}
    assert arm[0.2]["error"] == 0.0 and arm[1.0]["is_default"] and not arm[0.2]["is_default"]
    # a coarser arm step departs further from the finest one
    assert 0.0 < arm[1.0]["error"] < arm[10.0]["error"]
    assert all(r["speed"] > 0 for r in out["rows"])
    assert scenes.rendered_scenes() == ["following_proximity_rendered"]


def test_an_episode_without_poses_compares_as_nan_not_a_crash():
    from types import SimpleNamespace

    from tactile_rig.core.types import Trace

    tr = Trace()
    tr.append(0.0, confidence=0.5)  # an insertion that never localized: no pose read
    rep = SimpleNamespace(result=SimpleNamespace(trace=tr))
    t, xyz = scenes._path(rep)
    assert t.size == 0 and xyz.shape == (0, 3)
    ok = (np.linspace(0, 1, 3), np.zeros((3, 3)))
    assert all(math.isnan(v) for v in scenes.path_departure_mm(ok, (t, xyz)))

"""The trade table's Pareto front, default marking, text, JSON and plot."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.rig.trade import TradeRow, TradeTable, topic_module


def _table(points, default=0, tol=0.0):
    rows = [TradeRow({"k": i}, s, e, is_default=(i == default)) for i, (s, e) in enumerate(points)]
    return TradeTable("t", "frames_per_s", "error_mm", "unit test", rows, speed_tolerance=tol)


def test_front_keeps_only_undominated_rows_fastest_first():
    t = _table([(100, 1.0), (50, 0.5), (80, 1.2), (10, 0.4), (50, 0.7)])
    # (80, 1.2) is slower and worse than (100, 1.0); (50, 0.7) worse than (50, 0.5) at equal speed
    assert t.front() == [0, 1, 3]
    assert t.default_on_front()


def test_default_off_front_is_reported():
    t = _table([(100, 1.0), (200, 0.5)], default=0)
    assert t.front() == [1]
    assert not t.default_on_front()
    assert "NOT on the front" in t.format_text()


def test_speed_tolerance_treats_near_equal_speeds_as_equal():
    # 104 vs 100 is within 5 %: the slower but more accurate row stays on the front
    strict = _table([(104, 1.0), (100, 0.9), (100, 1.1)], tol=0.0)
    loose = _table([(104, 1.0), (100, 0.9), (100, 1.1)], tol=0.05)
    assert strict.front() == [0, 1]
    assert loose.front() == [1]


def test_failed_measurement_is_never_on_front_and_serialises_as_null():
    t = _table([(100, 1.0), (math.nan, 0.1)])
    assert t.front() == [0]
    d = json.loads(json.dumps(t.to_dict()))
    assert d["rows"][1]["speed"] is None and d["rows"][1]["on_front"] is False
    assert "failed" in t.format_text()


def test_exactly_one_default_required():
    with pytest.raises(ValueError, match="exactly 1"):
        TradeTable("t", "s", "e", "", [TradeRow({}, 1, 1), TradeRow({}, 2, 2)])
    with pytest.raises(ValueError, match="no rows"):
        TradeTable("t", "s", "e", "", [])


def test_unknown_topic_names_the_known_ones():
    with pytest.raises(ValueError, match="unknown trade topic 'nope'"):
        topic_module("nope")


def test_plot_writes_png(tmp_path):
    path = _table([(100, 1.0), (50, 0.5), (10, 0.4)]).plot(tmp_path / "t.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@given(st.lists(st.tuples(st.floats(0.1, 1e4), st.floats(0.0, 100.0)), min_size=1, max_size=25))
def test_front_is_exactly_the_undominated_set(points):
    t = _table(points)
    front = set(t.front())
    for i, (si, ei) in enumerate(points):
        dominated = any((sj >= si and ej <= ei) and (sj > si or ej < ei)
                        for j, (sj, ej) in enumerate(points) if j != i)
        assert (i in front) == (not dominated)


# -- serialisation, markdown, the default's reason ----------------------------------------------
def _rich_table():
    rows = [TradeRow({"solver": "dct", "ds": 1}, 800.0, 0.14, is_default=True, extra={"normal_deg": 8.1},
                     note="shipped"),
            TradeRow({"solver": "dct", "ds": 2}, 2400.0, 0.13, extra={"normal_deg": 8.0}),
            TradeRow({"solver": "poisson", "ds": 1}, math.nan, 0.10, note="crashed")]
    return TradeTable("demo", "frames_per_s", "height_rms_mm", "30 real presses, 5-fold by press", rows,
                      knobs={"solver": "integration", "ds": "downsample factor"},
                      notes=["speeds on one core"], default_note="registration needs full resolution",
                      conditions={"machine": "cpu", "cores": 2, "usable_cores": 2, "load_1min": 3.5})


def test_dict_round_trip_keeps_everything_and_nan_stays_failed():
    t = _rich_table()
    d = json.loads(json.dumps(t.to_dict(), allow_nan=False))  # strict JSON: no NaN tokens
    back = TradeTable.from_dict(d)
    assert back.to_dict() == t.to_dict()
    assert math.isnan(back.rows[2].speed) and back.default_note == t.default_note
    assert back.conditions["load_1min"] == 3.5
    with pytest.raises(ValueError, match="not a trade table"):
        TradeTable.from_dict({"topic": "x"})


def test_default_off_front_prints_its_reason_or_says_none_given():
    t = _rich_table()
    assert not t.default_on_front()  # ds=2 is faster and more accurate
    assert "NOT on the front: registration needs full resolution" in t.format_text()
    t.default_note = ""
    assert "NOT on the front: no reason given" in t.format_text()


def test_markdown_has_one_row_per_setting_sorted_by_speed_with_marks():
    md = _rich_table().to_markdown()
    rows = [ln for ln in md.splitlines() if ln.startswith("| ") and "`" in ln]
    assert len(rows) == 3
    assert "ds=2" in rows[0] and "**yes**" in rows[0]  # fastest first, on the front
    assert "**D**" in rows[1] and "**yes**" not in rows[1]
    assert "failed" in rows[2]
    assert "The default (solver=dct ds=1), NOT on the front: registration needs full resolution." in md
    assert "Measured on: cpu; 2/2 cores usable; load 3.5" in md
    assert "Pareto front, fastest first: solver=dct ds=2 (2400, 0.13)" in md


def test_setting_must_be_a_mapping():
    with pytest.raises(ValueError, match="mapping"):
        TradeTable("t", "s", "e", "", [TradeRow(["k", 1], 1, 1, is_default=True)])  # type: ignore[arg-type]


def test_groups_have_their_own_front_and_default(tmp_path):
    rows = [TradeRow({"scene": "a", "k": 1}, 100.0, 1.0, is_default=True),
            TradeRow({"scene": "a", "k": 2}, 10.0, 0.1),
            TradeRow({"scene": "a", "k": 3}, 5.0, 0.5),  # dominated within a
            TradeRow({"scene": "b", "k": 1}, 1.0, 5.0),  # slow and bad, but alone in b apart from k=2
            TradeRow({"scene": "b", "k": 2}, 0.5, 9.0, is_default=True)]
    t = TradeTable("g", "rtf", "err", "", rows, group_by="scene", speed_tolerance=0.0)
    # row 3 would be dominated by row 1 in one pool; within group b it leads the front
    assert t.front() == [0, 1, 3]
    assert t.default_indices == [0, 4] and not t.default_on_front()
    text = t.format_text()
    assert "Pareto front of scene=a, fastest first: k=1 [default] (100, 1) → k=2 (10, 0.1)" in text
    assert "Pareto front of scene=b, fastest first: k=1 (1, 5)" in text
    assert "scene=b k=2 NOT on its front" in text
    back = TradeTable.from_dict(json.loads(json.dumps(t.to_dict())))
    assert back.front() == t.front() and back.group_by == "scene"
    assert t.plot(tmp_path / "g.png").is_file()
    with pytest.raises(ValueError, match="group scene='b' marks 2 rows"):
        TradeTable("g", "s", "e", "", rows[:4] + [TradeRow({"scene": "b", "k": 9}, 1, 1, is_default=True),
                                                  rows[4]], group_by="scene")
    with pytest.raises(ValueError, match="has no such knob"):
        TradeTable("g", "s", "e", "", [TradeRow({"k": 1}, 1, 1, is_default=True)], group_by="scene")


@given(st.lists(st.tuples(st.sampled_from("ab"), st.floats(0.1, 1e4), st.floats(0.0, 100.0)), min_size=1,
                max_size=25))
def test_grouped_front_is_the_undominated_set_within_each_group(points):
    groups = sorted({g for g, _, _ in points})
    first = {g: next(i for i, p in enumerate(points) if p[0] == g) for g in groups}
    rows = [TradeRow({"g": g, "k": i}, s, e, is_default=(first[g] == i)) for i, (g, s, e) in enumerate(points)]
    t = TradeTable("t", "s", "e", "", rows, group_by="g", speed_tolerance=0.0)
    front = set(t.front())
    for i, (gi, si, ei) in enumerate(points):
        dominated = any(gj == gi and (sj >= si and ej <= ei) and (sj > si or ej < ei)
                        for j, (gj, sj, ej) in enumerate(points) if j != i)
        assert (i in front) == (not dominated)
